"""The Z-width predictor against analytic results and against closed-loop simulation.

Oracles: the passive endpoint impedance of Table I (the reference figures), eq. 22's
low-frequency stiffness with internal force feedback, the continuous DOB impedance of
:class:`~seaforce_ros.core.plant.PlantModel` (eq. 19 without sampling or delay), the Dahl
model's Coulomb and small-amplitude limits, and the project's simulator running the core
controller on random plants with a wrong model (measured as the Z-width tool measures: the
stiff position drive, 0.5 rad).
"""
import math

import numpy as np
import pytest

from helpers.delayed_hold import hold_grows
from helpers.configs import exact_feedforward
from seaforce_ros.commissioning.errors import CommissioningError
from seaforce_ros.commissioning.predictor import (
    PLANT_FIELDS, PREDICTED_MODES, LoopModel, PredictionError, closed_loop_radius,
    dahl_describing_function,
    hold_delay_limit, hold_verdict, predict_band, predict_impedance, predict_modes,
    torque_noise, wall_limits)
from seaforce_ros.core import ChannelController, ChannelSimulator, ControllerConfig
from seaforce_ros.core.analysis import (eq22_stiffness, eq23_stiffness, eq24_stiffness,
                                        frequency_response, hold_loop)
from seaforce_ros.core.dahl import DahlState
from seaforce_ros.core.params import (DahlParams, ForceFeedbackParams, GraspParams, PlantParams,
                                      TargetParams)
from seaforce_ros.core.plant import PlantModel
from seaforce_ros.core.sensors import SensorParams
from seaforce_ros.identification.zwidth_lib import simulate_impedance

TABLE_I = PlantParams.table_i()
DAHL = DahlParams()
DT = 5e-4


def db(z):
    return 20.0 * np.log10(np.abs(z))


# --- analytic oracles -------------------------------------------------------------------------
def test_passive_matches_the_reference_figures():
    z = predict_impedance(TABLE_I, None, ControllerConfig(), "passive", [0.1, 1.0, 3.0, 10.0])
    np.testing.assert_allclose(db(z), [7.08, -12.66, -20.51, -23.92], atol=0.006)


def test_force_feedback_low_frequency_stiffness_is_eq22():
    config = ControllerConfig(force_feedback=ForceFeedbackParams(gain=1.0))
    w = 1e-3
    z = predict_impedance(TABLE_I, None, config, "force_feedback", [w])
    assert abs(z[0]) * w == pytest.approx(eq22_stiffness(TABLE_I), rel=1e-3)
    assert eq22_stiffness(TABLE_I) == pytest.approx(0.1453, abs=1e-4)


def test_stiff_and_soft_motor_limits_are_eq23_and_eq24():
    """Unpowered with a non-backdrivable motor (k = 1e5 k_s): the endpoint's DC stiffness is
    k_s + k_e (eq. 23); internal force feedback K_f = 1 with a stiff hose (k_s = 1e4 k):
    k/2 + k_e (eq. 24)."""
    w = 1e-3
    rigid_motor = TABLE_I.scaled(motor_stiffness=1e5 * TABLE_I.hose_stiffness
                                 / TABLE_I.motor_stiffness)
    z = predict_impedance(rigid_motor, None, ControllerConfig(), "passive", [w])
    assert abs(z[0]) * w == pytest.approx(eq23_stiffness(rigid_motor), rel=1e-3)
    stiff_hose = TABLE_I.scaled(hose_stiffness=1e4 * TABLE_I.motor_stiffness
                                / TABLE_I.hose_stiffness)
    config = ControllerConfig(plant=stiff_hose, force_feedback=ForceFeedbackParams(gain=1.0))
    z = predict_impedance(stiff_hose, None, config, "force_feedback", [w])
    assert abs(z[0]) * w == pytest.approx(eq24_stiffness(stiff_hose), rel=1e-3)


@pytest.mark.parametrize("linear_ff", [False, True])
def test_dob_approaches_the_continuous_model_without_delay(linear_ff):
    """Sampled at 20 kHz with no loop delay, the predicted DOB impedance is the continuous
    eq. 19 one (PlantModel, the paper's exact feed-forward) within 0.05 dB; at 2 kHz with one
    sample of delay it differs."""
    config = exact_feedforward()
    mode = "dob_linear_ff" if linear_ff else "dob"
    omega = np.array([1.0, 3.0, 10.0, 30.0])
    z = predict_impedance(TABLE_I, None, config, mode, omega, delay=0, dt=5e-5)
    ref = frequency_response(PlantModel(TABLE_I).dob_impedance(config.dob, linear_ff), omega)
    np.testing.assert_allclose(db(z), db(ref), atol=0.05)


def test_describing_function_limits():
    """A << F_c/sigma: a spring sigma; A >> F_c/sigma: Coulomb friction j 4 F_c/(pi A); a play
    as wide as the motion leaves nothing; the general-n path agrees with a time-domain run."""
    assert dahl_describing_function(DAHL, 1e-7) == pytest.approx(DAHL.sigma, rel=1e-3)
    big = dahl_describing_function(DAHL, 50.0)
    assert big.imag == pytest.approx(4 * DAHL.coulomb_force / (math.pi * 50.0), rel=2e-3)
    assert abs(big.real) < 0.01 * big.imag
    assert dahl_describing_function(DAHL, 1e-4, play=2e-4) == 0j
    assert dahl_describing_function(None, 0.5) == 0j
    for exponent in (0.5, 1.0, 2.0):
        dahl = DahlParams(sigma=12.8, coulomb_force=0.032, exponent=exponent)
        for amplitude, play in ((0.002, 0.0), (0.01, 1e-3), (0.5, 1e-4)):
            assert dahl_describing_function(dahl, amplitude, play) == pytest.approx(
                _simulated_describing_function(dahl, amplitude, play), rel=0.01, abs=1e-4)


def _simulated_describing_function(dahl, amplitude, play, n=4000):
    """x = A cos(theta) through a play and DahlState, three cycles, first harmonic of the
    last one."""
    state = DahlState(dahl, amplitude - 0.5 * play)
    theta = 2 * math.pi * (np.arange(3 * n) + 1) / n
    y = amplitude - 0.5 * play
    f = np.empty(theta.size)
    for i, th in enumerate(theta):
        x = amplitude * math.cos(th)
        y = min(max(y, x - 0.5 * play), x + 0.5 * play)
        f[i] = state.update(y)
    last = slice(2 * n, 3 * n)
    return complex(2.0 / n * np.sum(f[last] * np.exp(-1j * theta[last])) / amplitude)


@pytest.mark.parametrize("delay", [0, 1, 3, 5])
def test_closed_loop_of_the_hold_is_the_analysis_modules(delay):
    """The generic sampled loop built from the controller's polynomials has, for the hold,
    the spectral radius of the hand-built hold loop (core.analysis.hold_loop)."""
    config = ControllerConfig()
    for endpoint, k in (("free", 0.0), ("clamped", 1e4)):
        b = 2.0 * 0.7 * math.sqrt(k * TABLE_I.endpoint_inertia)
        A, _ = hold_loop(TABLE_I, config.hold.stiffness, config.hold.damping, DT, delay,
                         endpoint, k or 1e4)
        rho = closed_loop_radius(TABLE_I, None, config, "hold", delay=delay,
                                 endpoint_stiffness=k, endpoint_damping=b)
        assert rho == pytest.approx(float(np.max(np.abs(np.linalg.eigvals(A)))), rel=1e-9)


def test_wall_limits_are_the_two_bounds():
    figures = LoopModel(pressure_noise=5e-4, encoder_resolution=2 * math.pi / 2 ** 14,
                          delay_p50=1, delay_p99=3)
    b_t = np.linspace(0.0, 0.05, 11)
    wall = wall_limits(TABLE_I, DAHL, ControllerConfig(), figures, b_t)
    T = figures.dt
    np.testing.assert_allclose(wall.passivity, np.maximum(0.0, wall.physical_damping - b_t)
                               / (0.5 * T + 3 * T))
    assert wall.quantisation == pytest.approx(2 * DAHL.coulomb_force
                                              / figures.encoder_resolution)
    np.testing.assert_allclose(wall.stiffness, np.minimum(wall.passivity, wall.quantisation))
    assert wall.physical_damping > 0.0
    assert wall.binding == tuple("passivity" if p <= wall.quantisation else "quantisation"
                                 for p in wall.passivity)
    assert np.all(np.diff(wall.stiffness) <= 0.0)
    # an encoder so coarse that 2 F_c/Delta is below the passivity bound at B = 0
    coarse = LoopModel(pressure_noise=5e-4, encoder_resolution=0.5, delay_p50=1,
                         delay_p99=3)
    wall = wall_limits(TABLE_I, DAHL, ControllerConfig(), coarse, [0.0])
    assert wall.binding == ("quantisation",)
    assert wall.stiffness[0] == pytest.approx(2 * DAHL.coulomb_force / 0.5)


def test_band_collapses_without_uncertainty_and_widens_with_it():
    omega = [1.0, 3.0]
    modes = ("hold", "dob_full_ff")
    flat = predict_band(TABLE_I, {}, DAHL, ControllerConfig(), omega, modes, draws=3)
    for m in modes:
        np.testing.assert_allclose(flat.lower[m], np.abs(flat.nominal[m]), rtol=1e-12)
        np.testing.assert_allclose(flat.upper[m], np.abs(flat.nominal[m]), rtol=1e-12)
    sigma = {n: 0.1 * getattr(TABLE_I, n) for n in PLANT_FIELDS}
    sigma.update(sigma=1.0, coulomb_force=0.003)
    band = predict_band(TABLE_I, sigma, DAHL, ControllerConfig(), omega, modes, draws=12)
    assert np.all(band.upper["dob_full_ff"] > band.lower["dob_full_ff"])
    assert np.all(band.zwidth_upper_db > band.zwidth_lower_db)
    assert band.zwidth_db.shape == (2,)


def test_bad_input_is_refused_with_a_reason():
    config = ControllerConfig()
    with pytest.raises(PredictionError, match="models"):
        predict_impedance(TABLE_I, None, config, "chirp", [1.0])
    for omega in ([0.0], [math.pi / DT], [float("nan")], []):
        with pytest.raises(PredictionError, match="omega"):
            predict_impedance(TABLE_I, None, config, "dob", omega)
    with pytest.raises(PredictionError, match="delay"):
        predict_impedance(TABLE_I, None, config, "dob", [1.0], delay=-1)
    with pytest.raises(CommissioningError, match="pressure_noise"):
        LoopModel(pressure_noise=float("nan"), encoder_resolution=1e-5)
    with pytest.raises(CommissioningError, match="p99"):
        LoopModel(pressure_noise=1e-4, encoder_resolution=1e-5, delay_p50=3, delay_p99=2)


# --- against the closed-loop simulation -------------------------------------------------------
def random_case(rng):
    """A plant 0.5x-2x Table I (log-uniform per parameter, Dahl too) and a controller whose
    model is 10-20 % off in every parameter."""
    def draw(v):
        return v * math.exp(rng.uniform(-math.log(2.0), math.log(2.0)))

    def wrong(v):
        return v * (1.0 + rng.choice([-1.0, 1.0]) * rng.uniform(0.1, 0.2))

    true = PlantParams(**{n: draw(getattr(TABLE_I, n)) for n in PLANT_FIELDS})
    dahl = DahlParams(sigma=draw(12.8), coulomb_force=draw(0.032))
    model = PlantParams(**{n: wrong(getattr(true, n)) for n in PLANT_FIELDS})
    config = ControllerConfig(
        plant=model, dahl=DahlParams(sigma=wrong(dahl.sigma),
                                     coulomb_force=wrong(dahl.coulomb_force)),
        target=TargetParams(stiffness=0.02 * model.hose_stiffness,
                            damping=2.0 * model.hose_damping),
        grasp=GraspParams(contact_damping=min(0.08, 10.0 * model.hose_damping)))
    return true, dahl, config


@pytest.mark.parametrize("seed", [11, 12])
def test_prediction_within_3_db_of_the_simulated_backdrive(seed):
    """Every mode at 1, 3 and 10 rad/s, drive 0.5 rad, true plant != model."""
    true, dahl, config = random_case(np.random.default_rng(seed))
    omegas = (1.0, 3.0, 10.0)
    assert hold_delay_limit(true, config.hold.stiffness, config.hold.damping) >= 1
    predicted = predict_modes(true, dahl, config, PREDICTED_MODES, omegas, amplitude=0.5)
    measured = simulate_impedance(true, dahl, config, PREDICTED_MODES, omegas, amplitude=0.5)
    for mode in PREDICTED_MODES:
        err = db(predicted[mode]) - db(measured[mode])
        assert np.all(np.abs(err) <= 3.0), (mode, err)


@pytest.mark.parametrize("seed", [21, 22, 23])
def test_hold_delay_limit_within_one_sample_of_the_simulated(seed):
    """The first delay at which the simulated hold grows (endpoint free, from an offset) is
    the predicted limit + 1, within one sample."""
    true, dahl, config = random_case(np.random.default_rng(seed))
    kp, kd = config.hold.stiffness, config.hold.damping
    predicted = hold_delay_limit(true, kp, kd)
    first_unstable = next(d for d in range(1, 40)
                          if hold_grows(true, dahl, config, d, seconds=1.5, seed=5))
    assert abs((first_unstable - 1) - predicted) <= 1
    verdict = hold_verdict(true, kp, kd, delay=1)
    assert verdict.delay_limit_free == predicted
    assert verdict.margins.stable == (predicted >= 1 and verdict.delay_limit_clamped >= 1)


@pytest.mark.parametrize("mode", ["dob", "dob_linear_ff"])
def test_torque_noise_matches_the_simulated_free_finger(mode):
    """RMS of F_a, finger free and at rest, from the simulator's pressure noise (no ADC step)
    on an ideal encoder: within 10 % of the prediction. With its 2^20-count encoder the
    total is within -30 %..+10 % of the prediction: the white model of the quantisation is
    exact once the motion spans many counts (dob_linear_ff: its share within 30 % of the
    root-sum-square difference of the two runs) and conservative when the finger moves by a
    count or two (dob: 1e-5 rad rms, 35 % over)."""
    def measured(counts):
        sensors = SensorParams(motor_counts_per_rev=counts, pressure_bits=0)
        sim = ChannelSimulator(TABLE_I, DAHL, dt=DT, seed=9, sensors=sensors)
        ctl = ChannelController(ControllerConfig(mode=mode), DT)
        m = sim.measurement()
        u = np.empty(12000)
        for i in range(u.size):
            u[i] = ctl.update(m.x, m.v, m.f_p)
            m = sim.step(u[i])
        return float(np.std(u[2000:]))

    sensors = SensorParams()
    figures = LoopModel(pressure_noise=sensors.pressure_noise,
                          encoder_resolution=sensors.motor_quantum)
    p_rms, x_rms = torque_noise(TABLE_I, DAHL, ControllerConfig(), figures, mode=mode)
    total, pressure_only = measured(2 ** 20), measured(0)
    assert 0.7 * math.hypot(p_rms, x_rms) <= total <= 1.1 * math.hypot(p_rms, x_rms)
    assert p_rms == pytest.approx(pressure_only, rel=0.10)
    if mode == "dob_linear_ff":
        assert x_rms == pytest.approx(math.sqrt(total ** 2 - pressure_only ** 2), rel=0.3)
