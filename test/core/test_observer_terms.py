"""The endpoint observer on the identified model's nonlinear terms (``plant_terms``): the
hose inversion against the hose's own equation, and the stroke-dependent feed-forward.

The oracle is analytic, not a simulator: the motor position X(t) and the hose deflection d(t)
are chosen as sums of sines, and the pressure force is what the hose equation gives for them,
``F_p = k_s d + b_s d' + c |d'| d' + kappa |d| d``. The observer, fed (X, V, F_p) at 2 kHz,
must return X_e = X + d and V_e = X' + d'.
"""
import math

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core.nonlinear_effects import (PLAUSIBLE, NonlinearEffects, hose_force,
                                                 model_terms)
from seaforce_ros.core.observer import EndpointObserver, hose_deflection, hose_flow
from seaforce_ros.core.params import (ControllerConfig, DahlParams, FeedforwardParams,
                                      PlantParams, PlantTermsParams)
from seaforce_ros.core.errors import InvalidParameterError

DT = 5e-4
TABLE_I = PlantParams()


def _run(plant, terms, x, v, f_p):
    obs = EndpointObserver(plant, FeedforwardParams(), DahlParams(), DT, terms)
    xe = np.empty_like(x)
    ve = np.empty_like(x)
    for k in range(x.size):
        obs.update(float(x[k]), float(v[k]), float(f_p[k]))
        xe[k], ve[k] = obs.position, obs.velocity
    return xe, ve


def _motion(seconds, amp_x, amp_d, w_x, w_d, phase):
    t = np.arange(int(round(seconds / DT))) * DT
    x = amp_x * np.sin(w_x * t)
    v = amp_x * w_x * np.cos(w_x * t)
    d = amp_d * (np.sin(w_d * t + phase) + 0.3 * np.sin(2.7 * w_d * t))
    dd = amp_d * w_d * (np.cos(w_d * t + phase) + 0.81 * np.cos(2.7 * w_d * t))
    return t, x, v, d, dd


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(ks_f=st.floats(0.5, 2.0), bs_f=st.floats(0.5, 2.0),
       doubling=st.floats(*PLAUSIBLE["hose_doubling_flow"]),
       stiffening=st.floats(*PLAUSIBLE["hose_stiffening"]),
       force=st.floats(0.05, 10.0), w_d=st.floats(0.5, 60.0), phase=st.floats(0.0, 6.28))
def test_the_nonlinear_hose_is_inverted(ks_f, bs_f, doubling, stiffening, force, w_d, phase):
    """Any hose of the plausible family (k_s, b_s 0.5x..2x Table I; damping doubling at 1-3
    rad/s of flow; stiffening 10-40 % per N m), any pressure force from 0.05 to 10 N m (a
    free finger to a hard hold), deflection rates to 60 rad/s: the observer's X_e_hat is within
    1 % of the deflection's amplitude and V_e_hat within 2 % of V_e's amplitude after
    50 ms, where the linear observer is off by more (the terms matter)."""
    plant = TABLE_I.scaled(hose_stiffness=ks_f, hose_damping=bs_f)
    effects = NonlinearEffects(hose_damping_rise=1.0 / doubling, hose_stiffening=stiffening)
    terms = model_terms(effects, plant)
    amp_d = hose_deflection(force, plant.hose_stiffness, terms.hose_pressure) / 1.3
    t, x, v, d, dd = _motion(0.6, 0.3, amp_d, 3.0, w_d, phase)
    f_p = np.array([hose_force(a, b, plant.hose_stiffness, plant.hose_damping, effects)
                    for a, b in zip(d, dd)])
    keep = t > 0.05
    xe, ve = _run(plant, terms, x, v, f_p)
    err_x = np.max(np.abs(xe - (x + d))[keep]) / amp_d
    flow_amp = np.max(np.abs(v + dd))
    err_v = np.max(np.abs(ve - (v + dd))[keep]) / flow_amp
    assert err_x < 0.01 and err_v < 0.02, (err_x, err_v)
    lin_x, lin_v = _run(plant, PlantTermsParams(), x, v, f_p)
    lin_err = max(np.max(np.abs(lin_x - (x + d))[keep]) / amp_d,
                  np.max(np.abs(lin_v - (v + dd))[keep]) / flow_amp)
    assert lin_err > max(err_x, err_v), (lin_err, err_x, err_v)


def test_the_static_deflection_and_flow_solve_their_equations():
    for force in (-12.0, -0.3, 0.0, 1e-9, 0.4, 10.0):
        for kappa in (0.0, 5.0, 60.0):
            d = hose_deflection(force, 13.0, kappa)
            assert math.isclose(13.0 * d + kappa * abs(d) * d, force, rel_tol=1e-12,
                                abs_tol=1e-15)
            r = hose_flow(force, 9.2e-3, kappa * 1e-4)
            assert math.isclose(9.2e-3 * r + kappa * 1e-4 * abs(r) * r, force, rel_tol=1e-12,
                                abs_tol=1e-15)


def test_a_steady_force_settles_at_the_true_deflection():
    plant = TABLE_I
    terms = PlantTermsParams(hose_flow=5e-3, hose_pressure=40.0)
    n = 400
    xe, ve = _run(plant, terms, np.zeros(n), np.zeros(n), np.full(n, 8.0))
    d = hose_deflection(8.0, plant.hose_stiffness, 40.0)
    assert math.isclose(xe[-1], d, rel_tol=1e-9) and abs(ve[-1]) < 1e-9
    assert d < 8.0 / plant.hose_stiffness * 0.7         # the stiffening shows


@settings(max_examples=40, deadline=None, derandomize=True)
@given(k2=st.floats(-0.2, 0.2), k3=st.floats(0.0, 1.0), u=st.floats(-0.6, 0.6),
       margin=st.floats(1.0, 3.0), unc=st.floats(0.01, 0.3), stroke=st.floats(0.01, 0.5))
def test_the_feedforward_adds_the_stroke_terms_under_the_margin(k2, k3, u, margin, unc, stroke):
    """F_cmp = s_b b_e V_e + s_k k_e u + s_s (k_2 u^2 + k_3 u^3) with the margin's scales (a
    model whose force falls along the stroke is refused by the config's rule); the model's
    feed-forward (a grasp's) has the terms in full."""
    ke = TABLE_I.endpoint_stiffness
    terms = PlantTermsParams(stroke_asymmetry=k2, stroke_stiffness=k3)
    ff = FeedforwardParams(margin=margin, damping_uncertainty=unc, stiffness_uncertainty=unc,
                           dahl_uncertainty=unc, stroke_uncertainty=stroke)
    if k2 * k2 > 3.0 * ke * k3:
        try:
            ControllerConfig(plant_terms=terms, feedforward=ff)
        except InvalidParameterError as exc:
            assert "plant_terms.stroke_asymmetry" in str(exc)
        else:
            raise AssertionError("a falling diaphragm force was accepted")
        return
    ControllerConfig(plant_terms=terms, feedforward=ff)
    obs = EndpointObserver(TABLE_I, ff, DahlParams(), DT, terms)
    f_p = 0.0
    obs.update(u, 0.0, f_p)
    sb, sk, _ = ff.scales()
    ss = ff.stroke_scale()
    xe = obs.position
    want = (sb * TABLE_I.endpoint_damping * obs.velocity + sk * ke * xe
            + ss * (k2 * xe ** 2 + k3 * xe ** 3))
    assert math.isclose(obs.compensation, want, rel_tol=1e-12, abs_tol=1e-15)
    full = (TABLE_I.endpoint_damping * obs.velocity + ke * xe + k2 * xe ** 2 + k3 * xe ** 3
            + obs.dahl_force)
    assert math.isclose(obs.model_feedforward(), full, rel_tol=1e-12, abs_tol=1e-15)


def test_terms_at_zero_are_the_linear_observer_to_the_bit():
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0, 1e-3, 3000))
    v = np.gradient(x, DT)
    f_p = rng.normal(0, 0.2, 3000)
    a = _run(TABLE_I, PlantTermsParams(), x, v, f_p)
    obs = EndpointObserver(TABLE_I, FeedforwardParams(), DahlParams(), DT)
    for k in range(x.size):
        obs.update(float(x[k]), float(v[k]), float(f_p[k]))
        assert obs.position == a[0][k] and obs.velocity == a[1][k]
