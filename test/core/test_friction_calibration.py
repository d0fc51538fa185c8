"""Friction calibration and adaptation: the fit against an analytic free
endpoint (no simulator), the calibration's branches, recovery after a random drift of the
simulated plant (parameters and |Z| of dob_full_ff at 1 rad/s), and properties over arbitrary
input sequences: the torque never beyond its limit, a non-finite input aborts with zero torque,
adapted values never leave their bounds, no adaptation without excitation."""
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, SensorParams, position_sine,
                               run_closed_loop)
from seaforce_ros.core.analysis import impedance_from_position, magnitude_db
from seaforce_ros.core.control_cycle import ControlCycle
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.friction_calibration import (
    CalibrationGoal, FrictionAdaptation, FrictionCalibration, FrictionFit,
    InvalidCalibrationError, check_calibration_goal, ratio_grid, with_friction)
from seaforce_ros.core.grasp import Grasp, GraspGoal
from seaforce_ros.identification.dahl_model import dahl_force

from helpers.configs import exact_feedforward, unlimited

DT = 5e-4
PLANT = PlantParams.table_i()
DAHL = DahlParams()
CONFIG = ControllerConfig(mode="dob_full_ff")
FAST = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def config(**friction):
    """CONFIG with these ``friction.*``; a calibration range beyond +-1.5 rad widens the joint
    range (``limits``) to +-100 rad with it."""
    wide = friction.get("position_min", 0.0) < -1.5 or friction.get("position_max", 0.0) > 1.5
    base = unlimited(CONFIG) if wide else CONFIG
    return base.replace(friction=dataclasses.replace(CONFIG.friction, **friction))


def free_endpoint(be, ke, fc, sigma, seconds=8.0, amp=0.4, w=2.5, me=PLANT.endpoint_inertia):
    """An analytic free endpoint starting at rest: X_e = A (1 - cos w t) + A/4 (1 - cos 2.3 w
    t), F_p from the endpoint's balance with F_e = 0 (exact derivatives, Dahl along the
    samples)."""
    t = np.arange(int(seconds / DT)) * DT
    x, v, a = (np.zeros_like(t) for _ in range(3))
    for gain, wk in ((amp, w), (0.25 * amp, 2.3 * w)):
        x += gain * (1.0 - np.cos(wk * t))
        v += gain * wk * np.sin(wk * t)
        a += gain * wk * wk * np.cos(wk * t)
    fp = -(me * a + be * v + ke * x + dahl_force(x, sigma, fc))
    return x, fp


def motor_side(xe, fp):
    """Motor X and V under an endpoint path: the hose deflection F_p/(b_s s + k_s) (held
    F_p, exact)."""
    a = math.exp(-PLANT.hose_stiffness / PLANT.hose_damping * DT)
    delta = np.zeros_like(fp)
    for k in range(1, fp.size):
        delta[k] = a * delta[k - 1] + (1.0 - a) * fp[k] / PLANT.hose_stiffness
    x = xe - delta
    return x, np.gradient(x, DT)


def fit_series(x, fp, ratios, skip=2000):
    fit = FrictionFit(PLANT, 1.0, ratios, DT, 30.0)
    for k, (xe, f) in enumerate(zip(x.tolist(), fp.tolist())):
        fit.update(xe, xe, f, record=k >= skip)
    fit.fold()
    return fit.estimate([fit.solve_candidate(k) for k in range(len(ratios))])


# --- the fit against an analytic free endpoint --------------------------------------------
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fit_recovers_an_analytic_endpoint(seed):
    rng = np.random.default_rng(seed)
    be, ke = PLANT.endpoint_damping * rng.uniform(0.5, 2.0), PLANT.endpoint_stiffness * \
        rng.uniform(0.5, 2.0)
    fc, sigma = DAHL.coulomb_force * rng.uniform(0.5, 2.0), DAHL.sigma * rng.uniform(0.6, 1.6)
    est = fit_series(*free_endpoint(be, ke, fc, sigma), ratio_grid(DAHL.sigma /
                                                                    DAHL.coulomb_force))
    assert est.reason == "" and est.sigma_reason == ""
    for value, truth, tol in ((est.endpoint_damping, be, 0.01), (est.endpoint_stiffness, ke, 0.01),
                              (est.coulomb_force, fc, 0.01), (est.sigma, sigma, 0.05)):
        assert value == pytest.approx(truth, rel=tol)
    assert 0 < est.coulomb_force_sigma < 0.05 * fc


def test_fit_reports_a_ratio_outside_its_grid():
    x, fp = free_endpoint(0.03, 0.06, 0.03, 12.8)
    est = fit_series(x, fp, ratio_grid(40.0, span=2.0))     # 20..80 /rad; the truth is 427
    assert "edge of the searched range" in est.sigma_reason


def test_fit_without_motion_is_not_identified():
    fit = FrictionFit(PLANT, 1.0, ratio_grid(400.0), DT, 30.0)
    for _ in range(600):
        fit.update(0.1, 0.1, -0.003)
    fit.fold()
    est = fit.estimate([fit.solve_candidate(k) for k in range(len(fit.ratios))])
    assert est.reason


# --- goals ---------------------------------------------------------------------------------
@pytest.mark.parametrize("field,value,words", [
    ("amplitude", 0.0, "amplitude"), ("amplitude", math.nan, "amplitude"),
    ("speed", -1.0, "speed"), ("speed", 10.0, "max_speed"), ("amplitude", 2.0, "joint range"),
    ("apply", 1, "bool"), ("speed", True, "speed")])
def test_bad_goals_are_rejected_with_the_field(field, value, words):
    goal = CalibrationGoal("pinch", 0.5, 1.0, True)
    setattr(goal, field, value)
    with pytest.raises(InvalidCalibrationError, match=words):
        check_calibration_goal(goal, CONFIG.friction, 0.0)


def test_goal_outside_the_joint_range_from_here_and_too_slow_a_period():
    goal = CalibrationGoal("pinch", 0.5, 1.0, True)
    with pytest.raises(InvalidCalibrationError, match="leaves the joint range"):
        check_calibration_goal(goal, CONFIG.friction, 1.2)
    with pytest.raises(InvalidCalibrationError, match="period"):
        check_calibration_goal(CalibrationGoal("pinch", 0.5, 0.1, True), CONFIG.friction, 0.0)
    check_calibration_goal(goal, CONFIG.friction, 0.0)


def test_reference_starts_and_ends_at_rest_within_the_amplitude():
    cal = FrictionCalibration(CalibrationGoal("pinch", 0.4, 1.2, True), CONFIG, DT)
    t = np.arange(0.0, CONFIG.friction.calibration_duration + 0.01, 1e-3)
    r = np.array([cal.reference(ti) for ti in t])
    assert np.max(np.abs(r[:, 0])) <= 0.4 + 1e-12
    assert np.max(np.abs(r[:, 1])) <= 1.2 * 1.6          # the fades add at most pi/2 w A/w
    assert abs(r[0, 0]) < 1e-12 and abs(r[-1, 0]) < 1e-9 and abs(r[-1, 1]) < 1e-9
    assert np.max(np.abs(np.diff(r[:, 0]))) < 1.2 * 1.6 * 1.01e-3   # continuous


# --- calibration in the simulator -------------------------------------------------------
def z_db(model_cfg, plant, dahl, omega=1.0, amp=0.5):
    """|Z| [dB] of dob_full_ff with the model of ``model_cfg`` and the paper's exact
    feed-forward (no margin: what the model's accuracy buys, which the margin would hide)."""
    period = 2.0 * math.pi / omega
    settle = 3.0
    n = int((settle + period) / DT) + 1
    sim = ChannelSimulator(plant, dahl, dt=DT, seed=1, environment=position_sine(amp, omega))
    rec = run_closed_loop(sim, ChannelController(exact_feedforward(model_cfg,
                                                                   mode="dob_full_ff"), DT), n)
    return magnitude_db(impedance_from_position(rec["f_e"], rec["x_e"], omega, DT, settle))


def calibrate(plant, dahl, cfg=CONFIG, amp=0.5, speed=1.0, apply=True, env=None, seed=2,
              sensors=None):
    sim = ChannelSimulator(plant, dahl, dt=DT, seed=seed, environment=env, sensors=sensors)
    ctl = ChannelController(cfg, DT)
    cal = FrictionCalibration(CalibrationGoal("pinch", amp, speed, apply), cfg, DT)
    n0 = 400
    n = n0 + int((cfg.friction.calibration_duration + 0.2) / DT)
    rec = run_closed_loop(sim, ctl, n, on_switch={n0: lambda s, c: c.request_job(cal)})
    return cal, ctl, rec


DRIFTS = [(1.5, 0.7, 1.5, 1.0)] + [tuple(np.round(r, 3)) for r in np.random.default_rng(
    13).uniform([0.6, 0.6, 0.6, 0.7], [1.6, 1.4, 1.6, 1.4], size=(3, 4))]


@pytest.mark.parametrize("drift", DRIFTS)
def test_calibration_after_drift_recovers_parameters_and_impedance(drift):
    """A worn finger's drift (b_e, F_c +50 %, k_e -30 %) and random ones within physical ranges."""
    fb, fk, ff, fs = drift
    true_plant = PLANT.scaled(endpoint_damping=fb, endpoint_stiffness=fk)
    true_dahl = DahlParams(sigma=DAHL.sigma * fs, coulomb_force=DAHL.coulomb_force * ff)
    cal, ctl, rec = calibrate(true_plant, true_dahl)
    assert cal.outcome == "succeeded", cal.message
    assert cal.applied and cal.old.endpoint_damping == PLANT.endpoint_damping
    new = cal.new
    for value, truth in ((new.endpoint_damping, true_plant.endpoint_damping),
                         (new.endpoint_stiffness, true_plant.endpoint_stiffness),
                         (new.coulomb_force, true_dahl.coulomb_force),
                         (new.sigma, true_dahl.sigma)):
        assert value == pytest.approx(truth, rel=0.10)
    assert ctl.config.plant.endpoint_damping == new.endpoint_damping
    assert ctl.config.dahl.sigma == new.sigma
    assert np.max(np.abs(rec["u"])) <= CONFIG.friction.torque_limit
    z_true = z_db(with_friction(CONFIG, (true_plant.endpoint_damping,
                                         true_plant.endpoint_stiffness,
                                         true_dahl.coulomb_force, true_dahl.sigma)),
                  true_plant, true_dahl)
    z_new = z_db(ctl.config, true_plant, true_dahl)
    assert abs(z_new - z_true) < 2.0
    if drift == DRIFTS[0]:
        z_old = z_db(CONFIG, true_plant, true_dahl)
        assert z_old > z_true + 10.0             # what the drift costs before recalibrating


@pytest.mark.parametrize("offset, known, rest", [(0.04, 0.0, 0.0), (-0.03, -0.01, 0.0),
                                                  (0.02, 0.0, 0.1)])
def test_calibration_finds_the_pressure_sensors_offset(offset, known, rest):
    """The fit's constant is the sensor's offset beyond the one configured (``known``), with
    the spring relaxed at ``feedforward.rest_position``: the calibration applies the sum. A
    rest configured 0.1 rad above the finger's true one (0) reads as k_e x 0.1 less offset --
    the value with which the feed-forward's spring and the finger's agree."""
    cfg = CONFIG.replace(pressure_offset=known, feedforward=dataclasses.replace(
        CONFIG.feedforward, rest_position=rest))
    cal, ctl, _ = calibrate(PLANT, DAHL, cfg, sensors=SensorParams(pressure_offset=offset))
    assert cal.outcome == "succeeded", cal.message
    expected = offset - PLANT.endpoint_stiffness * rest
    assert cal.old.pressure_offset == known
    assert cal.new.pressure_offset == pytest.approx(expected, abs=1.5e-3)
    assert 0.0 < cal.new.pressure_offset_sigma < 1e-3
    assert ctl.config.pressure_offset == cal.new.pressure_offset


def test_calibration_is_bumpless_and_apply_false_keeps_the_model():
    plant = PLANT.scaled(endpoint_damping=1.3)
    cal, ctl, rec = calibrate(plant, DAHL, apply=False)
    assert cal.outcome == "succeeded" and not cal.applied
    assert ctl.config == CONFIG
    jumps = np.abs(np.diff(rec["u"]))
    n0 = 400                                         # the calibration's first sample
    end = n0 + int(CONFIG.friction.calibration_duration / DT) + len(cal.fit.ratios)
    assert jumps[n0 - 1] < 1e-6                      # entry: the first output = the last
    # the end and the mode's re-entry: no step beyond the servo's own sample-to-sample noise
    assert np.max(jumps[end - 5:end + 40]) <= np.max(jumps[n0:end - 100])


@pytest.mark.parametrize("position, stiffness", [(0.2, 0.5), (0.4, 0.2), (0.3, 5.0),
                                                  (0.1, 1.0)])
def test_an_object_in_reach_aborts_the_calibration_nothing_applied(position, stiffness):
    """The model-free contact test: 0.5 N m/rad at 0.2 rad was applied as k_e +109 % before;
    objects 0.2..5 N m/rad reached by 0.1..0.4 rad now abort, with the reason, nothing
    applied, the channel back in its mode."""
    cal, ctl, rec = calibrate(PLANT, DAHL, env=contact_object(position, stiffness, 0.05))
    assert cal.outcome == "aborted" and "in reach of the finger" in cal.message, cal.message
    assert cal.contact_test.upper > cal.contact_test.lower      # the object is above
    assert not cal.applied and ctl.config == CONFIG


def test_free_air_calibrations_pass_the_contact_test_with_room():
    """Free air, plants 0.5x..2x: the contact test stays far below its threshold."""
    rng = np.random.default_rng(4)
    for i in range(3):
        f = np.exp(rng.uniform(-math.log(2.0), math.log(2.0), size=6))
        plant = PLANT.scaled(endpoint_damping=f[0], endpoint_stiffness=f[1],
                             endpoint_inertia=f[2], hose_stiffness=f[3])
        dahl = DahlParams(sigma=DAHL.sigma * f[4], coulomb_force=DAHL.coulomb_force * f[5])
        cal, ctl, rec = calibrate(plant, dahl, seed=i)
        assert 0.0 < cal.contact_test.peak < 0.2, (i, cal.contact_test.peak, cal.message)
        assert "in reach" not in cal.message


def test_an_implausible_result_is_refused_nothing_applied():
    """k_e 0.4x and F_c 2.5x of the model: outside friction.plausible_ratio (2), refused with
    the values named; a wider ratio applies them."""
    plant = PLANT.scaled(endpoint_stiffness=0.4)
    dahl = DahlParams(sigma=DAHL.sigma * 2.5, coulomb_force=DAHL.coulomb_force * 2.5)
    cal, ctl, rec = calibrate(plant, dahl)
    assert cal.outcome == "aborted" and "implausible" in cal.message, cal.message
    assert "k_e" in cal.message and "F_c" in cal.message
    assert not cal.applied and ctl.config == CONFIG
    wide = config(plausible_ratio=3.0)
    cal, ctl, rec = calibrate(plant, dahl, cfg=wide)
    assert cal.outcome == "succeeded" and cal.applied, cal.message


def test_calibration_aborts_on_a_blocked_finger():
    cal, ctl, rec = calibrate(PLANT, DAHL, env=contact_object(0.1, 50.0, 0.1))
    assert cal.outcome == "aborted" and "blocked" in cal.message
    assert not cal.applied and ctl.config == CONFIG
    assert ctl.job is None and ctl.mode == "dob_full_ff"


def test_calibration_aborts_when_the_motion_would_leave_the_joint_range():
    cal, ctl, _ = calibrate(PLANT, DAHL, cfg=config(position_min=-0.2, position_max=1.5),
                            amp=0.5)
    assert cal.outcome == "aborted" and "joint range" in cal.message


def test_cancel_mode_change_reset_and_busy():
    ctl = ChannelController(CONFIG, DT)
    goal = CalibrationGoal("pinch", 0.3, 1.0, True)
    cal = FrictionCalibration(goal, CONFIG, DT)
    ctl.request_job(cal)
    ctl.update(0.0, 0.0, 0.0)
    assert ctl.job is cal and cal.started
    other = FrictionCalibration(goal, CONFIG, DT)
    ctl.request_job(other)
    ctl.update(0.0, 0.0, 0.0)
    assert other.outcome == "aborted" and "busy" in other.message
    cal.request_cancel("goal canceled")
    u = ctl.update(0.0, 0.0, 0.0)
    assert cal.outcome == "canceled" and ctl.job is None
    assert ctl.update(0.0, 0.0, 0.0) == pytest.approx(u)         # back to the mode, bumpless
    # the node ended the goal (no states for state_timeout): aborted in the cycle's thread
    cal = FrictionCalibration(goal, CONFIG, DT)
    ctl.request_job(cal)
    ctl.update(0.0, 0.0, 0.0)
    cal.request_abort("no actuator_state for 0.06 s")
    assert cal.active
    ctl.update(0.0, 0.0, 0.0)
    assert cal.outcome == "aborted" and ctl.job is None and not cal.applied
    assert cal.message == "no actuator_state for 0.06 s, nothing applied"
    for action, words in ((lambda c: c.configure(CONFIG.replace(mode="hold")), "mode set"),
                          (lambda c: c.reset(), "re-initialised")):
        cal = FrictionCalibration(goal, CONFIG, DT)
        ctl.request_job(cal)
        ctl.update(0.0, 0.0, 0.0)
        action(ctl)
        ctl.update(0.0, 0.0, 0.0)
        assert cal.outcome == "aborted" and words in cal.message
    late = FrictionCalibration(goal, CONFIG, DT)
    assert late.withdraw("gave up waiting") and not late.claim()


# --- properties over arbitrary inputs --------------------------------------------------
values = st.one_of(st.floats(allow_nan=True, allow_infinity=True),
                   st.floats(-2.0, 2.0), st.floats(-0.01, 0.01))


@settings(max_examples=150, **FAST)
@given(st.lists(st.tuples(values, values, values, values, values), min_size=1, max_size=60),
       st.floats(1e-3, 10.0), st.floats(1e-3, 10.0))
def test_calibration_torque_bounded_and_non_finite_aborts(samples, limit, max_torque):
    """Invariants: |F_a| <= min(torque_limit, max_torque) always; a non-finite input ends the
    calibration (aborted, with the reason) and every later output is 0."""
    cfg = config(torque_limit=limit, position_min=-100.0,
                 position_max=100.0).replace(max_torque=max_torque)
    cal = FrictionCalibration(CalibrationGoal("p", 0.5, 1.0, True), cfg, DT)
    assert cal.claim()
    bound = min(limit, max_torque)
    u_prev = 0.0
    aborted_at = None
    for i, (x, v, xe, fp, u_in) in enumerate(samples):
        u = cal.update(x, v, xe, xe, fp, u_in if i % 2 else u_prev)
        assert math.isfinite(u) and abs(u) <= bound
        if aborted_at is None and not all(math.isfinite(a) for a in (x, v, xe, fp)) and \
                (i % 2 == 0 or math.isfinite(u_in)):
            aborted_at = i
        if aborted_at is not None and i >= aborted_at:
            assert u == 0.0 and cal.outcome == "aborted"
            assert cal.message
        u_prev = u


@settings(max_examples=40, **FAST)
@given(st.lists(st.tuples(st.floats(-1.0, 1.0), st.floats(-5.0, 5.0), st.floats(-1.0, 1.0)),
                min_size=20, max_size=300), st.floats(0.05, 2.0))
def test_controller_torque_bounded_while_calibrating(samples, limit):
    """Invariant: while a calibration runs, the controller's torque is within its limit."""
    cfg = config(torque_limit=limit, position_min=-100.0, position_max=100.0,
                 max_tracking_error=10.0)
    ctl = ChannelController(cfg, DT)
    cal = FrictionCalibration(CalibrationGoal("p", 0.5, 1.0, True), cfg, DT)
    ctl.request_job(cal)
    for x, v, fp in samples:
        running = ctl.job is not None or not cal.started
        u = ctl.update(x, v, fp)
        if running:
            assert abs(u) <= limit


def _adapt_segments():
    """Segments of (seconds, amplitude [rad], frequency [rad/s], F_p gain, F_p offset, free)."""
    return st.lists(st.tuples(st.floats(0.05, 0.6), st.floats(0.0, 1.0), st.floats(0.1, 20.0),
                              st.floats(-5.0, 5.0), st.floats(-0.5, 0.5), st.booleans()),
                    min_size=1, max_size=5)


@settings(max_examples=40, **FAST)
@given(_adapt_segments(), st.floats(0.0, 2.0))
def test_adapted_values_never_leave_their_bounds(segments, bound):
    """Invariant: whatever the endpoint and pressure do, the adapted b_e, k_e, F_c, sigma stay
    within [v/(1+r), v(1+r)]; the fast adaptation_time lets them reach the bounds."""
    cfg = config(adaptation=True, adaptation_time=0.1, adaptation_bound=bound,
                 min_velocity_excitation=1e-6, min_position_excitation=1e-6)
    ad = FrictionAdaptation(cfg, DT)
    t = 0.0
    for seconds, amp, w, gain, offset, free in segments:
        for _ in range(int(seconds / DT)):
            xe = amp * math.sin(w * t)
            fp = gain * xe + offset * math.cos(3.0 * w * t)
            ad.update(xe, xe, fp, free, 0.0)
            t += DT
            for value, (lo, hi) in zip(ad.values, ad.bounds):
                assert lo <= value <= hi


@settings(max_examples=25, **FAST)
@given(st.floats(0.0, 0.01), st.floats(0.1, 5.0), st.floats(0.0, 1e-3))
def test_no_adaptation_without_excitation(amp, w, noise):
    """Invariant: a motion whose velocity stays below min_velocity_excitation never moves a
    value, and the reason says the excitation is too low."""
    cfg = config(adaptation=True, adaptation_time=0.1, min_velocity_excitation=0.1,
                 min_position_excitation=0.02)
    ad = FrictionAdaptation(cfg, DT)
    start = ad.values
    rng = np.random.default_rng(0)
    for k in range(int(1.0 / DT)):
        xe = amp * math.sin(w * k * DT) if amp * w < 0.05 else 0.0
        ad.update(xe, xe, -0.05 * xe + noise * rng.standard_normal(), True, 0.0)
    assert ad.values == start and not ad.adapting and ad.updates == 0
    assert "excitation too low" in ad.reason


@pytest.mark.parametrize("sigma_factor", [0.6, 1.5])
def test_adaptation_converges_on_a_free_endpoint_and_stops_at_its_bound(sigma_factor):
    """sigma/F_c far outside the adaptation's first three candidates: they move to it."""
    truth = (PLANT.endpoint_damping * 1.3, PLANT.endpoint_stiffness * 0.8,
             DAHL.coulomb_force * 1.3, DAHL.sigma * sigma_factor)
    x, fp = free_endpoint(*truth, seconds=12.0)
    cfg = config(adaptation=True, adaptation_time=1.0)
    ad = FrictionAdaptation(cfg, DT)
    for xe, f in zip(x.tolist(), fp.tolist()):
        ad.update(xe, xe, f, True, 0.0)
    assert ad.updates > 0
    for value, t in zip(ad.values, truth):
        assert value == pytest.approx(t, rel=0.05)
    tight = FrictionAdaptation(config(adaptation=True, adaptation_time=1.0,
                                      adaptation_bound=0.1), DT)
    for xe, f in zip(x.tolist(), fp.tolist()):
        tight.update(xe, xe, f, True, 0.0)
    assert tight.values[0] == pytest.approx(tight.bounds[0][1])   # b_e +30 % > its +10 %
    assert tight.values[2] == pytest.approx(tight.bounds[2][1])


def test_adaptation_ignores_samples_in_contact():
    x, fp = free_endpoint(0.06, 0.05, 0.05, 12.8, seconds=4.0)
    ad = FrictionAdaptation(config(adaptation=True, adaptation_time=0.5), DT)
    start = ad.values
    for xe, f in zip(x.tolist(), fp.tolist()):
        ad.update(xe, xe, f, False, 0.0)
    assert ad.updates == 0 and ad.values == start


def test_controller_adapts_only_in_feedforward_modes():
    for mode, expected in (("dob_full_ff", True), ("hold", False)):
        cfg = config(adaptation=True, adaptation_time=0.2).replace(mode=mode)
        ctl = ChannelController(cfg, DT)
        # the model's own free endpoint, X_e = A/2 (1 - cos w t)^2: from rest, no jerk
        t = np.arange(int(3.0 / DT)) * DT
        w, amp = 3.0, 0.4
        c, s = np.cos(w * t), np.sin(w * t)
        xe = 0.5 * amp * (1.0 - c) ** 2
        fp = -(PLANT.endpoint_inertia * amp * w * w * (c - c * c + s * s)
               + PLANT.endpoint_damping * amp * w * (1.0 - c) * s
               + PLANT.endpoint_stiffness * xe + dahl_force(xe, DAHL.sigma, DAHL.coulomb_force))
        x, v = motor_side(xe, fp)
        for xi, vi, f in zip(x.tolist(), v.tolist(), fp.tolist()):
            ctl.update(xi, vi, f)
        assert (ctl.adaptation.updates > 0) == expected


def test_lost_samples_do_not_bias_the_fit():
    """A late loop answers only the newest state (30 % of the samples never seen, the
    controller told how many periods passed): the fit ramps its inputs over the gap and stays
    as accurate as with every sample (holding the newest biased b_e by +6 %)."""
    plant = PLANT.scaled(endpoint_damping=1.12, endpoint_stiffness=0.83)
    dahl = DahlParams(sigma=10.8, coulomb_force=0.0264)
    truth = (plant.endpoint_damping, plant.endpoint_stiffness, dahl.coulomb_force)
    rng = np.random.default_rng(5)
    cfg = CONFIG.replace(mode="hold")
    sim = ChannelSimulator(plant, dahl, dt=DT, seed=2)
    ctl = ChannelController(cfg, DT)
    cal = FrictionCalibration(CalibrationGoal("pinch", 0.4, 1.0, True), cfg, DT)
    ctl.request_job(cal)
    m, u, steps = sim.measurement(), 0.0, 1
    while cal.active:
        if rng.random() < 0.3:
            m, steps = sim.step(u), steps + 1       # a state this controller never sees
            continue
        u = ctl.update(m.x, m.v, m.f_p, steps)
        steps = 1
        m = sim.step(u)
    assert cal.outcome == "succeeded", cal.message
    for value, t in zip(cal.new[:3], truth):
        assert value == pytest.approx(t, rel=0.015)


def test_reference_waits_while_the_plant_applies_something_else():
    """A command timeout (the cycle calls reenter): the calibration's reference does not
    advance on that sample, so a coasting finger is not left behind."""
    ctl = ChannelController(CONFIG, DT)
    cal = FrictionCalibration(CalibrationGoal("pinch", 0.3, 1.0, True), CONFIG, DT)
    ctl.request_job(cal)
    for _ in range(10):
        ctl.update(0.0, 0.0, 0.0)
    before = cal.progress
    ctl.reenter(0.0)
    ctl.update(0.0, 0.0, 0.0, steps=5)
    assert cal.progress == before
    ctl.update(0.0, 0.0, 0.0)
    assert cal.progress > before


@pytest.mark.parametrize("bad,words", [
    (dict(x=(0.0, math.nan)), "fault latched: non-finite state"),
    (dict(advance=0.2), "no state for"),                         # a stall of the stream
    (dict(fp=(0.0, 2e3)), "fault latched: implausible state")])
def test_the_cycle_aborts_a_calibration_with_the_torque(bad, words):
    """Whatever zeroes a channel's torque in the ControlCycle ends its calibration: aborted
    with the reason, nothing applied, zero torque on that sample."""
    ctrls = [ChannelController(CONFIG, DT) for _ in range(2)]
    cc = ControlCycle(("wrist", "pinch"), ctrls)
    cal = FrictionCalibration(CalibrationGoal("pinch", 0.3, 1.0, True), CONFIG, DT)
    ctrls[1].request_job(cal)
    now, wall = 50.0, 1_800_000_000_000_000_000
    state = dict(x=(0.0, 0.0), v=(0.0, 0.0), fp=(0.0, 0.0), fa=(0.0, 0.0), advance=DT)
    for k in range(1, 30):
        s = {**state, **(bad if k == 29 else {})}
        now += s["advance"]
        wall += int(s["advance"] * 1e9)
        out = cc.step(["wrist", "pinch"], k, wall, list(s["x"]), list(s["v"]), list(s["fp"]),
                      list(s["fa"]), [0, 0], wall, now)
        if k == 20:
            assert cal.started and cal.active
    assert cal.outcome == "aborted" and words in cal.message, cal.message
    assert out.effort[1] == 0.0 and not cal.applied and ctrls[1].job is None


def test_a_grasp_and_a_calibration_never_share_a_channel():
    ctl = ChannelController(CONFIG, DT)
    cal = FrictionCalibration(CalibrationGoal("pinch", 0.3, 1.0, True), CONFIG, DT)
    ctl.request_job(cal)
    ctl.update(0.0, 0.0, 0.0)
    grasp = Grasp(GraspGoal("pinch", 0.3, 0.3, 0.6, False), CONFIG, DT)
    ctl.request_job(grasp)
    ctl.update(0.0, 0.0, 0.0)
    assert grasp.outcome == "aborted" and "friction calibration" in grasp.message
    assert ctl.job is cal
    cal.request_cancel()
    ctl.update(0.0, 0.0, 0.0)
    grasp = Grasp(GraspGoal("pinch", 0.3, 0.3, 0.6, False), CONFIG, DT)
    ctl.request_job(grasp)
    ctl.update(0.0, 0.0, 0.0)
    other = FrictionCalibration(CalibrationGoal("pinch", 0.3, 1.0, True), CONFIG, DT)
    ctl.request_job(other)
    ctl.update(0.0, 0.0, 0.0)
    assert ctl.job is grasp and other.outcome == "aborted" and "busy" in other.message


# --- the model-free contact test (core/sided.py) ------------------------------------------------
def sided_run(force, periods=2, amp=0.4, w=2.0):
    """SidedStiffness over ``periods`` whole periods of ``X = amp sin(w t)`` with
    ``F_p = force(x, v)``."""
    from seaforce_ros.core.sided import SidedStiffness
    test = SidedStiffness(0.005, 0.05, 0.01)
    test.reset(0.0)
    n = int(round(periods * 2 * math.pi / w / DT))
    for k in range(n):
        t = k * DT
        x, v = amp * math.sin(w * t), amp * w * math.cos(w * t)
        test.update(x, force(x, v))
    return test, test.judge()


def test_sided_stiffness_against_analytic_forces():
    """A spring, a damper, Coulomb friction and an offset alike on both sides: k_+ = k_- (the
    quadrature terms cancel over whole periods); a one-sided spring beyond 0.1 rad: k_+ - k_-
    is about its in-phase share (the one offset for both sides takes the rest); a side that
    hardly moved is not judged."""
    symmetric = lambda x, v: 0.02 - 0.06 * x - 0.03 * v - 0.03 * math.copysign(1.0, v)  # noqa
    test, level = sided_run(symmetric)
    assert test.upper == pytest.approx(0.06, abs=1e-3)
    assert test.lower == pytest.approx(0.06, abs=1e-3) and level < 0.05
    one_sided = lambda x, v: symmetric(x, v) - 1.0 * max(0.0, x - 0.1)   # noqa: E731
    test, level = sided_run(one_sided)
    assert test.upper - test.lower > 0.3 and level > 1.0
    from seaforce_ros.core.sided import SidedStiffness
    idle = SidedStiffness(0.005, 0.05, 0.01)
    idle.reset(0.0)
    for k in range(1000):
        idle.update(1e-4 * math.sin(k * 0.01), 0.0)
    assert idle.judge() == 0.0 and math.isnan(idle.upper)


@pytest.mark.parametrize("stiffening, asymmetry", [(0.3, 0.1), (0.2, -0.05)])
def test_calibration_fits_the_linear_part_beside_the_models_stroke_terms(stiffening, asymmetry):
    """A diaphragm force rising at the stroke's ends (the sim's nonlinear plant, 20-30 % at
    0.5 rad), the model holding those stroke terms (``plant_terms``): the calibration fits
    b_e and k_e beside them -- k_e within 5 % of the plant's linear k_e, where a fit that
    ignored them took the stiffening into k_e (more than 5 % high), which the feed-forward,
    adding the terms, would then count twice."""
    from seaforce_ros.core.nonlinear_effects import NonlinearEffects, model_terms
    from seaforce_ros.core.nonlinear_simulator import NonlinearChannelSimulator
    effects = NonlinearEffects(stroke_stiffening=stiffening, stroke_asymmetry=asymmetry)
    terms = model_terms(effects, PLANT)
    results = {}
    for name, cfg in (("with", CONFIG.replace(plant_terms=terms)), ("without", CONFIG)):
        sim = NonlinearChannelSimulator(PLANT, DAHL, effects, dt=DT, seed=2)
        ctl = ChannelController(cfg, DT)
        cal = FrictionCalibration(CalibrationGoal("pinch", 0.5, 1.0, False), cfg, DT)
        n0 = 400
        n = n0 + int((cfg.friction.calibration_duration + 0.2) / DT)
        run_closed_loop(sim, ctl, n, on_switch={n0: lambda s, c, cal=cal: c.request_job(cal)})
        assert cal.outcome == "succeeded", (name, cal.message)
        results[name] = cal.new.endpoint_stiffness / PLANT.endpoint_stiffness - 1.0
    assert abs(results["with"]) < 0.05, results
    assert results["without"] > 0.05, results
