"""The oracle with the real gripper's nonlinearities (:mod:`helpers.nonlinear_sim`) against
closed forms, so that what it says of the project is worth something:

* every effect off, no hysteresis: the passive backdrive's |F_e/V_e| is the model's analytic
  endpoint impedance (:func:`helpers.second_sim.transfer_functions`) on plants drawn 0.5x..2x,
  with no distortion;
* the quasi-static force of a slow backdrive (0.5 rad/s, within 0.5 % of its peak) (the mean of the up and down strokes, which
  cancels the rate terms) is the static equilibrium solved apart (scipy's brentq) with the
  diaphragm's stroke stiffness, the finger ratio, the hose's pressure stiffening and the
  cogging drawn on; without them it would be the linear one, 8-20 % away;
* the hose's flow-dependent damping b_s V (1 + |V|/q_2), the motor held still: the damping of
  the fundamental is b_e + b_s (1 + 8 V_0/(3 pi q_2)) and the 3rd and 5th harmonics are
  b_s V_0^2/q_2 times 8/(15 pi) and 8/(105 pi);
* the Dahl force on a fast path (20 rad/s, sigma 2x and F_c 0.5x of the paper's: its
  relaxation rate sigma |X_e'|/F_c is 32,000 /s) is the closed form over each sample, within
  +-F_c (with a fixed 2 substeps RK4 left its stability region there and the oracle diverged:
  seed 52584 of the compensation test);
* every effect on, under the project's controller: over a period the work of the finger's
  force and of the motor's torque is what the losses took (the integration keeps energy);
* the draws stay in the stated ranges, and an effect switched off is off;
* the drawn sensors (a real rig's: encoder, the drive's velocity filter, the pressure ADC with
  its noise and offset, extra delay) report what they say.
"""
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from helpers.nonlinear_sim import (EFFECTS, RANGES, SENSOR_RANGES, STROKE, Effects,
                                   NonlinearGripper, SinePath, draw_sensors, Unpowered, actuator_position, backdrive, diaphragm_force, draw_effects,
                                   finger_position, hose_force, linear_counterpart, ratio)
from helpers.second_sim import DAHL, TABLE_I, transfer_functions
from seaforce_ros.core.analysis import impedance_figures

EXACT = dict(pressure_noise=0.0, pressure_bits=0, motor_counts=0, finger_counts=0)


def _plant(rng, low=0.5, high=2.0):
    return {k: v * math.exp(rng.uniform(math.log(low), math.log(high)))
            for k, v in TABLE_I.items()}


@pytest.mark.parametrize("seed", range(3))
def test_without_effects_it_is_the_linear_model(seed):
    rng = np.random.default_rng(seed)
    plant = _plant(rng)
    for omega in (2.0, 10.0):
        rec = backdrive(plant, None, Effects(), Unpowered(), 0.3, omega, periods=1, **EXACT)
        fig = impedance_figures(rec["f_e"], rec["x_e"], omega, rec["dt"])
        z = 1.0 / (1j * omega * transfer_functions(plant, [omega])["D"][0])
        assert abs(fig.z / z - 1.0) < 2e-3, omega
        assert fig.distortion < 1e-3


def _static_force(q, plant, effects):
    """F_q at rest at finger position q: the motor in equilibrium with the hose (brentq)."""
    xe = actuator_position(q, effects)

    def motor(x):
        cog = effects.cogging * math.sin(effects.cogging_periods * x + effects.cogging_phase)
        return plant["motor_stiffness"] * x + cog - hose_force(xe - x, 0.0, plant, effects)
    x = brentq(motor, -3.0, 3.0, xtol=1e-14)
    return ratio(q, effects) * (diaphragm_force(xe, plant, effects)
                                + hose_force(xe - x, 0.0, plant, effects))


@pytest.mark.parametrize("seed", range(2))
def test_quasi_static_force_is_the_static_equilibrium(seed):
    rng = np.random.default_rng(10 + seed)
    plant = _plant(rng, 0.7, 1.4)
    effects = draw_effects(rng, ("hose_pressure", "stroke_stiffness", "finger_ratio",
                                 "cogging"))
    omega = 0.5
    rec = backdrive(plant, None, effects, Unpowered(), STROKE, omega, periods=1, settle=1.0,
                    **EXACT)
    q, f = rec["x_e"], rec["f_e"]
    up = np.gradient(q) > 0
    grid = np.linspace(-0.9 * STROKE, 0.9 * STROKE, 25)
    mean = 0.5 * sum(np.interp(grid, q[sel][np.argsort(q[sel])], f[sel][np.argsort(q[sel])])
                     for sel in (up, ~up))
    static = np.array([_static_force(g, plant, effects) for g in grid])
    linear = np.array([_static_force(g, plant, linear_counterpart(effects)) for g in grid])
    scale = np.max(np.abs(static))
    assert np.max(np.abs(mean - static)) < 5e-3 * scale
    assert np.max(np.abs(linear - static)) > 0.03 * scale       # the effects are there


@pytest.mark.parametrize("seed", range(2))
def test_flow_dependent_hose_damping_has_its_describing_function(seed):
    rng = np.random.default_rng(20 + seed)
    plant = dict(_plant(rng), motor_inertia=1e9, motor_damping=0.0, motor_stiffness=0.0)
    effects = draw_effects(rng, ("hose_flow",))
    q2 = effects.hose_flow
    omega, amplitude = float(rng.uniform(2.0, 5.0)), 0.4
    rec = backdrive(plant, None, effects, Unpowered(), amplitude, omega, periods=2,
                    settle=1.0, **EXACT)
    fig = impedance_figures(rec["f_e"], rec["x_e"], omega, rec["dt"])
    v0, bs = amplitude * omega, plant["hose_damping"]
    damping = plant["endpoint_damping"] + bs * (1.0 + 8.0 * v0 / (3.0 * math.pi * q2))
    assert fig.z.real == pytest.approx(damping, rel=1e-3)
    assert fig.harmonics[2] == pytest.approx(bs * v0 ** 2 / q2 * 8.0 / (15.0 * math.pi),
                                             rel=1e-3)
    assert fig.harmonics[4] == pytest.approx(bs * v0 ** 2 / q2 * 8.0 / (105.0 * math.pi),
                                             rel=1e-2)


def _dahl_after(fd, dx, sigma, fc):
    """The Dahl force (n = 1) after a monotone move dx from fd: the closed form of eq. 14-15."""
    if dx > 0.0:
        return fc - (fc - fd) * math.exp(-sigma * dx / fc)
    return -fc + (fc + fd) * math.exp(sigma * dx / fc)


def test_the_dahl_force_on_a_fast_path_is_its_closed_form():
    dahl = {"sigma": 2.0 * DAHL["sigma"], "coulomb_force": 0.5 * DAHL["coulomb_force"]}
    sigma, fc = dahl["sigma"], dahl["coulomb_force"]
    amplitude, omega = 0.5, 40.0                # 20 rad/s at the centre
    g = NonlinearGripper(TABLE_I, dahl, Effects(), SinePath(amplitude, omega), **EXACT)
    xe, fd = g.state[2], g.state[4]
    checked = 0
    for _ in range(int(2 * 2 * math.pi / omega / g.dt)):
        t0 = g.t
        g.step(0.0)
        xe_new, fd_new = g.state[2], g.state[4]
        assert abs(fd_new) <= fc * (1.0 + 1e-9)
        # a sample with no reversal of the path (its peaks at w t = pi/2 + n pi) in it
        if math.floor(omega * t0 / math.pi - 0.5) == math.floor(omega * g.t / math.pi - 0.5):
            assert fd_new == pytest.approx(_dahl_after(fd, xe_new - xe, sigma, fc),
                                           abs=1e-3 * fc)
            checked += 1
        xe, fd = xe_new, fd_new
    assert checked > 600


@pytest.mark.parametrize("mode", ["passive", "dob_full_ff"])
def test_energy_balance_with_every_effect_on(mode):
    from seaforce_ros.core.controller import ChannelController
    from seaforce_ros.core.params import ControllerConfig
    rng = np.random.default_rng(30)
    plant = _plant(rng, 0.7, 1.4)
    effects = draw_effects(rng)
    omega = 3.0
    period = 2.0 * math.pi / omega
    controller = (Unpowered() if mode == "passive" else
                  ChannelController(ControllerConfig(mode=mode), 5e-4))
    rec = backdrive(plant, DAHL, effects, controller, STROKE, omega, periods=0, settle=3 * period)
    g = rec["gripper"]
    work0, lost0 = g.work_in, g.dissipated
    for _ in range(int(round(period / g.dt))):
        g.step(controller.update(*g.measurement()[:3]))
    work, lost = g.work_in - work0, g.dissipated - lost0
    assert lost > 0.0
    # the stored energy returns within a period (periodic steady state up to the sample
    # that does not close it): the work is what the losses took
    assert work == pytest.approx(lost, rel=0.02)


def test_draws_stay_in_their_ranges_and_off_is_off():
    rng = np.random.default_rng(40)
    for _ in range(200):
        e = draw_effects(rng)
        for name in EFFECTS:
            lo, hi = RANGES[name]
            assert lo <= getattr(e, name) <= hi, name
        assert abs(e.stroke_asymmetry) <= e.stroke_stiffness / 3.0
        assert abs(e.finger_asymmetry) <= e.finger_ratio / 3.0
        # the finger ratio: 1 at the centre, 1 + c_2 +- c_1 at the stroke's ends
        assert ratio(0.0, e) == 1.0
        assert 1.0 + 2.0 * e.finger_ratio / 3.0 <= ratio(STROKE, e) <= 1.0 + 4 * e.finger_ratio / 3
        q = float(rng.uniform(-STROKE, STROKE))
        assert finger_position(actuator_position(q, e), e) == pytest.approx(q, abs=1e-12)
    e = draw_effects(rng)
    only = e.only("hose_flow")
    assert only.hose_flow == e.hose_flow and only.cogging == 0.0 and only.finger_ratio == 0.0
    off = linear_counterpart(e)
    assert off.describe().startswith("none")
    assert hose_force(0.01, 2.0, TABLE_I, off) == pytest.approx(
        TABLE_I["hose_stiffness"] * 0.01 + TABLE_I["hose_damping"] * 2.0)


def test_drawn_sensors_report_what_a_real_rig_reports():
    """:func:`draw_sensors` stays in its ranges, and each drawn sensor does what it says: the
    offset (and its drift) in F_p, the drive's velocity the mean of its last backward
    differences, the torque applied 1 + extra_delay samples after its sample, the ADC's step."""
    rng = np.random.default_rng(4)
    draws = [draw_sensors(rng) for _ in range(40)]
    for name, (lo, hi) in SENSOR_RANGES.items():
        values = [math.log2(s.motor_counts) if name == "motor_bits" else getattr(s, name)
                  for s in draws]
        assert lo <= min(values) and max(values) <= hi, name
        assert max(values) > min(values), name             # drawn, not fixed
    for s in draws[:6]:
        g = NonlinearGripper(TABLE_I, DAHL, Effects(), None, sensors=s, pressure_drift=0.01)
        n, q = s.velocity_samples, 2.0 * s.pressure_range / 2 ** s.pressure_bits
        xs, applied = [g.measurement().x] * n, []
        for k in range(300):
            m = g.step(0.2 * math.sin(0.05 * k) + (1.0 if k == 100 else 0.0))
            applied.append(m.f_a)
            assert m.v == pytest.approx((m.x - xs[-n]) / (n * g.dt), abs=1e-9)
            xs.append(m.x)
            bias = s.pressure_offset + 0.01 * g.t
            assert abs(m.f_p - g.true_f_p - bias) <= q / 2 + 6 * s.pressure_noise + 1e-12
        # the pulse commanded at sample 100 is applied over the step ending at sample
        # 101 + extra_delay (the measurement after the step reports it)
        assert np.argmax(np.abs(np.diff(applied))) == 100 + s.extra_delay
