"""Commissioning's verification of the feed-forward on the free finger
(:mod:`seaforce_ros.commissioning.verification`, :mod:`seaforce_ros.commissioning.candidates`).

* On the independent oracle (its own integrator, a rig's sensors drawn: a coarse encoder, the
  drive's velocity filter, a pressure ADC with noise and an offset, extra delay), the whole run
  as ``~/commission`` does it (:func:`helpers.oracle_commissioning.commission`): what the
  verification passes, a free finger rests under -- flicked by a hand at random points of the
  stroke, its motion dies out (an independent test, not the verification's windows); the run
  never chooses a candidate the finger failed, nor tries one the model predicts to fail.
* An over-compensating candidate (the exact inversion on a finger with a fifth less friction
  than the model) fails with its reason and nothing of it is chosen; none passing, the
  feed-forward keeps the starting settings.
* On the identified model itself, the prediction is what the verification measures.
* Properties over arbitrary inputs: the torque within ``min(commissioning.max_torque,
  max_torque)``; a non-finite input ends it with zero torque.
"""
import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.commissioning.candidates import FEEDFORWARD_KEYS, chosen_values
from seaforce_ros.commissioning.verification import (Candidate, FreeFingerVerification,
                                                     predict)
from seaforce_ros.core import ChannelController, ChannelSimulator, ControllerConfig, DahlParams
from seaforce_ros.core.jobs import JobSample
from seaforce_ros.core.params import PlantParams
from seaforce_ros.core.safety import REST_SPEED

from helpers.configs import exact_feedforward
from helpers.nonlinear_sim import NonlinearGripper, draw_sensors, run_loop
from helpers.oracle_commissioning import commission, draw

DT = 5e-4
CONFIG = ControllerConfig(max_torque=20.0)


def verify_on(sim, candidates, config=CONFIG, points=None):
    """The verification of ``candidates`` run by a controller on ``sim`` (at ``points``:
    default the job's own); the job."""
    ctl = ChannelController(config.replace(mode="passive"), DT)
    job = FreeFingerVerification(candidates, config, DT)
    if points is not None:
        job.points = list(points)
    ctl.request_job(job)
    m = sim.measurement()
    for _ in range(int(200.0 / DT)):
        m = sim.step(ctl.update(m.x, m.v, m.f_p))
        if not job.active:
            break
    return job


def flicked(plant, dahl, effects, sensors, config, start, push, seed, seconds=6.0):
    """The free finger on the oracle under ``config`` (dob_full_ff), at rest at ``start``,
    pushed by a hand for 0.1 s with ``push`` N m (at 0.5 s), then left alone: its true speed
    per sample and the controller's fall-back."""
    def hand(t, xe, ve):
        return push if 0.5 <= t < 0.6 else 0.0
    g = NonlinearGripper(plant, dahl, effects, None, seed=seed, sensors=sensors, hand=hand)
    g.place(start)
    ctl = ChannelController(config.replace(mode="dob_full_ff"), DT)
    ve = []
    m = g.measurement()
    for _ in range(int(seconds / DT)):
        m = g.step(ctl.update(m.x, m.v, m.f_p))
        ve.append(g.state[3])
    return np.asarray(ve), ctl.fallback


@pytest.mark.parametrize("seed", [0, 1])
def test_what_the_verification_passes_a_free_finger_rests_under(seed):
    rng = np.random.default_rng([45, seed])
    plant, dahl, effects = draw(rng, effects=bool(seed % 2))
    sensors = draw_sensors(rng)
    analysis, rig, _ = commission(plant, dahl, effects, sensors, seed=seed, duration=20.0)
    assert analysis.tuned, analysis.message
    assert rig <= 90.0
    rows = analysis.verification
    assert rows and not any(math.isnan(r.settle_predicted) for r in rows)
    verdicts = {r.candidate: r.verdict for r in rows}
    config = analysis.tuning.config
    binding = analysis.tuning.bindings["feedforward.dahl_stiffness_share"]
    passed = [name for name, verdict in verdicts.items() if verdict == "passed"]
    if passed:
        assert binding == f"verified on the gripper: {passed[0]}"
    else:
        assert "starting settings" in binding
    # every candidate tried before the chosen one failed on the finger
    tried = [name for name, verdict in verdicts.items()
             if verdict == "passed" or verdict.startswith("failed")]
    assert tried and all(verdicts[name].startswith("failed") for name in tried[:-1])
    # the model bounds the search: what it predicts to fail is not tried
    assert all(not r.verdict.startswith("predicted to fail") or math.isnan(r.settle)
               for r in rows)
    # an independent test: hand flicks at random points of the stroke (a finger speed of
    # 0.7-2 rad/s), then the finger alone: its motion dies out -- resting, or moving at the
    # end at most a quarter as fast as after the flick (a finger nearly without friction
    # coasts far and swings slowly on the spring that is left) -- and nothing trips
    for k in range(3):
        start = float(rng.uniform(-0.4, 0.4))
        push = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.005, 0.015))
        ve, fallback = flicked(plant, dahl, effects, sensors, config, start, push, seed + k)
        after = np.sqrt(np.mean(ve[int(0.6 / DT):int(1.6 / DT)] ** 2))
        last = np.sqrt(np.mean(ve[-int(1.0 / DT):] ** 2))
        assert not fallback, (start, push, fallback)
        assert last <= max(REST_SPEED, 0.25 * after), (start, push, last, after,
                                                       sensors.describe())


def test_an_over_compensating_candidate_fails_and_nothing_of_it_is_chosen():
    """The exact inversion (no margin, all of sigma) on a finger with a tenth less friction
    than the model: it creeps or rings; the model's own cautious setting (b_e, k_e x0.8)
    rests."""
    model = PlantParams.table_i()
    finger = model.scaled(endpoint_damping=0.9, endpoint_stiffness=0.9)
    dahl = DahlParams()
    bold = Candidate("exact", exact_feedforward(CONFIG))
    cautious = Candidate("cautious", CONFIG)
    sim = ChannelSimulator(finger, DahlParams(sigma=0.9 * dahl.sigma,
                                              coulomb_force=0.9 * dahl.coulomb_force), DT)
    job = verify_on(sim, [bold, cautious])
    assert job.outcome == "succeeded"
    first, second = job.outcomes
    assert not first.passed and first.reason and first.windows[-1].failed
    assert second.passed and job.chosen == 1
    values = chosen_values([bold, cautious], job.chosen, CONFIG, True)
    assert values == chosen_values([cautious], 0, CONFIG, True)
    # none passing: the starting settings; unverified: the last (most cautious) candidate
    start = CONFIG.replace(feedforward=dataclasses.replace(CONFIG.feedforward, margin=3.0))
    assert chosen_values([bold], None, start, True)["feedforward.damping_uncertainty"] == \
        start.feedforward.damping_uncertainty
    assert set(chosen_values([bold, cautious], None, start, False)) == set(FEEDFORWARD_KEYS)


def test_on_the_model_itself_the_prediction_is_the_measurement():
    plant, dahl = PlantParams.table_i(), DahlParams()
    candidates = [Candidate("defaults", CONFIG)]
    predicted = predict(plant, dahl, candidates, CONFIG, delay=1)[0]
    measured = verify_on(ChannelSimulator(plant, dahl, DT), candidates).outcomes[0]
    assert predicted.passed and measured.passed
    assert len(predicted.windows) == len(measured.windows) == 4
    for p, m in zip(predicted.windows, measured.windows):
        assert (p.point, p.kind) == (m.point, m.kind)
        assert m.settle == pytest.approx(p.settle, abs=0.15)
        assert m.peak_speed == pytest.approx(p.peak_speed, rel=0.2)


values = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.floats(-2.0, 2.0),
                   st.floats(-0.01, 0.01))


@pytest.mark.parametrize("start", [0.0, 0.2, 0.25])
def test_the_candidate_takes_over_from_the_static_load(start):
    """A stiff servo (the tuned hold: K_p 600 N m/rad) on a coarse encoder (2^14 counts/rev:
    one count is 0.23 N m of its torque) holds the finger at 0.25 rad; the candidate enters
    from the servo's mean torque over the still (the finger's static load), not from the
    count it happened to be on -- entered from that, its DOB pushed the finger with it, a
    flick of 3-4 rad/s to the walls. The shipped feed-forward on the finger of its model
    passes from every start, and no window's peak speed is beyond twice the pulse's aim."""
    from seaforce_ros.core.sensors import SensorParams
    config = CONFIG.replace(hold=CONFIG.hold.__class__(stiffness=600.0, damping=1.0))
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(), seed=3,
                           sensors=SensorParams(motor_counts_per_rev=2 ** 14))
    sim.reset((start, 0.0, start, 0.0))
    candidate = Candidate("the shipped feed-forward", config)
    job = verify_on(sim, [candidate], config, points=[0.25])
    outcome = job.outcomes[0]
    assert outcome.passed, outcome.reason
    assert all(w.peak_speed < 2.0 * config.verification.speed for w in outcome.windows), [
        w.peak_speed for w in outcome.windows]


@settings(max_examples=80, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(values, values, values, values, values), min_size=1, max_size=80),
       st.floats(1e-3, 5.0), st.floats(1e-3, 10.0))
def test_the_verification_torque_is_bounded_and_a_non_finite_input_stops_it(samples, limit,
                                                                             max_torque):
    """Invariants: |F_a| <= min(commissioning.max_torque, max_torque) at every sample; a
    non-finite input ends it aborted, and every later output is 0."""
    config = CONFIG.replace(max_torque=max_torque, commissioning=dataclasses.replace(
        CONFIG.commissioning, max_torque=limit))
    job = FreeFingerVerification([Candidate("defaults", config)], config, DT)
    assert job.claim()
    sample = JobSample(ChannelController(config, DT).estimator)
    bound = min(limit, max_torque)
    stopped = False
    for x, v, xe, fp, torque in samples:
        sample.x, sample.v, sample.endpoint_position, sample.f_p = x, v, xe, fp
        sample.torque = torque
        u = job.step(sample)
        assert math.isfinite(u) and abs(u) <= bound
        if not all(math.isfinite(a) for a in (x, v, xe, fp, torque)):
            stopped = True
        if stopped:
            assert u == 0.0 and job.outcome == "aborted" and job.message
