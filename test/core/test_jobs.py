"""The job slot of a channel (core/jobs.py, ChannelController.request_job): one job at a time,
the hand-over between the requesting thread and the cycle, the ends from either thread, a new
kind of job added as one class, and properties over arbitrary interleavings of requests,
withdrawals, aborts, cancels, mode changes and samples for grasps and friction calibrations on
the simulated gripper. No ROS."""
import math
import random
import threading
import time

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams)
from seaforce_ros.core.environment import contact_object
from seaforce_ros.core.friction_calibration import CalibrationGoal, FrictionCalibration
from seaforce_ros.core.grasp import Grasp, GraspGoal
from seaforce_ros.core.jobs import DONE, OUTCOMES, TORQUE, Job, JobSample

DT = 5e-4
CONFIG = ControllerConfig(mode="dob_full_ff")
FAST = dict(deadline=None, suppress_health_check=[HealthCheck.too_slow])


class Watched:
    """Mixed into a job: records every step and fails on one the controller must not make
    (on a job that is done, or that the cycle never claimed)."""

    def step(self, sample):
        assert self.started, "a job stepped that the cycle never claimed"
        assert self.active, "a job stepped after it was done"
        self.steps = getattr(self, "steps", 0) + 1
        out = super().step(sample)
        assert math.isfinite(out)
        if not self.active:
            self.last_output = out
        return out


class WatchedGrasp(Watched, Grasp):
    pass


class WatchedCalibration(Watched, FrictionCalibration):
    pass


def grasp(config=CONFIG):
    return WatchedGrasp(GraspGoal("pinch", 0.3, 0.3, 0.6, False), config, DT)


def calibration(config=CONFIG):
    return WatchedCalibration(CalibrationGoal("pinch", 0.05, 0.5, True), config, DT)


class Channel:
    """A controller closed around the simulated finger with an object at 0.1 rad."""

    def __init__(self, config=CONFIG):
        self.sim = ChannelSimulator(PlantParams.table_i(), DahlParams(), seed=1,
                                    environment=contact_object(0.1, 20.0, 0.05))
        self.ctl = ChannelController(config, DT)
        self.m = self.sim.measurement()
        self.u = 0.0

    def step(self, n=1):
        for _ in range(n):
            self.u = self.ctl.update(self.m.x, self.m.v, self.m.f_p)
            self.m = self.sim.step(self.u)
        return self.u


# --- the slot ----------------------------------------------------------------------------
@pytest.mark.parametrize("first,second,words", [
    (grasp, grasp, "the channel is busy with another grasp"),
    (grasp, calibration, "the channel is busy with a grasp"),
    (calibration, grasp, "the channel is busy with a friction calibration"),
    (calibration, calibration, "the channel is busy with another friction calibration")])
def test_a_second_job_is_refused_while_one_runs(first, second, words):
    c = Channel()
    running = first()
    c.ctl.request_job(running)
    c.step(20)
    assert c.ctl.job is running and running.active
    refused = second()
    c.ctl.request_job(refused)
    c.step()
    assert refused.outcome == "aborted" and refused.message == words
    assert refused.started and not getattr(refused, "steps", 0)      # claimed, never run
    assert c.ctl.job is running and running.active


def test_two_requests_in_one_sample_none_lost():
    """Every request is taken, in order: the first runs, the second is refused as busy (not
    dropped, waiting for a start time-out)."""
    c = Channel()
    a, b = grasp(), calibration()
    c.ctl.request_job(a)
    c.ctl.request_job(b)
    c.step()
    assert c.ctl.job is a and a.steps == 1
    assert b.outcome == "aborted" and "busy with a grasp" in b.message


def test_withdraw_before_claim():
    c = Channel()
    before = c.step(10)
    job = grasp()
    c.ctl.request_job(job)
    assert job.withdraw("the goal gave up waiting")
    assert job.phase == DONE and job.outcome == "aborted" and not job.active
    c.step()
    assert c.ctl.job is None and not job.started and not getattr(job, "steps", 0)
    assert not job.claim()                                  # never starts later
    assert job.message == "the goal gave up waiting"
    # withdrawn as canceled; and too late once claimed
    job = calibration()
    c.ctl.request_job(job)
    assert job.withdraw("canceled before it started", "canceled")
    assert job.outcome == "canceled"
    late = grasp()
    c.ctl.request_job(late)
    c.step()
    assert c.ctl.job is late and not late.withdraw("too late") and late.active
    assert math.isfinite(before)


@pytest.mark.parametrize("make", [grasp, calibration])
def test_abort_now_from_the_cycle_thread(make):
    """abort_job (a fault, a stall in the cycle): the job ends at once, aborted, and is never
    stepped again; the mode takes over from the torque the caller set (bumpless: its first
    output equals it)."""
    c = Channel()
    job = make()
    c.ctl.request_job(job)
    c.step(300)
    assert job.active
    steps = job.steps
    c.ctl.abort_job("fault latched: x")
    assert job.outcome == "aborted" and job.message == "fault latched: x"
    assert c.ctl.job is None
    c.ctl.reenter(0.0)                    # the cycle zeroed the torque
    u = c.ctl.update(c.m.x, c.m.v, c.m.f_p)
    assert u == pytest.approx(0.0, abs=1e-12) and job.steps == steps
    c.ctl.abort_job("again")              # nothing runs: no effect
    assert job.message == "fault latched: x"


def test_abort_now_keeps_what_a_grasp_measured():
    """A grasp aborted by the cycle after its contact keeps the object as the estimator had it
    (the estimator is reset right after: the controller's reset)."""
    c = Channel(ControllerConfig(mode="dob_full_ff"))
    job = grasp()
    c.ctl.request_job(job)
    while job.phase != "hold":
        c.step()
        assert c.ctl.job is job, job.message
    c.step(400)
    expected = c.ctl.estimator.estimate()
    c.ctl.reset(0.0, "the plant restarted")
    assert job.outcome == "aborted" and job.message == "the plant restarted"
    assert job.estimate == expected and job.contact


@pytest.mark.parametrize("make", [grasp, calibration])
def test_request_abort_from_another_thread(make):
    """request_abort (the node ended the goal: the cycle did not run) from another thread,
    while the cycle runs: taken at the next sample, in the cycle's thread."""
    c = Channel()
    job = make()
    c.ctl.request_job(job)
    c.step(50)
    stop = threading.Event()

    def cycle():
        while not stop.is_set():
            c.step()

    runner = threading.Thread(target=cycle)
    runner.start()
    try:
        time.sleep(0.05)
        job.request_abort("no actuator_state for 0.6 s")
        deadline = time.monotonic() + 10.0
        while job.active and time.monotonic() < deadline:
            time.sleep(0.005)
    finally:
        stop.set()
        runner.join()
    assert job.outcome == "aborted" and job.message.startswith("no actuator_state for 0.6 s")
    assert c.ctl.job is None


def test_requests_from_another_thread_race_the_cycle():
    """A thread requests jobs of both kinds and withdraws, cancels or aborts them at random
    moments while the cycle runs: at most one job runs at any sample, a job is either withdrawn
    or claimed (never both), and after the last request every job has ended with an outcome."""
    c = Channel()
    jobs, withdrawn = [], []
    done = threading.Event()

    def client():
        rng = random.Random(3)
        for _ in range(60):
            job = grasp() if rng.random() < 0.5 else calibration()
            jobs.append(job)
            c.ctl.request_job(job)
            time.sleep(rng.uniform(0.0, 0.004))
            what = rng.randrange(3)
            if what == 0 and job.withdraw("gave up"):
                withdrawn.append(job)
            elif what == 1:
                job.request_cancel()
            else:
                job.request_abort("stall")
        done.set()

    thread = threading.Thread(target=client)
    thread.start()
    while not done.is_set():
        c.step()
        running = [j for j in list(jobs) if j.started and j.active]
        assert len(running) <= 1
        assert running == ([c.ctl.job] if c.ctl.job is not None else [])
    thread.join()
    for job in jobs:
        job.request_abort("end of the test")
    c.step(2)
    assert c.ctl.job is None
    for job in jobs:
        assert job.outcome in OUTCOMES and job.phase == DONE, (job, job.message)
        assert not (job in withdrawn and job.started)


def test_a_new_kind_of_job_is_one_class():
    """A job the controller has never heard of: a torque step held for 100 samples. It runs in
    the slot like the others and the mode resumes bumplessly from its last torque."""
    class TorqueStep(Job):
        kind = "torque step"
        output = TORQUE

        def __init__(self):
            super().__init__()
            self.phase = "push"
            self.n = 0

        def step(self, sample: JobSample) -> float:
            if self._abort_request is not None:
                self.abort_now(self._abort_request)
                return 0.0
            self.n += sample.steps
            if self.n >= 100:
                self._finish("succeeded", "pushed")
            return 0.05

        def abort_now(self, reason: str) -> None:
            if self.active:
                self._finish("aborted", reason)

        def request_cancel(self, reason: str) -> None:
            self.request_abort(reason)

        def feedback(self, estimator):
            return {"phase": self.phase, "samples": float(self.n)}

    c = Channel()
    c.step(100)
    job = TorqueStep()
    c.ctl.request_job(job)
    outputs = [c.step() for _ in range(100)]
    assert outputs == [0.05] * 100 and job.outcome == "succeeded" and c.ctl.job is None
    assert c.ctl.disturbance != c.ctl.disturbance           # NaN: the DOB did not run
    assert c.step() == pytest.approx(0.05)                  # dob_full_ff, bumpless
    other = grasp()
    c.ctl.request_job(other)
    c.step()
    assert c.ctl.job is other


# --- properties over arbitrary interleavings --------------------------------------------------
OPERATIONS = st.lists(st.one_of(
    st.tuples(st.just("request"), st.sampled_from(["grasp", "calibration"])),
    st.tuples(st.just("withdraw"), st.integers(0, 20), st.sampled_from(OUTCOMES[1:])),
    st.tuples(st.just("request_abort"), st.integers(0, 20)),
    st.tuples(st.just("request_cancel"), st.integers(0, 20)),
    st.tuples(st.just("abort_now"),),
    st.tuples(st.just("reenter"),),
    st.tuples(st.just("reset"),),
    st.tuples(st.just("mode"), st.sampled_from(["passive", "hold", "dob", "dob_full_ff"])),
    st.tuples(st.just("update"), st.integers(1, 400))), min_size=1, max_size=25)

@settings(max_examples=120, **FAST)
@given(OPERATIONS)
def test_any_interleaving_keeps_the_slot(operations):
    """Invariants, checked after every operation and every sample:

    1. at most one job runs on the channel (claimed and not done), and it is the controller's
       job; none when the controller has none;
    2. no torque from a job after it is done: a job is stepped only while it runs and was
       claimed (Watched), and a job that is done is not the channel's any more;
    3. a job is done exactly when it has an outcome (one of OUTCOMES);
    4. a withdrawn job never starts;
    5. every claimed job ends with an outcome: after the sequence, a request_abort of every job
       and one sample leave none running, and every job requested has ended.
    """
    c = Channel()
    jobs, withdrawn = [], []

    def check():
        running = [j for j in jobs if j.started and j.active]
        assert len(running) <= 1                                               # 1
        assert running == ([c.ctl.job] if c.ctl.job is not None else [])       # 1, 2
        for j in jobs:
            assert (j.outcome is not None) == (j.phase == DONE)                  # 3
            assert j.outcome is None or j.outcome in OUTCOMES                    # 3
        for j in withdrawn:
            assert not j.started and not getattr(j, "steps", 0)                  # 4

    for op in operations:
        kind = op[0]
        pick = jobs[op[1] % len(jobs)] if len(op) > 1 and isinstance(op[1], int) and jobs \
            else None
        if kind == "request":
            job = grasp() if op[1] == "grasp" else calibration()
            jobs.append(job)
            c.ctl.request_job(job)
        elif kind == "withdraw" and pick is not None:
            if pick.withdraw("gave up", op[2]):
                withdrawn.append(pick)
        elif kind == "request_abort" and pick is not None:
            pick.request_abort("stall")
        elif kind == "request_cancel" and pick is not None:
            pick.request_cancel()
        elif kind == "abort_now":
            c.ctl.abort_job("fault")
        elif kind == "reenter":
            c.ctl.reenter(0.0)
        elif kind == "reset":
            c.ctl.reset(0.0, "re-initialised")
        elif kind == "mode":
            c.ctl.configure(CONFIG.replace(mode=op[1]))
        elif kind == "update":
            for _ in range(op[1]):
                c.step()
                check()
        check()
    for j in jobs:
        j.request_abort("end")
    c.step()
    check()
    assert c.ctl.job is None                                                    # 5
    for j in jobs:
        assert j.outcome in OUTCOMES and j.phase == DONE, (j, j.message)        # 5
