"""ControlCycle: state validation -> ChannelController -> output check, branch by branch, then
properties over arbitrary state sequences. No ROS."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from seaforce_ros.core import ChannelController, ChirpParams, ControllerConfig, MODES
from seaforce_ros.core.control_cycle import (DEFAULT_LATCHED, FAULT_KINDS, ControlCycle,
                                             StateChecks)
from seaforce_ros.core.errors import InvalidParameterError
from seaforce_ros.core.plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT

DT = 5e-4
CH = ('wrist', 'pinch')
T0_NS = 1_800_000_000_000_000_000


class Feed:
    """Sends states to a ControlCycle the way controller_node does, with a clock."""

    def __init__(self, cycle_obj):
        self.cc = cycle_obj
        self.cycle = 0
        self.now = 50.0                 # monotonic [s]
        self.wall = T0_NS               # system clock [ns]

    def state(self, x=(0.0, 0.0), v=(0.0, 0.0), fp=(0.0, 0.0), fa=(0.0, 0.0), status=(0, 0),
              names=CH, cycle=None, age=0.0, advance=DT):
        """One state, stamped ``age`` s before it arrives; returns (efforts, answered)."""
        self.now += advance
        self.wall += int(advance * 1e9)
        self.cycle = self.cycle + 1 if cycle is None else cycle
        out = self.cc.step(list(names), self.cycle, self.wall - int(age * 1e9), list(x),
                           list(v), list(fp), list(fa), list(status), self.wall, self.now)
        return list(out.effort), out.answered


def make(modes=('hold', 'hold'), checks=None, **config):
    ctrls = [ChannelController(ControllerConfig(mode=m, **config), dt=DT) for m in modes]
    cc = ControlCycle(CH, ctrls, checks)
    return cc, Feed(cc)


def test_first_state_starts_from_the_applied_torque():
    """A (re)started controller takes over from what the plant applies: no step."""
    cc, feed = make(('hold', 'dob_full_ff'))
    effort, answered = feed.state(x=(0.3, -0.2), v=(1.0, 2.0), fp=(0.4, -0.5), fa=(1.5, -0.7))
    assert answered and effort == pytest.approx([1.5, -0.7], abs=1e-12)


def test_hold_resists_motion_from_where_it_started():
    cc, feed = make()
    feed.state(x=(0.1, 0.1))
    effort, _ = feed.state(x=(0.11, 0.09))
    assert effort[0] < -0.1 and effort[1] > 0.1


def test_plant_restart_reinitialises_instead_of_stepping():
    """Defect: hold kept its old target after a plant restart and stepped -9.87 N m. Now the
    cycle going back re-initialises every channel from the new plant's present state."""
    cc, feed = make()
    feed.state(x=(0.0, 0.0))
    for _ in range(200):
        effort, _ = feed.state(x=(0.0, 0.005), fa=(0.0, -0.75))
    assert effort[1] < -0.7
    # a new plant: cycle 1 again, the finger elsewhere, nothing applied yet
    effort, _ = feed.state(cycle=1, x=(0.0, 0.5), fa=(0.0, 0.0), advance=3.0)
    assert effort == [0.0, 0.0]             # that state: zero, the stream re-arms
    effort, _ = feed.state(x=(0.0, 0.5), fa=(0.0, 0.0))
    assert effort == pytest.approx([0.0, 0.0], abs=1e-12)   # re-armed at the new position
    assert any('plant restarted' in text for _, text in cc.events.drain())
    assert cc.counts['state_gap'] == 1 and not cc.latched(1)


def test_state_out_of_order_is_dropped_unanswered():
    cc, feed = make()
    feed.state()
    feed.state(cycle=10)
    effort, answered = feed.state(cycle=8)
    assert not answered and cc.dropped == 1
    assert feed.state(cycle=11)[1]


def test_cycle_jump_and_stall_rearm_without_latching():
    cc, feed = make()
    feed.state()
    feed.state(x=(0.0, 0.005))
    effort, _ = feed.state(cycle=feed.cycle + 500, x=(0.0, 0.005), fa=(0.0, -0.5))
    assert effort == [0.0, 0.0] and cc.fault(1).startswith('re-arming: cycle jumped')
    effort, _ = feed.state(x=(0.0, 0.005), fa=(0.0, -0.5))
    assert effort == pytest.approx([0.0, -0.5]) and cc.fault(1) == ''
    effort, _ = feed.state(x=(0.0, 0.005), fa=(0.0, -0.5), advance=0.2)   # 200 ms silence
    assert effort == [0.0, 0.0] and 'no state for 200.0 ms' in cc.fault(0)
    effort, _ = feed.state(x=(0.0, 0.005), fa=(0.0, 0.0))
    assert effort == pytest.approx([0.0, 0.0]) and not cc.latched(0)


def test_stale_state_is_a_stall_not_a_data_fault():
    """Defect: under load the controller latched `stale state` and needed a manual reset,
    although the plant had already zeroed the torque. Now it re-arms by itself."""
    cc, feed = make()
    feed.state()
    effort, answered = feed.state(x=(0.0, 0.05), age=0.3)
    assert answered and effort == [0.0, 0.0] and 'stale state' in cc.fault(1)
    effort, _ = feed.state(x=(0.0, 0.05), fa=(0.0, 0.0))
    assert effort == [0.0, 0.0] and cc.fault(1) == ''      # re-armed at the present state
    effort, _ = feed.state(x=(0.0, 0.06))
    assert effort[1] < 0.0                                  # and holding again
    text = ' '.join(t for _, t in cc.events.drain())
    assert 'stale state' in text and 'states flow again' in text


def test_stale_state_latches_when_configured():
    cc, feed = make(checks=StateChecks(latched=DEFAULT_LATCHED + ('stale_state',)))
    feed.state()
    feed.state(age=0.3)
    for _ in range(5):
        effort, _ = feed.state(x=(0.0, 0.05))
        assert effort == [0.0, 0.0]
    assert cc.latched(0).startswith('stale state')


def test_start_up_backlog_is_dropped_unanswered():
    cc, feed = make()
    for _ in range(3):
        effort, answered = feed.state(age=1.0)
        assert not answered
    assert cc.dropped == 3 and not any(cc.latched(i) for i in range(2))
    assert feed.state()[1]


def test_state_from_the_future_latches():
    """Defect: a state stamped a day in the future passed the stale check."""
    cc, feed = make()
    feed.state()
    effort, _ = feed.state(age=-86400.0)
    assert effort == [0.0, 0.0] and 'in the future' in cc.latched(0)
    for _ in range(5):
        assert feed.state(x=(0.0, 0.1))[0] == [0.0, 0.0]


@pytest.mark.parametrize('field, value, kind', [
    ('x', math.nan, 'non-finite state'), ('v', math.inf, 'non-finite state'),
    ('fp', -math.inf, 'non-finite state'), ('fa', math.nan, 'non-finite state'),
    ('x', 1e308, 'implausible state'), ('v', -5e3, 'implausible state'),
    ('fp', 2e3, 'implausible state')])
def test_bad_values_latch_that_channel_only(field, value, kind):
    cc, feed = make()
    feed.state()
    kwargs = {field: (0.01, value)}
    effort, _ = feed.state(**kwargs)
    assert effort[1] == 0.0 and cc.latched(1).startswith(kind) and not cc.latched(0)
    for _ in range(3):
        effort, _ = feed.state(x=(0.02, 0.02))
        assert effort[0] < 0.0 and effort[1] == 0.0


@pytest.mark.parametrize('mode', ['dob_linear_ff', 'dob_full_ff', 'impedance'])
def test_huge_finite_inputs_never_give_nan_torque(mode):
    """Defect: 1e308 inputs gave NaN torque with diagnostics OK, and the NaN persisted. Now
    such a state latches (implausible), the torque stays finite and zero, and a reset brings
    the channel back bumplessly on normal states."""
    cc, feed = make((mode, mode), checks=StateChecks(force_limit=1e308, velocity_limit=1e308,
                                                     position_limit=1e308))
    feed.state()
    effort, _ = feed.state(x=(0.0, 1e308), v=(0.0, 1e308), fp=(0.0, 1e308))
    assert all(math.isfinite(e) for e in effort) and effort[1] == 0.0
    # (the position is far beyond the joint range too: whichever check meets it first)
    assert cc.latched(1).startswith(('non_finite', 'computed torque', 'torque',
                                     'beyond the joint range'))
    for _ in range(3):
        effort, _ = feed.state(fa=(0.0, 0.0))
        assert effort[1] == 0.0
    assert 'pinch' in cc.request_reset()
    effort, _ = feed.state(fa=(0.0, 0.0))
    assert effort == pytest.approx([0.0, 0.0], abs=1e-12)
    for _ in range(50):
        effort, _ = feed.state(fp=(0.0, 0.01))
        assert all(math.isfinite(e) for e in effort)
    assert effort[1] != 0.0 and not cc.latched(1)


def test_torque_beyond_max_torque_latches_and_reset_resumes_bumplessly():
    cc, feed = make(max_torque=0.5)
    feed.state()
    effort, _ = feed.state(x=(0.001, 0.1))            # hold: -15 N m wanted on pinch
    assert effort[1] == 0.0 and 'beyond max_torque 0.5' in cc.latched(1)
    assert effort[0] < 0.0
    cc.request_reset()
    effort, _ = feed.state(x=(0.001, 0.1), fa=(0.0, 0.0))
    assert effort[1] == 0.0 and not cc.latched(1)     # re-captured where it is now
    effort, _ = feed.state(x=(0.001, 0.101), fa=(0.0, 0.0))
    assert -0.5 <= effort[1] < 0.0


def test_an_arithmetic_error_in_the_controller_latches_instead_of_escaping():
    class Overflowing(ChannelController):
        def update(self, x, v, f_p, steps=1):
            if x > 0.5:
                raise OverflowError('math range error')
            return super().update(x, v, f_p, steps)

    ctrls = [ChannelController(ControllerConfig(mode='hold'), dt=DT),
             Overflowing(ControllerConfig(mode='hold'), dt=DT)]
    cc = ControlCycle(CH, ctrls)
    feed = Feed(cc)
    feed.state()
    effort, answered = feed.state(x=(0.001, 0.6))
    assert answered and effort[1] == 0.0 and effort[0] < 0.0
    assert 'overflowed' in cc.latched(1)
    assert feed.state(x=(0.001, 0.7))[0][1] == 0.0       # latched: still served, still zero


def test_malformed_state_faults_every_channel_and_the_node_keeps_serving():
    """Defect: a status array shorter than name crashed controller_node (IndexError)."""
    cc, feed = make()
    feed.state()
    effort, answered = feed.state(status=(0,))
    assert answered and effort == [0.0, 0.0]
    assert 'status 1' in cc.latched(0) and 'malformed' in cc.latched(1)
    effort, answered = feed.state(names=('pinch', 'pinch'))
    assert answered and effort == [0.0, 0.0]


def test_missing_channel_faults_that_channel():
    cc, feed = make()
    feed.state()
    effort, answered = feed.state(names=('wrist', 'thumb'), x=(0.01, 0.0))
    assert answered and effort[1] == 0.0 and effort[0] < 0.0
    assert cc.latched(1) == 'channel missing from actuator_state'


def test_state_naming_no_channel_is_dropped():
    cc, feed = make()
    effort, answered = feed.state(names=('left', 'right'))
    assert not answered and cc.dropped == 1
    assert not any(cc.latched(i) for i in range(2))
    assert 'dropped' in cc.events.drain()[0][1]


def test_channels_in_another_order_are_mapped_by_name():
    cc, feed = make()
    feed.state(names=('pinch', 'wrist'))
    effort, _ = feed.state(names=('pinch', 'wrist'), x=(0.01, -0.02))
    assert effort[0] > 0.0 and effort[1] < 0.0         # wrist at -0.02, pinch at 0.01


def test_repeated_state_gets_the_same_answer():
    cc, feed = make()
    feed.state()
    first, _ = feed.state(x=(0.01, 0.01))
    again, answered = feed.state(cycle=feed.cycle, x=(0.5, 0.5))
    assert answered and again == first


@pytest.mark.parametrize('bits', [STATUS_COMMAND_TIMEOUT, STATUS_FAULT])
def test_plant_side_stop_makes_the_channel_follow_the_applied_torque(bits):
    """While the plant reports it zeroed a channel, the controller follows the applied torque
    (no windup) and resumes without a step: after a brief stop hold ramps back to its target,
    after one longer than state_timeout it holds where the finger is now."""
    for stop, recaptured in ((10, False), (300, True)):
        cc, feed = make(('dob', 'hold'))
        feed.state(fp=(0.2, 0.0))
        for _ in range(100):
            effort, _ = feed.state(fp=(0.2, 0.0), x=(0.0, 0.005))
        held = effort[1]
        assert abs(effort[0]) > 0.1 and held < -0.5
        for _ in range(stop):
            effort, _ = feed.state(fp=(0.2, 0.0), x=(0.0, 0.006), fa=(0.0, 0.0),
                                   status=(bits, bits))
            assert effort == pytest.approx([0.0, 0.0], abs=1e-12)
        resumed = [feed.state(fp=(0.2, 0.0), x=(0.0, 0.006))[0] for _ in range(400)]
        assert abs(resumed[0][0]) < 0.05 and abs(resumed[0][1]) < 0.05
        steps = [abs(a[1] - b[1]) for a, b in zip(resumed, resumed[1:])]
        assert max(steps) < 0.05                               # a ramp, not a step
        if recaptured:
            assert resumed[-1][1] == pytest.approx(0.0, abs=1e-9)
        else:                                                  # K_p (0.006 - 0) N m
            assert resumed[-1][1] == pytest.approx(held - 150.0 * 0.001, rel=0.05)


def test_configs_of_several_channels_arrive_in_the_same_cycle():
    cc, feed = make(('passive', 'passive'))
    feed.state()
    cc.configure_channels({0: ControllerConfig(mode='hold')})
    cc.configure_channels({1: ControllerConfig(mode='hold')})      # before the next step
    assert [c.mode for c in cc.controllers] == ['passive', 'passive']
    effort, _ = feed.state(x=(0.0, 0.0))
    assert [c.mode for c in cc.controllers] == ['hold', 'hold']
    effort, _ = feed.state(x=(0.001, 0.001))
    assert effort[0] < 0.0 and effort[1] < 0.0


def test_two_publishers_of_the_state_zero_every_channel_until_one_is_left():
    """Two plants on one topic (or a bag played into a running one): whose state would the
    torque answer? Zero everywhere while the graph lists two; then re-armed, bumplessly."""
    cc, feed = make()
    feed.state()
    assert feed.state(x=(0.001, 0.001))[0][0] < 0.0
    cc.set_state_publishers(['/sim', '/sim_2'])
    effort, answered = feed.state(x=(0.001, 0.001), fa=(-0.15, -0.15))
    assert answered and effort == [0.0, 0.0] and '/sim_2' in cc.fault(0)
    assert feed.state(cycle=feed.cycle, x=(0.001, 0.001))[0] == [0.0, 0.0]   # no old answer
    cc.set_state_publishers(['/sim'])
    effort, _ = feed.state(x=(0.002, 0.002), fa=(0.0, 0.0))
    assert effort == pytest.approx([0.0, 0.0], abs=1e-12) and not cc.latched(0)


def test_new_checks_take_effect_at_the_next_step():
    cc, feed = make()
    feed.state()
    cc.configure(StateChecks(velocity_limit=1.0))
    assert cc.checks.velocity_limit == 1e3
    feed.state(v=(0.0, 2.0))
    assert cc.latched(1).startswith('implausible')


def test_latched_channel_keeps_live_estimates():
    """controller_status must not freeze on a fault: the estimators keep running."""
    cc, feed = make(('dob_full_ff', 'dob_full_ff'), max_torque=1e-3)
    feed.state()
    feed.state(fp=(0.5, 0.5))
    assert cc.latched(0)
    estimates = []
    for k in range(20):
        feed.state(v=(0.1 * k, 0.1 * k), fp=(0.0, 0.0))
        estimates.append(cc.controllers[0].endpoint_velocity_estimate)
    assert len(set(estimates)) > 10


def test_checks_are_validated():
    with pytest.raises(InvalidParameterError, match='latched_faults'):
        StateChecks(latched=('stale', 'oops'))
    with pytest.raises(InvalidParameterError, match='state_timeout'):
        StateChecks(state_timeout=0.0)
    with pytest.raises(InvalidParameterError, match='state_limits.force'):  # the ROS key
        StateChecks(force_limit=math.nan)
    with pytest.raises(TypeError):
        ControlCycle(CH, [object(), object()])
    with pytest.raises(InvalidParameterError):
        ControlCycle(CH, [ChannelController(dt=DT), ChannelController(dt=1e-3)])


# --- properties over arbitrary state sequences ------------------------------------------------
ACTIVE = [m for m in MODES if m != 'passive']


def rarely(value, normal, one_in):
    return st.sampled_from(range(one_in)).flatmap(lambda k: st.just(value) if k == 0 else normal)


VALUE = rarely(math.nan, rarely(1e308, rarely(-math.inf, st.floats(-0.5, 0.5), 200), 200), 200)


@st.composite
def states(draw):
    """Mostly plausible states of a moving finger; sometimes malformed, stale, from the
    future, out of order, with NaN/huge values or a plant-side stop."""
    n = draw(rarely(1, st.just(2), 100))
    names = list(CH) if draw(st.integers(0, 50)) else draw(st.permutations(
        ['wrist', 'pinch', 'thumb'][:draw(st.integers(1, 3))]))[:2]
    if n == 1:
        names = names[:1]
    arrays = [draw(st.lists(VALUE, min_size=len(names), max_size=len(names))) for _ in range(4)]
    status = draw(st.lists(rarely(STATUS_COMMAND_TIMEOUT, st.just(0), 30), min_size=len(names),
                           max_size=len(names)))
    if not draw(st.integers(0, 80)):
        status = status[:-1]                   # malformed
    step = draw(rarely(-5, rarely(300, st.just(1), 80), 80))
    age = draw(rarely(0.3, rarely(-100.0, st.floats(0.0, 0.01), 150), 60))
    advance = draw(rarely(0.2, st.just(DT), 80))
    return ('state', names, arrays, status, step, age, advance)


OPS = st.one_of(states(), states(), states(), states(), states(),
                rarely(('reset',), st.just(('mode',) ), 3).flatmap(
                    lambda op: st.just(op) if op[0] == 'reset' else st.tuples(
                        st.just('mode'), st.integers(0, 1), st.sampled_from(MODES))))


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(OPS, min_size=10, max_size=150),
       modes=st.lists(st.sampled_from(ACTIVE), min_size=2, max_size=2))
def test_properties_over_arbitrary_states(ops, modes):
    """Invariants, whatever states arrive:

    1. every effort is finite and within the channel's max_torque;
    2. a latched channel gets zero until a reset;
    3. a non-zero effort only comes from a sample whose values for that channel were finite
       and plausible and whose stamp was fresh;
    4. no step: the first effort after the start, a reset, a re-arm (stall, gap, restart,
       transient condition) or a plant-side stop equals the applied torque the state reports
       (except in 'passive', the deliberate zero); a runaway monitor's fall-back is no
       re-arm: the channel runs on in ``monitor.fallback`` from its own last torque.
    """
    max_torque = 3.0
    ctrls = [ChannelController(ControllerConfig(mode=m, max_torque=max_torque,
                                                chirp=ChirpParams(amplitude=0.2)), dt=DT) for m in modes]
    cc = ControlCycle(CH, ctrls)
    feed = Feed(cc)
    was_latched = [False, False]
    resumed = 0
    for op in ops:
        if op[0] == 'reset':
            cc.request_reset()
            was_latched = [False, False]
            continue
        if op[0] == 'mode':
            _, i, mode = op
            ctrls[i].configure(ctrls[i].config.replace(mode=mode))
            continue
        _, names, (x, v, fp, fa), status, step, age, advance = op
        repeated = max(0, feed.cycle + step) == cc.out.cycle and names == cc._answered_names
        # a fault, or a re-arm pending; not a runaway monitor's fall-back: the channel runs
        # on in it (entered bumpless from its own last torque)
        before = [(cc.fault(i) != '' and not ctrls[i].fallback) or cc._needs_reset[i]
                  for i in range(2)]
        active_before = [c.mode for c in ctrls]
        stopped = {n: s for n, s in zip(names, status)}
        effort, answered = feed.state(x=x, v=v, fp=fp, fa=fa, status=status, names=names,
                                      cycle=max(0, feed.cycle + step), age=age, advance=advance)
        for i, channel in enumerate(CH):
            e = effort[i]
            assert math.isfinite(e) and abs(e) <= max_torque                       # 1
            if was_latched[i]:
                assert e == 0.0 or not answered                                    # 2
            if cc.latched(i):
                was_latched[i] = True
            if not answered or e == 0.0 or repeated:
                continue           # (a repeated state gets the answer of its first copy)
            assert channel in names                                                # 3
            j = names.index(channel)
            assert all(math.isfinite(a[j]) and abs(a[j]) < 1e3 for a in (x, v, fp, fa))
            assert -0.05 <= age <= 0.05
            if (before[i] or stopped.get(channel, 0)) and active_before[i] == ctrls[i].mode \
                    and ctrls[i].mode != 'passive':
                assert e == pytest.approx(fa[j], abs=1e-9)                         # 4
                resumed += 1
    event('a channel resumed from the applied torque' if resumed else 'no resume seen')


def test_random_fault_mix_reaches_every_condition_and_never_misbehaves():
    """Seeded random interleavings of every kind of bad state with resets: each condition kind
    is met (the branches are live), and the efforts stay finite and within max_torque."""
    seen = set()
    for seed in range(40):
        rng = np.random.default_rng(seed)
        cc, feed = make(('dob', 'hold'))
        for _ in range(300):
            r = rng.random()
            kwargs = {}
            if r < 0.02:
                kwargs['age'] = 0.3
            elif r < 0.04:
                kwargs['age'] = -100.0
            elif r < 0.06:
                kwargs['x'] = (math.nan, 0.0)
            elif r < 0.08:
                kwargs['v'] = (0.0, 1e308)
            elif r < 0.10:
                kwargs['status'] = (0,)
            elif r < 0.12:
                kwargs['names'] = ('wrist', 'thumb')
            elif r < 0.14:
                kwargs['cycle'] = 1
            elif r < 0.16:
                kwargs['fp'] = (50.0, 0.0)
            cc.set_state_publishers(['/sim', '/other'] if 0.16 <= r < 0.18 else ['/sim'])
            effort, _ = feed.state(**kwargs)
            assert all(math.isfinite(e) and abs(e) <= 5.0 for e in effort)
            if rng.random() < 0.05:
                cc.request_reset()
        seen |= {k for k, n in cc.counts.items() if n}
    assert seen >= set(FAULT_KINDS) - {'non_finite_torque'}
