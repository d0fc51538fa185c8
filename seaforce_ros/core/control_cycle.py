"""Controller side of the real-time cycle: check the state, run the controllers, check the torque.

:class:`ControlCycle` is what controller_node runs for every ``actuator_state`` (and what the
plant's cycle thread calls directly in the direct layout): state validation ->
:meth:`ChannelController.update <seaforce_ros.core.controller.ChannelController.update>` per
channel -> output check. Plain Python with explicit state, no ROS; the node converts messages
and publishes.

Conditions, by kind (the strings are the values of the ``latched_faults`` parameter):

==================== ====================================================== ===========
kind                 condition                                              default
==================== ====================================================== ===========
``stale_state``      stamp older than ``state_timeout``, or no state for    re-arms
                     longer than that (a stall)
``state_gap``        cycle went backwards by more than ``state_timeout``    re-arms
                     (plant restarted) or jumped forwards by more than it
``state_sources``    more than one publisher of ``actuator_state`` in the   re-arms
                     graph: whose state would the torque answer?
``future_stamp``     stamp more than ``state_timeout`` in the future        latches
``malformed_state``  arrays shorter/longer than ``name``, repeated names    latches
``missing_channel``  a channel of this controller is not in the state       latches
``non_finite_state`` NaN/inf in position, velocity, pressure or torque      latches
``implausible_state`` a value beyond the plausibility limits                 latches
``torque_limit``     computed torque beyond the channel's ``max_torque``    latches
``non_finite_torque`` computed torque NaN/inf (an intermediate overflowed)   latches
``joint_limit``      the motor or the estimated endpoint beyond the joint   latches
                     range ``limits.position_min..position_max`` in a mode
                     that commands torque (:mod:`.safety`)
==================== ====================================================== ===========

The runaway monitor (:mod:`.safety`) is the controller's: when it trips, the channel falls
back to ``monitor.fallback`` by itself (no zero torque from here); this cycle reports it once,
as an error, and shows it as the channel's fault until :meth:`ControlCycle.request_reset`
clears it with the latched faults.

A state older than the newest answered, by less than ``state_timeout``, arrived out of order:
it is dropped unanswered (answering it would look like a second command source to the
plant). States the plant produced but this controller never saw (a late loop answers only
the newest) are not a condition: the controllers integrate over the real number of cycles since the
previous state (``steps``), up to ``state_timeout``.

A *latched* fault gives the channel zero torque until :meth:`ControlCycle.request_reset`;
a *re-arming* condition gives zero torque while it holds and re-initialises the channel from
the plant's present state on the next clean sample. Either way the channel restarts
bumplessly: its first torque after a reset, a re-arm, a plant restart or a plant-side stop
(``STATUS_COMMAND_TIMEOUT``/``STATUS_FAULT``) equals the torque the plant reports it applies
(``motor_effort``), and the DOB integrator starts from it. ``hold`` re-captures its target
where the finger is after a reset, a re-arm, a restart or a plant-side stop longer than
``state_timeout``; after a shorter stop it returns to its target through a 50 ms ramp (a
ratchet otherwise: a loaded finger would give way a little at every blip).

While a channel is faulted its estimators keep running on valid samples, so
``controller_status`` shows live values.

A job (:mod:`.jobs`: a grasp, a friction calibration) ends, aborted with the reason, whenever
its channel's torque is zeroed here (a latched fault, a re-arming condition, a stall of the
state stream): nothing it commanded comes back when the channel re-arms, which it does in the
channel's mode (a calibration applies nothing).
"""

import math
from collections import deque
from collections.abc import Iterable, Mapping, Sequence

from .controller import ChannelController
from .episodes import ERROR, Episode, EventLog
from .errors import InvalidParameterError
from .handover import Mailbox
from .params import ControllerConfig
from .plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT
from .schema import CONTROLLER, ParameterGroup, group, param

__all__ = ["StateChecks", "ControlCycle", "ControlOutput", "FAULT_KINDS",
           "DEFAULT_LATCHED", "STALE_STATE", "STATE_GAP", "STATE_SOURCES", "FUTURE_STAMP",
           "MALFORMED_STATE",
           "MISSING_CHANNEL", "NON_FINITE_STATE", "IMPLAUSIBLE_STATE", "TORQUE_LIMIT",
           "NON_FINITE_TORQUE", "JOINT_LIMIT"]

STALE_STATE = "stale_state"
STATE_GAP = "state_gap"
STATE_SOURCES = "state_sources"
FUTURE_STAMP = "future_stamp"
MALFORMED_STATE = "malformed_state"
MISSING_CHANNEL = "missing_channel"
NON_FINITE_STATE = "non_finite_state"
IMPLAUSIBLE_STATE = "implausible_state"
TORQUE_LIMIT = "torque_limit"
NON_FINITE_TORQUE = "non_finite_torque"
JOINT_LIMIT = "joint_limit"

#: Every condition kind, in the order of the table above.
FAULT_KINDS = (STALE_STATE, STATE_GAP, STATE_SOURCES, FUTURE_STAMP, MALFORMED_STATE,
               MISSING_CHANNEL, NON_FINITE_STATE, IMPLAUSIBLE_STATE, TORQUE_LIMIT,
               NON_FINITE_TORQUE, JOINT_LIMIT)

#: Kinds that latch by default: faults of the data itself. A stall or a restart of the plant
#: is not one: the plant's own watchdog has already zeroed the torque.
DEFAULT_LATCHED = FAULT_KINDS[3:]

#: The plant reports it applies something other than our command on this channel.
_PLANT_STOPPED = STATUS_COMMAND_TIMEOUT | STATUS_FAULT


@group("", nodes=(CONTROLLER,), per_channel=False)
class StateChecks(ParameterGroup):
    """Run-time settings of :class:`ControlCycle` (ROS parameters of controller_node)."""

    state_timeout: float = param(0.05, "s", "maximum age of a state (header stamp vs now) and "
                                 "time between two states: older, or none for this long, "
                                 "zeroes the torque until states flow again; a stamp this far "
                                 "in the future is a fault", ge=1e-4, le=10.0)
    position_limit: float = param(1e3, "rad", "plausible |motor_position|; beyond it the state "
                                  "is a fault", gt=0.0, key="state_limits.position")
    velocity_limit: float = param(1e3, "rad/s", "plausible |motor_velocity|; beyond it the "
                                  "state is a fault", gt=0.0, key="state_limits.velocity")
    force_limit: float = param(1e3, "N m", "plausible |pressure_force| and |motor_effort|; "
                               "beyond it the state is a fault", gt=0.0,
                               key="state_limits.force")
    latched: tuple = param(list(DEFAULT_LATCHED), "", "conditions that latch until ~/reset; "
                           "the others re-arm by themselves", choices=FAULT_KINDS,
                           key="latched_faults")


class ControlOutput:
    """What :meth:`ControlCycle.step` decided (lists reused from cycle to cycle).

    effort : list of float
        Torque command per channel [N m]; 0 on a faulted or re-arming channel.
    answered : bool
        False when the state was dropped (no channel could be mapped, or start-up backlog):
        send no command.
    cycle : int or None
        The state's cycle (the command answers it); -1 before the first answer, None when
        every channel was zeroed before any state was admitted.
    """

    def __init__(self, n: int) -> None:
        self.effort: list[float] = [0.0] * n
        self.answered: bool = False
        self.cycle: int | None = -1


class _StreamState:
    """What the cycle keeps about the stream of states from one sample to the next.

    last_cycle : int or None
        Cycle of the newest state admitted (None before the first).
    last_arrival : float
        Monotonic time it arrived [s].
    answered_names : list of str or None
        Names of the state ``out.effort`` answers (None: no answer to repeat).
    names, index, ours
        The mapping of the last well-formed names: the names, the index of each channel in
        them (-1: missing) and whether any channel is there.
    publishers : tuple of str
        The publishers of ``actuator_state`` the graph shows.
    """

    __slots__ = ("last_cycle", "last_arrival", "answered_names", "names", "index", "ours",
                 "publishers")

    def __init__(self) -> None:
        self.last_cycle: int | None = None
        self.last_arrival = 0.0
        self.answered_names: list[str] | None = None
        self.names: list[str] = []
        self.index: tuple[int, ...] = ()
        self.ours = False
        self.publishers: tuple[str, ...] = ()


class _ChannelState:
    """Fault bookkeeping of one channel from one sample to the next.

    latched : str
        The latched fault ('' when none).
    rearming : str
        The re-arming condition that held at the last sample ('' when none).
    needs_reset : bool
        Re-initialise the controller at the next clean sample.
    stopped : int
        Cycles the plant has been applying its own torque instead of the command ...
    status : int
        ... and its ``STATUS_*`` bits then.
    episode : Episode
        The log episode of the channel's re-arming conditions.
    """

    __slots__ = ("latched", "rearming", "needs_reset", "stopped", "status", "episode")

    def __init__(self, episode: Episode) -> None:
        self.latched = ""
        self.rearming = ""
        self.needs_reset = True
        self.stopped = 0
        self.status = 0
        self.episode = episode


class _Sample:
    """What the admission and stream stages found in the sample being processed.

    index : tuple of int or None
        Index of each channel in the state's arrays (-1: missing); None when malformed.
    kind : str or None
        The condition of the whole stream (``STALE_STATE``, ``STATE_GAP``, ``FUTURE_STAMP``),
        or None.
    reason : str
        Its description.
    steps : int
        Sample periods since the previous admitted state (1 after a gap or a restart).
    """

    __slots__ = ("index", "kind", "reason", "steps")

    def __init__(self) -> None:
        self.index: tuple[int, ...] | None = None
        self.kind: str | None = None
        self.reason = ""
        self.steps = 1


class ControlCycle:
    """The controller side of the cycle for a set of channels (see module docstring).

    Parameters
    ----------
    channels : sequence of str
    controllers : sequence of ChannelController
        One per channel, same order.
    checks : StateChecks, optional
    quiet_period : float >= 0
        Minimum time between two log reports of the same repeated condition [s].

    Notes
    -----
    :meth:`step` runs five stages in turn, each a method over explicit state
    (:class:`_StreamState` for the stream, one :class:`_ChannelState` per channel, the
    sample's findings in :class:`_Sample`): take the hand-overs, admit the sample (drop it or
    answer it as before), classify the stream (stale, gap, restart), check each channel's
    values, run each channel's controller and check its torque.
    """

    def __init__(self, channels: Sequence[str], controllers: Sequence[ChannelController],
                 checks: StateChecks | None = None, quiet_period: float = 10.0) -> None:
        self.channels: tuple[str, ...] = tuple(channels)
        self.controllers: list[ChannelController] = list(controllers)
        n = len(self.channels)
        if n == 0 or len(set(self.channels)) != n:
            raise InvalidParameterError("channels", list(channels), "unique names, at least one")
        if len(self.controllers) != n or not all(isinstance(c, ChannelController)
                                                 for c in self.controllers):
            raise TypeError(f"controllers must be {n} ChannelController objects")
        dts = {c.dt for c in self.controllers}
        if len(dts) != 1:
            raise InvalidParameterError("dt", sorted(dts), "the same for every channel")
        self.dt: float = dts.pop()
        self.events = EventLog()
        self.out = ControlOutput(n)
        self._checks_box: Mailbox[StateChecks] = Mailbox()
        self._reset_box: Mailbox[bool] = Mailbox()
        self._configs: deque = deque()     # ({index: ControllerConfig}, mode set) hand-overs
        self._apply_checks(StateChecks() if checks is None else checks)
        self._stream = _StreamState()
        self._stream_ep = Episode(self.events, quiet_period)
        self._drop_ep = Episode(self.events, quiet_period)
        self._ch = [_ChannelState(Episode(self.events, quiet_period)) for _ in range(n)]
        self._sample = _Sample()
        self.counts: dict[str, int] = {kind: 0 for kind in FAULT_KINDS}
        self.faults_latched = 0
        self.dropped = 0

    # --- hand-over from other threads ------------------------------------------------------
    def configure(self, checks: StateChecks) -> None:
        """New :class:`StateChecks`, effective at the start of the next step."""
        if not isinstance(checks, StateChecks):
            raise TypeError("checks must be a StateChecks")
        self._checks_box.put(checks)

    def configure_channels(self, configs: Mapping[int, ControllerConfig],
                           mode_set: Iterable[int] = ()) -> None:
        """New configurations ``{channel index: ControllerConfig}`` (validated), taken together
        at the start of the next step: a change that sets several channels reaches all of them
        in the same cycle. ``mode_set``: the channels whose mode was set (to any mode, the one
        in force included: a running job ends, :meth:`ChannelController.configure`)."""
        self._configs.append((dict(configs), frozenset(mode_set)))

    def set_state_publishers(self, names: Iterable[str]) -> None:
        """The publishers of ``actuator_state`` the ROS graph shows now (node names)."""
        self._stream.publishers = tuple(names)

    def request_reset(self) -> str:
        """Clear every latched fault and the runaway monitor's fall-backs at the start of the
        next step; returns what it clears."""
        self._reset_box.put(True)
        cleared = [c for c, ch, ctrl in zip(self.channels, self._ch, self.controllers)
                   if ch.latched or ctrl.fallback]
        return ("cleared faults on " + ", ".join(cleared)) if cleared else "no fault was latched"

    # --- status ----------------------------------------------------------------------------
    @property
    def checks(self) -> StateChecks:
        """The :class:`StateChecks` in force."""
        return self._checks

    def fault(self, i: int) -> str:
        """Channel ``i``'s latched fault, or its re-arming condition, or the runaway monitor's
        fall-back, or ''."""
        ch = self._ch[i]
        if ch.latched:
            return ch.latched
        if ch.rearming:
            return "re-arming: " + ch.rearming
        ctrl = self.controllers[i]
        if ctrl.fallback:
            return f"fallback to {ctrl.fallback}: {ctrl.fallback_reason}"
        return ""

    def latched(self, i: int) -> str:
        """Channel ``i``'s latched fault, or ''."""
        return self._ch[i].latched

    def plant_stopped(self, i: int) -> str:
        """Why the plant applies its own torque on channel ``i`` instead of the command, or
        '': its fault (``STATUS_FAULT``, latched on the plant's side until its reset) at
        once, a command timeout (``STATUS_COMMAND_TIMEOUT``) once it has lasted longer than
        ``state_timeout`` -- a late command now and then (a loaded host) is no stop."""
        ch = self._ch[i]
        if ch.stopped and (ch.status & STATUS_FAULT or ch.stopped > self._gap_cycles):
            return _plant_stop_reason(ch.status)
        return ""

    @property
    def _answered_names(self) -> list[str] | None:
        # the names the present answer is for (the property tests compare with it)
        return self._stream.answered_names

    @property
    def _needs_reset(self) -> list[bool]:
        # which channels re-initialise at their next clean sample (read by the property tests)
        return [ch.needs_reset for ch in self._ch]

    # --- the cycle -------------------------------------------------------------------------
    def step(self, names: Sequence[str], cycle: int, stamp_ns: int, x: Sequence[float],
             v: Sequence[float], f_p: Sequence[float], f_a: Sequence[float],
             status: Sequence[int], now_ns: int, now: float) -> ControlOutput:
        """One state sample -> one command.

        Parameters
        ----------
        names : sequence of str
            ``ActuatorState.name``.
        cycle : int
            ``ActuatorState.cycle``.
        stamp_ns : int
            The state's header stamp [ns, system clock].
        x, v, f_p, f_a : sequence of float
            Motor position [rad], velocity [rad/s], pressure force [N m], applied torque
            [N m], indexed like ``names``.
        status : sequence of int
            ``STATUS_*`` bits per name.
        now_ns : int
            System time now [ns] (the clock of the stamps).
        now : float
            Monotonic time now [s].

        Returns
        -------
        ControlOutput
        """
        self._take_handovers()
        out = self.out
        sample = self._sample
        age_ns = now_ns - stamp_ns
        if not self._admit(sample, names, cycle, age_ns, x, v, f_p, f_a, status, now):
            return out
        self._classify_stream(sample, cycle, age_ns, now)
        index = sample.index
        if index is None:
            self.counts[MALFORMED_STATE] += 1
            self._condition_all(now, MALFORMED_STATE,
                                _malformed_reason(names, x, v, f_p, f_a, status))
            return out
        effort = out.effort
        for i, ctrl in enumerate(self.controllers):
            j = index[i]
            if self._check_channel(i, j, x, v, f_p, f_a, now):
                ctrl.cycle = cycle          # what a job records with its sample
                ctrl.applied = f_a[j]
                effort[i] = self._run_channel(i, ctrl, x[j], v[j], f_p[j], f_a[j], status[j],
                                              sample, now)
            else:
                effort[i] = 0.0
        out.cycle = cycle
        stream = self._stream
        if names != stream.answered_names:
            stream.answered_names = list(names)
        return out

    # --- stages of a step ------------------------------------------------------------------
    def _take_handovers(self) -> None:
        """Stage 1: what other threads handed over since the last step -- new checks, new
        controller configurations (all of a change in the same cycle), a reset."""
        checks = self._checks_box.take()
        if checks is not None:
            self._apply_checks(checks)
        configs = self._configs
        while configs:
            changed, mode_set = configs.popleft()
            for i, config in changed.items():
                self.controllers[i].configure(config, i in mode_set)
        if self._reset_box.take():
            for ch, ctrl in zip(self._ch, self.controllers):
                ctrl.clear_fallback()
                if ch.latched:
                    ch.latched = ""
                    ch.needs_reset = True

    def _admit(self, sample: _Sample, names: Sequence[str], cycle: int, age_ns: int,
               x: Sequence[float], v: Sequence[float], f_p: Sequence[float],
               f_a: Sequence[float], status: Sequence[int], now: float) -> bool:
        """Stage 2: whether the sample goes on to the controllers. It does not when it is
        dropped unanswered (``out.answered`` False: no channel of ours in it, the start-up
        backlog, delivered out of order) or answered as it stands (zero torque while two
        publishers of ``actuator_state`` exist; the same answer to a re-published state).
        Sets ``sample.index`` (None for a malformed state, which goes on to be reported)."""
        out = self.out
        stream = self._stream
        n = len(names)
        if (len(x) != n or len(v) != n or len(f_p) != n or len(f_a) != n
                or len(status) != n):
            index = None
        else:
            index = self._map(names)
        sample.index = index
        if index is not None and not stream.ours:
            # nothing here to control: not our plant (or all names wrong)
            self.dropped += 1
            self._drop_ep.begin(now, f"actuator_state names none of the channels "
                                     f"{list(self.channels)} (it names {list(names)}): "
                                     "dropped, no command sent")
            self._drop_ep.end(now)
            out.answered = False
            return False
        last = stream.last_cycle
        if last is None and age_ns > self._timeout_ns:
            self.dropped += 1      # start-up backlog: states older than the first fresh one
            out.answered = False
            return False
        if last is not None and last - self._gap_cycles <= cycle < last:
            # older than the newest state already answered: delivered out of order. Answering
            # it would look like a second command source to the plant; a restarted plant
            # starts far lower (its cycles start at 1, and it takes longer than that to start)
            self.dropped += 1
            out.answered = False
            return False
        out.answered = True
        publishers = stream.publishers
        if len(publishers) > 1:
            # two plants (or a bag played into a running one): whose state would we answer?
            self.counts[STATE_SOURCES] += 1
            self._condition_all(now, STATE_SOURCES,
                                f"{len(publishers)} publishers of actuator_state: "
                                + ", ".join(publishers))
            return False
        # a re-published state gets the same answer again
        return not (cycle == out.cycle and names == stream.answered_names)

    def _classify_stream(self, sample: _Sample, cycle: int, age_ns: int, now: float) -> None:
        """Stage 3: the condition of the whole stream this sample (a stamp from the future, a
        stale state or a stall, a gap or a restart of the plant), ``sample.steps`` since the
        previous state; a condition latches or re-arms every channel, and the end of a
        re-arming one is reported."""
        stream = self._stream
        last = stream.last_cycle
        timeout_ns = self._timeout_ns
        gap = self._gap_cycles
        kind = None
        reason = ""
        if age_ns < -timeout_ns:
            kind = FUTURE_STAMP
            reason = f"state stamped {-age_ns * 1e-6:.1f} ms in the future"
        elif age_ns > timeout_ns:
            kind = STALE_STATE
            reason = f"stale state: {age_ns * 1e-6:.1f} ms old (> state_timeout)"
        elif last is not None:
            if cycle < last:
                kind = STATE_GAP
                reason = f"cycle went back from {last} to {cycle} (plant restarted)"
            elif cycle - last > gap:
                kind = STATE_GAP
                reason = f"cycle jumped from {last} to {cycle} ({cycle - last - 1} missing)"
            elif now - stream.last_arrival > self._checks.state_timeout:
                kind = STALE_STATE
                reason = (f"no state for {1e3 * (now - stream.last_arrival):.1f} ms "
                          "(> state_timeout)")
        sample.steps = cycle - last if last is not None and 0 < cycle - last <= gap else 1
        sample.kind = kind
        sample.reason = reason
        stream.last_cycle = cycle
        stream.last_arrival = now
        if kind is not None:
            self.counts[kind] += 1
            if kind in self._checks.latched:
                for i in range(len(self._ch)):
                    self._latch(i, reason)
            else:
                self._stream_ep.begin(now, reason + ": zero torque; every channel re-arms "
                                                    "from the plant's present state")
                for ch in self._ch:
                    ch.needs_reset = True
                    ch.rearming = reason
        elif self._stream_ep.active:
            self._stream_ep.end(now, "states flow again: channels re-initialised from the "
                                     "plant's present state")

    def _check_channel(self, i: int, j: int, x: Sequence[float], v: Sequence[float],
                       f_p: Sequence[float], f_a: Sequence[float], now: float) -> bool:
        """Stage 4, channel ``i`` at index ``j`` of the state: True when it is there with
        finite, plausible values; else the condition is met (latched or re-arming)."""
        if j < 0:
            self.counts[MISSING_CHANNEL] += 1
            self._condition(i, now, MISSING_CHANNEL, "channel missing from actuator_state")
            return False
        plim, vlim, flim = self._limits
        xi, vi, fpi, fai = x[j], v[j], f_p[j], f_a[j]
        if (-plim <= xi <= plim and -vlim <= vi <= vlim and -flim <= fpi <= flim
                and -flim <= fai <= flim):
            return True
        kind, reason = _bad_values(xi, vi, fpi, fai)
        self.counts[kind] += 1
        self._condition(i, now, kind, reason)
        return False

    def _run_channel(self, i: int, ctrl: ChannelController, x: float, v: float, f_p: float,
                     f_a: float, status: int, sample: _Sample, now: float) -> float:
        """Stage 5, channel ``i`` with checked values: its torque [N m] this sample. Zero
        while it is latched or the stream has a condition (its estimators stay live);
        otherwise it takes over from the plant where it must, runs and its torque is
        checked."""
        ch = self._ch[i]
        if ch.latched or sample.kind is not None:
            self._follow_while_faulted(ch, ctrl, x, v, f_p, f_a, sample)
            return 0.0
        self._take_over(i, ch, ctrl, f_a, status, sample.steps, now)
        try:
            u = ctrl.update(x, v, f_p, sample.steps)
        except ArithmeticError:        # an overflow the checks above did not foresee
            u = math.nan
        if ctrl.tripped:
            self.events.add(ERROR, f"{self.channels[i]}: runaway monitor: {ctrl.tripped}; call "
                                   "~/reset (std_srvs/Trigger) to clear")
            ctrl.tripped = ""
        if ctrl.beyond:
            self.counts[JOINT_LIMIT] += 1
            self._condition(i, now, JOINT_LIMIT, ctrl.beyond)
            return 0.0
        limit = ctrl.config.max_torque
        if -limit <= u <= limit:
            return u
        if math.isfinite(u):
            kind = TORQUE_LIMIT
            reason = f"torque {u:.4g} N m beyond max_torque {limit:g} N m"
        else:
            kind = NON_FINITE_TORQUE
            reason = f"computed torque is {u!r} (an intermediate overflowed)"
        self.counts[kind] += 1
        self._condition(i, now, kind, reason)
        return 0.0

    # --- parts of the stages ---------------------------------------------------------------
    @staticmethod
    def _follow_while_faulted(ch: _ChannelState, ctrl: ChannelController, x: float, v: float,
                              f_p: float, f_a: float, sample: _Sample) -> None:
        """A channel with zero torque: its job ends, its estimators follow the plant (no
        windup), the torque it would give is dropped."""
        if ctrl.job is not None:
            ctrl.abort_job(f"fault latched: {ch.latched}" if ch.latched else sample.reason)
        ctrl.reenter(f_a)
        fallback, reason = ctrl.fallback, ctrl.fallback_reason
        try:
            ctrl.update(x, v, f_p, sample.steps)
        except ArithmeticError:
            pass
        if ctrl.tripped:        # its torque was not applied: the motion is not its doing
            ctrl.restore_fallback(fallback, reason)

    def _take_over(self, i: int, ch: _ChannelState, ctrl: ChannelController, f_a: float,
                   status: int, steps: int, now: float) -> None:
        """A clean sample: a channel to re-initialise starts from the applied torque ``f_a``
        [N m]; while the plant applies its own torque the controller follows it (a brief stop
        keeps the targets, one longer than ``state_timeout`` re-captures them); a re-arming
        channel is reported re-armed."""
        if ch.needs_reset:
            ch.needs_reset = False
            ch.stopped = 0
            ctrl.reset(f_a)
        elif status & _PLANT_STOPPED:
            ch.stopped += steps
            ch.status = status
            if ch.stopped > self._gap_cycles:
                ctrl.reset(f_a, f"the plant stopped the channel ({_plant_stop_reason(status)}) "
                                "for longer than state_timeout")
            else:
                ctrl.reenter(f_a)
        else:
            ch.stopped = 0
        if ch.rearming:
            ch.rearming = ""
            ch.episode.end(now, f"{self.channels[i]}: re-armed from the plant's present state")

    def _apply_checks(self, checks: StateChecks) -> None:
        self._checks = checks
        self._timeout_ns = int(checks.state_timeout * 1e9)
        self._gap_cycles = max(1, int(math.ceil(checks.state_timeout / self.dt)))
        self._limits = (checks.position_limit, checks.velocity_limit, checks.force_limit)

    def _map(self, names: Sequence[str]) -> tuple[int, ...] | None:
        """Index of each channel in ``names`` (-1: not there), or None for repeated names;
        the last mapping is kept with whether any channel is there."""
        stream = self._stream
        if names == stream.names:
            return stream.index
        if len(set(names)) != len(names):
            return None
        position = {name: j for j, name in enumerate(names)}
        index = tuple(position.get(c, -1) for c in self.channels)
        stream.names = list(names)
        stream.index = index
        stream.ours = any(j >= 0 for j in index)
        return index

    def _condition(self, i: int, now: float, kind: str, reason: str) -> None:
        """Channel ``i`` met ``kind`` this sample: latch it, or zero it until a clean one."""
        if kind in self._checks.latched:
            self._latch(i, reason)
            return
        ch = self._ch[i]
        self.controllers[i].abort_job(reason)
        ch.needs_reset = True
        ch.rearming = reason
        ch.episode.begin(now, f"{self.channels[i]}: {reason}: zero torque until a clean "
                              "sample re-arms it")

    def _condition_all(self, now: float, kind: str, reason: str) -> None:
        for i in range(len(self._ch)):
            self.out.effort[i] = 0.0
            self._condition(i, now, kind, reason)
        self.out.cycle = self._stream.last_cycle
        self._stream.answered_names = None

    def _latch(self, i: int, reason: str) -> None:
        ch = self._ch[i]
        if ch.latched:
            return
        self.controllers[i].abort_job(f"fault latched: {reason}")
        ch.latched = reason
        ch.needs_reset = True
        self.faults_latched += 1
        self.events.add(ERROR, f"{self.channels[i]}: FAULT latched, zero torque: {reason}; "
                               "call ~/reset (std_srvs/Trigger) to clear")


def _bad_values(x: float, v: float, f_p: float, f_a: float) -> tuple[str, str]:
    """The condition kind and its description for values the plausibility check refused."""
    values = (("motor_position", x), ("motor_velocity", v), ("pressure_force", f_p),
              ("motor_effort", f_a))
    for name, value in values:
        if not math.isfinite(value):
            return NON_FINITE_STATE, f"non-finite state: {name} = {value!r}"
    return IMPLAUSIBLE_STATE, "implausible state: " + ", ".join(
        f"{name} = {value:.4g}" for name, value in values) + " (beyond the state limits)"


def _malformed_reason(names: Sequence[str], x: Sequence[float], v: Sequence[float],
                      f_p: Sequence[float], f_a: Sequence[float], status: Sequence[int]) -> str:
    """What is wrong with a malformed state, in words."""
    if len(set(names)) != len(names):
        return f"malformed actuator_state: repeated names {list(names)}"
    sizes = ", ".join(f"{field} {len(seq)}" for field, seq in (
        ("motor_position", x), ("motor_velocity", v), ("pressure_force", f_p),
        ("motor_effort", f_a), ("status", status)) if len(seq) != len(names))
    return f"malformed actuator_state: {len(names)} names but {sizes} entries"


def _plant_stop_reason(status: int) -> str:
    """The plant-side stop ``status`` (``STATUS_*`` bits) says, in words."""
    words = [text for bit, text in ((STATUS_FAULT, "a plant fault: clear it with the plant's "
                                                   "~/reset"),
                                    (STATUS_COMMAND_TIMEOUT, "command timeout"))
             if status & bit]
    return ", ".join(words) or f"status {status}"
