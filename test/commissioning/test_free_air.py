"""Self-identification in free air (:mod:`seaforce_ros.commissioning.free_air`).

Oracles that do not come from the project's simulator: records of the exact linear model and
of :mod:`helpers.second_sim` (its own integration, Dahl model and sensors), plants drawn at
random, and the module docstring's claims checked one by one (which response gives which
parameter: a change of the motor in the data leaves the endpoint and hose unchanged, and the
other way round; the band a record must excite).

Randomised family. Goal: m, m_e, k_s within 5 %; b, k, b_e, k_e, b_s within 15 %; sigma, F_c
within 25 %, for >= 95 % of 40 draws (each Table I parameter, sigma and F_c log-uniform in
[0.5x, 2x]; the rig's sensors; no endpoint encoder; alternately on the second simulator and the
core simulator): here all 40 are drawn (~1.9 s each: a 0.5 s simulation, a ~1.4 s fit) and at
most 2 may miss. A method that misses 1 % of the family fails this test with probability
0.8 %; one that misses 10 % is caught with probability 78 % per run. No draw may miss a limit
by more than 2x. ``bench/free_air_identification.py`` prints the distributions. Every run
draws its own seed (printed; ``SEAFORCE_FREEAIR_SEED=<seed>`` replays one).
"""
import concurrent.futures
import math
import multiprocessing
import os

import numpy as np
import pytest

from helpers.free_air_records import (DT, GOALS, TABLE_I, as_record, core_sim_record, draw,
                                      errors, second_sim_record)
from helpers.second_sim import DAHL
from seaforce_ros.commissioning.errors import CommissioningError
from seaforce_ros.commissioning.free_air import (
    PLANT_KEYS, LowCoherenceError, NonFiniteRecordError, NotExcitedError,
    RecordTooShortError, identify_free_air)
from seaforce_ros.core.params import DahlParams, PlantParams

MOTOR = PLANT_KEYS[:3]
PORT = PLANT_KEYS[3:]


@pytest.fixture(scope="module")
def exact():
    """The exact linear model (no Dahl, no noise, no quantisation) and its identification."""
    result = identify_free_air(second_sim_record(ideal=True))
    return result


def test_exact_linear_model_gives_all_eight_within_one_percent(exact):
    for key in PLANT_KEYS:
        assert exact.value(key) == pytest.approx(TABLE_I[key], rel=0.01), key
        assert exact.parameters[key].sigma > 0.0
    # no hysteresis in the data: none reported, with the reason
    assert not exact.parameters["sigma"].identified
    assert "no hysteresis" in exact.parameters["sigma"].reason
    assert exact.misfit["motor"] < 0.01 and exact.misfit["port"] < 0.01
    plant = exact.plant()
    assert isinstance(plant, PlantParams)
    with pytest.raises(CommissioningError, match="sigma"):
        exact.dahl()


@pytest.mark.parametrize("key", PLANT_KEYS)
def test_each_parameter_moves_only_itself(exact, key):
    """The docstring: m, b, k from X/(F_a + F_p) alone, the other five from F_p/X alone, each
    its own coefficient: 30 % more of one parameter in the (exact) data moves that one by
    30 % (within 1 %) and leaves the other seven where they were (within 0.5 %; k_e, which
    the other coefficients' errors reach through the low band, within 1 %)."""
    plant = dict(TABLE_I, **{key: 1.3 * TABLE_I[key]})
    r = identify_free_air(second_sim_record(plant, ideal=True))
    assert r.value(key) == pytest.approx(plant[key], rel=0.01)
    for other in PLANT_KEYS:
        if other != key:
            tol = 0.01 if other == "endpoint_stiffness" else 0.005
            assert r.value(other) == pytest.approx(exact.value(other), rel=tol), other


def test_the_port_resonance_is_where_m_e_shows(exact):
    """The docstring: m_e from the hose resonance w_h = sqrt((k_s + k_e)/m_e), the pole of
    F_p/X: the measured |F_p/X| peaks there."""
    w_h = math.sqrt((TABLE_I["hose_stiffness"] + TABLE_I["endpoint_stiffness"])
                    / TABLE_I["endpoint_inertia"])
    port = exact.port
    peak = port.omega[np.argmax(np.abs(port.h) / np.abs(
        TABLE_I["hose_stiffness"] + 1j * port.omega * TABLE_I["hose_damping"]))]
    assert peak == pytest.approx(w_h, rel=0.1)


def test_port_tends_to_the_hose_above_its_resonance(exact):
    """The docstring: above the hose resonance -F_p/X -> b_s s + k_s (k_s its real part, b_s
    its imaginary part over w), on the measured response (up to 1000 rad/s: above, the held
    torque's aliasing, which the model folds in, moves it by more than 5 %)."""
    w_h = math.sqrt((TABLE_I["hose_stiffness"] + TABLE_I["endpoint_stiffness"])
                    / TABLE_I["endpoint_inertia"])
    port = exact.port
    top = (port.omega >= 6.0 * w_h) & (port.omega <= 1000.0)
    assert top.any()
    zs = TABLE_I["hose_stiffness"] + 1j * port.omega[top] * TABLE_I["hose_damping"]
    assert np.max(np.abs(-port.h[top] / zs - 1.0)) < 0.05
    below = port.omega <= w_h / 6.0
    zs_below = TABLE_I["hose_stiffness"] + 1j * port.omega[below] * TABLE_I["hose_damping"]
    assert np.min(np.abs(-port.h[below] / zs_below - 1.0)) > 0.9     # not the hose down there


@pytest.mark.parametrize("simulator", [second_sim_record, core_sim_record])
def test_table_i_with_dahl_and_sensors_meets_the_goals(simulator):
    result = identify_free_air(simulator(dict(TABLE_I), dict(DAHL), seed=3))
    err = errors(result, TABLE_I, DAHL)
    for key, tol in GOALS.items():
        assert abs(err[key]) <= tol, (key, err[key])
    dahl = result.dahl()
    assert isinstance(dahl, DahlParams) and dahl.exponent == 1.0
    for key in GOALS:
        e = result.parameters[key]
        assert e.identified and 0.0 < e.sigma < e.value, key
    # the responses for plots: one grid, coherences in (0, 1], the model close to the data
    for resp in (result.motor, result.port):
        assert resp.h.shape == resp.omega.shape == resp.sigma.shape == resp.model.shape
        assert np.all((resp.coherence > 0.0) & (resp.coherence <= 1.0))
    assert result.misfit["motor"] < 0.05 and result.misfit["port"] < 0.05


def _family_draw(seed, i):
    """Draw ``i`` of the family of ``seed``: (plant, dahl, errors)."""
    rng = np.random.default_rng(seed)
    for _ in range(i + 1):
        plant, dahl = draw(rng)
    simulator = second_sim_record if i % 2 == 0 else core_sim_record
    result = identify_free_air(simulator(plant, dahl, seed=seed + i))
    return plant, dahl, errors(result, plant, dahl)


# 40 fits of ~1.4 s CPU, two at a time: beside a CPU-burning process per core and other work
# the suite's 300 s guard is too short
@pytest.mark.timeout(900)
def test_randomised_family_meets_the_goals():
    seed = int(os.environ.get("SEAFORCE_FREEAIR_SEED", np.random.SeedSequence().entropy % 2 ** 32))
    print(f"SEAFORCE_FREEAIR_SEED={seed}")
    failing = []
    # the draws are independent: one per core (pytest itself runs on one)
    with concurrent.futures.ProcessPoolExecutor(max_workers=min(2, os.cpu_count() or 1),
                                                mp_context=multiprocessing.get_context(
                                                    "forkserver")) as pool:
        draws = pool.map(_family_draw, [seed] * 40, range(40))
        for i, (plant, dahl, err) in enumerate(draws):
            missed = {k: e for k, e in err.items() if not abs(e) <= GOALS[k]}
            gross = {k: e for k, e in err.items() if not abs(e) <= 2.0 * GOALS[k]}
            assert not gross, f"seed {seed}, draw {i}: {gross} ({plant}, {dahl})"
            if missed:
                failing.append((i, missed))
    assert len(failing) <= 2, f"seed {seed}: {failing}"


# --- errors ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def short_chirp():
    return second_sim_record(duration=8.0, start_hz=0.5, end_hz=400.0)


def test_a_record_too_short_says_record_longer(short_chirp):
    n = 2000
    r = short_chirp
    cut = as_record({k: getattr(r, k)[:n] for k in ("x", "v", "f_p", "applied", "command",
                                                    "excitation")})
    with pytest.raises(RecordTooShortError, match="record longer"):
        identify_free_air(cut)
    with pytest.raises(RecordTooShortError):
        identify_free_air(as_record({k: getattr(r, k)[:10] for k in (
            "x", "v", "f_p", "applied", "command", "excitation")}))


def test_a_record_not_excited_in_the_band_says_widen_the_chirp():
    r = second_sim_record(duration=10.0, start_hz=0.5, end_hz=50.0)
    with pytest.raises(NotExcitedError, match="chirp"):
        identify_free_air(r)
    flat = as_record({"x": r.x, "v": r.v, "f_p": r.f_p, "applied": r.applied,
                      "command": r.command, "excitation": np.zeros(len(r))})
    with pytest.raises(NotExcitedError, match="constant"):
        identify_free_air(flat)


@pytest.mark.parametrize("name", ["x", "v", "f_p", "applied", "excitation"])
@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_samples_are_refused(short_chirp, name, bad):
    data = {k: getattr(short_chirp, k).copy() for k in ("x", "v", "f_p", "applied", "command",
                                                        "excitation")}
    data[name][1234] = bad
    with pytest.raises(NonFiniteRecordError, match=f"{name} has 1 non-finite.*1234"):
        identify_free_air(as_record(data))


def test_noise_without_the_excitation_is_refused_as_low_coherence(short_chirp):
    rng = np.random.default_rng(0)
    n = len(short_chirp)
    noise = {k: rng.standard_normal(n) * 1e-3 for k in ("x", "v", "f_p", "applied")}
    rec = as_record(dict(noise, command=short_chirp.command,
                         excitation=short_chirp.excitation))
    with pytest.raises(LowCoherenceError, match="raise the excitation"):
        identify_free_air(rec, band=(10.0, 1200.0))


def test_band_outside_what_the_record_can_hold_is_refused(short_chirp):
    with pytest.raises(CommissioningError, match="Nyquist"):
        identify_free_air(short_chirp, band=(10.0, 5000.0))
    with pytest.raises(CommissioningError, match="0 < lo < hi"):
        identify_free_air(short_chirp, band=(100.0, 10.0))


def test_gaps_in_the_cycle_are_filled_and_progress_is_reported():
    r = second_sim_record(dict(TABLE_I), dict(DAHL), seed=5)
    keep = np.ones(len(r), bool)
    keep[5000:5003] = keep[40000:40001] = False
    gappy = type(r)(DT, r.cycle[keep], *(getattr(r, k)[keep] for k in (
        "x", "v", "f_p", "applied", "command", "excitation")))
    seen = []
    result = identify_free_air(gappy, progress=lambda msg, frac: seen.append(frac))
    assert seen and seen[-1] == 1.0 and all(0.0 <= f <= 1.0 for f in seen)
    for key, tol in GOALS.items():
        assert abs(errors(result, TABLE_I, DAHL)[key]) <= tol, key
    with pytest.raises(TypeError):
        identify_free_air(object())  # type: ignore[arg-type]


def test_a_linear_start_100x_off_is_fitted_again_from_the_bound():
    """A plant whose port's linear start put m_e and b_e 100x too high (the second simulator,
    found by the family test): the bounded fit ended on its bound with a 14 % misfit and m_e not
    identified; restarted from there it identifies every parameter within its goal."""
    plant = {'motor_inertia': 0.0020449796752801857, 'motor_damping': 0.04026317676999222,
             'motor_stiffness': 0.1820090219803304, 'endpoint_inertia': 0.0004856862864079033,
             'endpoint_damping': 0.05281901559937108, 'endpoint_stiffness': 0.049446437780530796,
             'hose_damping': 0.014419142539178042, 'hose_stiffness': 11.24523398337605}
    dahl = {'sigma': 21.182857253431, 'coulomb_force': 0.05058845948374867}
    result = identify_free_air(second_sim_record(plant, dahl, seed=2833222416 + 8))
    err = errors(result, plant, dahl)
    assert {k: e for k, e in err.items() if not abs(e) <= GOALS[k]} == {}, err
    assert result.misfit["port"] < 0.05


def _preloaded_endpoint(preload, seed=0):
    """(X_e, F_p) of a free finger at rest for 0.5 s -- its Dahl force ``preload`` [N m] (a
    finger left stuck under a pressure force, as after a canceled excitation) -- then driven
    along sines of 1-8 Hz growing to 0.3 rad: Table I's endpoint and the paper's Dahl model,
    F_p the force that moves it (a little noise)."""
    from seaforce_ros.core.dahl import DahlState
    dt = DT
    p = PlantParams.table_i()
    n = int(6.0 / dt)
    t = np.arange(n) * dt
    ramp = np.clip((t - 0.5) / 0.3, 0.0, 1.0)
    xe = np.where(t < 0.5, 0.0, ramp * 0.3 * np.sin(2 * math.pi * (1.0 + 1.2 * (t - 0.5))
                                                     * (t - 0.5)))
    dahl = DahlState(DahlParams())
    dahl.reset(0.0, preload)
    fd = np.array([dahl.update(x) for x in xe])
    v = np.gradient(xe, dt)
    f_p = -(p.endpoint_inertia * np.gradient(v, dt) + p.endpoint_damping * v
            + p.endpoint_stiffness * xe + fd)
    return xe, f_p + 1e-4 * np.random.default_rng(seed).standard_normal(n)


@pytest.mark.parametrize("preload", [0.0, 0.016, -0.016, 0.028])
def test_a_finger_stuck_under_a_preload_does_not_bias_the_dahl_stiffness(preload):
    """The friction fit counts samples from SETTLE_TRAVEL of travel on, not from a time: a
    Dahl state forgets its start through motion. Counted from 0.5 s (the excitation's start),
    these gave sigma 85 / 5.8 / 320 for preloads 0.016 / -0.016 / 0.028 N m (12.1 without);
    short records over ROS of one plant, 10.5-39.9 against 12.8."""
    from seaforce_ros.commissioning.free_air import _fit_friction
    xe, f_p = _preloaded_endpoint(preload)
    est = _fit_friction(xe, f_p, PlantParams.table_i().endpoint_inertia, DT)
    assert not est.reason, est.reason
    assert abs(est.sigma / 12.8 - 1.0) < 0.15, est.sigma
    assert abs(est.coulomb_force / 0.032 - 1.0) < 0.05, est.coulomb_force
