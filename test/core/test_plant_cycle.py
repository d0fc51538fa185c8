"""PlantCycle: every safety branch of the plant side, then properties over arbitrary input.

No ROS, no root: this is the code that decides what reaches a motor in sim_node,
hardware_node and the direct layout.
"""
import math

import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from seaforce_ros.core.errors import InvalidParameterError
from seaforce_ros.core.plant_cycle import (INT16_MAX, RESET_GRACE_CYCLES, STATUS_COMMAND_TIMEOUT,
                                           STATUS_FAULT, STATUS_LIMIT, PlantCycle, PlantLimits)

DT = 5e-4
CH = ('wrist', 'pinch')
LIMITS = PlantLimits(command_timeout=0.01, torque_limit=5.0, max_velocity=30.0,
                     wkc_error_limit=3)


class Clock:
    """Drives a PlantCycle the way a plant node's cycle thread does."""

    def __init__(self, plant):
        self.plant = plant
        self.now = 100.0

    def cycle(self, velocity=None, drives=None, publish=True):
        """One cycle: step, then (optionally) publish the fresh sample; returns the output."""
        self.now += DT
        out = self.plant.step(self.now, velocity, drives)
        snapshot = (list(out.torque), list(out.status), list(out.enable),
                    list(out.fault_reset), list(out.units))
        if publish:
            self.plant.state_published()
        return snapshot

    def send(self, names, efforts, answers=None):
        """A command answering the newest state (or ``answers``), arriving now."""
        cycle = self.plant.cycle if answers is None else answers
        self.plant.command(list(names), list(efforts), cycle)


def make(**kw):
    plant = PlantCycle(CH, DT, kw.pop('limits', LIMITS), **kw)
    return plant, Clock(plant)


def test_no_command_yet_means_zero_torque_and_timeout_everywhere():
    plant, clock = make()
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0]
    assert status == [STATUS_COMMAND_TIMEOUT] * 2
    assert not plant.events          # the start is not an episode worth a log line


def test_a_fresh_command_is_applied_next_cycle():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, -2.0])
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, -2.0] and status == [0, 0]


def test_watchdog_is_per_channel():
    """Defect: commands naming only `wrist` kept pinch's torque alive. Now pinch times out
    after command_timeout although wrist keeps being commanded."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 2.0])
    clock.cycle()
    n = int(LIMITS.command_timeout / DT)
    for k in range(n + 2):
        clock.send(['wrist'], [1.0])
        torque, status, *_ = clock.cycle()
        if k < n - 2:     # (exactly at command_timeout, float rounding decides)
            assert torque == [1.0, 2.0], k
    assert torque == [1.0, 0.0]
    assert status == [0, STATUS_COMMAND_TIMEOUT]
    text = ' '.join(t for _, t in plant.events.drain())
    assert 'pinch: no fresh actuator_command' in text and 'wrist' not in text
    assert plant.timeouts(1) == 1 and plant.timeouts(0) == 0


def test_unknown_channel_commands_feed_no_watchdog():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 2.0])
    clock.cycle()
    for _ in range(40):
        clock.send(['thumb'], [3.0])
        torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and status == [STATUS_COMMAND_TIMEOUT] * 2
    assert plant.rejected['unknown'] == 1      # reported once per name set, not per message


@pytest.mark.parametrize('effort, expect', [(7.0, 5.0), (-1e308, -5.0), (5.0, 5.0)])
def test_finite_commands_are_clamped_to_torque_limit(effort, expect):
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [effort, 0.5])
    torque, status, *_ = clock.cycle()
    assert torque == [expect, 0.5]
    assert status[0] == (STATUS_LIMIT if abs(effort) > 5.0 else 0) and status[1] == 0


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_non_finite_command_latches_that_channel_until_reset(bad):
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, bad])
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, 0.0] and status == [0, STATUS_FAULT]
    for _ in range(5):
        clock.send(CH, [1.0, 2.0])
        torque, status, *_ = clock.cycle()
        assert torque == [1.0, 0.0] and status[1] & STATUS_FAULT
    assert 'non-finite torque command' in plant.request_reset()
    torque, status, *_ = clock.cycle()
    # the reset forgot every command: torque only after a new one
    assert torque == [0.0, 0.0] and status == [STATUS_COMMAND_TIMEOUT] * 2
    clock.send(CH, [1.0, 2.0])
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, 2.0] and status == [0, 0]


def test_command_answering_an_old_state_is_ignored():
    plant, clock = make()
    for _ in range(50):
        clock.cycle()
    max_age = int(LIMITS.command_timeout / DT)
    # (the age counts the plant's steps until the command is taken, at the next step)
    clock.send(CH, [1.0, 1.0], answers=plant.cycle - max_age)
    torque, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and plant.rejected['stale'] == 1
    clock.send(CH, [1.0, 1.0], answers=plant.cycle - max_age + 1)
    torque, *_ = clock.cycle()
    assert torque == [1.0, 1.0]


def test_command_from_before_a_plant_restart_is_ignored():
    """A controller still answering an earlier plant sends cycles this plant has not
    published: no torque from them."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [3.0, 3.0], answers=50_000)
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and plant.rejected['future'] == 1
    assert not status[0] & STATUS_FAULT


def test_a_plant_activated_again_goes_on_numbering_and_takes_no_earlier_answer():
    """A new run (a lifecycle activate) numbers on from start_cycle, the number after the
    last run's: its first state is timed out (zero torque: the controller re-enters from
    it), an answer to any earlier run's state -- a late command, or the cache of a controller
    that saw that number -- is stale, and no answer is taken until one to this run's states
    arrives (its initial state, start_cycle, included: a lockstep plant publishes it)."""
    first, clock_first = make()
    for _ in range(40):
        clock_first.cycle()
        clock_first.send(CH, [2.0, 2.0])
    last = first.cycle
    plant, clock = make(start_cycle=last + 1)
    torque, status, *_ = clock.cycle()
    assert plant.cycle == last + 2
    assert torque == [0.0, 0.0] and status == [STATUS_COMMAND_TIMEOUT] * 2
    for answers in (last, last - 5, 0):
        clock.send(CH, [2.0, 2.0], answers=answers)
        torque, status, *_ = clock.cycle()
        assert torque == [0.0, 0.0] and status == [STATUS_COMMAND_TIMEOUT] * 2, answers
    assert plant.rejected['stale'] == 3
    clock.send(CH, [0.5, 0.5], answers=last + 1)
    torque, status, *_ = clock.cycle()
    assert torque == [0.5, 0.5] and status == [0, 0]
    clock.send(CH, [0.25, 0.25])
    torque, status, *_ = clock.cycle()
    assert torque == [0.25, 0.25] and status == [0, 0]
    with pytest.raises(InvalidParameterError, match="start_cycle"):
        PlantCycle(CH, DT, start_cycle=-1)


def test_malformed_commands_are_rejected_whole():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0])                         # 2 names, 1 effort
    clock.send(['pinch', 'pinch'], [1.0, 2.0])    # repeated name
    torque, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and plant.rejected['malformed'] == 2


def test_two_different_answers_to_one_cycle_latch_a_conflict():
    """Defect: two controllers fought, the torque flipping between them. The first sign of two
    sources zeroes every channel until a reset with one source left."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [0.0, 0.0])
    clock.send(CH, [0.0, 5.0])       # another controller's answer to the same state
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and status == [STATUS_FAULT] * 2
    assert 'answered twice' in plant.conflict
    for _ in range(20):               # it never chatters afterwards
        clock.send(CH, [0.0, 5.0])
        clock.send(CH, [0.0, 0.0])
        torque, *_ = clock.cycle()
        assert torque == [0.0, 0.0]
    plant.set_publishers(['/controller', '/controller_2'])
    assert 'conflict stays latched' not in plant.request_reset()
    clock.cycle()
    assert any('conflict stays latched' in text for _, text in plant.events.drain())
    assert plant.conflict
    plant.set_publishers(['/controller'])
    plant.request_reset()
    clock.cycle()
    clock.send(CH, [0.5, 0.5])
    torque, status, *_ = clock.cycle()
    assert not plant.conflict and torque == [0.5, 0.5] and status == [0, 0]


def test_answers_going_back_in_cycle_latch_a_conflict():
    plant, clock = make()
    for _ in range(3):
        clock.cycle()
    clock.send(CH, [1.0, 1.0])
    clock.send(CH, [1.0, 1.0], answers=plant.cycle - 1)    # a slower second source
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and 'answered after cycle' in plant.conflict


def test_a_second_publisher_in_the_graph_blocks_every_channel_while_listed():
    """Two publishers of actuator_command: no command is applied while two could be. The graph
    alone does not latch (a controller killed a moment ago stays listed until its DDS lease
    expires); when one is left, only commands sent from then on apply."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    plant.set_publishers(['/controller', '/my_script'])
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and status == [STATUS_FAULT] * 2
    assert '/controller' in plant.conflict and '/my_script' in plant.conflict
    assert '/my_script' in plant.channel_fault(0)
    clock.send(CH, [1.0, 1.0])
    assert clock.cycle()[0] == [0.0, 0.0]
    assert 'zero torque on every channel' in plant.events.drain()[0][1]
    plant.set_publishers(['/controller'])
    torque, status, *_ = clock.cycle()
    assert torque == [0.0, 0.0] and not plant.conflict          # the old command is forgotten
    assert status == [STATUS_COMMAND_TIMEOUT] * 2
    clock.send(CH, [0.5, 0.5])
    torque, status, *_ = clock.cycle()
    assert torque == [0.5, 0.5] and status == [0, 0]


def test_the_same_answer_again_is_no_conflict():
    """Lockstep re-publishes a state until it is answered; the controller answers again."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 2.0])
    clock.send(CH, [1.0, 2.0])
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, 2.0] and not plant.conflict


@pytest.mark.parametrize('v', [31.0, -31.0, math.nan])
def test_velocity_trip_latches_that_channel(v):
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    torque, status, *_ = clock.cycle(velocity=[0.0, v])
    assert torque == [1.0, 0.0] and status == [0, STATUS_FAULT]
    clock.send(CH, [1.0, 1.0])
    torque, *_ = clock.cycle(velocity=[0.0, 0.0])
    assert torque == [1.0, 0.0]
    assert ('non-finite' if math.isnan(v) else 'max_velocity') in plant.channel_fault(1)


def test_velocity_trip_off_when_max_velocity_is_zero():
    plant, clock = make(limits=PlantLimits(max_velocity=0.0))
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    torque, *_ = clock.cycle(velocity=[1e6, -1e6])
    assert torque == [1.0, 1.0]


def test_drive_fault_latches_and_reset_sends_one_fault_reset_with_grace():
    plant, clock = make()
    clock.cycle(drives=[(True, False)] * 2)
    clock.send(CH, [1.0, 1.0])
    torque, *_ = clock.cycle(drives=[(True, False), (False, True)])
    assert torque == [1.0, 0.0] and 'drive reports a fault' in plant.channel_fault(1)
    plant.request_reset()
    torque, status, enable, resets, _ = clock.cycle(drives=[(True, False), (False, True)])
    assert resets == [True, True] and not plant.channel_fault(1)
    # the drive takes a while to leave Fault: no re-latch during the grace period
    for _ in range(RESET_GRACE_CYCLES - 1):
        _, _, _, resets, _ = clock.cycle(drives=[(True, False), (False, True)])
        assert resets == [False, False]
    assert not plant.channel_fault(1)
    clock.cycle(drives=[(True, False), (False, True)])
    clock.cycle(drives=[(True, False), (False, True)])
    assert plant.channel_fault(1)


def test_drive_not_enabled_gets_zero_torque_and_says_so():
    """A drive on its way to Operation enabled gets zero torque, and STATUS_FAULT tells the
    controller its torque is not applied (else it would wind up meanwhile), without a latch."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    torque, status, *_ = clock.cycle(drives=[(True, False), (False, False)])
    assert torque == [1.0, 0.0] and status == [0, STATUS_FAULT]
    assert not plant.channel_fault(1)
    clock.send(CH, [1.0, 1.0])
    torque, status, *_ = clock.cycle(drives=[(True, False), (True, False)])
    assert torque == [1.0, 1.0] and status == [0, 0]


def test_drive_leaving_operation_enabled_by_itself_latches():
    """Quick stop, safe torque off, a mode drop: the drive leaves Operation enabled without the
    node asking. It must not come back with torque by itself."""
    plant, clock = make()
    clock.cycle(drives=[(True, False)] * 2)
    for allowed in (True, False, True, True):
        clock.send(CH, [1.0, 1.0])
        torque, status, enable, *_ = clock.cycle(drives=[(True, False), (allowed, False)])
    assert torque == [1.0, 0.0] and status == [0, STATUS_FAULT]
    assert 'left Operation enabled' in plant.channel_fault(1)
    assert enable == [True, False]                      # and its drive is disabled
    plant.request_reset()
    clock.cycle(drives=[(True, False), (False, False)])
    clock.send(CH, [1.0, 1.0])
    torque, status, enable, *_ = clock.cycle(drives=[(True, False), (True, False)])
    assert torque == [1.0, 1.0] and enable == [True, True]


def test_lost_frames_count_toward_the_command_timeout():
    """The watchdog counts the plant's steps, lost frames included: commands stop, every
    other frame is lost, the channel still times out after command_timeout."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    n = int(LIMITS.command_timeout / DT)
    torques = [clock.cycle(publish=k % 2 == 0)[0] for k in range(n + 3)]
    assert torques[0] == [1.0, 1.0] and torques[-1] == [0.0, 0.0]


def test_repeated_non_finite_command_is_no_conflict():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [0.5, math.nan])
    clock.send(CH, [0.5, math.nan])
    torque, status, *_ = clock.cycle()
    assert not plant.conflict and torque == [0.5, 0.0]
    assert 'non-finite torque command' in plant.channel_fault(1)


def test_rounding_to_drive_units_never_crosses_the_limit():
    plant, clock = make(units_per_nm=(1000.0, 1000.0), limits=PlantLimits(torque_limit=0.0006))
    clock.cycle()
    clock.send(CH, [0.001, -0.001])
    torque, status, _, _, units = clock.cycle()
    assert units == [0, 0] and torque == [0.0, 0.0]


def test_non_finite_velocity_latches_even_without_the_speed_trip():
    plant, clock = make(limits=PlantLimits(max_velocity=0.0))
    clock.cycle()
    clock.send(CH, [0.5, 0.5])
    torque, *_ = clock.cycle(velocity=[0.0, math.inf])
    assert torque == [0.5, 0.0] and 'non-finite motor velocity' in plant.channel_fault(1)


def test_consecutive_working_counter_errors_latch_a_bus_fault():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    clock.cycle(publish=False)
    for k in range(LIMITS.wkc_error_limit):
        assert not plant.bus_fault
        assert plant.exchange(3, 4) is False
    assert '3 consecutive working-counter errors (got 3, expected 4)' in plant.bus_fault
    torque, status, enable, *_ = clock.cycle(publish=False)
    assert torque == [0.0, 0.0] and status[0] & STATUS_FAULT and enable == [False, False]
    # a good frame does not clear it: only a reset does
    assert plant.exchange(4, 4) is True
    torque, status, enable, *_ = clock.cycle()
    assert plant.bus_fault and enable == [False, False]
    plant.request_reset()
    torque, status, enable, resets, _ = clock.cycle()
    assert not plant.bus_fault and enable == [True, True] and resets == [True, True]
    assert plant.wkc_errors_total == 3


def test_isolated_working_counter_errors_do_not_latch():
    plant, clock = make()
    for _ in range(10):
        plant.exchange(3, 4)
        plant.exchange(4, 4)
    assert not plant.bus_fault and plant.wkc_errors_total == 10


def test_drive_units_round_and_saturate_to_int16():
    plant, clock = make(units_per_nm=(1000.0 / 0.5, 1000.0 / 0.001),
                        limits=PlantLimits(torque_limit=100.0))
    clock.cycle()
    clock.send(CH, [0.12345, 40.0])
    torque, status, _, _, units = clock.cycle()
    assert units == [247, INT16_MAX]
    assert torque == [247 / 2000.0, INT16_MAX / 1e6]
    assert status == [0, STATUS_LIMIT]


def test_a_stalled_plant_does_not_blame_the_controller():
    """The watchdog counts the plant's cycles: a lockstep simulation waiting a minute for its
    command, or a plant cycle thread that stalled, is no command timeout."""
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [1.0, 1.0])
    clock.now += 60.0
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, 1.0] and status == [0, 0]


def test_new_limits_take_effect_at_the_next_step():
    plant, clock = make()
    clock.cycle()
    clock.send(CH, [4.0, 4.0])
    plant.configure(PlantLimits(torque_limit=1.0))
    assert plant.limits.torque_limit == 5.0
    torque, status, *_ = clock.cycle()
    assert torque == [1.0, 1.0] and status == [STATUS_LIMIT] * 2


def test_repeated_timeouts_are_logged_once_per_quiet_period_and_counted():
    """Defect: the sim logged 319 WARN/INFO pairs in 5 minutes under load."""
    plant, clock = make(quiet_period=10.0)
    clock.cycle()
    for episode in range(30):             # 30 episodes within ~2 s
        clock.send(CH, [1.0, 1.0])
        for _ in range(30):
            clock.cycle()
    events = plant.events.drain()
    assert plant.timeouts(0) == 30 and plant.timeouts(1) == 30
    assert len(events) == 4               # one episode per channel: begin + end
    clock.now += 20.0
    clock.send(CH, [1.0, 1.0])
    for _ in range(30):
        clock.cycle()
    events = plant.events.drain()
    assert any('29 more such episode(s)' in text for _, text in events), events


@pytest.mark.parametrize('kw, match', [
    (dict(command_timeout=0.0), 'command_timeout'), (dict(torque_limit=math.inf), 'torque_limit'),
    (dict(max_velocity=-1.0), 'max_velocity'), (dict(wkc_error_limit=0), 'wkc_error_limit'),
    (dict(wkc_error_limit=2.5), 'wkc_error_limit'), (dict(torque_limit=True), 'torque_limit')])
def test_limits_are_validated(kw, match):
    with pytest.raises(InvalidParameterError, match=match):
        PlantLimits(**kw)


def test_construction_is_validated():
    with pytest.raises(InvalidParameterError):
        PlantCycle([], DT)
    with pytest.raises(InvalidParameterError):
        PlantCycle(['a', 'a'], DT)
    with pytest.raises(InvalidParameterError):
        PlantCycle(CH, 0.0)
    with pytest.raises(InvalidParameterError):
        PlantCycle(CH, DT, units_per_nm=[1.0])
    with pytest.raises(TypeError):
        PlantCycle(CH, DT, limits={'torque_limit': 1.0})


def test_status_bits_match_the_message_definition():
    """The core mirrors ActuatorState's constants (it must not import the message)."""
    text = (pytest.importorskip('pathlib').Path(__file__).resolve().parents[2]
            / 'msg_defs' / 'msg' / 'ActuatorState.msg').read_text()
    for name, value in (('STATUS_OK', 0), ('STATUS_COMMAND_TIMEOUT', STATUS_COMMAND_TIMEOUT),
                        ('STATUS_LIMIT', STATUS_LIMIT), ('STATUS_FAULT', STATUS_FAULT)):
        assert f'uint8 {name}={value}' in text


# --- properties over arbitrary input sequences ------------------------------------------------
EFFORT = st.one_of(st.floats(min_value=-6.0, max_value=6.0), st.floats(min_value=-6.0, max_value=6.0),
                   st.floats(allow_nan=True, allow_infinity=True))


@st.composite
def commands(draw):
    """Mostly well-formed commands (a subset of the channels, maybe an unknown one, one effort
    per name), sometimes malformed (lengths differ, repeated names)."""
    names = draw(st.lists(st.sampled_from(['wrist', 'pinch', 'thumb']), min_size=0, max_size=3,
                          unique=draw(st.integers(0, 9)) > 0))
    n_efforts = len(names) if draw(st.integers(0, 9)) > 0 else draw(st.integers(0, 3))
    efforts = draw(st.lists(EFFORT, min_size=n_efforts, max_size=n_efforts))
    offset = draw(st.one_of(st.just(0), st.just(0), st.integers(min_value=-30, max_value=3)))
    return ('command', names, efforts, offset)


def rarely(value, normal, one_in=40):
    """``value`` about once in ``one_in`` draws, else a draw from ``normal``."""
    return st.sampled_from(range(one_in)).flatmap(lambda k: st.just(value) if k == 0 else normal)


VELOCITY = rarely(math.nan, rarely(35.0, rarely(-31.0, st.floats(-29.0, 29.0), 300), 300), 300)
DRIVE = st.one_of(
    st.tuples(rarely(False, st.just(True), 20), rarely(True, st.just(False), 300)),
    # a backend that knows what the fault is (the simulator's divergence) says so
    st.tuples(rarely(False, st.just(True), 20), rarely(True, st.just(False), 300),
              st.sampled_from(('', 'the simulated plant diverged'))))
OPS = st.one_of(
    commands(), commands(), commands(),
    st.tuples(st.just('advance'), rarely(0.02, st.floats(min_value=0.0, max_value=0.004), 8)),
    st.tuples(st.just('cycle'), st.lists(VELOCITY, min_size=2, max_size=2),
              st.lists(DRIVE, min_size=2, max_size=2),
              rarely(False, st.just(True), 10)),                # exchange complete?
    st.tuples(st.just('cycle'), st.just([0.0, 0.0]), st.just(None), st.just(True)),
    st.tuples(st.just('outage'), st.integers(1, 4)),            # consecutive lost frames
    st.tuples(st.just('publishers'), rarely(2, st.sampled_from([0, 1]), 30)),
    rarely(('reset',), st.just(('advance', 0.0)), 5),
)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(ops=st.lists(OPS, min_size=20, max_size=150), units=st.booleans())
def test_properties_over_arbitrary_input(ops, units):
    """Invariants, whatever arrives in whatever order:

    1. every torque is finite and within +-torque_limit;
    2. a non-zero torque on a channel is the (clamped) effort of a command naming that channel,
       sent after the last reset, answering a state this plant had published at most
       command_timeout (in cycles) ago: no torque nobody commanded;
    3. STATUS_FAULT means zero torque;
    4. two publishers in the graph give STATUS_FAULT while listed; an incomplete-exchange
       streak of wkc_error_limit or a velocity beyond max_velocity give STATUS_FAULT from then
       on until a reset;
    5. STATUS_COMMAND_TIMEOUT means zero torque.
    """
    upn = (2000.0, 1000.0) if units else None
    plant = PlantCycle(CH, DT, LIMITS, units_per_nm=upn)
    now = 0.0
    sent = []                 # (sent at op number, answers, names, efforts)
    last_reset = 0
    latched = [False, False]
    wkc_streak = 0
    max_age = int(math.ceil(LIMITS.command_timeout / DT))
    driven = 0                # cycles with torque on some channel (the test must see some)
    for op in ops:
        kind = op[0]
        if kind == 'command':
            _, names, efforts, offset = op
            answers = plant.cycle + offset
            plant.command(names, efforts, answers)
            sent.append((len(sent), answers, list(names), list(efforts)))
        elif kind == 'advance':
            now += op[1]
        elif kind == 'publishers':
            plant.set_publishers([f'/node{i}' for i in range(op[1])])
        elif kind == 'outage':
            for _ in range(op[1]):
                now += DT
                plant.step(now)
                plant.exchange(0, 4)
                wkc_streak += 1
            if wkc_streak >= LIMITS.wkc_error_limit:
                latched = [True, True]
        elif kind == 'reset':
            plant.request_reset()
            last_reset = len(sent)
            latched = [False, False]
            wkc_streak = 0
        else:
            _, velocity, drives, complete = op
            now += DT
            out = plant.step(now, velocity, drives)
            for i, channel in enumerate(CH):
                u, status = out.torque[i], out.status[i]
                assert math.isfinite(u) and abs(u) <= LIMITS.torque_limit          # 1
                if status & (STATUS_FAULT | STATUS_COMMAND_TIMEOUT):
                    assert u == 0.0                                                # 3, 5
                if latched[i]:
                    assert status & STATUS_FAULT                                   # 4
                if len(plant._publishers) > 1 or wkc_streak >= LIMITS.wkc_error_limit:
                    assert status & STATUS_FAULT                                   # 4
                if u != 0.0:                                                       # 2
                    driven += 1
                    def clamp(e):
                        e = max(-LIMITS.torque_limit, min(LIMITS.torque_limit, e))
                        return round(e * upn[i]) / upn[i] if upn else e
                    assert any(
                        channel in names and len(names) == len(efforts)
                        and len(set(names)) == len(names)
                        and number >= last_reset and 0 <= plant.cycle - answers <= max_age
                        and math.isfinite(efforts[names.index(channel)])
                        and clamp(efforts[names.index(channel)]) == u
                        for number, answers, names, efforts in sent), (channel, u)
            for i, v in enumerate(velocity):
                if not abs(v) <= LIMITS.max_velocity:
                    latched[i] = True
            if plant.exchange(4 if complete else 3, 4):
                wkc_streak = 0
                plant.state_published()
            else:
                wkc_streak += 1
    event('torque on some cycle' if driven else 'never any torque')


@settings(max_examples=200, deadline=None)
@given(a=st.lists(st.floats(-4.0, 4.0), min_size=5, max_size=40),
       b=st.lists(st.floats(-4.0, 4.0), min_size=5, max_size=40),
       order=st.lists(st.booleans(), min_size=5, max_size=40))
def test_two_interleaved_controllers_never_chatter(a, b, order):
    """Two controllers each answer every state, in any interleaving. Whenever their answers
    differ, the torque is zero from then on (never one, then the other); while they agree,
    the torque is the common answer."""
    plant = PlantCycle(CH, DT, LIMITS)
    now = 0.0
    differed = False
    ea = None
    for k, (ea, eb, a_first) in enumerate(zip(a, b, order)):
        now += DT
        out = plant.step(now)
        if differed:
            assert out.torque == [0.0, 0.0] and out.status == [STATUS_FAULT] * 2
        plant.state_published()
        first, second = (ea, eb) if a_first else (eb, ea)
        plant.command(list(CH), [0.0, first], plant.cycle)
        plant.command(list(CH), [0.0, second], plant.cycle)
        differed = differed or ea != eb
    now += DT
    out = plant.step(now)
    if differed:
        assert out.torque == [0.0, 0.0]
    else:
        assert out.torque[1] == ea      # the last (common) answer
