"""ChannelController: modes, bumpless switching, faults, estimates."""

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, MODES, NonFiniteInputError, PlantParams,
                               SensorParams, position_sine, run_closed_loop, torque_sine)
from seaforce_ros.core.analysis import hold_margins, impedance_from_position
from seaforce_ros.core.params import (DEFAULT_HOLD_DAMPING, DEFAULT_HOLD_STIFFNESS, ChirpParams,
                                      ForceFeedbackParams, TargetParams)

from helpers.configs import exact_feedforward, unlimited

TABLE_I = PlantParams.table_i()
DT = 5e-4
PRESSURE_NOISE = SensorParams().pressure_noise


def switch_to(mode):
    return lambda sim, ctl: ctl.configure(ctl.config.replace(mode=mode))


def _free_finger(config, sensors, samples, change=None):
    """X_e of a free finger (Table I, exact model) under ``config`` for ``samples``; at the
    middle sample ``change`` (a config) is configured. Returns (X_e, V_e_hat, torque)."""
    ctl = ChannelController(config, DT)
    sim = ChannelSimulator(TABLE_I, DahlParams(), sensors=sensors)
    m = sim.measurement()
    out = np.empty((samples, 3))
    for k in range(samples):
        if change is not None and k == samples // 2:
            ctl.configure(change)
        u = ctl.update(m.x, m.v, m.f_p)
        out[k] = sim.state[2], ctl.endpoint_velocity_estimate, u
        m = sim.step(u)
    return out


@pytest.mark.parametrize("offset", [-0.05, 0.02])
def test_a_pressure_offset_the_controller_knows_leaves_a_free_finger_still(offset):
    """With the offset unknown the DOB pushes the finger with it (it makes the measured F_p
    vanish, so the hose pushes the endpoint with the offset, and dob_full_ff cancels most of
    the finger's stiffness: it slides away); known, the finger stays where it rested."""
    sensors = SensorParams(pressure_offset=offset)
    unknown = _free_finger(ControllerConfig(mode="dob_full_ff"), sensors, 6000)
    known = _free_finger(ControllerConfig(mode="dob_full_ff", pressure_offset=offset), sensors,
                         6000)
    assert np.max(np.abs(unknown[:, 0])) > 0.1
    assert np.sign(unknown[-1, 0]) == np.sign(offset)
    assert np.max(np.abs(known[:, 0])) < 1e-3


def test_a_new_pressure_offset_is_taken_up_without_a_spike():
    """A changed offset moves the hose inversion's state with it: no jump of V_e_hat (a step
    of F_p would read as flow, 0.05 N m / b_s = 5 rad/s) and no torque step."""
    config = ControllerConfig(mode="dob_full_ff")
    run = _free_finger(config, SensorParams(pressure_noise=0.0), 2000,
                       change=config.replace(pressure_offset=0.05))
    around = slice(1000 - 5, 1000 + 5)          # (the finger then moves: it is pushed)
    assert np.max(np.abs(np.diff(run[around, 1]))) < 0.05      # (3.9 without the shift)
    assert np.max(np.abs(np.diff(run[around, 2]))) < 0.01      # a ramp (a step of 0.039)


@pytest.mark.parametrize("start", ["passive", "dob", "hold", "dob_full_ff"])
def test_bumpless_switching_at_rest(start):
    """At rest against a static load (endpoint held at 0.5 rad), every switch
    between active modes changes the torque by less than the pressure-sensor
    noise, although the holding torque is mostly 100x larger."""
    env = position_sine(0.0, 0.0, offset=0.5)       # static position drive
    # every active mode, then back to the start ("passive" is the immediate safe
    # state by design, tested separately)
    targets = [m for m in MODES if m not in ("passive", start)] + ([start] if start != "passive" else [])
    sim = ChannelSimulator(TABLE_I, DahlParams(), seed=11, environment=env)
    # the finger at the drive's set point from the start (a jerk from 0 to 0.5 rad at
    # 25 rad/s would trip the runaway monitor)
    sim.reset(state=(0.5, 0.0, 0.5, 0.0))
    ctl = ChannelController(ControllerConfig(mode="dob"))
    hooks = {3000: switch_to(start)}
    k0, period = 6000, 2000
    for j, mode in enumerate(targets):
        hooks[k0 + j * period] = switch_to(mode)
    rec = run_closed_loop(sim, ctl, k0 + len(targets) * period + 10, on_switch=hooks)
    u = rec["u"]
    holdings = []
    for j, mode in enumerate(targets):
        k = k0 + j * period
        holdings.append(abs(u[k - 1]))
        assert abs(u[k] - u[k - 1]) <= PRESSURE_NOISE, (start, mode)
        # (afterwards the torque moves continuously to the new mode's own
        # equilibrium, e.g. the DOB makes F_p track -F_ref within ~1/lambda)
    # most switches happen while holding a torque far above the noise (from
    # "passive", hold/force feedback keep the passive equilibrium: ~0 torque)
    assert np.mean(np.array(holdings) > 100 * PRESSURE_NOISE) >= 0.5, holdings


def test_off_is_immediate_zero_torque():
    sim = ChannelSimulator(TABLE_I, None, environment=position_sine(0.0, 0.0, offset=0.5))
    sim.reset(state=(0.5, 0.0, 0.5, 0.0))       # at the drive's set point (no jerk)
    ctl = ChannelController(ControllerConfig(mode="dob"))
    rec = run_closed_loop(sim, ctl, 3000, on_switch={2000: switch_to("passive")})
    assert abs(rec["u"][1999]) > 0.05
    assert np.all(rec["u"][2000:] == 0.0)


def test_configure_takes_effect_at_next_update():
    ctl = ChannelController(ControllerConfig(mode="passive"))
    ctl.update(0.0, 0.0, 0.1)
    ctl.configure(ControllerConfig(mode="force_feedback",
                                   force_feedback=ForceFeedbackParams(gain=0.5)))
    assert ctl.mode == "passive" and ctl.config.mode == "passive"
    u = ctl.update(0.0, 0.0, 0.1)
    assert ctl.mode == "force_feedback"
    assert u == pytest.approx(0.0)          # bumpless entry from 0
    for _ in range(2000):                   # the transfer offset decays (50 ms)
        u = ctl.update(0.0, 0.0, 0.1)
    assert u == pytest.approx(0.05, abs=1e-6)


@pytest.mark.parametrize("bad", [(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0),
                                 (0.0, 0.0, -math.inf)])
def test_non_finite_input_raises_and_changes_nothing(bad):
    """The controller computes, it does not judge: a non-finite input raises (naming it) and
    leaves the state alone; latching is ControlCycle's job (test_control_cycle.py)."""
    ctl = ChannelController(ControllerConfig(mode="dob"))
    twin = ChannelController(ControllerConfig(mode="dob"))
    for c in (ctl, twin):
        assert c.update(0.0, 0.0, 0.2) == 0.0            # bumpless start from rest
    with pytest.raises(NonFiniteInputError) as info:
        ctl.update(*bad)
    assert info.value.name == ("x", "v", "f_p")[[math.isfinite(b) for b in bad].index(False)]
    for _ in range(5):
        assert ctl.update(0.01, 0.1, 0.2) == twin.update(0.01, 0.1, 0.2) != 0.0


@pytest.mark.parametrize("mode", [m for m in MODES if m != "passive"])
def test_reset_and_reenter_start_from_the_applied_torque(mode):
    """After reset(applied) or reenter(applied) the next output equals the applied torque,
    in every active mode and whatever the controller did before (no step)."""
    ctl = ChannelController(ControllerConfig(
        mode=mode, chirp=ChirpParams(amplitude=0.2), force_feedback=ForceFeedbackParams(gain=0.5)))
    rng = np.random.default_rng(3)
    for k in range(400):
        ctl.update(0.01 * math.sin(0.01 * k), 0.1 * math.cos(0.01 * k), 0.3)
    for applied in (0.0, -1.7, 2.4):
        x, v, fp = rng.normal(size=3) * (0.1, 1.0, 0.5)
        ctl.reenter(applied)
        assert ctl.update(x, v, fp) == pytest.approx(applied, abs=1e-12)
        ctl.reset(applied)
        assert ctl.update(x, v, fp) == pytest.approx(applied, abs=1e-12)
        # and it continues smoothly from there: the next sample moves by far less than a
        # newton metre (hold: K_p * 0 motion, DOB: lambda * dt * error)
        assert abs(ctl.update(x, v, fp) - applied) < 0.2


def test_hold_reset_recaptures_reenter_keeps_the_target():
    """reset() (a new plant, a re-armed channel, a long interruption) holds where the finger
    is now; reenter() (the plant cut the torque for a moment) keeps the target and ramps back
    to it in ~50 ms: no step either way."""
    ctl = ChannelController(ControllerConfig(mode="hold"))
    ctl.update(0.0, 0.0, 0.0)
    held = ctl.update(0.01, 0.0, 0.0)
    assert held < -1.0                                     # pushed away: resists
    ctl.reenter(0.0)
    assert ctl.update(0.01, 0.0, 0.0) == 0.0               # no step
    ramp = [ctl.update(0.01, 0.0, 0.0) for _ in range(1000)]
    assert all(a >= b for a, b in zip(ramp, ramp[1:]))     # monotonic, no overshoot
    assert abs(ramp[99] - held) == pytest.approx(abs(held) * math.exp(-100 * DT / 0.05),
                                                 rel=1e-6)
    assert ramp[-1] == pytest.approx(held, rel=1e-3)       # back at the old target
    ctl.reset(0.0)
    assert ctl.update(0.05, 0.0, 0.0) == 0.0               # a new target here
    assert ctl.update(0.05, 0.0, 0.0) == 0.0
    assert ctl.update(0.051, 0.0, 0.0) < 0.0


def test_dob_matches_integral_form_eq19():
    """F_a = (lambda/s)(F_p - m_n s V) for a ramp F_p with V = 0: the output is
    lambda * integral(F_p) by the trapezoidal rule."""
    cfg = ControllerConfig(mode="dob")
    ctl = ChannelController(cfg)
    lam = cfg.dob.cutoff
    fp = np.linspace(0.0, 0.1, 401)
    outs = [ctl.update(0.0, 0.0, float(f)) for f in fp]
    expected = lam * np.concatenate([[0.0], np.cumsum(0.5 * (fp[1:] + fp[:-1]) * DT)])
    np.testing.assert_allclose(outs, expected, atol=1e-12)
    # the velocity term is proportional: -lambda m_n V
    ctl.reset()
    ctl.update(0.0, 0.0, 0.0)
    assert ctl.update(0.0, 2.0, 0.0) == pytest.approx(-lam * TABLE_I.motor_inertia * 2.0)


def test_endpoint_state_estimate_tracks_truth():
    sim = ChannelSimulator(TABLE_I, DahlParams(), environment=torque_sine(0.3, 6.0))
    ctl = ChannelController(ControllerConfig(mode="passive"))
    rec = run_closed_loop(sim, ctl, 12000)
    late = slice(4000, None)
    ve_err = rec["endpoint_velocity_estimate"][late] - rec["v_e_true"][late]
    ve_amp = np.max(np.abs(rec["v_e_true"][late]))
    assert ve_amp > 0.5
    assert np.sqrt(np.mean(ve_err ** 2)) < 0.1 * ve_amp
    assert np.all(np.isfinite(rec["feedforward"]))
    assert np.all(np.isnan(rec["disturbance"]))          # not a DOB mode
    assert np.max(np.abs(rec["dahl_force"])) <= DahlParams().coulomb_force


def test_endpoint_position_estimate_tracks_truth():
    sim = ChannelSimulator(TABLE_I, None, environment=position_sine(0.5, 1.0))
    ctl = ChannelController(ControllerConfig(mode="dob"))
    xs, xt = [], []
    m = sim.measurement()
    for _ in range(8000):
        u = ctl.update(m.x, m.v, m.f_p)
        xs.append(ctl.endpoint_position_estimate)
        xt.append(sim.state[2])
        m = sim.step(u)
    assert np.max(np.abs(np.array(xs) - np.array(xt))[2000:]) < 5e-4


def test_feedforward_sign_drives_external_force_to_zero():
    """With the linear feed-forward (no hysteresis in the plant), F_e is much
    smaller than with the DOB alone -- a sign error would double it."""
    peaks = {}
    for mode in ("dob", "dob_linear_ff"):
        sim = ChannelSimulator(TABLE_I, None, environment=position_sine(0.5, 1.0))
        rec = run_closed_loop(sim, ChannelController(ControllerConfig(mode=mode)), 20000)
        peaks[mode] = np.max(np.abs(rec["f_e"][8000:]))
    # (the default margin leaves 20 % of k_e and b_e, and the free finger's damping reserve
    # adds to them; a sign error would give more than 1)
    assert peaks["dob_linear_ff"] < 0.4 * peaks["dob"]


def test_hold_is_stiff():
    sim = ChannelSimulator(TABLE_I, None, environment=position_sine(0.0, 0.0, offset=0.05))
    ctl = ChannelController(ControllerConfig(mode="hold"))
    rec = run_closed_loop(sim, ctl, 6000)
    # the hose force k_s * 0.05 is resisted by K_p: motor deflection ~ F_p/K_p
    x_final = rec["x_true"][-1]
    fp_final = rec["f_p_true"][-1]
    assert fp_final == pytest.approx(0.05 * TABLE_I.hose_stiffness * 150 / 163, rel=0.05)
    assert abs(x_final) == pytest.approx(abs(fp_final) / DEFAULT_HOLD_STIFFNESS, rel=0.05)


def test_default_hold_gains_have_margin_and_are_near_maximal():
    for endpoint in ("free", "clamped"):
        m = hold_margins(TABLE_I, DEFAULT_HOLD_STIFFNESS, DEFAULT_HOLD_DAMPING,
                         endpoint=endpoint)
        assert m.stable and m.modulus_margin >= 0.5
        assert m.gain_margin_db >= 6.0 and m.phase_margin_deg >= 29.0
        twice = hold_margins(TABLE_I, 2 * DEFAULT_HOLD_STIFFNESS, DEFAULT_HOLD_DAMPING,
                             endpoint=endpoint)
        assert twice.modulus_margin < 0.5
    unstable = hold_margins(TABLE_I, 20 * DEFAULT_HOLD_STIFFNESS, DEFAULT_HOLD_DAMPING)
    assert not unstable.stable


def test_impedance_mode_renders_target():
    kt, bt, w = 2.0, 0.05, 1.0
    sim = ChannelSimulator(TABLE_I, DahlParams(), environment=position_sine(0.2, w))
    ctl = ChannelController(ControllerConfig(mode="impedance",
                                             target=TargetParams(stiffness=kt, damping=bt)))
    rec = run_closed_loop(sim, ctl, int((3.0 + 2 * 2 * math.pi / w) / DT))
    z = impedance_from_position(rec["f_e"], rec["x_e"], w, DT, 3.0)
    target = kt / (1j * w) + bt
    assert abs(z - target) < 0.03 * abs(target)


def test_chirp_mode_output():
    cfg = ControllerConfig(mode="chirp", chirp=ChirpParams(
        amplitude=0.2, start_frequency=1.0, end_frequency=100.0, duration=2.0))
    ctl = ChannelController(cfg)
    u = np.array([ctl.update(0.0, 0.0, 0.0) for _ in range(4400)])
    assert u[0] == 0.0 and np.max(np.abs(u)) <= 0.2 + 1e-12
    assert np.max(np.abs(u[:4000])) > 0.19
    assert np.all(u[4000:] == 0.0)                     # after the duration
    # frequency rises: more zero crossings in the second second than in the first
    zc = lambda x: np.count_nonzero(np.diff(np.sign(x)) != 0)
    assert zc(u[2000:4000]) > 5 * zc(u[:2000])


def test_impedance_mode_at_its_limits_is_stable_with_free_endpoint():
    from seaforce_ros.core import free
    cfg = ControllerConfig(mode="impedance", target=TargetParams(
        stiffness=TABLE_I.hose_stiffness, damping=10 * TABLE_I.hose_damping), max_torque=100.0)
    sim = ChannelSimulator(TABLE_I, DahlParams(), environment=free())
    rec = run_closed_loop(sim, ChannelController(cfg), 12000)
    assert np.max(np.abs(rec["u"][-4000:])) < 0.1       # noise-level, not diverging
    assert np.max(np.abs(rec["x_true"][-4000:])) < 1e-3


@pytest.mark.parametrize("every", [4, 16])
def test_updates_every_nth_sample_integrate_the_real_elapsed_time(every):
    """A loop that answers only every n-th state (a late controller takes the newest state
    only) must integrate over n sample periods: the hose inversion over n dt, the DOB
    integrator over n dt. With ``steps`` the sparse controller stays close to the one that
    sees every sample; treating the gap as one dt overestimates V_e_hat by ~n (at n = 16 the
    peak torque more than doubles). (The runaway monitor would catch that defect: the
    comparison runs without it.)"""
    def run(steps_aware):
        sim = ChannelSimulator(TABLE_I, DahlParams(), seed=5,
                               environment=position_sine(0.5, 1.0), torque_saturation=20.0)
        ctl = ChannelController(unlimited(exact_feedforward(mode="dob_full_ff")))
        m = sim.measurement()
        u, peak = 0.0, 0.0
        for k in range(8000):                         # 4 s
            if k % every == 0:
                u = ctl.update(m.x, m.v, m.f_p, every if steps_aware and k else 1)
            peak = max(peak, abs(u)) if k > 2000 else peak
            m = sim.step(u)
        return peak
    dense = ChannelSimulator(TABLE_I, DahlParams(), seed=5,
                             environment=position_sine(0.5, 1.0), torque_saturation=20.0)
    ref = run_closed_loop(dense, ChannelController(unlimited(exact_feedforward(mode="dob_full_ff"))),
                          8000)
    ref_peak = np.max(np.abs(ref["u"][2000:]))
    aware = run(True)
    assert aware < 2.0 * ref_peak + 0.05, (aware, ref_peak)
    if every == 16:
        assert run(False) > 1.8 * aware          # the defect the steps argument removes


def test_chirp_plays_once_per_selection_never_again_by_itself():
    """An identification chirp that ended (or was interrupted) must not replay after a
    plant-side stop or a reset: an open-loop torque nobody asked for again."""
    cfg = ControllerConfig(mode="chirp", chirp=ChirpParams(
        amplitude=0.3, duration=0.2, start_frequency=5.0, end_frequency=50.0))
    ctl = ChannelController(cfg)
    played = [ctl.update(0.0, 0.0, 0.0) for _ in range(600)]     # 0.3 s: the whole chirp
    assert max(map(abs, played)) > 0.2 and played[-1] == 0.0
    for restart in (ctl.reenter, ctl.reset):
        restart(0.0)
        assert max(abs(ctl.update(0.0, 0.0, 0.0)) for _ in range(600)) == 0.0
    # interrupted half-way: over as well
    ctl.configure(cfg, mode_set=True)
    head = [ctl.update(0.0, 0.0, 0.0) for _ in range(200)]
    assert max(map(abs, head)) > 0.1
    ctl.reenter(0.05)
    assert all(ctl.update(0.0, 0.0, 0.0) == 0.05 for _ in range(600))
    # a parameter set within the mode does not replay it ...
    ctl.configure(cfg.replace(hold=dataclasses.replace(cfg.hold, stiffness=22.0)))
    assert all(ctl.update(0.0, 0.0, 0.0) == 0.05 for _ in range(600))
    # ... selecting the mode again (``<channel>.mode`` set, even to chirp) plays it again
    ctl.configure(cfg, mode_set=True)
    assert max(abs(ctl.update(0.0, 0.0, 0.0)) for _ in range(600)) > 0.2


# --- parameter sets within a mode ---------------------------------------------------------------
#: Sets of a channel's parameters that leave its mode alone: (name, new config from the old).
WITHIN = {
    "hold gains": lambda c, r: c.replace(hold=dataclasses.replace(
        c.hold, stiffness=float(r.uniform(5.0, 40.0)))),
    "target": lambda c, r: c.replace(target=TargetParams(
        stiffness=float(r.uniform(0.0, 2.0)), damping=float(r.uniform(0.0, 0.05)))),
    "max torque": lambda c, r: c.replace(max_torque=float(r.uniform(15.0, 25.0))),
    # the chirp's own values: a running chirp goes on with those it was selected with
    "chirp": lambda c, r: c.replace(chirp=ChirpParams(
        amplitude=float(r.uniform(0.05, 3.0)), start_frequency=float(r.uniform(1.0, 5.0)),
        end_frequency=float(r.uniform(6.0, 80.0)), duration=float(r.uniform(0.05, 0.5)))),
    "the same values again": lambda c, r: c,
}


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mode=st.sampled_from(["chirp", "impedance", "hold"]),
       sets=st.lists(st.tuples(st.integers(1, 500), st.sampled_from(sorted(WITHIN))),
                     min_size=1, max_size=6),
       seed=st.integers(0, 2 ** 16))
def test_parameter_sets_within_a_mode_keep_what_its_selection_captured(mode, sets, seed):
    """Invariant: parameters set without the mode (whichever, however often, whenever) never
    select the mode anew. The chirp's torque is, sample for sample, a twin's that saw no set
    -- once its duration has passed since the selection it is u_0 and stays so (a set once
    replayed it, or restarted it with the torque of that instant as u_0, left on after it);
    ``hold``'s set point and ``impedance``'s rest position stay where the selection captured
    them (a set once moved the spring's rest to where the finger was pushed). On a plant drawn
    0.5x..2x of Table I, the finger driven 0.3 rad at 5 rad/s (free under the chirp)."""
    rng = np.random.default_rng(seed)
    plant = TABLE_I.scaled(**{k: float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
                              for k in ("motor_inertia", "endpoint_inertia", "endpoint_damping",
                                        "endpoint_stiffness", "hose_stiffness")})
    chirp = ChirpParams(amplitude=0.3, start_frequency=2.0, end_frequency=40.0, duration=0.2)
    config = ControllerConfig(mode=mode, chirp=chirp)
    env = None if mode == "chirp" else position_sine(0.3, 5.0)
    sim = ChannelSimulator(plant, DahlParams(), seed=seed, environment=env)
    ctl, twin = ChannelController(config), ChannelController(config)
    when, k = {}, 0
    for gap, kind in sets:
        k += gap
        when.setdefault(k, []).append(kind)
    captured = None
    for k in range(2600):
        for kind in when.get(k, ()):
            ctl.configure(WITHIN[kind](ctl.config, rng))
        m = sim.measurement()
        u = ctl.update(m.x, m.v, m.f_p)
        u_twin = twin.update(m.x, m.v, m.f_p)
        if mode == "chirp":
            assert u == u_twin, (k, u, u_twin)
            if k * DT > chirp.duration:
                assert u == 0.0, (k, u)
        else:
            x0 = ctl._modes[mode]._x0        # what the selection captured
            captured = x0 if captured is None else captured
            assert x0 == captured, (k, x0, captured)
        sim.step(u)
