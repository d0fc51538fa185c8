"""Offline simulator: exact linear part, nonlinear parts, sensors, determinism."""

import math

import numpy as np
import pytest
import scipy.linalg

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, NonFiniteInputError, PlantParams, SensorParams,
                               free, position_sine, run_closed_loop, torque_chirp,
                               torque_sine)
from seaforce_ros.core.simulator import continuous_matrices

TABLE_I = PlantParams.table_i()
DT = 5e-4


def exact_solution(z0, torque, t, env_stiffness=0.0, env_damping=0.0, frequency=0.0,
                   osc=(0.0, 0.0)):
    """Continuous solution with a constant motor torque, by one matrix exponential."""
    A, B = continuous_matrices(TABLE_I, env_stiffness, env_damping, frequency)
    M = np.zeros((7, 7))
    M[:6, :6] = A
    M[:6, 6] = B[:, 0] * torque
    e = scipy.linalg.expm(M * t)
    return e[:6, :] @ np.r_[z0, osc, 1.0]


def test_linear_part_is_exact_for_a_torque_step():
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams.ideal(), command_delay=0)
    z0 = (0.01, -0.2, 0.03, 0.5)
    sim.reset(state=z0)
    for _ in range(3000):                       # 1.5 s, long steps for any integrator
        sim.step(0.2)
    expected = exact_solution(z0, 0.2, 3000 * DT)
    np.testing.assert_allclose(sim.state, expected[:4], rtol=1e-9, atol=1e-12)
    # the ideal sensors report the true state
    m = sim.measurement()
    assert m.x == sim.state[0] and m.x_e == sim.state[2]
    assert m.f_p == pytest.approx(sim.pressure_force, abs=1e-15)


def test_position_drive_is_exact_and_tracks():
    env = position_sine(0.5, 1.0)
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams.ideal(), command_delay=0,
                           environment=env)
    n = 4000
    for _ in range(n):
        sim.step(0.0)
    expected = exact_solution((0, 0, 0, 0), 0.0, n * DT, env.stiffness, env.damping,
                              env.frequency, osc=(0.0, env.amplitude))
    np.testing.assert_allclose(sim.state, expected[:4], rtol=1e-9, atol=1e-12)
    assert sim.drive_position == pytest.approx(0.5 * math.sin(n * DT), abs=1e-12)
    # the stiff drive keeps the endpoint within ~1 % of the set-point (off mode)
    errs = []
    for _ in range(12000):
        sim.step(0.0)
        errs.append(abs(sim.state[2] - sim.drive_position))
    assert max(errs) < 0.01 * 0.5
    # F_e is the spring-damper force
    x, v, xe, ve = sim.state
    fe = env.stiffness * (sim.drive_position - xe) + env.damping * (
        0.5 * math.cos(sim.t) - ve)
    assert sim.measurement().f_e == pytest.approx(fe, rel=1e-9)


def test_torque_environments_report_fe():
    sim = ChannelSimulator(TABLE_I, None, environment=torque_sine(0.3, 10.0))
    for _ in range(100):
        m = sim.step(0.0)
    assert m.f_e == pytest.approx(0.3 * math.sin(10.0 * 100 * DT), rel=1e-12)
    chirp = torque_chirp(duration=2.0)
    sim.set_environment(chirp)
    t0 = sim.t
    for _ in range(10):
        m = sim.step(0.0)
    assert m.f_e == pytest.approx(chirp.torque(sim.t - t0), rel=1e-12)
    sim.set_environment(free())
    assert sim.measurement().f_e == 0.0
    assert sim.step(0.0).f_e == 0.0


def test_chirp_instantaneous_frequency_is_logarithmic():
    chirp = torque_chirp(0.3, 0.01, 1000.0, 100.0)
    dt = 1e-6
    for t, f in ((0.0, 0.01), (40.0, 1.0), (60.0, 10.0), (99.0, 1000.0 * 10 ** -0.05)):
        inst = (chirp.chirp_phase(t + dt) - chirp.chirp_phase(t)) / dt / (2 * math.pi)
        assert inst == pytest.approx(f, rel=1e-4)
    assert chirp.torque(100.0) == 0.0


def test_determinism_and_seed():
    def run(seed):
        sim = ChannelSimulator(TABLE_I, DahlParams(), seed=seed,
                               environment=position_sine(0.5, 1.0))
        ctl = ChannelController(ControllerConfig(mode="dob_full_ff"))
        return run_closed_loop(sim, ctl, 3000)
    a, b, c = run(7), run(7), run(8)
    for key in a:
        np.testing.assert_array_equal(a[key], b[key])
    assert np.any(a["f_p"] != c["f_p"])


def test_run_closed_loop_equals_manual_lockstep_loop():
    sim1 = ChannelSimulator(TABLE_I, DahlParams(), seed=3, motor_coulomb=0.01,
                            environment=position_sine(0.3, 2.0))
    sim2 = ChannelSimulator(TABLE_I, DahlParams(), seed=3, motor_coulomb=0.01,
                            environment=position_sine(0.3, 2.0))
    c1 = ChannelController(ControllerConfig(mode="dob_full_ff"))
    c2 = ChannelController(ControllerConfig(mode="dob_full_ff"))
    rec = run_closed_loop(sim1, c1, 2000)
    m = sim2.measurement()
    us = []
    for _ in range(2000):
        u = c2.update(m.x, m.v, m.f_p)
        us.append(u)
        m = sim2.step(u)
    np.testing.assert_array_equal(rec["u"], us)
    assert sim1.measurement() == sim2.measurement()


def test_motor_coulomb_friction_sticks_without_chatter_and_slips():
    fc = 0.05
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams.ideal(), command_delay=0,
                           motor_coulomb=fc)
    for _ in range(2000):
        sim.step(0.03)                      # below F_c: stuck
    x, v, _, _ = sim.state
    assert v == 0.0 and abs(x) < 1e-12
    assert sim.motor_friction == pytest.approx(0.03, rel=1e-6)
    # slow sine above F_c: slips, the velocity changes sign only at the reversals
    vs = []
    for i in range(8000):                   # 4 s, 1 rad/s sine of 0.3 N m
        sim.step(0.3 * math.sin(1.0 * i * DT))
        vs.append(sim.state[1])
    vs = np.array(vs)
    moving = vs[np.abs(vs) > 0]
    sign_changes = np.count_nonzero(np.diff(np.sign(moving)) != 0)
    assert sign_changes <= 2
    assert np.max(np.abs(vs)) > 0.1
    # while slipping the friction force is exactly F_c
    assert abs(sim.motor_friction) == pytest.approx(fc) or sim.state[1] == 0.0


def test_endpoint_coulomb_friction_is_unobservable_but_resists():
    env = torque_sine(0.02, 1.0)            # below the 0.03 N m endpoint friction
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams.ideal(), command_delay=0,
                           endpoint_coulomb=0.03, environment=env)
    for _ in range(4000):
        sim.step(0.0)
    assert abs(sim.state[2]) < 1e-12 and sim.pressure_force == pytest.approx(0.0, abs=1e-12)


def test_backlash_dead_zone():
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams.ideal(), backlash=0.1,
                           environment=position_sine(0.04, 5.0))
    fe = [sim.step(0.0).f_e for _ in range(4000)]
    assert np.all(np.array(fe) == 0.0) and sim.state[2] == 0.0
    sim.set_environment(position_sine(0.2, 5.0))
    fe = np.array([sim.step(0.0).f_e for _ in range(4000)])
    assert np.mean(fe == 0.0) > 0.2 and np.max(np.abs(fe)) > 0.01


def test_sensor_quantisation_and_velocity():
    sensors = SensorParams(pressure_range=10.0, pressure_bits=16, pressure_noise=0.0,
                           motor_counts_per_rev=4096, endpoint_counts_per_rev=40000)
    sim = ChannelSimulator(TABLE_I, None, sensors=sensors, environment=torque_sine(0.3, 5.0))
    qx, qe, qp = 2 * math.pi / 4096, 2 * math.pi / 40000, 20.0 / 65536
    prev = sim.measurement()
    for _ in range(500):
        m = sim.step(0.0)
        assert m.x / qx == pytest.approx(round(m.x / qx), abs=1e-6)
        assert m.x_e / qe == pytest.approx(round(m.x_e / qe), abs=1e-6)
        assert m.f_p / qp == pytest.approx(round(m.f_p / qp), abs=1e-6)
        assert abs(m.x - sim.state[0]) <= qx / 2 + 1e-15
        assert abs(m.f_p - sim.pressure_force) <= qp / 2 + 1e-12
        assert m.v == pytest.approx((m.x - prev.x) / DT, abs=1e-9)
        prev = m


@pytest.mark.parametrize("samples", [2, 3, 4])
def test_drive_velocity_averages_the_last_backward_differences(samples):
    sensors = SensorParams(motor_counts_per_rev=2 ** 14, velocity_samples=samples)
    sim = ChannelSimulator(TABLE_I, None, sensors=sensors, environment=torque_sine(0.3, 5.0))
    xs = [sim.measurement().x] * samples
    for _ in range(400):
        m = sim.step(0.1)
        assert m.v == pytest.approx((m.x - xs[-samples]) / (samples * DT), abs=1e-9)
        xs.append(m.x)


def test_pressure_offset_and_its_drift_are_read_with_the_force():
    drift = 0.01
    sensors = SensorParams(pressure_bits=0, pressure_noise=0.0, pressure_offset=-0.03,
                           pressure_drift=drift)
    sim = ChannelSimulator(TABLE_I, None, sensors=sensors, environment=torque_sine(0.3, 5.0))
    for _ in range(2000):
        m = sim.step(0.05)
        assert m.f_p - sim.pressure_force == pytest.approx(-0.03 + drift * sim.t, abs=1e-12)


def test_pressure_noise_statistics():
    sensors = SensorParams(pressure_noise=2e-3, pressure_bits=0)
    sim = ChannelSimulator(TABLE_I, None, sensors=sensors)
    err = [sim.step(0.0).f_p - sim.pressure_force for _ in range(5000)]
    assert np.std(err) == pytest.approx(2e-3, rel=0.05)
    assert abs(np.mean(err)) < 2e-4


def test_command_delay_and_saturation():
    sim = ChannelSimulator(TABLE_I, None, torque_saturation=2.0)
    assert sim.step(1.0).f_a == 0.0               # one-sample transport delay
    assert sim.step(-5.0).f_a == 1.0
    m = sim.step(0.0)
    assert m.f_a == -2.0 and sim.limited
    sim0 = ChannelSimulator(TABLE_I, None, command_delay=0)
    assert sim0.step(1.0).f_a == 1.0
    with pytest.raises(NonFiniteInputError):
        sim0.step(math.nan)


def test_simulator_dahl_hysteresis_is_bounded():
    d = DahlParams()
    sim = ChannelSimulator(TABLE_I, d, environment=position_sine(0.5, 1.0))
    fd = []
    for _ in range(15000):
        sim.step(0.0)
        fd.append(sim.dahl_force)
    assert max(np.abs(fd)) <= d.coulomb_force
    assert max(fd) > 0.99 * d.coulomb_force and min(fd) < -0.99 * d.coulomb_force


# --- objects ---------------------------------------------------------------------------
def test_object_contact_is_the_exact_spring_damper_while_pushing():
    """In contact the object is the position drive's spring-damper to a fixed point: the
    trajectory equals the matrix-exponential solution (drive at x_c, zero frequency) from the
    first step in contact on, and F_e = -(k (X_e - x_c) + b V_e)."""
    from seaforce_ros.core.environment import contact_object
    k, b, xc = 5.0, 0.05, 0.01
    z0 = (0.02, 0.0, 0.02, 0.0)                   # already pressed 10 mrad in, at rest
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams(pressure_noise=0.0),
                           command_delay=0, environment=contact_object(xc, k, b))
    sim.reset(z0)
    for _ in range(400):
        m = sim.step(0.3)
    t = 400 * DT
    expected = exact_solution(np.array(z0), 0.3, t, k, b, 0.0, osc=(xc, 0.0))
    # the drive's offset form: x_d = x_c held in the oscillator state (frequency 0)
    assert np.allclose(sim.state, expected[:4], atol=1e-9)
    x_e, v_e = sim.state[2], sim.state[3]
    assert m.f_e == pytest.approx(-(k * (x_e - xc) + b * v_e), abs=1e-12)
    # static equilibrium against a constant motor torque: the object takes what k and
    # the hose pass on
    for _ in range(40000):
        m = sim.step(0.3)
    assert m.f_e == pytest.approx(-k * (sim.state[2] - xc), abs=1e-9)
    assert sim.state[1] == pytest.approx(0.0, abs=1e-9)


def test_object_never_pulls_and_contact_ends_where_the_push_ends():
    from seaforce_ros.core.environment import contact_object
    sim = ChannelSimulator(TABLE_I, None, sensors=SensorParams(pressure_noise=0.0),
                           environment=contact_object(0.05, 20.0, 0.1))
    forces = []
    for i in range(6000):
        m = sim.step(0.5 if i < 2000 else -0.5)    # press, then pull away
        forces.append(m.f_e)
        x_e = sim.state[2]
        if x_e <= 0.05:
            assert m.f_e == 0.0
    assert min(forces) < -0.3 and max(forces) == 0.0
    assert sim.state[2] < 0.0                      # it let go


def test_object_environment_from_parameters_and_a_drifting_plant():
    from seaforce_ros.core.environment import environment_from_dict
    env = environment_from_dict({'pinch.environment.mode': 'object',
                                 'pinch.environment.position': 0.2,
                                 'pinch.environment.stiffness': 3.0,
                                 'pinch.environment.damping': 0.05})
    assert env.is_object and env.position == 0.2 and not env.is_position_drive
    sim = ChannelSimulator(TABLE_I, DahlParams(), environment=env)
    soft_hose = TABLE_I.scaled(hose_stiffness=0.5)
    sim.set_plant(soft_hose, None)
    assert sim.plant is soft_hose and sim.dahl_params is None
    for _ in range(200):
        sim.step(0.1)
    assert sim.dahl_force == 0.0
    z = sim.state
    assert sim.pressure_force == pytest.approx(
        soft_hose.hose_stiffness * (z[2] - z[0]) + soft_hose.hose_damping * (z[3] - z[1]))
