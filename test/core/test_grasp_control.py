"""Grasps in the control core: the ``force`` mode, a grasp run by ChannelController on the
simulated gripper (objects drawn at random, the controller's model 15 % off the plant), what a
cancel, a mode change, a fault or a reset leaves behind, and properties over arbitrary
sequences through ControlCycle. No ROS."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import (ChannelController, ChannelSimulator, ControllerConfig,
                               DahlParams, PlantParams, position_sine, run_closed_loop)
from seaforce_ros.core.control_cycle import ControlCycle
from seaforce_ros.core.environment import contact_object, free
from seaforce_ros.core.estimator import FLOOR_FRACTION, SPREAD_TIME
from seaforce_ros.core.grasp import Grasp, GraspGoal, check_goal
from seaforce_ros.core.params import LimitParams, TargetParams
from seaforce_ros.core.plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT

DT = 5e-4
TABLE_I = PlantParams.table_i()
PLANT_FIELDS = ('motor_inertia', 'motor_damping', 'motor_stiffness', 'endpoint_inertia',
                'endpoint_damping', 'endpoint_stiffness', 'hose_damping', 'hose_stiffness')


def model_error(rng, magnitude=0.15):
    """The sim's true plant and Dahl: every parameter of the controller's model (Table I and
    the paper's Dahl fit) off by +-magnitude, signs at random."""
    sign = lambda: 1.0 + magnitude * rng.choice((-1.0, 1.0))    # noqa: E731
    plant = TABLE_I.scaled(**{name: sign() for name in PLANT_FIELDS})
    d = DahlParams()
    return plant, DahlParams(sigma=d.sigma * sign(), coulomb_force=d.coulomb_force * sign())


class Grasping:
    """A channel's controller running a grasp on the simulator, recording what matters."""

    def __init__(self, env, mode='passive', plant=TABLE_I, dahl=DahlParams(), seed=0,
                 **config):
        self.sim = ChannelSimulator(plant, dahl, seed=seed, environment=env)
        self.config = ControllerConfig(mode=mode, **config)
        self.ctl = ChannelController(self.config, dt=DT)
        self.m = self.sim.measurement()
        self.t = 0.0
        self.log = []                      # (t, true contact force, phase, u)
        # (step_lossy) the plant's command, states lost since, the plant stopped meanwhile
        self._u, self._lost, self._stopped = 0.0, 0, False

    def start(self, v, grip, max_force, probe=True):
        goal = GraspGoal('pinch', v, grip, max_force, probe)
        check_goal(goal, self.config.grasp, self.config.estimator, self.config.max_torque)
        self.grasp = Grasp(goal, self.config, DT)
        self.ctl.request_job(self.grasp)
        return self.grasp

    def step(self, n=1):
        for _ in range(n):
            u = self._u = self.ctl.update(self.m.x, self.m.v, self.m.f_p)
            self.m = self.sim.step(u)
            self.t += DT
            self.log.append((self.t, -self.m.f_e, self.ctl.grasp_phase, u))
        return self

    def step_lossy(self, rng, loss, longest, n=1, timeout=None):
        """``n`` samples of the plant, the controller answering only the states that reach it:
        each is lost with probability ``loss`` (at most ``longest - 1`` in a row, as a late
        separate controller process with a depth-1 subscription sees them); the plant holds
        the last command meanwhile -- or, ``timeout`` samples without a fresh one, applies
        zero torque (the sim's command_timeout; the controller, told by the state, re-enters
        from it as ControlCycle has it do) -- and the controller integrates over the gap."""
        for _ in range(n):
            stopped = timeout is not None and self._lost >= timeout
            self.m = self.sim.step(0.0 if stopped else self._u)
            self.t += DT
            self._lost += 1
            self._stopped = self._stopped or stopped
            if self._lost < longest and rng.random() < loss:
                self.log.append((self.t, -self.m.f_e, self.ctl.grasp_phase, self._u))
                continue
            if self._stopped:
                self.ctl.reenter(0.0)
            self._u = self.ctl.update(self.m.x, self.m.v, self.m.f_p, steps=self._lost)
            self._lost, self._stopped = 0, False
            self.log.append((self.t, -self.m.f_e, self.ctl.grasp_phase, self._u))
        return self

    def until(self, predicate, limit=20.0):
        while not predicate() and self.t < limit:
            self.step()
        assert predicate(), f'timed out at {self.t:.2f} s in {self.ctl.grasp_phase}'
        return self


def random_grasp(seed, k_max):
    """(rng, Grasping, k, b, grip): the plant 15 % off the model, an object at 0.2 rad drawn
    from 0.5..k_max N m/rad (log-uniform), 0.04..0.1 N m s/rad, a grip of 0.2..0.5 N m it
    takes within 1 rad."""
    rng = np.random.default_rng(seed)
    plant, dahl = model_error(rng)
    k = float(np.exp(rng.uniform(np.log(0.5), np.log(k_max))))
    b = float(rng.uniform(0.04, 0.1))
    grip = min(float(rng.uniform(0.2, 0.5)), k)
    g = Grasping(contact_object(0.2, k, b), plant=plant, dahl=dahl, seed=seed % 1000)
    return rng, g, k, b, grip


def test_force_mode_presses_with_the_reference():
    """force: the DOB with F_ref = target.force: at rest the hose pushes the motor with
    F_p = -F_ref (eq. 19), entered bumplessly."""
    sim = ChannelSimulator(TABLE_I, DahlParams(), environment=position_sine(0.0, 0.0, 0.5))
    ctl = ChannelController(ControllerConfig(mode='dob'))
    rec = run_closed_loop(sim, ctl, 8000, on_switch={
        2000: lambda s, c: c.configure(c.config.replace(mode='force', target=TargetParams(force=0.4)))})
    assert abs(rec['u'][2000] - rec['u'][1999]) < 1e-3
    assert np.mean(rec['f_p'][-500:]) == pytest.approx(-0.4, abs=2e-3)


def test_a_grasp_with_the_exact_model():
    g = Grasping(contact_object(0.2, 2.0, 0.05))
    grasp = g.start(0.3, 0.4, 0.8)
    g.until(lambda: grasp.phase == 'hold').step(2000)
    true_contact = next(t for t, f, _, _ in g.log if f > 0.0)
    assert grasp.contact and grasp.contact_time - true_contact < 0.01
    e = g.ctl.estimator.estimate()
    assert e.stiffness == pytest.approx(2.0, rel=0.02) and e.damping == pytest.approx(0.05,
                                                                                       rel=0.1)
    assert e.contact_position == pytest.approx(0.2, abs=2e-3)
    hold = [f for _, f, p, _ in g.log[-400:]]
    assert np.mean(hold) == pytest.approx(0.4, rel=0.01)
    assert grasp.grip_force == pytest.approx(0.4, rel=0.01)


@pytest.mark.parametrize('before', ['passive', 'hold', 'dob_full_ff'])
def test_cancel_releases_to_the_mode_before_without_the_grip(before):
    """The grip is never carried over: after a cancel the channel is back in its mode and the
    torque is what that mode commands with no object force -- not the squeeze (hold would
    otherwise capture the grip torque as its bumpless bias and keep crushing)."""
    g = Grasping(contact_object(0.2, 5.0, 0.05), mode=before)
    g.step(200)
    grasp = g.start(0.3, 0.6, 1.2, probe=False)
    g.until(lambda: grasp.phase == 'hold').step(600)
    grip_torque = g.log[-1][3]
    grasp.request_release('released')
    g.until(lambda: not grasp.active).step(1)
    assert grasp.outcome == 'canceled' and g.ctl.job is None and g.ctl.mode == before
    after = g.log[-1][3]
    if before == 'passive':
        assert after == 0.0
    assert abs(after) < 0.1 * abs(grip_torque)
    g.step(4000)
    assert g.log[-1][1] < 0.05 * 0.6          # the object is no longer squeezed
    assert abs(g.log[-1][3]) < 0.1 * abs(grip_torque)


def test_passive_ends_a_grasp_at_once_another_mode_releases_it_first():
    g = Grasping(contact_object(0.2, 5.0, 0.05), mode='dob')
    grasp = g.start(0.3, 0.5, 1.0)
    g.until(lambda: grasp.phase == 'hold')
    g.ctl.configure(g.config.replace(mode='impedance'))
    g.step()
    assert grasp.phase == 'release' and grasp.message == 'mode set to impedance'
    g.until(lambda: not grasp.active).step(1)
    assert grasp.outcome == 'aborted' and g.ctl.mode == 'impedance'
    grasp = g.start(0.3, 0.5, 1.0)
    g.step(200)
    g.ctl.configure(g.config.replace(mode='passive'))
    g.step()
    assert grasp.phase == 'done' and grasp.message == 'mode set to passive'
    assert g.log[-1][3] == 0.0


@pytest.mark.parametrize('mode, phase', [('dob', 'release'), ('passive', 'done')])
def test_setting_the_mode_in_force_ends_a_grasp_as_a_change_does(mode, phase):
    """``<channel>.mode`` set to the mode the channel has: the grasp ends as at a change of
    mode (the grasp overrides the mode; setting it asks for it); another parameter set does
    not end it."""
    g = Grasping(contact_object(0.2, 5.0, 0.05), mode=mode)
    grasp = g.start(0.3, 0.5, 1.0)
    g.until(lambda: grasp.phase == 'hold')
    g.ctl.configure(g.config.replace(max_torque=4.0))
    g.step(20)
    assert grasp.phase == 'hold'
    g.ctl.configure(g.config.replace(mode=mode), mode_set=True)
    g.step()
    assert grasp.phase == phase and grasp.message == f'mode set to {mode}'
    g.until(lambda: not grasp.active).step(1)
    assert grasp.outcome == 'aborted' and g.ctl.job is None and g.ctl.mode == mode


def test_reset_ends_a_grasp():
    g = Grasping(contact_object(0.2, 5.0, 0.05))
    grasp = g.start(0.3, 0.5, 1.0)
    g.step(100)
    g.ctl.reset(0.0)
    g.step()
    assert grasp.outcome == 'aborted' and 're-initialised' in grasp.message
    assert g.log[-1][3] == 0.0 and g.ctl.job is None


def test_a_second_grasp_on_a_held_channel_never_runs():
    g = Grasping(contact_object(0.2, 5.0, 0.05))
    first = g.start(0.3, 0.5, 1.0)
    g.step(10)
    second = g.start(0.3, 0.5, 1.0)
    g.step(1)
    assert second.outcome == 'aborted' and 'another grasp' in second.message
    assert g.ctl.job is first


@pytest.mark.parametrize('seed', range(6))
def test_an_object_taken_away_in_hold_is_let_go_at_once(seed):
    """Closed loop, the sim's plant 15 % off the model, an object drawn at random taken away
    in a settled hold (the sim's environment set free): the grasp lets go within 30 ms
    (SLIP_TIME after the force estimate falls below SLIP_FRACTION of the grip), the finger --
    free, pushed by the grip until then, at about grip / (contact_damping + b_e) -- has
    travelled less than 0.07 rad by then and less than 0.15 rad when the grasp ends (the
    damper stays through the release); the grasp ends aborted and the channel is back in
    passive with zero torque. (Before: the estimator kept seeing a contact -- the model's
    b_e error times that speed is ~6 % of the grip -- the hold went on pushing, and in one
    run of six the finger ran 8 rad in 2 s on nothing.)"""
    rng, g, k, b, grip = random_grasp(200 + seed, 10.0)
    where = dict(seed=seed, k=k, b=b, grip=grip)
    grasp = g.start(float(rng.uniform(0.1, 0.3)), grip, 2.0 * grip, probe=False)
    g.until(lambda: grasp.phase == 'hold').step(int(0.3 / DT))
    assert grasp.phase == 'hold', (where, grasp.message)
    g.sim.set_environment(free())
    taken, at = g.t, g.m.x_e
    while grasp.phase == 'hold' and g.t < taken + 1.0:
        g.step()
    assert g.t - taken <= 0.030, (where, g.t - taken)
    assert g.m.x_e - at < 0.07, (where, g.m.x_e - at)
    farthest = 0.0
    while grasp.active and g.t < taken + 2.0:
        g.step()
        farthest = max(farthest, g.m.x_e - at)
    assert farthest < 0.15, (where, farthest)
    assert grasp.outcome == 'aborted', where
    assert 'gave way' in grasp.message or 'contact lost' in grasp.message, grasp.message
    g.step(2)
    assert g.ctl.job is None and g.ctl.mode == 'passive' and g.log[-1][3] == 0.0


@pytest.mark.parametrize('seed', range(8))
def test_an_object_nearer_than_the_arming_distance_is_grasped(seed):
    """An object 0-30 mm(rad) from the finger at rest -- touching it, or nearer than the
    finger needs to move steadily before its detection arms: the finger is held up by it (a
    soft one) or bounces back off it (a stiff one) and that is the contact; the grasp
    reaches hold with the grip within 5 %, the peak contact force before the squeeze below
    0.05 N m and max_force never exceeded. (Before: a stiff one made the approach bounce on
    it until the time limit, 8.5 s, then abort with 'no contact'.)"""
    rng = np.random.default_rng(300 + seed)
    plant, dahl = model_error(rng)
    position = float(rng.uniform(0.0, 0.03))
    k = float(np.exp(rng.uniform(np.log(0.5), np.log(15.0))))
    b = float(rng.uniform(0.04, 0.1))
    v = float(rng.uniform(0.05, 0.3))
    grip = min(float(rng.uniform(0.2, 0.5)), k)
    where = dict(seed=seed, position=position, k=k, b=b, v=v, grip=grip)
    g = Grasping(contact_object(position, k, b), plant=plant, dahl=dahl, seed=seed)
    g.step(200)
    grasp = g.start(v, grip, 2.0 * grip, probe=False)
    g.until(lambda: grasp.phase in ('hold', 'release', 'done'), limit=5.0)
    assert grasp.phase == 'hold' and grasp.contact, (where, grasp.message)
    g.step(int(max(0.3, 6.0 * (b + g.config.grasp.contact_damping) / k) / DT))
    forces = np.array([f for _, f, _, _ in g.log])
    phases = [p for _, _, p, _ in g.log]
    assert forces[:phases.index('squeeze')].max() < 0.05, where
    assert forces.max() <= 2.0 * grip, where
    assert abs(np.mean(forces[-int(0.1 / DT):]) - grip) <= 0.05 * grip, where


def test_an_object_too_soft_for_the_grip_aborts():
    """0.2 N m/rad gripped with 0.45 N m: 2.25 rad of squeeze, beyond grasp.give_way_travel (1.5
    rad) past the contact -- the grasp gives up, never beyond max_force, and lets go. (A joint
    range wide enough for that travel: within the default +-1.5 rad the walls stop the
    finger first, and the cycle's joint_limit fault ends the grasp: test_safety.py.)"""
    g = Grasping(contact_object(0.2, 0.2, 0.05),
                 limits=LimitParams(position_min=-5.0, position_max=5.0))
    grasp = g.start(0.2, 0.45, 0.9, probe=False)
    g.until(lambda: not grasp.active, limit=30.0).step(2)
    assert grasp.outcome == 'aborted' and grasp.contact
    assert 'past the contact' in grasp.message and 'too soft for this grip' in grasp.message
    assert max(f for _, f, _, _ in g.log) <= 0.9
    assert g.ctl.mode == 'passive' and g.log[-1][3] == 0.0


def free_approach_with_lost_states(seed, speed, sign, loss, longest, timeout=None):
    """A grasp's approach in free motion, the plant 15 % off the model, the controller missing
    states (:meth:`Grasping.step_lossy`), released after 0.4 rad. Invariants: the estimator
    reports no contact once the approach is armed, and the grasp finds none."""
    rng = np.random.default_rng(seed)
    plant, dahl = model_error(rng)
    g = Grasping(free(), mode='dob_full_ff', plant=plant, dahl=dahl, seed=seed)
    est = g.ctl.estimator
    g.step(400)
    grasp = g.start(sign * speed, 0.3, 0.6)
    start = est.position
    while grasp.phase == 'approach' and g.t < 3.0:
        g.step_lossy(rng, loss, longest, timeout=timeout)
        if grasp.armed:
            assert not est.contact, (g.t, est.force, est.threshold)
        if abs(est.position - start) >= 0.4:
            grasp.request_release('enough')
    assert not grasp.contact, grasp.message


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 16), speed=st.floats(0.05, 1.0),
       sign=st.sampled_from([1.0, -1.0]), loss=st.floats(0.0, 0.3),
       longest=st.integers(2, 30))
def test_no_contact_in_free_motion_when_states_are_lost(seed, speed, sign, loss, longest):
    """Up to 30 % of the states lost, up to 29 in a row (a separate controller process in
    real time lost 6 % with gaps of up to 10 in the measurement that found this). (Before:
    the estimator held its inputs at the new value over a gap, the motion's ramp became a
    step, and 6 of 10 free approaches at 0.3 rad/s with 6 % lost, gaps up to 10, found a
    contact.)"""
    free_approach_with_lost_states(seed, speed, sign, loss, longest)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 16), speed=st.floats(0.05, 1.0),
       sign=st.sampled_from([1.0, -1.0]), loss=st.floats(0.0, 0.2),
       longest=st.integers(20, 120))
def test_no_contact_in_free_motion_when_the_plant_stops_now_and_then(seed, speed, sign, loss,
                                                                      longest):
    """Gaps of up to 60 ms, and the plant applying zero torque after 10 ms without a command
    (the sim's command_timeout) -- what a separate controller process beside a CPU hog met:
    the estimator goes quiet after a long gap or a plant stop (QUIET_TIME) and the approach
    arms again, so the disturbance is never taken for a contact."""
    free_approach_with_lost_states(seed, speed, sign, loss, longest, timeout=20)


@pytest.mark.parametrize('seed', range(3))
def test_grasps_when_states_are_lost(seed):
    """An object drawn at random, 6 % of the states lost (gaps up to 10), now and then a gap
    of 20 ms with the plant stopped after 10: the grasp holds it, its stiffness within 10 %
    (objects up to 5 N m/rad), the grip within 5 %, max_force never exceeded."""
    rng, g, k, b, grip = random_grasp(400 + seed, 5.0)
    where = dict(seed=seed, k=k, b=b, grip=grip)
    grasp = g.start(float(rng.uniform(0.1, 0.3)), grip, 2.0 * grip)
    # 6 % lost, gaps up to 10; now and then (0.05 % of the states) a gap of 40 with the
    # plant stopped after 20
    loss, longest = 0.06, 11

    def lossy(n=1):
        for _ in range(n):
            if rng.random() < 5e-4:
                g.step_lossy(rng, 1.0, 41, n=41, timeout=20)
            else:
                g.step_lossy(rng, loss, longest, timeout=20)
    while grasp.phase != 'hold' and g.t < 10.0:
        lossy()
    assert grasp.phase == 'hold', (where, grasp.message)
    lossy(int(max(0.5, 6.0 * (b + 0.08) / k) / DT))
    estimate = g.ctl.estimator.estimate()
    assert abs(estimate.stiffness - k) <= 0.10 * k, (where, estimate)
    forces = np.array([f for _, f, _, _ in g.log])
    assert forces.max() <= 2.0 * grip, where
    assert abs(np.mean(forces[-int(0.1 / DT):]) - grip) <= 0.05 * grip, where


# --- through ControlCycle ---------------------------------------------------------------
CH = ('wrist', 'pinch')


class Cycle:
    def __init__(self, modes=('passive', 'passive'), **config):
        self.configs = [ControllerConfig(mode=m, **config) for m in modes]
        self.ctrls = [ChannelController(c, dt=DT) for c in self.configs]
        self.cc = ControlCycle(CH, self.ctrls)
        self.cycle = 0
        self.now = 10.0
        self.wall = 1_800_000_000_000_000_000

    def state(self, x=0.0, fp=0.0, fa=0.0, age=0.0, advance=DT, status=0):
        self.cycle += 1
        self.now += advance
        self.wall += int(advance * 1e9)
        out = self.cc.step(list(CH), self.cycle, self.wall - int(age * 1e9), [0.0, x],
                           [0.0, 0.0], [0.0, fp], [0.0, fa], [0, status], self.wall, self.now)
        return list(out.effort)

    def grasp(self):
        goal = GraspGoal('pinch', 0.3, 0.5, 1.0, True)
        g = Grasp(goal, self.configs[1], DT)
        self.ctrls[1].request_job(g)
        return g


def test_a_latched_fault_aborts_the_grasp_and_zeroes_the_torque():
    c = Cycle()
    c.state()
    g = c.grasp()
    for _ in range(50):
        effort = c.state()
    assert g.phase == 'approach' and effort[1] != 0.0
    effort = c.state(x=math.nan)
    assert effort[1] == 0.0 and g.outcome == 'aborted'
    assert g.message.startswith('fault latched: non-finite state')
    c.cc.request_reset()
    c.state()
    effort = c.state()
    assert effort[1] == 0.0 and c.ctrls[1].job is None    # back in passive


def test_a_grasp_requested_on_a_latched_channel_is_aborted():
    c = Cycle(max_torque=5.0)
    c.state()
    c.state(fp=math.inf)
    g = c.grasp()
    for _ in range(3):
        assert c.state()[1] == 0.0
    assert g.outcome == 'aborted' and 'fault latched' in g.message


def test_a_stalled_state_stream_aborts_the_grasp():
    c = Cycle()
    c.state()
    g = c.grasp()
    c.state()
    c.state(advance=0.3)
    assert g.outcome == 'aborted' and 'no state for' in g.message


@pytest.mark.parametrize('status, words', [
    (STATUS_FAULT, "a plant fault: clear it with the plant's ~/reset"),
    (STATUS_COMMAND_TIMEOUT, 'command timeout')])
def test_a_plant_that_stops_the_channel_for_longer_than_state_timeout_aborts_it(status, words):
    """The plant applies its own torque (a command timeout, its fault): a short stop leaves
    the grasp running, a longer one than state_timeout ends it with the plant's reason --
    the grasp's targets do not survive it -- and plant_stopped says why meanwhile."""
    c = Cycle()
    c.state()
    g = c.grasp()
    for _ in range(20):
        c.state()
    assert c.cc.plant_stopped(1) == ''
    for _ in range(5):
        c.state(status=status)
    assert g.active
    # a plant fault refuses goals at once; a command timeout (late commands on a loaded
    # host) only once it lasts longer than state_timeout
    assert c.cc.plant_stopped(1) == (words if status == STATUS_FAULT else '')
    c.state()
    assert c.cc.plant_stopped(1) == ''
    limit = int(c.cc.checks.state_timeout / DT) + 5
    for n in range(limit):
        c.state(status=status)
        if not g.active:
            break
    assert not g.active and n >= int(c.cc.checks.state_timeout / DT) - 2
    assert c.cc.plant_stopped(1) == words
    assert g.outcome == 'aborted'
    assert g.message == f'the plant stopped the channel ({words}) for longer than state_timeout'
    assert c.ctrls[1].job is None


OPS = st.one_of(
    st.tuples(st.just('state'), st.floats(-0.5, 0.5), st.floats(-1.0, 1.0),
              st.sampled_from([0.0, 0.0, 0.0, 0.3, -0.05, math.nan]), st.integers(1, 40)),
    st.tuples(st.just('grasp')), st.tuples(st.just('release')),
    st.tuples(st.just('reset')), st.tuples(st.just('mode'), st.sampled_from(
        ['passive', 'hold', 'dob_full_ff', 'force'])))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(OPS, min_size=3, max_size=30))
def test_no_torque_nobody_commanded(ops):
    """Whatever the states, requests, faults and resets:

    1. a grasp never commands a contact force beyond its max_force;
    2. from the sample after a grasp is done (canceled, aborted, reset, fault), a channel
       whose mode is passive gets zero torque -- nothing of the grasp remains;
    3. a latched channel gets zero torque;
    4. every effort is finite and within max_torque.
    """
    c = Cycle(max_torque=5.0)
    grasps = []
    for op in ops:
        if op[0] == 'grasp':
            grasps.append(c.grasp())
            continue
        if op[0] == 'release':
            for g in grasps:
                g.request_release('client')
            continue
        if op[0] == 'reset':
            c.cc.request_reset()
            continue
        if op[0] == 'mode':
            c.configs[1] = c.configs[1].replace(mode=op[1])
            c.ctrls[1].configure(c.configs[1])
            continue
        _, x, fp, age, n = op
        for _ in range(n):
            idle = c.ctrls[1].job is None and c.ctrls[1].mode == 'passive'
            effort = c.state(x=x, fp=fp, fa=0.0, age=0.0 if math.isnan(age) else age,
                             advance=DT if math.isnan(age) or age < 0.2 else 0.3)
            if math.isnan(age):
                effort = c.state(x=math.nan)
            e = effort[1]
            assert math.isfinite(e) and abs(e) <= 5.0                                 # 4
            for g in grasps:
                assert abs(g.force_command) <= g.goal.max_force + 1e-12               # 1
            if c.cc.latched(1):
                assert e == 0.0                                                      # 3
            if idle and c.ctrls[1].job is None and c.ctrls[1].mode == 'passive':
                assert e == 0.0                                                      # 2


# --- random objects, the model 15 % off ----------------------------------------------------
OBJECTS = [   # (k [N m/rad], b [N m s/rad], position [rad], closing speed [rad/s], grip [N m])
    (0.3, 0.06, 0.2, 0.25, 0.25), (1.5, 0.08, 0.15, 0.2, 0.4), (4.5, 0.05, 0.25, 0.3, 0.3),
    (12.0, 0.07, 0.2, 0.2, 0.5)]


def draw_objects(seed, n):
    """``n`` objects from the goal ranges, drawn by the test: k log-uniform 0.2..20 N m/rad,
    b 0.04..0.1 N m s/rad, at 0.15..0.3 rad, closed at 0.05..0.3 rad/s, gripped with
    0.2..0.5 N m but at most k x 1 rad (a softer object is squeezed past grasp.give_way_travel,
    1.5 rad, and the grasp aborts: test_an_object_too_soft_for_the_grip_aborts)."""
    rng = np.random.default_rng(seed)
    objects = []
    for _ in range(n):
        k = float(np.exp(rng.uniform(np.log(0.2), np.log(20.0))))
        b, position, v = rng.uniform(0.04, 0.1), rng.uniform(0.15, 0.3), rng.uniform(0.05, 0.3)
        grip = min(float(rng.uniform(0.2, 0.5)), max(0.2, k * 1.0))
        objects.append((k, float(b), float(position), float(v), grip))
    return objects


@pytest.mark.parametrize('k, b, position, v, grip', OBJECTS + draw_objects(12, 4))
def test_grasp_goals_with_the_model_15_percent_off(k, b, position, v, grip):
    """The grasp's goals, on the simulated gripper whose plant is 15 % off the controller's
    model (every parameter, random signs):

    * stiffness within 10 % up to 5 N m/rad, 25 % up to 15 (30 % at the top of the range: the
      hose's k_s 15 % off alone makes a 20 N m/rad object look 21 % softer), settled 0.5 s
      after the contact;
      the 1-sigma it reports covers the error within 2.5 sigma (six error sources at 1 sigma
      each add up to at most sqrt(6) sigma);
    * damping within 30 % up to 3 N m/rad (beyond, the hose's k_s error dominates and the
      sigma says so);
    * contact detected within 10 ms at 0.15-0.3 rad/s (slower, the force b_o v that stands out
      of the noise first is smaller, and the finger slows as it meets the object: within 30 ms
      down to 0.05 rad/s; docs/grasping.md: the bound), peak contact force before the squeeze
      below 0.05 N m (objects up to 5 N m/rad);
    * grip within 5 % in a settled hold (softer than 0.3 N m/rad: the finger's own k_e, 15 %
      off, is a fifth of the object's stiffness: within 8 %); max_force never exceeded.
    """
    rng = np.random.default_rng(int(k * 1000) + int(b * 1e4))
    plant, dahl = model_error(rng)
    max_force = grip * 2.0
    g = Grasping(contact_object(position, k, b), plant=plant, dahl=dahl,
                 seed=int(rng.integers(1000)))
    grasp = g.start(v, grip, max_force)
    t_true = None
    estimate = None
    while g.t < 20.0 and grasp.phase != 'hold':
        g.step()
        if t_true is None and g.log[-1][1] > 0.0:
            t_true = g.t
        if t_true is not None and estimate is None and g.t >= t_true + 0.5:
            estimate = g.ctl.estimator.estimate()
    assert grasp.phase == 'hold', grasp.message
    settle = 6.0 * (b + g.config.grasp.contact_damping) / k     # the soft object's creep
    g.step(int(max(0.3, settle) / DT))
    if estimate is None:
        estimate = g.ctl.estimator.estimate()
    delay = grasp.contact_time - t_true
    forces = np.array([f for _, f, _, _ in g.log])
    phases = [p for _, _, p, _ in g.log]
    before_squeeze = forces[:phases.index('squeeze')]
    assert forces.max() <= max_force
    if k <= 5.0:
        assert before_squeeze.max() < 0.05
        assert delay <= (0.010 if v >= 0.15 else 0.030), delay
    k_tol = 0.10 if k <= 5.0 else 0.25 if k <= 15.0 else 0.30
    assert abs(estimate.stiffness - k) <= k_tol * k, estimate
    assert abs(estimate.stiffness - k) <= 2.5 * estimate.stiffness_sigma, estimate
    if k <= 3.0:
        assert abs(estimate.damping - b) <= 0.30 * b, estimate
    assert abs(estimate.damping - b) <= 2.5 * estimate.damping_sigma, estimate
    grip_error = abs(np.mean(forces[-int(0.1 / DT):]) - grip) / grip
    assert grip_error <= (0.05 if k >= 0.3 else 0.08), grip_error


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 16), speed=st.floats(0.05, 1.0), back=st.floats(0.05, 1.0),
       sign=st.sampled_from([1.0, -1.0]), travel=st.floats(0.1, 0.6))
# found by this test: a slow finger reversing, held up by the Dahl model's error (the grasp
# took it for an object touched at the start); a reversal whose residual was still settling
# when the approach armed, the threshold adapted to the quiet motion before
@example(seed=66, speed=1.0, back=0.0546875, sign=1.0, travel=0.25)
@example(seed=0, speed=0.5, back=0.5, sign=1.0, travel=0.5)
def test_no_contact_in_free_motion_with_a_wrong_model(seed, speed, back, sign, travel):
    """Free motion, the sim's plant 15 % off the model (every parameter, random signs): a grasp
    from rest at any speed 0.05-1 rad/s either way, released after ``travel``, then one the
    other way (the Dahl model's error flips with the direction of motion), released likewise.
    Invariant: the estimator never reports a contact once the approach is armed, and neither
    grasp finds one -- the adaptive threshold (a third of contact_threshold at its lowest)
    stays above the residual of the model's error and the sensors' noise."""
    rng = np.random.default_rng(seed)
    plant, dahl = model_error(rng)
    g = Grasping(free(), mode='dob_full_ff', plant=plant, dahl=dahl, seed=seed)
    est = g.ctl.estimator
    ceiling = est.params.contact_threshold
    lowest, armed = ceiling, 0.0
    for v in (sign * speed, -sign * back):
        grasp = g.start(v, 0.3, 0.6)
        start = None
        while grasp.phase == 'approach':
            g.step()
            if start is None:
                start = est.position
            if grasp.armed:
                assert not est.contact, (v, g.t, est.force, est.threshold)
                bounds = (FLOOR_FRACTION * ceiling * (1 - 1e-9), ceiling * (1 + 1e-9))
                assert bounds[0] <= est.threshold <= bounds[1]
                lowest = min(lowest, est.threshold)
                armed += DT
            if abs(est.position - start) >= travel:
                grasp.request_release('enough')
        g.until(lambda: not grasp.active, limit=g.t + 5.0)
        assert not grasp.contact and grasp.outcome == 'canceled', grasp.message
    if armed >= 4.0 * SPREAD_TIME:
        assert lowest < 0.8 * ceiling       # it adapted to the residual's spread
