"""The tare of the pressure sensor's offset (:mod:`seaforce_ros.core.tare`).

* On the independent oracle (:mod:`helpers.nonlinear_sim`: its own integrator, a rig's sensors
  drawn -- the offset within +-50 mN m, an ADC of 12-16 bit over +-10..40 N m, noise,
  a coarse encoder, the drive's velocity filter, extra delay), plants 0.5x..2x of the
  hand-typed model, linear and nonlinear, the finger left resting anywhere within +-0.3 rad by
  its friction after a flick: the tare finds the offset within 1.5 mN m (where the Dahl force
  alone could hide 32 mN m), and the channel goes on with it.
* Refusals, nothing applied: an object on one side of the finger, a preloaded object on both,
  a finger held (it does not follow the servo), a rest outside the range.
* Properties over arbitrary inputs: the torque within ``min(friction.torque_limit,
  max_torque)``, a non-finite input ends it aborted with zero torque.
"""
import math
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, SensorParams)
from seaforce_ros.core.environment import contact_object, position_sine
from seaforce_ros.core.jobs import JobSample
from seaforce_ros.core.params import HoldParams
from seaforce_ros.core.tare import PressureTare

from helpers.configs import unlimited
from helpers.nonlinear_sim import NonlinearGripper, draw_sensors
from helpers.oracle_commissioning import draw

DT = 5e-4
CONFIG = ControllerConfig(max_torque=20.0)


def run_tare(plant, controller, tare, limit=20000):
    """Run ``tare`` on ``controller`` against ``plant`` (the oracle or the core simulator)
    until it ends; the number of samples."""
    controller.request_job(tare)
    m = plant.measurement()
    k = 0
    while tare.active and k < limit:
        m = plant.step(controller.update(m.x, m.v, m.f_p))
        k += 1
    return k


@pytest.mark.parametrize("seed", range(8))
def test_the_tare_finds_a_drawn_offset_on_the_oracle(seed):
    rng = np.random.default_rng([44, seed])
    plant, dahl, effects = draw(rng, effects=bool(seed % 2))
    sensors = draw_sensors(rng)
    g = NonlinearGripper(plant, dahl, effects, None, seed=seed, sensors=sensors)
    g.place(float(rng.uniform(-0.3, 0.3)))
    ctl = ChannelController(CONFIG, DT)
    m = g.measurement()
    for k in range(3000):          # a flick, then rest: the Dahl force holds what it holds
        ctl.update(m.x, m.v, m.f_p)
        m = g.step(0.1 * math.sin(2 * math.pi * k / 400) if k < 400 else 0.0)
    tare = PressureTare(ctl.config, DT)
    samples = run_tare(g, ctl, tare)
    assert tare.outcome == "succeeded", tare.message
    assert samples * DT < 6.0
    assert tare.offset == pytest.approx(sensors.pressure_offset, abs=1.5e-3), sensors.describe()
    assert ctl.config.pressure_offset == tare.offset and tare.applied
    assert abs(g.state[2] - CONFIG.feedforward.rest_position) < 0.03     # it was taken home


@pytest.mark.parametrize("seed", range(3))
def test_a_tare_requested_while_the_offset_drives_the_finger(seed):
    """``dob_full_ff`` with the hand-typed model turns an offset of 30-50 mN m into a finger
    running at up to 1 rad/s; the tare, requested 0.1-0.35 s into that, with the shipped hold
    gains (K_p 20: the mode's torque at the request, up to 0.3 N m, would hold the servo
    15 mrad off the dither's centre if it stayed on), finds the offset and the sides balanced."""
    rng = np.random.default_rng([4402, seed])
    plant, dahl, effects = draw(rng, effects=bool(seed % 2))
    sensors = draw_sensors(rng)
    sensors = replace(sensors, pressure_offset=float(rng.choice([-1, 1]) * rng.uniform(0.03, 0.05)))
    g = NonlinearGripper(plant, dahl, effects, None, seed=seed, sensors=sensors)
    config = CONFIG.replace(mode="dob_full_ff", hold=HoldParams(stiffness=20.0, damping=0.1))
    ctl = ChannelController(config, DT)
    m = g.measurement()
    for _ in range(int(rng.integers(200, 700))):
        m = g.step(ctl.update(m.x, m.v, m.f_p))
    speed = abs(g.state[3])
    tare = PressureTare(ctl.config, DT)
    run_tare(g, ctl, tare)
    where = f"{sensors.describe()}, entered at {speed:.2f} rad/s"
    assert tare.outcome == "succeeded", f"{tare.message} ({where})"
    assert tare.offset == pytest.approx(sensors.pressure_offset, abs=1.5e-3), where
    assert abs(tare.contact_test.upper - tare.contact_test.lower) < 0.5, where


@pytest.mark.parametrize("depth", [0.01, 0.1])
def test_an_object_against_the_finger_is_refused(depth):
    """An object 5 N m/rad at the finger: touched on one side of the dither (0.01 rad in), or
    pressing on both (0.1 rad in: the finger rests in it)."""
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(),
                           environment=contact_object(-depth, 5.0, 0.05))
    ctl = ChannelController(CONFIG, DT)
    m = sim.measurement()
    for _ in range(4000):
        ctl.update(m.x, m.v, m.f_p)
        m = sim.step(0.0)
    tare = PressureTare(ctl.config, DT)
    run_tare(sim, ctl, tare)
    assert tare.outcome == "aborted" and "nothing applied" in tare.message
    assert "contact" in tare.message or "holds the finger" in tare.message
    assert ctl.config.pressure_offset == 0.0 and not tare.applied


def test_a_held_finger_and_a_rest_out_of_range_are_refused():
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(),
                           environment=position_sine(0.0, 1.0))     # clamped at 0
    ctl = ChannelController(CONFIG.replace(feedforward=CONFIG.feedforward.__class__(
        rest_position=0.3)), DT)
    tare = PressureTare(ctl.config, DT)
    run_tare(sim, ctl, tare)
    assert tare.outcome == "aborted" and "held" in tare.message
    far = CONFIG.replace(feedforward=CONFIG.feedforward.__class__(rest_position=1.49))
    tare = PressureTare(far, DT)
    run_tare(ChannelSimulator(PlantParams.table_i(), DahlParams()),
             ChannelController(far, DT), tare)
    assert tare.outcome == "aborted" and "position_min..max" in tare.message


def test_a_cancel_ends_it_with_nothing_applied():
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(),
                           sensors=SensorParams(pressure_offset=0.02))
    ctl = ChannelController(CONFIG, DT)
    tare = PressureTare(ctl.config, DT)
    ctl.request_job(tare)
    m = sim.measurement()
    for k in range(1000):
        if k == 500:
            tare.request_cancel()
        m = sim.step(ctl.update(m.x, m.v, m.f_p))
    assert tare.outcome == "canceled" and ctl.config.pressure_offset == 0.0
    assert ctl.job is None


values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-2.0, 2.0),
                   st.floats(-0.01, 0.01))


@settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(values, values, values, values, values), min_size=1, max_size=60),
       st.floats(1e-3, 10.0), st.floats(1e-3, 10.0))
def test_the_tare_torque_is_bounded_and_a_non_finite_input_stops_it(samples, limit,
                                                                     max_torque):
    """Invariants: |F_a| <= min(friction.torque_limit, max_torque) at every sample; a
    non-finite input ends it aborted, and every later output is 0."""
    config = unlimited(CONFIG).replace(max_torque=max_torque,
                                       friction=CONFIG.friction.__class__(
                                           torque_limit=limit, position_min=-100.0,
                                           position_max=100.0))
    tare = PressureTare(config, DT)
    sample = JobSample(ChannelController(config, DT).estimator)
    bound = min(limit, max_torque)
    stopped = False
    for x, v, xe, fp, torque in samples:
        sample.x, sample.v, sample.endpoint_position, sample.f_p = x, v, xe, fp
        sample.torque = torque
        u = tare.step(sample)
        assert math.isfinite(u) and abs(u) <= bound
        if not all(math.isfinite(a) for a in (x, v, xe, fp, torque)):
            stopped = True
        if stopped:
            assert u == 0.0 and tare.outcome == "aborted" and tare.message
