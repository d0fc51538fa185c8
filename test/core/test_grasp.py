"""Grasp: goal checks, each phase and transition branch by branch against a scripted estimator,
then properties over arbitrary estimator sequences and requests. No simulator, no ROS."""
import dataclasses
import math
import re

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from seaforce_ros.core.grasp import (ARM_TIME, ARM_TIME_MAX, CONTACT_TIME, RELAX_TIMES,
                                     SLIP_FRACTION, SLIP_TIME, STILL_SPEED, STILL_TIME, Grasp,
                                     GraspGoal, InvalidGoalError, check_goal)
from seaforce_ros.core.estimator import ObjectEstimate
from seaforce_ros.core.params import ControllerConfig, EstimatorParams, GraspParams

DT = 5e-4
CONFIG = ControllerConfig()
GP = CONFIG.grasp


class Est:
    """What a grasp reads from the estimator, set by the test."""

    def __init__(self):
        self.contact = False
        self.direction = 0
        self.force = 0.0
        self.position = 0.0
        self.velocity = 0.0
        self.bias = 0.0
        self.rearms = 0
        self.frozen = False
        self.quiet = False

    def rearm(self):
        self.rearms += 1

    def freeze(self):
        self.frozen = True

    def let_go(self):
        self.frozen = self.contact = False

    def estimate(self):
        return ObjectEstimate(2.0, 0.1, 0.05, 0.01, 0.2, 0.01, 0.1)

    def touch(self, force, direction=1):
        """A contact pushing back with ``force`` [N m] on the closing side of +X_e."""
        self.contact, self.direction, self.force = True, direction, -direction * force


def make(v=0.3, grip=0.5, max_force=1.0, probe=True, config=CONFIG):
    goal = GraspGoal('pinch', v, grip, max_force, probe)
    check_goal(goal, config.grasp, config.estimator, config.max_torque)
    g = Grasp(goal, config, DT)
    assert g.claim()
    return g


def steps(g, est, seconds, ve=0.0, move=True):
    """Run ``seconds``; the fake endpoint moves at the estimator's velocity if ``move``."""
    out = []
    for _ in range(int(round(seconds / DT))):
        if move:
            est.position += est.velocity * DT
        out.append(g.update(est, ve))
    return out


def finish_release(g, est):
    """The finger comes to rest after the release ramp: the grasp ends STILL_TIME later."""
    est.velocity = 0.0
    return steps(g, est, GP.release_time + STILL_TIME + 2 * DT, move=False)


def armed(v=0.3, **kwargs):
    """A grasp whose approach runs steadily at ``v`` and is armed."""
    g = make(v=v, **kwargs)
    est = Est()
    est.velocity = v
    steps(g, est, ARM_TIME + 0.05)
    assert g._armed and est.rearms == 1 and g.phase == 'approach'
    return g, est


# --- goals ---------------------------------------------------------------------------
@pytest.mark.parametrize('field, value, words', [
    ('closing_velocity', math.nan, 'closing_velocity = nan: must be a finite number'),
    ('grip_force', math.inf, 'grip_force = inf: must be a finite number'),
    ('max_force', -math.inf, 'max_force = -inf'),
    ('closing_velocity', 0.0, '|closing_velocity| must be within 0.01'),
    ('closing_velocity', -0.005, '|closing_velocity| must be within 0.01'),
    ('closing_velocity', 1e9, 'grasp.max_closing_velocity = 2 rad/s'),
    ('grip_force', 0.001, 'a lighter grip is no contact'),
    ('grip_force', -1.0, 'must be > estimator.contact_threshold'),
    ('max_force', 0.4, 'must be >= grip_force = 0.5'),
    ('max_force', 1e9, "must be <= the channel's max_torque = 5 N m"),
    ('probe', 1, 'probe = 1: must be a bool'),
    ('grip_force', True, 'must be a finite number'),
])
def test_bad_goals_are_refused_with_the_reason(field, value, words):
    goal = GraspGoal('pinch', 0.3, 0.5, 1.0, True)
    setattr(goal, field, value)
    with pytest.raises(InvalidGoalError, match=re.escape(words)):
        check_goal(goal, GP, EstimatorParams(), CONFIG.max_torque)


def test_max_force_must_exceed_the_touch():
    goal = GraspGoal('pinch', 0.3, 0.01, 0.015, False)
    with pytest.raises(InvalidGoalError, match='grasp.approach_force'):
        check_goal(goal, GP, EstimatorParams(), 5.0)


# --- approach ------------------------------------------------------------------------
def test_approach_servo_is_bounded_by_the_approach_force():
    g = make()
    est = Est()
    out = steps(g, est, 0.1, move=False)              # stalled: the integral winds up
    assert all(0.0 < f <= GP.approach_force + 1e-12 for f in out)
    assert out[-1] == pytest.approx(GP.approach_force)
    est.velocity = 5.0                                 # far too fast: brakes, bounded
    out = steps(g, est, 0.05, move=False)
    assert out[-1] == pytest.approx(-GP.approach_force)
    assert g.phase == 'approach' and not g._armed


def test_no_contact_is_armed_before_the_finger_moves_steadily():
    g = make()
    est = Est()
    est.touch(0.5)                                     # a "contact" while starting
    steps(g, est, 0.1, move=False)                     # not moving: never steady
    assert g.phase == 'approach' and not g._armed
    est.contact = False
    est.velocity = 0.3
    steps(g, est, ARM_TIME + 0.03)
    assert g._armed and g.phase == 'approach'


def test_never_armed_while_the_finger_does_not_move_steadily():
    """A finger that crawls or oscillates (a friction model's error against the speed servo)
    is never armed: its residual is the model's error changing, not an object."""
    g = make()
    est = Est()
    est.velocity = 0.01                                # crawling, nothing touched
    steps(g, est, 2 * ARM_TIME_MAX)
    assert not g._armed and est.rearms == 0 and g.phase == 'approach'
    est.touch(0.01)
    for i in range(int(2 * ARM_TIME_MAX / DT)):        # oscillating about the commanded
        est.velocity = 0.3 + 0.2 * (-1) ** (i // 40)   # speed, "touching" all along
        g.update(est, 0.0)
    assert not g._armed and g.phase == 'approach'


def test_a_finger_that_bounces_back_before_it_armed_takes_that_as_the_contact():
    """An object nearer than the finger needs to arm: the finger closing at speed meets it and
    bounces back while the servo pushes on towards it with all of approach_force -- a free
    finger pushed that way cannot move away. A finger that moves away without having closed
    (it was moving so when the goal came) is no contact."""
    g = make()
    est = Est()
    est.velocity = 0.3
    steps(g, est, 0.5 * ARM_TIME)                      # closing, not armed yet
    assert not g._armed
    est.touch(0.03)
    est.velocity = -0.1                                # ... bounced off something
    out = []
    while g.phase == 'approach' and len(out) < 0.05 / DT:
        out += steps(g, est, DT)
    assert g.phase == 'contact' and g.contact and est.rearms == 0
    assert max(out) <= GP.approach_force
    g2 = make()
    est2 = Est()
    est2.touch(0.03)
    est2.velocity = -0.1                               # moving away from the start
    steps(g2, est2, 2 * ARM_TIME_MAX)
    assert g2.phase == 'approach' and not g2._armed


def test_a_finger_that_starts_touching_the_object_takes_that_as_the_contact():
    """Held up from the start by a push on the closing side (it never got going): at
    ARM_TIME_MAX the contact is the object's, not the model starting to move."""
    g = make()
    est = Est()
    est.touch(0.02)
    steps(g, est, ARM_TIME_MAX + DT, move=False)
    assert g.phase == 'contact' and g.contact and est.rearms == 0


def test_a_held_up_finger_counts_as_touching_only_with_its_servo_at_approach_force():
    """A slow approach (0.05 rad/s) held up from the start by a push on the closing side: at
    ARM_TIME_MAX its servo's integral has not reached approach_force -- the friction model's
    error may be what holds it (with a real finger the integral frees it first) -- so no
    contact yet; once the servo pushes with all of approach_force and the finger still does not
    move, the push is the object's."""
    g = make(v=0.05)
    est = Est()
    est.touch(0.005)
    out = steps(g, est, ARM_TIME_MAX + DT, move=False)
    assert g.phase == 'approach' and not g.contact and max(out) < GP.approach_force
    before = g.force_command
    for _ in range(int(2.0 / DT)):
        if g.phase != 'approach':
            break
        before = g.force_command
        g.update(est, 0.0)
    assert g.phase == 'contact' and g.contact and est.rearms == 0
    assert before == pytest.approx(GP.approach_force)


def test_contact_on_the_closing_side_starts_the_contact_phase():
    g, est = armed()
    est.touch(0.005)
    f = g.update(est, 0.3)
    assert g.phase == 'contact' and g.contact and g.message == 'contact'
    assert g.force_command == pytest.approx(GP.approach_force)
    assert f == pytest.approx(GP.approach_force - GP.contact_damping * 0.3)
    assert g.contact_time > ARM_TIME


def test_negative_closing_velocity_mirrors_everything():
    g, est = armed(v=-0.3)
    est.touch(0.005, direction=-1)
    g.update(est, 0.0)
    assert g.phase == 'contact' and g.force_command == pytest.approx(-GP.approach_force)


def test_a_push_from_the_other_side_aborts():
    g, est = armed()
    est.touch(0.01, direction=-1)
    g.update(est, 0.0)
    assert g.phase == 'release' and 'other side' not in g.message
    assert 'away from the object' in g.message
    finish_release(g, est)
    assert g.phase == 'done' and g.outcome == 'aborted'


def test_no_contact_within_max_travel_aborts():
    g, est = armed(config=ControllerConfig(grasp=GraspParams(max_travel=0.05)))
    steps(g, est, 0.2)
    assert g.phase == 'release'
    finish_release(g, est)
    assert g.outcome == 'aborted' and 'no contact within' in g.message
    assert 'grasp.max_travel 0.05 rad' in g.message


def test_no_contact_within_the_time_limit_aborts():
    """A finger that cannot move (something blocks it before the detection is armed) gives
    up after 2 max_travel/|v| + 1 s."""
    g = make(v=2.0)
    est = Est()
    steps(g, est, 2.0 * GP.max_travel / 2.0 + 1.0 + DT, move=False)
    assert g.phase == 'release'
    finish_release(g, est)
    assert g.outcome == 'aborted' and 'no contact within' in g.message


# --- contact, squeeze, probe, hold ---------------------------------------------------
def run_to_hold(grip=0.5, max_force=1.0, probe=True, config=CONFIG):
    g, est = armed(grip=grip, max_force=max_force, probe=probe, config=config)
    est.velocity = 0.0
    est.touch(0.01)
    seen = {}
    t = 0.0
    while g.phase != 'hold' and t < 5.0:
        f = g.update(est, 0.0)
        seen.setdefault(g.phase, []).append((t, f, g.force_command))
        est.touch(max(g.force_command, 0.005))            # the object pushes back as hard
        t += DT
    return g, est, seen


def test_phases_in_order_with_their_forces():
    g, est, seen = run_to_hold()
    assert list(seen) == ['contact', 'squeeze', 'probe', 'hold']
    contact = [c for _, _, c in seen['contact']]
    assert all(c == pytest.approx(GP.approach_force) for c in contact)
    assert len(contact) == pytest.approx(CONTACT_TIME / DT, abs=2)
    squeeze = [c for _, _, c in seen['squeeze']]
    assert all(b >= a - 1e-12 for a, b in zip(squeeze, squeeze[1:]))      # monotone
    assert squeeze[-1] == pytest.approx(0.5, rel=1e-3)
    probe = [c for _, _, c in seen['probe']]
    amplitude = min(GP.probe_amplitude * 0.5, 0.5 * (1.0 - 0.5))
    assert 0.5 + 0.8 * amplitude < max(probe) <= 0.5 + amplitude
    assert 0.5 - amplitude <= min(probe) < 0.5 - 0.4 * amplitude
    assert len(probe) == pytest.approx(GP.probe_duration / DT, abs=2)
    steps(g, est, 0.5, move=False)
    assert g.phase == 'hold' and g.force_command == 0.5 and g.message == 'holding'
    assert g.grip_force == pytest.approx(0.5, rel=1e-3)


def test_without_probe_the_squeeze_goes_to_hold():
    _, _, seen = run_to_hold(probe=False)
    assert list(seen) == ['contact', 'squeeze', 'hold']


def test_the_probe_uses_half_the_headroom_to_max_force():
    _, _, seen = run_to_hold(grip=0.5, max_force=0.6)
    assert max(c for _, _, c in seen['probe']) <= 0.55 + 1e-9


def test_bias_and_damping_are_commanded_away_in_contact():
    g, est, _ = run_to_hold()
    est.bias = 0.01
    f = g.update(est, 0.2)
    assert f == pytest.approx(0.5 - 0.01 - GP.contact_damping * 0.2)
    assert g.force_command == 0.5


def test_contact_lost_aborts_with_a_release():
    g, est, _ = run_to_hold()
    est.contact = False
    est.position = 0.3
    g.update(est, 0.0)
    assert g.phase == 'release' and 'contact lost at 0.3 rad in hold' in g.message
    out = finish_release(g, est)
    assert all(abs(b) <= abs(a) + 1e-12 for a, b in zip(out, out[1:]))   # ramps down
    assert g.phase == 'done' and g.outcome == 'aborted' and out[-1] == 0.0
    assert g.update(est, 1.0) == 0.0 and g.force_command == 0.0


def test_force_beyond_max_force_aborts():
    g, est, _ = run_to_hold()
    est.touch(1.2)
    g.update(est, 0.0)
    assert g.phase == 'release' and 'beyond max_force 1 N m in hold' in g.message


def test_release_request_ramps_down_then_canceled():
    g, est, _ = run_to_hold()
    g.request_release('released by the client')
    g.update(est, 0.0)
    assert est.frozen and est.contact                # the estimator's fit stops meanwhile
    out = finish_release(g, est)
    assert out[0] < 0.5 and out[-1] == 0.0 and not est.frozen and not est.contact
    assert g.estimate == est.estimate()              # taken before the estimator lets go
    assert g.outcome == 'canceled' and g.message == 'released by the client'
    g.request_release('again')                      # no effect once done
    g.update(est, 0.0)
    assert g.outcome == 'canceled' and g.message == 'released by the client'


def test_the_release_waits_for_the_finger_to_come_to_rest_with_the_damper_on():
    g, est, _ = run_to_hold()
    g.request_release('released')
    est.velocity = -1.0                             # the object pushes the finger open
    out = steps(g, est, GP.release_time + 0.1, ve=-1.0, move=False)
    assert g.phase == 'release' and out[-1] == pytest.approx(GP.contact_damping)
    est.velocity = 0.5 * STILL_SPEED
    steps(g, est, STILL_TIME + DT, move=False)
    assert g.phase == 'done'
    g2, est2, _ = run_to_hold()
    g2.request_release('released')
    est2.velocity = 1.0                             # never still (the friction model's error
    relax = RELAX_TIMES * (0.05 + GP.contact_damping) / 2.0      # creeps): the object's time
    steps(g2, est2, GP.release_time + relax - 2 * DT, move=False)
    assert g2.phase == 'release'
    steps(g2, est2, 3 * DT, move=False)
    assert g2.phase == 'done' and g2.outcome == 'canceled'


def test_abort_now_commands_nothing_more():
    g, est, _ = run_to_hold()
    g.abort_now('fault latched: x')
    assert g.phase == 'done' and g.outcome == 'aborted' and g.force_command == 0.0
    assert g.update(est, 0.3) == 0.0
    g.abort_now('again')
    assert g.message == 'fault latched: x'


def test_abort_now_keeps_the_estimate_of_a_contact():
    g, est, _ = run_to_hold()
    g.abort_now('the plant stopped', est.estimate())
    assert g.estimate == est.estimate() and g.contact
    g2 = make()                                      # no contact: nothing to keep
    g2.abort_now('the plant stopped', est.estimate())
    assert g2.estimate is None and not g2.contact


@pytest.mark.parametrize('phase', ['contact', 'squeeze', 'hold'])
def test_travel_past_the_contact_beyond_give_way_travel_drops_the_grip(phase):
    """An object that gives way leaves the estimator seeing a contact (the model's error at
    the speed the grip drives a free finger); the grasp lets go at once: nothing pushes from
    the next sample on, the damper stays."""
    g, est, _ = run_to_hold() if phase == 'hold' else (None, None, None)
    if g is None:
        g, est = armed()
        est.touch(0.03)
        g.update(est, 0.0)
        if phase == 'squeeze':
            steps(g, est, CONTACT_TIME + DT, move=False)
        assert g.phase == phase
    contact_at = est.position       # the finger has not moved since the touch
    est.position = contact_at + GP.give_way_travel * 0.999
    g.update(est, 0.0)
    assert g.phase == phase
    est.position = contact_at + GP.give_way_travel * 1.001
    f = g.update(est, 0.4)
    assert g.phase == 'release' and g.force_command == 0.0
    assert f == pytest.approx(-GP.contact_damping * 0.4)
    assert f'past the contact in {phase}' in g.message and 'gave way' in g.message
    finish_release(g, est)
    assert g.outcome == 'aborted'


def test_an_object_that_gives_way_during_the_release_ramp_is_dropped():
    """A cancel ramps the force down; if the finger runs past give_way_travel meanwhile (the
    object gave way as the client let go: found by the properties below, the release request
    and the travel on one sample), nothing pushes from then on."""
    g, est, _ = run_to_hold()
    g.request_release('released')
    f = g.update(est, 0.0)
    assert g.phase == 'release' and 0.0 < f < 0.5
    est.position += GP.give_way_travel * 1.001
    f = g.update(est, 0.2)
    assert g.force_command == 0.0 and f == pytest.approx(-GP.contact_damping * 0.2)
    finish_release(g, est)
    assert g.outcome == 'canceled'


def test_a_hold_whose_force_falls_below_the_slip_level_drops_the_grip():
    """In hold the object's force only rises towards the grip (a soft object creeps); below
    SLIP_FRACTION of the grip for SLIP_TIME the object gave way: release at once, aborted.
    A shorter dip (a probe's echo, noise) does not."""
    g, est, _ = run_to_hold(probe=False)
    steps(g, est, 0.3, move=False)
    assert g.phase == 'hold'
    grip = g.grip_force
    est.touch(0.9 * SLIP_FRACTION * grip)
    steps(g, est, SLIP_TIME - 3 * DT, move=False)
    est.touch(grip)
    steps(g, est, 0.05, move=False)
    assert g.phase == 'hold'
    est.touch(0.9 * SLIP_FRACTION * grip)
    out = steps(g, est, SLIP_TIME + 2 * DT, move=False)
    assert g.phase == 'release' and 'gave way in hold' in g.message
    assert out[-1] == 0.0 and g.force_command == 0.0
    finish_release(g, est)
    assert g.outcome == 'aborted'


def test_a_quiet_estimator_disarms_the_approach():
    """Lost states or a plant stop in the approach (the estimator goes quiet): the motion the
    bias was captured in was interrupted, so the grasp arms again -- a new bias -- once the
    finger moves steadily; meanwhile no contact is taken."""
    g, est = armed()
    est.quiet = True
    est.touch(0.03)
    g.update(est, 0.0)
    assert g.phase == 'approach' and not g._armed
    est.quiet = est.contact = False
    steps(g, est, ARM_TIME + 0.01)
    assert g._armed and est.rearms == 2


def test_a_quiet_estimator_neither_slips_nor_overloads_a_hold():
    """In hold, while the estimator is quiet its force estimate is no sample of the object:
    no slip and no max_force abort on it, the grip commanded on; once it is sampled again a
    slip is a slip."""
    g, est, _ = run_to_hold(probe=False)
    steps(g, est, 0.3, move=False)
    grip = g.grip_force
    est.quiet = True
    est.touch(0.1 * grip)
    out = steps(g, est, 3 * SLIP_TIME, move=False)
    est.touch(5.0)                                  # beyond max_force (1 N m)
    out += steps(g, est, 3 * SLIP_TIME, move=False)
    assert g.phase == 'hold' and g.force_command == 0.5 and g.grip_force == grip
    assert all(f == pytest.approx(0.5) for f in out)
    est.quiet = False
    est.touch(0.1 * grip)
    steps(g, est, SLIP_TIME + 2 * DT, move=False)
    assert g.phase == 'release' and 'gave way in hold' in g.message


def test_a_hold_entered_on_a_quiet_estimate_starts_from_the_grip_commanded():
    """The squeeze ends while the estimator is quiet (its force no sample of the object): the
    hold's average starts from grip_force, not from that force -- a wrong start (0.8 for a
    0.2 grip) made the true 0.2 look like a slip 10 ms after the quiet period."""
    g, est = armed(grip=0.2, max_force=1.0, probe=False)
    est.touch(0.02)
    while g.phase != 'hold':
        if g.phase == 'squeeze' and g._t >= GP.squeeze_time - 5 * DT:
            est.quiet = True
            est.touch(0.8)
        g.update(est, 0.0)
    assert g.grip_force == 0.2
    est.quiet = False
    est.touch(0.2)
    steps(g, est, 0.1, move=False)
    assert g.phase == 'hold' and g.grip_force == pytest.approx(0.2)


def test_one_sample_after_a_gap_is_one_sample_of_slip():
    """A state after a gap of 20 samples (not yet a quiet one) below the slip level counts as
    one sample, not as 10 ms of them; SLIP_TIME of samples seen still drops the object."""
    g, est, _ = run_to_hold(probe=False)
    steps(g, est, 0.3, move=False)
    est.touch(0.1 * g.grip_force)
    g.update(est, 0.0, 20)
    assert g.phase == 'hold'
    steps(g, est, SLIP_TIME, move=False)
    assert g.phase == 'release' and 'gave way in hold' in g.message


def test_slip_before_a_quiet_period_does_not_add_to_slip_after_it():
    g, est, _ = run_to_hold(probe=False)
    steps(g, est, 0.3, move=False)
    est.touch(0.1 * g.grip_force)
    steps(g, est, SLIP_TIME - 4 * DT, move=False)
    est.quiet = True
    steps(g, est, 0.03, move=False)
    est.quiet = False
    steps(g, est, 3 * DT, move=False)
    assert g.phase == 'hold'
    steps(g, est, SLIP_TIME, move=False)
    assert g.phase == 'release'


def test_a_long_quiet_gap_neither_arms_nor_takes_a_contact():
    """One update covering a gap longer than ARM_TIME, the estimator quiet: the approach does
    not count the gap as steady or held-up motion."""
    g = make()
    est = Est()
    est.velocity = 0.3
    est.quiet = True
    g.update(est, 0.0, int(ARM_TIME_MAX / DT) + 200)
    assert not g._armed and est.rearms == 0
    est.touch(0.03)
    est.velocity = 0.0
    g.update(est, 0.0, int(ARM_TIME_MAX / DT) + 200)
    assert g.phase == 'approach' and not g.contact


def test_request_abort_ends_the_grasp_at_the_next_sample():
    """The node ends a goal whose cycle stopped running and asks the grasp to end in the
    cycle's thread: at the next sample it is done, aborted, commanding nothing, with the
    object's estimate."""
    g, est, _ = run_to_hold()
    g.request_abort('no actuator_state for 0.06 s')
    assert g.phase == 'hold'                        # nothing happens in the caller's thread
    assert g.update(est, 0.3) == 0.0
    assert g.phase == 'done' and g.outcome == 'aborted' and g.force_command == 0.0
    assert g.message == 'no actuator_state for 0.06 s' and g.estimate == est.estimate()


def test_withdraw_only_before_the_cycle_claims_it():
    goal = GraspGoal('pinch', 0.3, 0.5, 1.0, True)
    g = Grasp(goal, CONFIG, DT)
    assert g.withdraw('the cycle did not run') and g.phase == 'done'
    assert not g.claim() and g.outcome == 'aborted'
    g2 = Grasp(goal, CONFIG, DT)
    assert g2.claim() and not g2.withdraw('too late') and g2.phase == 'approach'


# --- properties ----------------------------------------------------------------------
EVENTS = st.one_of(
    st.tuples(st.just('state'), st.booleans(), st.sampled_from([-1, 1]),
              st.floats(-3.0, 3.0), st.floats(-1.0, 1.0), st.floats(-0.05, 0.05),
              st.integers(1, 40), st.floats(-2.0, 2.0)),
    # what reaches the later phases: a steady approach at the goal's speed (it arms);
    st.tuples(st.just('steady'), st.integers(int(ARM_TIME / DT), int(ARM_TIME / DT) + 200)),
    # an object on the closing side pressing with a share of the grip, the finger moving
    # (towards it: it gives way) at a speed
    st.tuples(st.just('press'), st.floats(0.0, 1.5), st.floats(-1.0, 3.0), st.integers(1, 800)),
    # lost states or a plant stop: the estimator is quiet (or no longer)
    st.tuples(st.just('quiet'), st.booleans()),
    st.tuples(st.just('release')), st.tuples(st.just('abort')))


INVARIANTS = """
    1. the commanded contact force never exceeds max_force (nor approach_force in approach);
    2. F_g stays within max_force + |bias| + contact_damping |V_e| (what a contact adds; the
       largest |bias| so far: a release ramps down from what it pushed with then);
    3. phases only move forward; once done, F_g is zero for ever and the outcome is set;
    4. a release ends in 'canceled' unless an abort came first; an abort_now ends at once;
    5. an abort never leaves a non-zero force: done means F_g == 0;
    6. once the finger is more than give_way_travel past the contact (on the closing side) while
       the grasp pushes, nothing pushes from that sample on: F_g is the damper's
       -contact_damping V_e alone (zero once done) -- an object that gave way is dropped;
    7. in hold, a contact force below SLIP_FRACTION of the grip for SLIP_TIME of samples
       (and one sample's rounding; a quiet estimator's are none) ends the hold -- never a grip
       held on nothing.
"""


def goal_forces(grip, headroom):
    """(grip, max_force) a goal may have: max_force above the touch, within max_torque."""
    max_force = min(grip * headroom, CONFIG.max_torque)
    if max_force <= GP.approach_force:
        max_force = GP.approach_force * 1.5
        grip = min(grip, max_force)
    return grip, max_force


def check_invariants(g, est, events, give_way_travel, contact_at=None):
    """Feed ``events`` to grasp ``g`` through the scripted estimator ``est``, asserting
    :data:`INVARIANTS` at every sample; ``contact_at``: where a grasp already in contact
    touched."""
    v, grip, max_force = g.goal.closing_velocity, g.goal.grip_force, g.goal.max_force
    sign = 1.0 if v > 0 else -1.0
    dropped = False
    slipping = 0
    order = ['approach', 'contact', 'squeeze', 'probe', 'hold', 'release', 'done']
    last = order.index(g.phase)
    released = aborted = False
    biggest_bias = 0.0
    for ev in events:
        if ev[0] == 'release':
            g.request_release('client')
            released = released or g.phase not in ('release', 'done')
            continue
        if ev[0] == 'abort':
            was_done = g.phase == 'done'
            g.abort_now('fault')
            aborted = aborted or not was_done
            assert g.phase == 'done'
            continue
        if ev[0] == 'quiet':
            est.quiet = ev[1]
            continue
        if ev[0] == 'steady':
            ev = ('state', False, 1, 0.0, v, 0.0, ev[1], 0.0)
        elif ev[0] == 'press':
            _, share, speed, n = ev
            ev = ('state', True, int(sign), -sign * share * grip, sign * speed, 0.0, n,
                  sign * speed)
        _, contact, direction, force, velocity, bias, n, ve = ev
        est.contact, est.direction, est.force = contact, direction, force
        est.velocity, est.bias = velocity, bias
        for _ in range(n):
            est.position += velocity * DT
            pushing = g.phase in ('contact', 'squeeze', 'probe', 'hold')
            if g.phase == 'hold' and est.contact and \
                    -sign * est.force < SLIP_FRACTION * g.grip_force:
                slipping += 0 if est.quiet else 1
            else:
                slipping = 0
            f = g.update(est, ve)
            if contact_at is None and g.contact:
                contact_at = est.position
            if pushing and sign * (est.position - contact_at) > give_way_travel:
                dropped = True
            if dropped:
                assert g.force_command == 0.0                                        # 6
                assert f == (0.0 if g.phase == 'done' else -GP.contact_damping * ve)  # 6
            if slipping > SLIP_TIME / DT:
                assert g.phase != 'hold'                                             # 7
            limit = GP.approach_force if g.phase == 'approach' else max_force
            assert abs(g.force_command) <= limit + 1e-12                           # 1
            biggest_bias = max(biggest_bias, abs(bias))
            assert abs(f) <= max_force + biggest_bias + GP.contact_damping * abs(ve) + 1e-12  # 2
            now = order.index(g.phase)
            assert now >= last                                                       # 3
            last = now
            if g.phase == 'done':
                assert f == 0.0 and g.outcome in ('canceled', 'aborted')          # 3, 5
    if g.phase == 'done' and released and not aborted and g.outcome == 'canceled':
        assert g.message == 'client'                                               # 4


def travel_config(give_way_travel):
    return CONFIG.replace(grasp=dataclasses.replace(GP, give_way_travel=give_way_travel))


TRAVELS = st.sampled_from([GP.give_way_travel, 0.2, 0.05, 0.005])


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(events=st.lists(EVENTS, min_size=1, max_size=60),
       v=st.sampled_from([-0.3, -0.05, 0.1, 0.3, 1.5]), grip=st.floats(0.01, 2.0),
       headroom=st.floats(1.0, 3.0), probe=st.booleans(), give_way_travel=TRAVELS)
def test_properties_over_arbitrary_estimates(events, v, grip, headroom, probe, give_way_travel):
    """From the start of a grasp, whatever the estimator says and whenever releases and
    aborts come: the INVARIANTS."""
    grip, max_force = goal_forces(grip, headroom)
    g = make(v=v, grip=grip, max_force=max_force, probe=probe,
             config=travel_config(give_way_travel))
    check_invariants(g, Est(), events, give_way_travel)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
# found by this test in CI: a release requested on the sample the finger passed
# give_way_travel ramped down instead of dropping
@example(events=[('quiet', True), ('press', 0.0, 2.0, 3), ('press', 0.0, 0.134765625, 696),
                 ('release',), ('steady', 100)], grip=1.0, headroom=1.0, probe=False,
         give_way_travel=0.05)
@given(events=st.lists(EVENTS, min_size=1, max_size=30), grip=st.floats(0.05, 2.0),
       headroom=st.floats(1.0, 3.0), probe=st.booleans(), give_way_travel=TRAVELS)
def test_properties_from_a_hold(events, grip, headroom, probe, give_way_travel):
    """From a settled hold (where an object gives way, slips, is pulled out): the INVARIANTS
    whatever the estimator says next."""
    grip, max_force = goal_forces(grip, headroom)
    g, est, _ = run_to_hold(grip=grip, max_force=max_force, probe=probe,
                            config=travel_config(give_way_travel))
    assert g.phase == 'hold'
    check_invariants(g, est, events, give_way_travel, contact_at=est.position)
