"""The sim's nonlinear plant (:mod:`seaforce_ros.core.nonlinear_simulator`) against closed
forms and against the independent oracle (:mod:`helpers.nonlinear_sim`):

* every effect off: the linear simulator, to rounding; the sim's factory gives the linear
  simulator itself; a finger ratio alone in free air changes only what the encoder reads;
* quasi-static equilibria solved apart (scipy's brentq): a constant motor torque in free air
  with the hose's pressure stiffening and the diaphragm's stroke terms; the finger held by the
  drive, whose force is the virtual work's r(q) (F_k + F_p);
* the hose's flow term with the motor stuck: the fundamental's damping
  b_e + b_s (1 + 8 c_q V_0/(3 pi)) and the 3rd harmonic 8 b_s c_q V_0^2/(15 pi);
* energy: the free finger's stored energy falls by what the losses dissipate, never rises;
* the oracle, on random draws of the commissioning family with every effect in the oracle's
  stated ranges: the same motions and impedance figures within stated tolerances;
* the rows' ranges and rules refuse bad values with the reason; the draws stay in range.
"""
import dataclasses
import math

import numpy as np
import pytest
from scipy.optimize import brentq

from helpers.free_air_records import draw as draw_family
from helpers.nonlinear_sim import STROKE, NonlinearGripper, Unpowered, backdrive
from helpers.nonlinear_sim import draw_effects as draw_oracle_effects
from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, InvalidParameterError, PlantParams, SensorParams,
                               contact_object, free, position_sine, run_closed_loop,
                               torque_chirp)
from seaforce_ros.core.analysis import impedance_figures
from seaforce_ros.core.nonlinear_effects import (PLAUSIBLE, NonlinearEffects, cogging_energy,
                                                 diaphragm_energy, diaphragm_force,
                                                 draw_effects, endpoint_of_finger,
                                                 finger_of_endpoint, finger_ratio, hose_energy,
                                                 hose_force)
from seaforce_ros.core.nonlinear_simulator import NonlinearChannelSimulator, make_simulator

TABLE_I = PlantParams.table_i()
DT = 5e-4
IDEAL = SensorParams.ideal()
EVERY_EFFECT = NonlinearEffects(
    hose_damping_rise=0.5, hose_stiffening=0.3, stroke_stiffening=0.2, stroke_asymmetry=0.05,
    finger_ratio=0.12, finger_asymmetry=-0.03, cogging=0.008, cogging_periods=42,
    cogging_phase=1.0)


def _effects(**values):
    return NonlinearEffects(**values)


def _torque(k):
    """An open-loop motor torque [N m]: a few sines over the band the plant moves in."""
    t = k * DT
    return (0.15 * math.sin(2 * math.pi * 0.7 * t) + 0.1 * math.sin(2 * math.pi * 3.1 * t + 1.0)
            + 0.05 * math.sin(2 * math.pi * 17.0 * t + 2.0))


# --- the linear limit ----------------------------------------------------------------------------
@pytest.mark.parametrize("env", [free(), position_sine(0.5, 2.0), torque_chirp(0.3, 0.5, 50.0, 2.0),
                                 contact_object(0.02, 50.0, 0.1)],
                         ids=lambda e: e.mode)
def test_every_effect_off_is_the_linear_simulator(env):
    kw = dict(dahl=DahlParams(), environment=env, sensors=IDEAL, motor_coulomb=0.005)
    linear = ChannelSimulator(TABLE_I, **kw)
    nonlinear = NonlinearChannelSimulator(TABLE_I, effects=NonlinearEffects(), **kw)
    worst = 0.0
    for k in range(3000):
        a, b = linear.step(_torque(k) + 0.05), nonlinear.step(_torque(k) + 0.05)
        worst = max(worst, abs(a.f_p - b.f_p), abs(a.f_e - b.f_e), abs(a.x_e - b.x_e))
    np.testing.assert_allclose(nonlinear.state, linear.state, rtol=1e-9, atol=1e-12)
    assert worst < 1e-10
    assert nonlinear.endpoint_velocity == pytest.approx(linear.endpoint_velocity, abs=1e-10)


def test_the_factory_gives_the_linear_simulator_itself_with_every_effect_off():
    assert type(make_simulator(TABLE_I)) is ChannelSimulator
    assert type(make_simulator(TABLE_I, None, NonlinearEffects(cogging_periods=24))) \
        is ChannelSimulator
    sim = make_simulator(TABLE_I, None, _effects(cogging=0.005), dt=DT)
    assert type(sim) is NonlinearChannelSimulator and sim.effects.cogging == 0.005


def test_a_finger_ratio_in_free_air_moves_nothing_but_the_encoder():
    """The finger link is massless: with no force at the finger the plant is the linear one,
    and the encoder reads q(X_e)."""
    ratio = _effects(finger_ratio=0.15, finger_asymmetry=0.05)
    linear = ChannelSimulator(TABLE_I, DahlParams(), sensors=IDEAL)
    nonlinear = NonlinearChannelSimulator(TABLE_I, DahlParams(), ratio, sensors=IDEAL)
    for k in range(4000):
        linear.step(3.0 * _torque(k))
        m = nonlinear.step(3.0 * _torque(k))
    np.testing.assert_allclose(nonlinear.state, linear.state, rtol=1e-9, atol=1e-12)
    xe = nonlinear.state[2]
    assert abs(xe) > 0.2                                  # far enough for the ratio to show
    assert endpoint_of_finger(m.x_e, ratio) == pytest.approx(xe, abs=1e-12)
    assert abs(m.x_e - xe) > 1e-3
    assert m.f_e == 0.0


def test_run_closed_loop_records_the_nonlinear_hose_force():
    class Open:
        k = 0

        def update(self, x, v, f_p):
            self.k += 1
            return 2.0 * _torque(self.k)
    sim = NonlinearChannelSimulator(TABLE_I, None, EVERY_EFFECT, sensors=IDEAL)
    rec = run_closed_loop(sim, Open(), 2000)
    expected = [hose_force(xe - x, ve - v, TABLE_I.hose_stiffness, TABLE_I.hose_damping,
                           EVERY_EFFECT)
                for x, v, xe, ve in zip(rec["x_true"], rec["v_true"], rec["x_e_true"],
                                        rec["v_e_true"])]
    np.testing.assert_allclose(rec["f_p_true"], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(rec["f_p"], rec["f_p_true"], atol=1e-12)   # ideal sensors
    assert np.max(np.abs(rec["f_p_true"] - TABLE_I.hose_stiffness
                         * (rec["x_e_true"] - rec["x_true"]))) > 1e-3


# --- quasi-static equilibria -------------------------------------------------------------------
def _deflection(force, effects, stiffness=TABLE_I.hose_stiffness):
    """The hose deflection d at rest under the pressure force ``force`` (its elastic law
    inverted by brentq)."""
    return brentq(lambda d: hose_force(d, 0.0, stiffness, 0.0, effects) - force, -2.0, 2.0,
                  xtol=1e-15)


def test_a_constant_torque_rests_where_the_nonlinear_springs_balance():
    effects = _effects(hose_stiffening=0.4, stroke_stiffening=0.3, stroke_asymmetry=0.1)
    torque = 0.06
    p = TABLE_I
    sim = NonlinearChannelSimulator(p, None, effects, sensors=IDEAL)
    for _ in range(16000):                      # 8 s: the slowest pole is -4 rad/s
        sim.step(torque)

    def motor_balance(xe):          # endpoint at rest: F_p = -F_k(X_e); motor: F_a + F_p = k X
        fp = -diaphragm_force(xe, p.endpoint_stiffness, effects)
        return torque + fp - p.motor_stiffness * (xe - _deflection(fp, effects))
    xe = brentq(motor_balance, -2.0, 2.0, xtol=1e-15)
    x = xe - _deflection(-diaphragm_force(xe, p.endpoint_stiffness, effects), effects)
    np.testing.assert_allclose(sim.state, (x, 0.0, xe, 0.0), atol=1e-7)
    k, ke, ks = p.motor_stiffness, p.endpoint_stiffness, p.hose_stiffness
    linear_xe = torque * ks / (k * (ks + ke) + ks * ke)
    assert abs(xe / linear_xe - 1.0) > 0.01     # the nonlinear springs show


@pytest.mark.parametrize("q0,drift", [(-0.4, False), (0.15, False), (0.45, False),
                                       (0.3, True)])
def test_the_held_finger_feels_the_virtual_work_force(q0, drift):
    """The drive holds the finger at q0 with the motor passive: at rest, the force on the
    finger is r(q) (F_k(X_e) + F_p), X_e = X_e(q), the motor in balance with the hose (with
    ``drift``: the plant changed on the way, as ``sim.plant.*`` at run time)."""
    effects = _effects(hose_stiffening=0.3, stroke_stiffening=0.25, stroke_asymmetry=-0.08,
                       finger_ratio=0.15, finger_asymmetry=0.05)
    p = TABLE_I
    env = position_sine(0.0, 0.0, offset=q0)
    sim = NonlinearChannelSimulator(p, None, effects, sensors=IDEAL, environment=env)
    if drift:
        for _ in range(4000):
            sim.step(0.0)
        p = dataclasses.replace(p, hose_stiffness=0.5 * p.hose_stiffness,
                                endpoint_stiffness=2.0 * p.endpoint_stiffness)
        sim.set_plant(p)
    for _ in range(12000):
        m = sim.step(0.0)
    q = sim.finger_position
    xe = endpoint_of_finger(q, effects)
    x = brentq(lambda x: hose_force(xe - x, 0.0, p.hose_stiffness, 0.0, effects)
               - p.motor_stiffness * x, -2.0, 2.0, xtol=1e-15)
    fp = p.motor_stiffness * x
    expected = finger_ratio(q, effects) * (diaphragm_force(xe, p.endpoint_stiffness, effects) + fp)
    assert q == pytest.approx(q0, abs=1e-3)                 # the drive's spring gives a little
    assert sim.state[2] == pytest.approx(xe, abs=1e-12)
    assert m.f_e == pytest.approx(expected, rel=1e-6)
    linear = q * (p.endpoint_stiffness + p.motor_stiffness * p.hose_stiffness
                  / (p.motor_stiffness + p.hose_stiffness))
    assert abs(m.f_e / linear - 1.0) > 0.02


# --- the hose's flow term ------------------------------------------------------------------------
def test_flow_dependent_hose_damping_has_its_describing_function():
    """The motor stuck (a Coulomb friction far above any force here), the finger driven at
    V_0: F_e = m_e A + (b_e + b_s) V + b_s c_q |V| V + (k_e + k_s) X, whose fundamental has the
    damping b_e + b_s (1 + 8 c_q V_0/(3 pi)) and 3rd harmonic 8 b_s c_q V_0^2/(15 pi)."""
    c_q, omega = 1.0, 2.0
    p = TABLE_I
    sim = NonlinearChannelSimulator(p, None, _effects(hose_damping_rise=c_q), sensors=IDEAL,
                                    motor_coulomb=50.0, environment=position_sine(0.5, omega))
    n = int(round((1.0 + 2.0 * math.pi / omega) / DT))
    rec = np.array([(m.f_e, m.x_e) for m in (sim.step(0.0) for _ in range(n))])
    assert sim.state[1] == 0.0 and abs(sim.state[0]) < 1e-3     # the motor stuck
    fig = impedance_figures(rec[:, 0], rec[:, 1], omega, DT, settle_time=1.0)
    v0 = fig.amplitude * omega
    damping = p.endpoint_damping + p.hose_damping * (1.0 + 8.0 * c_q * v0 / (3.0 * math.pi))
    assert fig.z.real == pytest.approx(damping, rel=0.01)
    assert fig.harmonics[2] == pytest.approx(8.0 * p.hose_damping * c_q * v0 ** 2
                                             / (15.0 * math.pi), rel=0.03)
    linear = p.endpoint_damping + p.hose_damping
    assert fig.z.real > 1.1 * linear                 # the flow term shows


# --- energy ---------------------------------------------------------------------------------------
def _stored_energy(sim):
    p, e = sim.plant, sim.effects
    x, v, xe, ve = sim.state
    return (0.5 * p.motor_inertia * v * v + 0.5 * p.endpoint_inertia * ve * ve
            + 0.5 * p.motor_stiffness * x * x + hose_energy(xe - x, p.hose_stiffness, e)
            + diaphragm_energy(xe, p.endpoint_stiffness, e) + cogging_energy(x, e))


def _dissipation(sim):
    """The losses' power [W]: the dampers and the hose's flow-dependent damping."""
    p, e = sim.plant, sim.effects
    _, v, _, ve = sim.state
    flow = ve - v
    return (p.motor_damping * v * v + p.endpoint_damping * ve * ve
            + p.hose_damping * flow * flow * (1.0 + e.hose_damping_rise * abs(flow)))


@pytest.mark.parametrize("coulomb", [0.0, 0.01])
def test_the_free_finger_loses_what_its_losses_dissipate(coulomb):
    """Released from a deflected hose (F_p about 2.6 N m) with the motor unpowered: the stored
    energy never rises, and without Coulomb friction it falls by the integral of the losses'
    power."""
    sim = NonlinearChannelSimulator(TABLE_I, None, EVERY_EFFECT, sensors=IDEAL,
                                    motor_coulomb=coulomb, command_delay=0)
    sim.reset(state=(0.1, 0.0, 0.3, 0.0))
    energy, power = [_stored_energy(sim)], [_dissipation(sim)]
    for _ in range(4000):
        sim.step(0.0)
        energy.append(_stored_energy(sim))
        power.append(_dissipation(sim))
    energy = np.array(energy)
    assert np.diff(energy).max() <= 1e-6 * energy[0]
    assert energy[-1] < 0.05 * energy[0]
    if not coulomb:
        lost = np.trapezoid(power, dx=DT)
        assert energy[0] - energy[-1] == pytest.approx(lost, rel=0.01)


# --- the oracle ---------------------------------------------------------------------------------
#: The oracle's sensors without noise or quantisation.
EXACT = dict(pressure_noise=0.0, pressure_bits=0, motor_counts=0, finger_counts=0)


def _as_package(effects):
    """The oracle's effects as the sim's rows (and its motor Coulomb friction)."""
    return NonlinearEffects(
        hose_damping_rise=1.0 / effects.hose_flow if effects.hose_flow else 0.0,
        hose_stiffening=effects.hose_pressure, stroke_stiffening=effects.stroke_stiffness,
        stroke_asymmetry=effects.stroke_asymmetry, finger_ratio=effects.finger_ratio,
        finger_asymmetry=effects.finger_asymmetry, half_stroke=STROKE, cogging=effects.cogging,
        cogging_periods=effects.cogging_periods, cogging_phase=effects.cogging_phase)


def _sim_backdrive(sim, controller, omega, settle):
    """(F_e, x_e) of the sim's finger over one period after ``settle`` [s] of drive."""
    m = sim.measurement()
    n_settle, n_rec = int(round(settle / DT)), int(round(2.0 * math.pi / omega / DT))
    rec = []
    for k in range(n_settle + n_rec):
        if k >= n_settle:
            rec.append((m.f_e, m.x_e))
        m = sim.step(controller.update(m.x, m.v, m.f_p))
    rec = np.array(rec)
    return impedance_figures(rec[:, 0], rec[:, 1], omega, DT)


def _free_air_misfit(plant, dahl, effects, coulomb):
    """Relative rms differences of X and F_p between the oracle and the sim under the same
    open-loop torque."""
    oracle = NonlinearGripper(plant, dahl, effects, None, **EXACT)
    sim = NonlinearChannelSimulator(PlantParams(**plant), DahlParams(**dahl),
                                    _as_package(effects), sensors=IDEAL, motor_coulomb=coulomb)
    rec = np.array([(a.x, b.x, a.f_p, b.f_p) for a, b in
                    ((oracle.step(_torque(k)), sim.step(_torque(k))) for k in range(8000))])

    def misfit(i):
        return math.sqrt(np.mean((rec[:, i] - rec[:, i + 1]) ** 2) / np.mean(rec[:, i] ** 2))
    return misfit(0), misfit(2)


#: Stated tolerances of the agreement with the oracle (its RK4 with every force on the stage's
#: state and a kinematic finger path, tanh-regularised Coulomb friction; the sim's exact step
#: with the effects' excess by the trapezoidal rule, a 1000 N m/rad drive, stick-slip Coulomb
#: friction). Seen on 3 draws: 0.05 % (X) and 0.3 % (F_p) in free air, 0.03 dB and 1 % of
#: the peaks in the backdrives.
FREE_AIR_TOLERANCE = 0.01
DB_TOLERANCE = 0.15
PEAK_TOLERANCE = 0.03


@pytest.mark.parametrize("seed", range(3))
def test_agrees_with_the_oracle_on_random_draws(seed):
    rng = np.random.default_rng([33, seed])
    plant, dahl = draw_family(rng)
    effects = draw_oracle_effects(rng)
    assert all(v for k, v in dataclasses.asdict(effects).items() if k != "cogging_phase")
    misfits = _free_air_misfit(plant, dahl, effects, effects.motor_coulomb)
    assert max(misfits) < FREE_AIR_TOLERANCE
    config = ControllerConfig()
    for mode, omega in (("passive", 1.0), ("dob_full_ff", 3.0)):
        def controller():
            return (Unpowered() if mode == "passive"
                    else ChannelController(config.replace(mode=mode), DT))
        rec = backdrive(plant, dahl, effects, controller(), 0.5, omega, periods=1, settle=1.0,
                        **EXACT)
        expected = impedance_figures(rec["f_e"], rec["x_e"], omega, DT)
        sim = NonlinearChannelSimulator(PlantParams(**plant), DahlParams(**dahl),
                                        _as_package(effects), sensors=IDEAL,
                                        motor_coulomb=effects.motor_coulomb,
                                        environment=position_sine(0.5, omega))
        got = _sim_backdrive(sim, controller(), omega, settle=1.0)
        assert got.z_db == pytest.approx(expected.z_db, abs=DB_TOLERANCE), mode
        assert got.z_rms_db == pytest.approx(expected.z_rms_db, abs=DB_TOLERANCE), mode
        assert got.peak == pytest.approx(expected.peak, rel=PEAK_TOLERANCE), mode
        assert got.peak_centre == pytest.approx(expected.peak_centre, rel=PEAK_TOLERANCE), mode


# --- rows, rules, draws ---------------------------------------------------------------------------
@pytest.mark.parametrize("values,named,said", [
    (dict(hose_stiffening=-0.1), "sim.nonlinear.hose_stiffening", ">= 0 and <= 1"),
    (dict(hose_damping_rise=5.0), "sim.nonlinear.hose_damping_rise", "too stiff"),
    (dict(cogging_periods=0), "sim.nonlinear.cogging_periods", ">= 1 and <= 1000"),
    (dict(stroke_stiffening=0.01, stroke_asymmetry=0.3), "sim.nonlinear.stroke_asymmetry",
     "falls"),
    (dict(finger_ratio=0.01, finger_asymmetry=-0.5), "sim.nonlinear.finger_asymmetry",
     "dead point"),
])
def test_bad_values_are_refused_with_the_reason(values, named, said):
    with pytest.raises(InvalidParameterError) as caught:
        NonlinearEffects(**values)
    assert named in str(caught.value) and said in str(caught.value)


def test_draws_stay_in_the_plausible_ranges_and_the_finger_map_inverts():
    rng = np.random.default_rng(0)
    for _ in range(200):
        effects, coulomb = draw_effects(rng)
        assert PLAUSIBLE["hose_doubling_flow"][0] <= 1.0 / effects.hose_damping_rise \
            <= PLAUSIBLE["hose_doubling_flow"][1]
        for name in ("hose_stiffening", "stroke_stiffening", "finger_ratio", "cogging"):
            low, high = PLAUSIBLE[name]
            assert low <= getattr(effects, name) <= high, name
        assert PLAUSIBLE["motor_coulomb"][0] <= coulomb <= PLAUSIBLE["motor_coulomb"][1]
        assert abs(effects.stroke_asymmetry) <= effects.stroke_stiffening / 3.0
        assert abs(effects.finger_asymmetry) <= effects.finger_ratio / 3.0
        for q in (-0.7, -0.2, 0.3, 0.7):
            assert finger_of_endpoint(endpoint_of_finger(q, effects), effects) == \
                pytest.approx(q, abs=1e-12)
    assert "hose damping x2" in effects.describe()
    assert NonlinearEffects().describe().startswith("none")
