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
==================== ====================================================== ===========

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

from .controller import ChannelController
from .episodes import ERROR, Episode, EventLog
from .errors import InvalidParameterError
from .handover import Mailbox
from .plant_cycle import STATUS_COMMAND_TIMEOUT, STATUS_FAULT
from .schema import CONTROLLER, ParameterGroup, group, param

__all__ = ["StateChecks", "ControlCycle", "ControlOutput", "FAULT_KINDS",
           "DEFAULT_LATCHED", "STALE_STATE", "STATE_GAP", "STATE_SOURCES", "FUTURE_STAMP",
           "MALFORMED_STATE",
           "MISSING_CHANNEL", "NON_FINITE_STATE", "IMPLAUSIBLE_STATE", "TORQUE_LIMIT",
           "NON_FINITE_TORQUE"]

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

#: Every condition kind, in the order of the table above.
FAULT_KINDS = (STALE_STATE, STATE_GAP, STATE_SOURCES, FUTURE_STAMP, MALFORMED_STATE,
               MISSING_CHANNEL, NON_FINITE_STATE, IMPLAUSIBLE_STATE, TORQUE_LIMIT,
               NON_FINITE_TORQUE)

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
    cycle : int
        The state's cycle (the command answers it).
    """

    def __init__(self, n):
        self.effort = [0.0] * n
        self.answered = False
        self.cycle = -1


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
    """

    def __init__(self, channels, controllers, checks=None, quiet_period=10.0):
        self.channels = tuple(channels)
        self.controllers = list(controllers)
        n = len(self.channels)
        if n == 0 or len(set(self.channels)) != n:
            raise InvalidParameterError("channels", list(channels), "unique names, at least one")
        if len(self.controllers) != n or not all(isinstance(c, ChannelController)
                                                 for c in self.controllers):
            raise TypeError(f"controllers must be {n} ChannelController objects")
        dts = {c.dt for c in self.controllers}
        if len(dts) != 1:
            raise InvalidParameterError("dt", sorted(dts), "the same for every channel")
        self.dt = dts.pop()
        self.events = EventLog()
        self.out = ControlOutput(n)
        self._checks_box = Mailbox()
        self._reset_box = Mailbox()
        self._configs = deque()            # {channel index: ControllerConfig} hand-overs
        self._state_publishers = ()
        self._apply_checks(StateChecks() if checks is None else checks)
        self._latched = [""] * n           # latched fault reason per channel
        self._rearming = [""] * n          # re-arming condition holding this sample
        self._needs_reset = [True] * n     # full re-initialisation at the next clean sample
        self._stopped = [0] * n            # cycles the plant has been applying fai, not ours
        self._status = [0] * n             # ... and its status bits then
        self._stream_ep = Episode(self.events, quiet_period)
        self._channel_ep = [Episode(self.events, quiet_period) for _ in range(n)]
        self._drop_ep = Episode(self.events, quiet_period)
        self._mapping = ([], ())
        self._answered_names = None        # names of the state out.effort answers
        self._last_cycle = None
        self._last_arrival = None
        self.counts = {kind: 0 for kind in FAULT_KINDS}
        self.faults_latched = 0
        self.dropped = 0

    # --- hand-over from other threads ------------------------------------------------------
    def configure(self, checks):
        """New :class:`StateChecks`, effective at the start of the next step."""
        if not isinstance(checks, StateChecks):
            raise TypeError("checks must be a StateChecks")
        self._checks_box.put(checks)

    def configure_channels(self, configs):
        """New configurations ``{channel index: ControllerConfig}`` (validated), taken together
        at the start of the next step: a change that sets several channels reaches all of them
        in the same cycle."""
        self._configs.append(dict(configs))

    def set_state_publishers(self, names):
        """The publishers of ``actuator_state`` the ROS graph shows now (node names)."""
        self._state_publishers = tuple(names)

    def request_reset(self):
        """Clear every latched fault at the start of the next step; returns what it clears."""
        self._reset_box.put(True)
        cleared = [c for c, f in zip(self.channels, self._latched) if f]
        return ("cleared faults on " + ", ".join(cleared)) if cleared else "no fault was latched"

    # --- status ----------------------------------------------------------------------------
    @property
    def checks(self):
        return self._checks

    def fault(self, i):
        """Channel ``i``'s latched fault, or its re-arming condition, or ''."""
        if self._latched[i]:
            return self._latched[i]
        if self._rearming[i]:
            return "re-arming: " + self._rearming[i]
        return ""

    def latched(self, i):
        return self._latched[i]

    def plant_stopped(self, i):
        """Why the plant applies its own torque on channel ``i`` instead of the command, or
        '': its fault (``STATUS_FAULT``, latched on the plant's side until its reset) at
        once, a command timeout (``STATUS_COMMAND_TIMEOUT``) once it has lasted longer than
        ``state_timeout`` -- a late command now and then (a loaded host) is no stop."""
        stopped, status = self._stopped[i], self._status[i]
        if stopped and (status & STATUS_FAULT or stopped > self._gap_cycles):
            return _plant_stop_reason(status)
        return ""

    # --- the cycle -------------------------------------------------------------------------
    def step(self, names, cycle, stamp_ns, x, v, f_p, f_a, status, now_ns, now):
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
        checks = self._checks_box.take()
        if checks is not None:
            self._apply_checks(checks)
        configs = self._configs
        while configs:
            for i, config in configs.popleft().items():
                self.controllers[i].configure(config)
        if self._reset_box.take():
            self._reset()
        out = self.out
        effort = out.effort
        n_names = len(names)
        if (len(x) != n_names or len(v) != n_names or len(f_p) != n_names
                or len(f_a) != n_names or len(status) != n_names):
            mapping = None
        else:
            mapping = self._map(names)
        if mapping is not None and not any(j >= 0 for j in mapping[1]):
            # nothing here to control: not our plant (or all names wrong)
            self.dropped += 1
            self._drop_ep.begin(now, f"actuator_state names none of the channels "
                                     f"{list(self.channels)} (it names {list(names)}): "
                                     "dropped, no command sent")
            self._drop_ep.end(now)
            out.answered = False
            return out
        checks = self._checks
        age_ns = now_ns - stamp_ns
        last = self._last_cycle
        if last is None and age_ns > self._timeout_ns:
            self.dropped += 1      # start-up backlog: states older than the first fresh one
            out.answered = False
            return out
        if last is not None and last - self._gap_cycles <= cycle < last:
            # older than the newest state already answered: delivered out of order. Answering
            # it would look like a second command source to the plant; a restarted plant
            # starts far lower (its cycles start at 1, and it takes longer than that to start)
            self.dropped += 1
            out.answered = False
            return out
        out.answered = True
        if len(self._state_publishers) > 1:
            # two plants (or a bag played into a running one): whose state would we answer?
            self.counts[STATE_SOURCES] += 1
            self._condition_all(now, STATE_SOURCES,
                                f"{len(self._state_publishers)} publishers of actuator_state: "
                                + ", ".join(self._state_publishers))
            return out
        if cycle == out.cycle and names == self._answered_names:
            return out             # a re-published state: the same answer again
        stream = ""                # a condition of the whole stream this sample
        stream_kind = None
        if age_ns < -self._timeout_ns:
            stream_kind = FUTURE_STAMP
            stream = f"state stamped {-age_ns * 1e-6:.1f} ms in the future"
        elif age_ns > self._timeout_ns:
            stream_kind = STALE_STATE
            stream = f"stale state: {age_ns * 1e-6:.1f} ms old (> state_timeout)"
        elif last is not None:
            if cycle < last:
                stream_kind = STATE_GAP
                stream = f"cycle went back from {last} to {cycle} (plant restarted)"
            elif cycle - last > self._gap_cycles:
                stream_kind = STATE_GAP
                stream = f"cycle jumped from {last} to {cycle} ({cycle - last - 1} missing)"
            elif now - self._last_arrival > checks.state_timeout:
                stream_kind = STALE_STATE
                stream = (f"no state for {1e3 * (now - self._last_arrival):.1f} ms "
                          "(> state_timeout)")
        steps = cycle - last if last is not None and 0 < cycle - last <= self._gap_cycles else 1
        self._last_cycle = cycle
        self._last_arrival = now
        if stream_kind is not None:
            self.counts[stream_kind] += 1
            if stream_kind in checks.latched:
                for i in range(len(self.channels)):
                    self._latch(i, stream)
            else:
                self._stream_ep.begin(now, stream + ": zero torque; every channel re-arms "
                                               "from the plant's present state")
                for i in range(len(self.channels)):
                    self._needs_reset[i] = True
                    self._rearming[i] = stream
        elif self._stream_ep.active:
            self._stream_ep.end(now, "states flow again: channels re-initialised from the "
                                     "plant's present state")
        if mapping is None:
            self.counts[MALFORMED_STATE] += 1
            self._condition_all(now, MALFORMED_STATE, self._malformed_reason(names, x, v, f_p,
                                                                             f_a, status))
            return out
        index = mapping[1]
        plim, vlim, flim = checks.position_limit, checks.velocity_limit, checks.force_limit
        for i, ctrl in enumerate(self.controllers):
            j = index[i]
            if j < 0:
                self.counts[MISSING_CHANNEL] += 1
                self._condition(i, now, MISSING_CHANNEL, "channel missing from actuator_state")
                effort[i] = 0.0
                continue
            xi, vi, fpi, fai = x[j], v[j], f_p[j], f_a[j]
            if not (-plim <= xi <= plim and -vlim <= vi <= vlim and -flim <= fpi <= flim
                    and -flim <= fai <= flim):
                kind, reason = self._bad_values(xi, vi, fpi, fai)
                self.counts[kind] += 1
                self._condition(i, now, kind, reason)
                effort[i] = 0.0
                continue
            if self._latched[i] or stream_kind is not None:
                if ctrl.job is not None:
                    ctrl.abort_job(f"fault latched: {self._latched[i]}" if self._latched[i]
                                   else stream)
                ctrl.reenter(fai)          # estimators stay live; no windup meanwhile
                try:
                    ctrl.update(xi, vi, fpi, steps)
                except ArithmeticError:
                    pass
                effort[i] = 0.0
                continue
            if self._needs_reset[i]:
                self._needs_reset[i] = False
                self._stopped[i] = 0
                ctrl.reset(fai)
            elif status[j] & _PLANT_STOPPED:
                # the plant applies fai instead of our torque: follow it (no windup); a brief
                # stop keeps the targets, a longer one than state_timeout re-captures them
                self._stopped[i] += steps
                self._status[i] = status[j]
                if self._stopped[i] > self._gap_cycles:
                    ctrl.reset(fai, f"the plant stopped the channel "
                                    f"({_plant_stop_reason(status[j])}) for longer than "
                                    "state_timeout")
                else:
                    ctrl.reenter(fai)
            else:
                self._stopped[i] = 0
            if self._rearming[i]:
                self._rearming[i] = ""
                self._channel_ep[i].end(now, f"{self.channels[i]}: re-armed from the plant's "
                                             "present state")
            try:
                u = ctrl.update(xi, vi, fpi, steps)
            except ArithmeticError:        # an overflow the checks above did not foresee
                u = math.nan
            if not -ctrl.config.max_torque <= u <= ctrl.config.max_torque:
                if math.isfinite(u):
                    kind = TORQUE_LIMIT
                    reason = (f"torque {u:.4g} N m beyond max_torque "
                              f"{ctrl.config.max_torque:g} N m")
                else:
                    kind = NON_FINITE_TORQUE
                    reason = f"computed torque is {u!r} (an intermediate overflowed)"
                self.counts[kind] += 1
                self._condition(i, now, kind, reason)
                u = 0.0
            effort[i] = u
        out.cycle = cycle
        self._answered_names = list(names) if names != self._answered_names else \
            self._answered_names
        return out

    # --- internals -------------------------------------------------------------------------
    def _apply_checks(self, checks):
        self._checks = checks
        self._timeout_ns = int(checks.state_timeout * 1e9)
        self._gap_cycles = max(1, int(math.ceil(checks.state_timeout / self.dt)))

    def _map(self, names):
        """(names, index of each channel in ``names`` or -1), or None for repeated names."""
        cached_names, _ = self._mapping
        if names == cached_names:
            return self._mapping
        if len(set(names)) != len(names):
            return None
        position = {name: j for j, name in enumerate(names)}
        self._mapping = (list(names), tuple(position.get(c, -1) for c in self.channels))
        return self._mapping

    def _condition(self, i, now, kind, reason):
        """Channel ``i`` met ``kind`` this sample: latch it, or zero it until a clean one."""
        if kind in self._checks.latched:
            self._latch(i, reason)
            return
        self.controllers[i].abort_job(reason)
        self._needs_reset[i] = True
        self._rearming[i] = reason
        self._channel_ep[i].begin(now, f"{self.channels[i]}: {reason}: zero torque until a "
                                       "clean sample re-arms it")

    def _condition_all(self, now, kind, reason):
        for i in range(len(self.channels)):
            self.out.effort[i] = 0.0
            self._condition(i, now, kind, reason)
        self.out.cycle = self._last_cycle
        self._answered_names = None

    def _latch(self, i, reason):
        if self._latched[i]:
            return
        self.controllers[i].abort_job(f"fault latched: {reason}")
        self._latched[i] = reason
        self._needs_reset[i] = True
        self.faults_latched += 1
        self.events.add(ERROR, f"{self.channels[i]}: FAULT latched, zero torque: {reason}; "
                               "call ~/reset (std_srvs/Trigger) to clear")

    def _reset(self):
        for i in range(len(self.channels)):
            if self._latched[i]:
                self._latched[i] = ""
                self._needs_reset[i] = True

    @staticmethod
    def _bad_values(x, v, f_p, f_a):
        values = (("motor_position", x), ("motor_velocity", v), ("pressure_force", f_p),
                  ("motor_effort", f_a))
        for name, value in values:
            if not math.isfinite(value):
                return NON_FINITE_STATE, f"non-finite state: {name} = {value!r}"
        return IMPLAUSIBLE_STATE, "implausible state: " + ", ".join(
            f"{name} = {value:.4g}" for name, value in values) + " (beyond the state limits)"

    @staticmethod
    def _malformed_reason(names, x, v, f_p, f_a, status):
        if len(set(names)) != len(names):
            return f"malformed actuator_state: repeated names {list(names)}"
        sizes = ", ".join(f"{field} {len(seq)}" for field, seq in (
            ("motor_position", x), ("motor_velocity", v), ("pressure_force", f_p),
            ("motor_effort", f_a), ("status", status)) if len(seq) != len(names))
        return f"malformed actuator_state: {len(names)} names but {sizes} entries"


def _plant_stop_reason(status):
    """The plant-side stop ``status`` (``STATUS_*`` bits) says, in words."""
    words = [text for bit, text in ((STATUS_FAULT, "a plant fault: clear it with the plant's "
                                                   "~/reset"),
                                    (STATUS_COMMAND_TIMEOUT, "command timeout"))
             if status & bit]
    return ", ".join(words) or f"status {status}"
