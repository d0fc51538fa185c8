"""The free-air excitation (commissioning): properties over arbitrary input sequences, the goal's
checks, random plants on the simulator (limits kept, no false contact, the band covered), an
object in the way (a contact abort, zero torque from then on), and the job inside a
ControlCycle (bumpless return, the cycle and applied torque it records)."""
import dataclasses
import math
import os
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.commissioning.excitation import (CENTRE_TOLERANCE, GAIN_RANGE, ExcitationGoal,
                                                   FreeAirExcitation, check_excitation_goal,
                                                   nominal_amplitude)
from seaforce_ros.commissioning.experiments import (ExcitationFailed, run_free_air_excitation,
                                                    simulate_excitation)
from seaforce_ros.core import ChannelController, ChannelSimulator, ControllerConfig
from seaforce_ros.core.control_cycle import ControlCycle
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.jobs import InvalidJobGoalError
from seaforce_ros.core.params import DahlParams, PlantParams

from helpers.second_sim import DAHL, TABLE_I, MotorTorqueSim

DT = 5e-4
FAST = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])


def with_commissioning(config=None, **changes):
    config = ControllerConfig() if config is None else config
    return config.replace(commissioning=dataclasses.replace(config.commissioning, **changes))


# --- properties over arbitrary inputs (a coarse clock so that whole excitations fit) --------
P_DT = 0.01
P_CONFIG = with_commissioning(rest_duration=0.05, max_torque=0.8)
P_GOAL = ExcitationGoal("a", band=(1.0, 40.0), duration=1.0)     # 105 samples in all
P_LIMIT = min(P_CONFIG.commissioning.max_torque, P_CONFIG.max_torque)

BAD = st.sampled_from([math.nan, math.inf, -math.inf, 1e300, -1e300])
SMALL = st.floats(-0.02, 0.02)
VALUE = st.one_of(SMALL, SMALL, SMALL, SMALL, st.floats(-5.0, 5.0), BAD)
EVENT = st.sampled_from(["", "", "", "", "", "", "", "", "cancel", "abort", "abort_now"])
SAMPLE = st.tuples(VALUE, VALUE, VALUE, VALUE, st.floats(-0.5, 0.5) | BAD, EVENT,
                   st.integers(1, 3))


@settings(max_examples=300, **FAST)
@given(st.lists(SAMPLE, min_size=1, max_size=160))
def test_properties_over_arbitrary_inputs(samples):
    """Invariants, whatever the inputs and requests:
    * |F_a| <= min(commissioning.max_torque, max_torque) at every sample;
    * the output is exactly 0.0 from the sample the job ends on without success, and at every
      sample after it ends;
    * a job that saw a non-finite input never ends 'succeeded';
    * an outcome, once set, never changes (an aborted job stays aborted);
    * the record never exceeds its capacity and holds one row per sample it commanded;
    * a cancel ends it 'canceled' with zero torque at once (unless it had ended already, or
      that sample's input was non-finite: then it aborts);
    * nothing is recorded while it centres the finger (a start away from rest)."""
    job = FreeAirExcitation(P_GOAL, P_CONFIG, P_DT)
    bad_seen = False
    outcome = None
    rows = 0
    for i, (x, v, fp, applied, u_prev, event, steps) in enumerate(samples):
        if event == "cancel":
            job.request_cancel("client canceled")
        elif event == "abort":
            job.request_abort("the cycle stopped")
        elif event == "abort_now":
            job.abort_now("a fault latched")
        was_done = not job.active
        before = len(job)
        centring = job.centring
        finite = all(math.isfinite(a) for a in (x, v, fp, applied, u_prev))
        bad_seen = bad_seen or not finite
        u = job.update(x, v, fp, u_prev, applied, i, steps)
        assert math.isfinite(u) and abs(u) <= P_LIMIT
        if was_done or (not job.active and job.outcome != "succeeded"):
            assert u == 0.0
        if outcome is not None:
            assert job.outcome == outcome
        outcome = job.outcome
        if bad_seen:
            assert job.outcome != "succeeded"
        if event == "cancel" and not was_done and finite:
            assert job.outcome == "canceled" and u == 0.0
        rows += len(job) - before
        if centring and job.centring:
            assert len(job) == before
        assert len(job) <= job.capacity
    record = job.record()
    assert len(record) == rows == len(job)
    assert np.all(np.abs(record.command) <= P_LIMIT)


def test_finite_samples_end_succeeded_and_the_clock_counts_steps():
    """The other side of the properties: finite, quiet samples run to the end (succeeded), one
    row per sample, the phases in order, progress 0..1; skipped samples advance the clock."""
    job = FreeAirExcitation(P_GOAL, P_CONFIG, P_DT)
    phases = []
    for i in range(200):
        job.update(0.001 * math.sin(i), 0.0, 0.0, 0.0, 0.0, i, 2 if i % 10 == 0 else 1)
        phases.append(job.phase)
        if not job.active:
            break
    assert job.outcome == "succeeded", job.message
    assert phases[0] == "rest" and "excite" in phases and phases[-1] == "done"
    assert job.progress == 1.0
    assert len(job) == len(phases) < 105


def test_the_per_sample_path_keeps_no_memory():
    """Traced memory after N more job updates (excitation phase, the contact test running) is
    what it was after N: the record is preallocated, nothing is built per sample and kept."""
    config = ControllerConfig()
    job = FreeAirExcitation(ExcitationGoal("a", (20.0, 400.0), 8.0), config, DT)
    n = 4000

    def feed(samples):              # a free finger's motion at ~95 Hz, F_p against it
        for i in samples:
            job.update(5e-3 * math.sin(0.3 * i), 3.0 * math.cos(0.3 * i),
                       -5e-3 * math.sin(0.3 * i), 0.0, 0.0, i)

    feed(range(n))                  # the rest and the start of the chirp, before tracing
    tracemalloc.start()
    try:
        feed(range(n, 2 * n))
        first, _ = tracemalloc.get_traced_memory()
        feed(range(2 * n, 3 * n))
        second, _ = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert job.phase == "excite" and len(job) == 3 * n
    assert 0.0 < job.contact_level < 1.0            # the contact test ran
    assert abs(second - first) < 512


def test_goal_checks_name_the_field():
    c = ControllerConfig().commissioning
    assert check_excitation_goal(ExcitationGoal("a"), c) == (0.2, 800.0, 40.0)
    assert check_excitation_goal(ExcitationGoal("a", (1.0, 100.0), 5.0), c) == (1.0, 100.0, 5.0)
    for goal, text in [(ExcitationGoal("a", (10.0, 5.0)), "below the end"),
                       (ExcitationGoal("a", (1.0, 950.0)), "Nyquist"),
                       (ExcitationGoal("a", (math.nan, 5.0)), "band start"),
                       (ExcitationGoal("a", (1.0, 2.0)), "band between"),
                       (ExcitationGoal("a", (1.0, 100.0), 0.1), "0.05 s"),
                       (ExcitationGoal("a", (1.0, 100.0), -1.0), "duration"),
                       (ExcitationGoal("a", "wide"), "band")]:
        with pytest.raises(InvalidJobGoalError, match=text):
            check_excitation_goal(goal, c)


def test_start_outside_the_range_or_under_load_aborts_with_zero_torque():
    job = FreeAirExcitation(P_GOAL, P_CONFIG, P_DT)
    assert job.update(1.6, 0.0, 0.0, 0.0, 0.0) == 0.0
    assert job.outcome == "aborted" and "joint range" in job.message
    job = FreeAirExcitation(P_GOAL, P_CONFIG, P_DT)
    assert job.update(0.0, 0.0, 0.0, 0.7, 0.7) == 0.0
    assert job.outcome == "aborted" and "holds" in job.message


def test_a_start_away_from_rest_is_centred_first_and_a_held_finger_aborts_it():
    """A start beyond CENTRE_TOLERANCE of rest: the motor is servoed to rest along a path
    (nothing recorded, |F_a| within the bound), dithered and released bumplessly to the weak
    servo there; a finger that does not follow (held) aborts it with zero torque; a rest
    outside the joint range is refused."""
    config = with_commissioning(rest_duration=0.05)
    goal = ExcitationGoal("a", band=(1.0, 40.0), duration=1.0)
    # a motor like Table I's (m 2 g m^2, b 0.03, k 0.3 with its rest at 0): the servo carries it
    job = FreeAirExcitation(goal, config, DT)
    x, v, u, seen = 0.25, 0.0, 0.0, []
    for i in range(40000):
        u_new = job.update(x, v, 0.0, u, u, i)
        seen.append((job.centring, len(job), u_new))
        if not job.centring:
            break
        acc = (u_new - 0.3 * x - 0.03 * v) / 0.002
        v += acc * DT
        x += v * DT
        u = u_new
    assert job.active and not job.centring and job.message == "resting", job.message
    assert all(n == 0 for c, n, _ in seen[:-1])
    assert max(abs(w) for *_, w in seen) <= min(config.commissioning.max_torque,
                                                config.max_torque)
    assert abs(x) < CENTRE_TOLERANCE
    assert job.update(x, v, 0.0, u, u, 40001) == pytest.approx(u, abs=0.05)  # bumpless
    # a finger that is held: it falls behind its path, the job aborts with zero torque
    job = FreeAirExcitation(goal, config, DT)
    outputs = [job.update(0.25, 0.0, 0.0, 0.0, 0.0, i) for i in range(20000)
               if job.active or i == 0]
    assert job.outcome == "aborted" and "behind its path" in job.message, job.message
    assert outputs[-1] == 0.0 and job.update(0.25, 0.0, 0.0, 0.0, 0.0) == 0.0
    # rest outside the joint range
    far = config.replace(feedforward=dataclasses.replace(config.feedforward,
                                                         rest_position=2.0))
    job = FreeAirExcitation(goal, far, DT)
    assert job.update(0.3, 0.0, 0.0, 0.0, 0.0) == 0.0
    assert job.outcome == "aborted" and "rest_position" in job.message


def test_amplitude_law_rises_with_frequency_and_respects_the_bound():
    """The model part: small at low frequency (the springs), the torque bound at high
    frequency (the inertia), and the model's motion at it within 60 % of the limits."""
    config = ControllerConfig()
    f = np.array([0.3, 1.0, 200.0, 800.0])
    a = nominal_amplitude(config, f, 1.5, 1.0)
    assert a[0] < 0.5 and a[-1] == pytest.approx(1.0) and a[2] == pytest.approx(1.0)
    assert np.all(a <= 1.0)
    # Table I in free air near 0.3 Hz is the springs: |X/F| ~ 1/(k + K_p + k_e k_s/(k_e + k_s))
    # (the damping and inertia change it by a few %), so the position target 60 % of 1.5 rad
    # rules
    p, c = config.plant, config.commissioning
    ke = p.endpoint_stiffness * p.hose_stiffness / (p.endpoint_stiffness + p.hose_stiffness)
    static = 0.6 * 1.5 * (p.motor_stiffness + c.stiffness + ke)
    assert a[0] == pytest.approx(static, rel=0.05)


# --- random plants on the simulator ---------------------------------------------------------
def random_plant(rng):
    """Every Table I parameter and the Dahl sigma, F_c log-uniform in 0.5x..2x."""
    names = [f.name for f in dataclasses.fields(PlantParams)]
    factors = {n: float(np.exp(rng.uniform(math.log(0.5), math.log(2.0)))) for n in names}
    d = np.exp(rng.uniform(math.log(0.5), math.log(2.0), 2))
    return (PlantParams.table_i().scaled(**factors),
            DahlParams(sigma=12.8 * d[0], coulomb_force=0.032 * d[1]))


def decade_energy(record, edges):
    """The excitation's spectral energy in each band of ``edges`` [Hz]."""
    spectrum = np.abs(np.fft.rfft(record.excitation)) ** 2
    f = np.fft.rfftfreq(len(record), record.dt)
    return [float(spectrum[(f >= lo) & (f < hi)].sum()) for lo, hi in zip(edges, edges[1:])]


def test_random_plants_free_air_limits_kept_band_covered_no_false_contact():
    """10 plants 0.5x..2x of Table I (the model: Table I): every excitation succeeds (no false
    contact, no limit hit), |X - x_0| stays within 75 % of the room and |V| within 90 % of
    max_speed, |F_a| within the bound, and every decade of 0.3..300 Hz carries energy."""
    rng = np.random.default_rng(20261203)
    model = ControllerConfig()
    c = model.commissioning
    for draw in range(10):
        plant, dahl = random_plant(rng)
        run = simulate_excitation(plant, dahl, model, seed=draw, duration=20.0)
        job, record = run.job, run.record
        assert job.outcome == "succeeded", (draw, job.message)
        assert job.contact_level < 1.0
        room = min(-c.position_min, c.position_max)
        assert np.max(np.abs(record.x)) <= 0.75 * room, draw
        assert np.max(np.abs(record.v)) <= 0.9 * c.max_speed, draw
        assert np.max(np.abs(record.command)) <= c.max_torque + 1e-12
        assert GAIN_RANGE[0] <= job.gain <= GAIN_RANGE[1]
        energy = decade_energy(record, [0.3, 3.0, 30.0, 300.0, 500.0])
        assert min(energy) > 1e-3 * max(energy), (draw, energy)
        # the record: the truth filled in; the torque a state reports applied (over the period
        # before it) is the command that answered the state two samples before (the one-sample
        # command delay)
        assert np.all(np.isfinite(record.x_e)) and np.all(record.f_e == 0.0)
        assert np.array_equal(record.applied[2:], record.command[:-2])


def test_runner_is_deterministic_per_seed_and_raises_when_it_fails():
    plant, dahl = PlantParams.table_i(), DahlParams()
    short = dict(duration=4.0, band=(2.0, 400.0))
    a = run_free_air_excitation(plant, dahl, ControllerConfig(), seed=3, **short)
    b = run_free_air_excitation(plant, dahl, ControllerConfig(), seed=3, **short)
    c = run_free_air_excitation(plant, dahl, ControllerConfig(), seed=4, **short)
    assert np.array_equal(a.f_p, b.f_p) and not np.array_equal(a.f_p, c.f_p)
    assert a.duration == pytest.approx(4.5, abs=2 * DT)
    outside = with_commissioning(position_min=-1.5, position_max=-0.1)   # x_0 = 0 beyond it
    with pytest.raises(ExcitationFailed, match="joint range") as info:
        run_free_air_excitation(plant, dahl, outside, **short)
    assert info.value.run.outcome == "aborted"


def test_on_the_second_simulator_the_record_identifies_the_motor_plant():
    """An independent oracle: the job in a ChannelController on the second simulator (its own
    discretisation, Dahl and sensors), 3 plants 0.5x..2x of Table I. Each excitation
    succeeds within the limits, and the record is consistent with the true motor plant: a
    least-squares fit of ``F_a + F_p = m X'' + b X' + k X`` (central differences; the torque
    applied around sample i is the mean of ``applied[i]`` and ``applied[i + 1]``, the samples
    up to 100 Hz) gives the true m, b, k within 3 %: cycle, X, F_p and the applied torque are
    aligned."""
    rng = np.random.default_rng(7)
    config = ControllerConfig()
    c = config.commissioning
    for draw in range(3):
        plant = {k: v * math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
                 for k, v in TABLE_I.items()}
        dahl = {k: v * math.exp(rng.uniform(math.log(0.5), math.log(2.0)))
                for k, v in DAHL.items()}
        sim = MotorTorqueSim(plant, dahl, seed=draw)
        ctrl = ChannelController(config, DT)
        job = FreeAirExcitation(ExcitationGoal("a", duration=20.0), config, DT)
        ctrl.request_job(job)
        k = 0
        while job.active and k < job.capacity:
            x, v, fp, fa = sim.measure()
            ctrl.cycle, ctrl.applied = 7 * k, fa
            sim.step(ctrl.update(x, v, fp))
            k += 1
        assert job.outcome == "succeeded", (draw, job.message)
        r = job.record()
        assert np.array_equal(r.cycle, 7 * np.arange(len(r)))
        assert job.peak_position < 0.75 * min(-c.position_min, c.position_max)
        assert job.peak_speed < 0.9 * c.max_speed
        rate = math.log(c.end_frequency / c.start_frequency) / 20.0
        end = int((c.rest_duration + math.log(100.0 / c.start_frequency) / rate) / DT)
        i = np.arange(int(c.rest_duration / DT) + 1, end)
        regressors = np.column_stack([(r.x[i + 1] - 2.0 * r.x[i] + r.x[i - 1]) / DT ** 2,
                                      (r.x[i + 1] - r.x[i - 1]) / (2.0 * DT), r.x[i]])
        force = 0.5 * (r.applied[i] + r.applied[i + 1]) + r.f_p[i]
        m, b, k_fit = np.linalg.lstsq(regressors, force, rcond=None)[0]
        assert m == pytest.approx(plant["motor_inertia"], rel=0.03), draw
        assert b == pytest.approx(plant["motor_damping"], rel=0.03), draw
        assert k_fit == pytest.approx(plant["motor_stiffness"], rel=0.03), draw


# --- contact ---------------------------------------------------------------------------------
@pytest.mark.parametrize("position,stiffness", [(0.2, 100.0), (0.3, 20.0)])
def test_object_in_the_way_aborts_with_zero_torque_from_then_on(position, stiffness):
    """An object inside the motion range (the finger reaches 0.7 rad in free air): the job
    aborts with a contact reason; the controller's torque is exactly zero from that sample on
    (passive after the job)."""
    run = simulate_excitation(PlantParams.table_i(), DahlParams(), ControllerConfig(),
                              environment=contact_object(position, stiffness, 0.05),
                              settle=400)
    job = run.job
    assert job.outcome == "aborted" and "contact" in job.message, job.message
    assert np.any(run.record.f_e != 0.0)                # it did touch
    assert np.all(run.output[run.ended:] == 0.0)
    assert job.contact_level > 1.0
    assert job.touched


def _late_loop(late_share, seed, measured=False, environment=None):
    """A free-air excitation (12 s, 1..400 Hz) through a loop whose plant applies, at
    ``late_share`` of the cycles chosen at random, the command it applied before instead of
    the new one (a controller in another process, over topics); ``measured``: the plant
    reports its torque with a 1e-4 N m quantum and noise (a drive's measured torque, no exact
    match). The job."""
    rng = np.random.default_rng(seed)
    config = ControllerConfig(mode="passive")
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(), 5e-4, seed=seed,
                           environment=environment)
    ctrl = ChannelController(config, 5e-4)
    job = FreeAirExcitation(ExcitationGoal("pinch", (1.0, 400.0), 12.0), config, 5e-4)
    ctrl.request_job(job)
    m, k, applied = sim.measurement(), 0, 0.0
    while job.active and k < job.capacity + 1:
        ctrl.cycle = k
        ctrl.applied = m.f_a if not measured else \
            round((m.f_a + rng.normal(0.0, 3e-4)) / 1e-4) * 1e-4
        u = ctrl.update(m.x, m.v, m.f_p)
        applied = applied if rng.random() < late_share else u
        m = sim.step(applied)
        k += 1
    return job


def test_a_loop_that_applies_commands_late_is_named_not_taken_for_a_contact():
    """A free finger driven through a loop that applies a share of the commands a cycle late
    trips the contact test (its drive is distorted at random instants); the abort names the
    loop's timing and the layouts that work instead of a contact: the default two-process
    layout aborted so on every run. On time, or late at 5 %, it is no abort; a drive that
    reports a measured torque is no evidence either way (the contact reason stands); an object
    in the way is still a contact, on time."""
    job = _late_loop(0.4, 1)
    assert job.outcome == "aborted", job.message
    assert "commands later than the others" in job.message and "loop:=direct" in job.message
    assert "contact below" not in job.message and "contact above" not in job.message
    for share in (0.0, 0.05):
        job = _late_loop(share, 1)
        assert job.outcome == "succeeded", (share, job.message)
    job = _late_loop(0.4, 1, measured=True)
    assert job.outcome == "aborted" and "later than" not in job.message, job.message
    job = _late_loop(0.0, 1, environment=contact_object(0.2, 100.0, 0.05))
    assert job.outcome == "aborted" and "contact" in job.message, job.message


@pytest.mark.parametrize("seed", [100, 102, 103])
def test_a_free_finger_leaves_no_stale_contact(seed):
    """The channel's contact estimator, made for a grasp's approach, starts contacts under the
    chirp with a model 0.7x..1.4x off (about 96 in 12 s); the job's successful end re-arms it,
    so 2 s later in hold it sees no contact (without the re-arm 4 of 6 such plants were left
    in one, which turned the next commissioning away as 'not free')."""
    rng = np.random.default_rng(seed)
    table = PlantParams.table_i()
    true = PlantParams(**{k: getattr(table, k) * float(np.exp(rng.uniform(np.log(0.7),
                                                                          np.log(1.4))))
                          for k in ("motor_inertia", "motor_damping", "motor_stiffness",
                                    "endpoint_inertia", "endpoint_damping",
                                    "endpoint_stiffness", "hose_damping", "hose_stiffness")})
    run = simulate_excitation(true, DahlParams(), ControllerConfig(), seed=seed % 100,
                              duration=12.0, band=(1.0, 400.0), mode="hold", settle=4000)
    assert run.outcome == "succeeded", run.job.message
    assert not run.job.touched and not run.contact_after


@pytest.mark.parametrize("seed", [0, 2, 3])
@pytest.mark.parametrize("mode", ["passive", "hold"])
def test_a_canceled_chirp_leaves_no_stale_contact(seed, mode):
    """A cancel mid-chirp (zero torque at once: the finger coasts on, 2.5..6 s into a 12 s
    chirp): the estimator is re-armed once the finger is at rest, so 3 s later it sees no
    contact. Re-armed at the cancel, 11 of 12 such
    cancels (passive, then hold) left a contact standing (0.02..0.05 N m at rest) and the
    next commissioning was turned away ('not free'; the over-ROS test's failure in CI)."""
    rng = np.random.default_rng(seed)
    table = PlantParams.table_i()
    true = table.scaled(**{k: float(np.exp(rng.uniform(np.log(0.7), np.log(1.4))))
                           for k in ("motor_inertia", "motor_damping", "motor_stiffness",
                                     "endpoint_inertia", "endpoint_damping",
                                     "endpoint_stiffness", "hose_damping", "hose_stiffness")})
    at = int(rng.uniform(2.5, 6.0) / DT)
    run = simulate_excitation(true, DahlParams(), ControllerConfig(), seed=seed, duration=12.0,
                              band=(1.0, 400.0), mode=mode, settle=6000, cancel_after=at)
    assert run.outcome == "canceled", run.job.message
    if mode == "passive":
        assert np.all(run.output[run.ended:] == 0.0)
    assert not run.contact_after


# --- inside the control cycle ------------------------------------------------------------------
def test_in_a_control_cycle_bumpless_return_and_the_sample_fields():
    """ControlCycle -> ChannelController -> the job: the record's cycle and applied torque are
    what the cycle was given; when the job ends the channel's mode (hold) takes over from the
    job's last torque (its first output equals it) and stays in its mode."""
    config = ControllerConfig(mode="hold")
    ctrl = ChannelController(config, DT)
    cc = ControlCycle(("a",), [ctrl])
    sim = ChannelSimulator(PlantParams.table_i(), DahlParams(), DT, seed=1)
    job = FreeAirExcitation(ExcitationGoal("a", (5.0, 200.0), 8.0), config, DT)
    m = sim.measurement()
    cycles, applied, outputs = [], [], []
    wall = 1_800_000_000_000_000_000
    for k in range(18000):
        if k == 100:
            ctrl.request_job(job)
        cycle = 1000 + 2 * k               # an increasing count, not the sample index
        fa = m.f_a + 1e-4 * (k % 7)        # what the plant reports (distinct per sample)
        out = cc.step(["a"], cycle, wall + k * 500_000, [m.x], [m.v], [m.f_p], [fa], [0],
                      wall + k * 500_000, 10.0 + k * DT)
        u = out.effort[0]
        cycles.append(cycle)
        applied.append(fa)
        outputs.append(u)
        m = sim.step(u)
    assert job.outcome == "succeeded", job.message
    record = job.record()
    n = len(record)
    assert np.array_equal(record.cycle, cycles[100:100 + n])
    assert np.array_equal(record.applied, applied[100:100 + n])
    assert record.command[-1] == outputs[100 + n - 1]
    assert outputs[100 + n] == pytest.approx(outputs[100 + n - 1], abs=1e-12)   # bumpless
    assert ctrl.job is None and ctrl.mode == "hold"
    assert max(abs(u) for u in outputs[100 + n:]) < 0.5    # hold holds, nothing runs away


CENTRE_SEED = int(os.environ.get("SEAFORCE_CENTRE_SEED",
                                 np.random.SeedSequence().entropy % 100000))


def test_a_finger_friction_holds_off_rest_is_centred_and_identifies_as_from_rest():
    """On the oracle (a plant of the family drawn 0.5x..2x, the linear class), a finger
    released 0.1-0.3 rad off rest -- its Dahl friction holds it up to about 0.2 rad off --
    starts its record at rest and gives the same port misfit as from rest, within 0.25
    points (the port misfit flags the model class at 2.5 %). Measured with the 40 s chirp on
    three draws: without the centring move 0.1 rad off gave 1.6-3.8 % where rest gave
    0.3-1.2 %, with it 0.33-1.3 %; with this test's 20 s chirp, on seeds 11-20, the two
    misfits were within 0.06 points."""
    from helpers.nonlinear_sim import Effects
    from helpers.oracle_commissioning import draw, excite, identify
    from seaforce_ros.commissioning.analyse import model_class_stage
    rng = np.random.default_rng([CENTRE_SEED, 7])
    plant, dahl, _ = draw(rng, effects=False)
    start = float(rng.uniform(0.1, 0.3)) * float(rng.choice([-1.0, 1.0]))
    where = f"SEAFORCE_CENTRE_SEED={CENTRE_SEED}, start {start:+.3f} rad"
    misfits = []
    for x0 in (0.0, start):
        # the finger left at x0 and settled unpowered for 1 s (its friction holds it off rest)
        record = excite(plant, dahl, Effects(), seed=CENTRE_SEED, duration=20.0, start=x0,
                        settle=1.0)
        verdict, _ = model_class_stage(record, identify(record))
        misfits.append(verdict.misfit["port"])
        assert abs(record.x[0]) < CENTRE_TOLERANCE + 0.005, (where, record.x[0])
    assert abs(misfits[1] - misfits[0]) < 0.0025, (where, misfits)
