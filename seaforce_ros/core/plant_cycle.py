"""Plant side of the real-time cycle: the torque each channel may have, this cycle.

:class:`PlantCycle` is the one place that decides what reaches a motor, for sim_node,
hardware_node and the direct layout alike (ros2_control's split: this is the safety layer
between the controller's commands and the hardware interface's write). It is plain Python
with explicit state; the nodes only feed it and act on its output.

Per cycle, on the plant's cycle thread::

    out = cycle.step(now, velocity, drives)   # commands received since the last step
    ...apply out.torque (simulator) or out.units (drive PDOs), exchange process data...
    cycle.exchange(wkc, expected_wkc)         # hardware only: was the frame complete?
    k = cycle.state_published()               # after a fresh sample went out as cycle k

From any thread: :meth:`PlantCycle.command` (an ``actuator_command``, or the direct call's
answer), :meth:`PlantCycle.set_publishers` (the graph's publishers of ``actuator_command``),
:meth:`PlantCycle.request_reset` (``~/reset``), :meth:`PlantCycle.configure` (parameters).
They only hand data over; everything takes effect at the start of the next :meth:`step`.

Rules (each with a status bit per channel, an event for the log and a counter):

* **command watchdog, per channel**: a channel whose newest accepted command answers a state
  more than ``command_timeout`` old (counted in the plant's own steps, ``command_timeout /
  dt`` of them, lost frames included) gets zero torque and ``STATUS_COMMAND_TIMEOUT``.
  Before the first command every channel is timed out. Counting steps rather than wall time
  means a stall of the plant's own cycle (or a lockstep simulation waiting for its command)
  is never blamed on the controller; a plant that keeps cycling while commands stop times
  out on schedule.
* **freshness**: a command must answer a state this plant published at most
  ``command_timeout`` ago (its ``cycle``); an answer to an older state, or to a cycle this plant
  has not published (a controller still answering a plant that was restarted), is ignored.
* **one command source**: two different answers to the same cycle, or answers going back in
  cycle (only two interleaved sources produce either), latch a conflict: zero torque on every
  channel, ``STATUS_FAULT``, until ``~/reset`` with a single publisher left. A second
  publisher of ``actuator_command`` in the graph alone gives the same zero torque and status
  for as long as the graph lists it (it may be a process killed a moment ago, which DDS
  lists until its lease expires): no command is applied while two could be.
* **non-finite command** for a channel latches that channel's fault (zero torque).
* **torque limit**: a finite command beyond ``+-torque_limit`` is clamped (``STATUS_LIMIT``);
  with drive units (hardware) the value is then rounded and saturated to int16.
* **velocity trip**: ``|V| > max_velocity`` (0 turns this off), or a non-finite V, latches
  that channel's fault.
* **drives** (hardware): a drive that is not in Operation enabled gets zero torque and its
  channel ``STATUS_FAULT`` (the controller then follows the applied torque); one that leaves
  Operation enabled without being told to, or reports a fault (except during a grace period
  after a reset, while it leaves its Fault state), latches that channel's fault (its reason
  becomes the drive's own as soon as the backend knows it: an error code read after the bit). A latched
  channel fault also disables that channel's drive.
* **bus fault** (hardware): ``wkc_error_limit`` consecutive incomplete exchanges latch a bus
  fault: zero torque everywhere and the drives disabled.
* **reset**: clears the latched faults (a conflict only once a single publisher is left),
  sends one fault reset to every drive, forgets every command: torque resumes only with a
  new command.
"""

import math
from array import array
from collections import deque
from collections.abc import Iterable, Sequence

from .episodes import ERROR, INFO, Episode, EventLog
from .errors import InvalidParameterError
from .handover import Mailbox
from .schema import HARDWARE, PLANTS, SIM, ParameterGroup, group, param

__all__ = ["PlantLimits", "PlantCycle", "PlantOutput", "STATUS_OK", "STATUS_COMMAND_TIMEOUT",
           "STATUS_LIMIT", "STATUS_FAULT", "INT16_MIN", "INT16_MAX"]

#: Status bits of ``ActuatorState.status`` (same values as the message's constants).
STATUS_OK = 0
STATUS_COMMAND_TIMEOUT = 1
STATUS_LIMIT = 2
STATUS_FAULT = 4

INT16_MIN, INT16_MAX = -32768, 32767

#: Cycles a drive may still report Fault after a reset before it latches again (0.1 s at
#: 2 kHz: a drive takes a few cycles to leave Fault after the fault-reset edge).
RESET_GRACE_CYCLES = 200

#: States whose publication time (in steps) is remembered, for the age of the commands.
_TICK_RING = 1 << 16


@group("", nodes=PLANTS, per_channel=False)
class PlantLimits(ParameterGroup):
    """Run-time settings of :class:`PlantCycle` (ROS parameters of the plant nodes)."""

    command_timeout: float = param(0.01, "s", "a channel that no fresh actuator_command names "
                                   "for this long gets zero torque and STATUS_COMMAND_TIMEOUT; "
                                   "a command is fresh when it answers a state at most this "
                                   "old", ge=1e-4, le=10.0)
    torque_limit: float = param(5.0, "N m", "commands are clamped to +-torque_limit "
                                "(STATUS_LIMIT)", gt=0.0, le=1e3, node_defaults={SIM: 20.0})
    max_velocity: float = param(30.0, "rad/s", "motor speed |V| beyond which the channel's "
                                "torque is removed and a fault latched; 0 disables the trip",
                                ge=0.0, le=1e4,
                                # the sim: a command timeout in hold releases a backdriven
                                # motor at up to ~35 rad/s (hardware_node: 30 to start)
                                node_defaults={SIM: 100.0})
    wkc_error_limit: int = param(10, "", "consecutive working-counter errors that latch a bus "
                                 "fault (safe state)", ge=1, le=100000, nodes=(HARDWARE,))


class PlantOutput:
    """What :meth:`PlantCycle.step` decided, per channel (lists reused from cycle to cycle).

    torque : float
        Torque to apply [N m] (after clamp and, with drive units, rounding).
    units : int
        Drive units (per mille of rated torque) when the cycle has ``units_per_nm``.
    status : int
        ``STATUS_*`` bits for this cycle's ``ActuatorState``.
    enable : bool
        The drive should be in Operation enabled (False after a bus fault).
    fault_reset : bool
        Send one fault reset to the drive this cycle (after ``~/reset``).
    """

    def __init__(self, n: int) -> None:
        self.torque: list[float] = [0.0] * n
        self.units: list[int] = [0] * n
        self.status: list[int] = [STATUS_COMMAND_TIMEOUT] * n
        self.enable: list[bool] = [True] * n
        self.fault_reset: list[bool] = [False] * n


class _PlantChannel:
    """One channel's state from one cycle to the next.

    fault : str
        The latched fault ('' when none).
    was_allowed : bool
        The drive was in Operation enabled last cycle.
    grace : int
        Cycles the drive may still report Fault (after a reset).
    timeout_episode : Episode
        The log episode of its command timeouts.
    effort : float
        The accepted command [N m] (0 for a non-finite one).
    raw : float
        The command as received: a repeated answer must match it.
    answer : int
        The cycle the accepted command answers (-1: none since the start or a reset).
    answer_tick : int
        The plant's step count when that state was published.
    """

    __slots__ = ("fault", "drive_fault", "was_allowed", "grace", "timeout_episode", "effort",
                 "raw", "answer", "answer_tick")

    def __init__(self, timeout_episode: Episode) -> None:
        self.fault = ""
        self.drive_fault = False       # the latched fault is the drive's own
        self.was_allowed = False
        self.grace = 0
        self.timeout_episode = timeout_episode
        self.forget()

    def forget(self) -> None:
        """No command: none accepted yet, or forgotten by a reset."""
        self.effort = 0.0
        self.raw = 0.0
        self.answer = -1
        self.answer_tick = 0


class PlantCycle:
    """The plant side of the cycle for a set of channels (see module docstring).

    Parameters
    ----------
    channels : sequence of str
        Channel names, in the order of every per-channel list.
    dt : float > 0
        Cycle period [s].
    limits : PlantLimits
    units_per_nm : sequence of float > 0, optional
        Per channel, drive units per N m (hardware: 1000 / rated torque); the torque is then
        rounded to units and saturated to int16.
    quiet_period : float >= 0
        Minimum time between two log reports of the same repeated condition [s].
    start_cycle : int >= 0
        The number of the state before the first step (a lockstep plant publishes it as its
        initial state; every step's state is numbered one more). A plant that starts again
        (a lifecycle node activated anew) goes on from its previous numbers: no state of
        this run then has the number of an earlier one, so a command answering an earlier
        run's state -- late, or a controller's cached answer to the same number -- is never
        taken for an answer to this run's, and the controller sees the numbers go on.

    Notes
    -----
    :meth:`step` runs its stages in turn, each a method over explicit state (one
    :class:`_PlantChannel` per channel): take the hand-overs (limits, reset, the commands
    received), judge the command sources, then per channel check the channel (velocity trip,
    drive), watch its commands (timeout) and decide its torque.
    """

    def __init__(self, channels: Sequence[str], dt: float, limits: PlantLimits | None = None,
                 units_per_nm: Sequence[float] | None = None,
                 quiet_period: float = 10.0, start_cycle: int = 0) -> None:
        self.channels: tuple[str, ...] = tuple(channels)
        n = len(self.channels)
        if n == 0:
            raise InvalidParameterError("channels", list(channels), "at least one channel")
        if len(set(self.channels)) != n:
            raise InvalidParameterError("channels", list(channels), "unique names")
        if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
            raise InvalidParameterError("dt", dt, "> 0 and finite")
        limits = PlantLimits() if limits is None else limits
        if not isinstance(limits, PlantLimits):
            raise TypeError("limits must be a PlantLimits")
        if not (isinstance(start_cycle, int) and start_cycle >= 0):
            raise InvalidParameterError("start_cycle", start_cycle, "an integer >= 0")
        if units_per_nm is not None:
            units_per_nm = tuple(float(u) for u in units_per_nm)
            if len(units_per_nm) != n or not all(math.isfinite(u) and u > 0
                                                 for u in units_per_nm):
                raise InvalidParameterError("units_per_nm", units_per_nm,
                                            f"{n} finite values > 0")
        self.dt = float(dt)
        self._units_per_nm = units_per_nm
        self._index = {c: i for i, c in enumerate(self.channels)}
        self.events = EventLog()
        self.out = PlantOutput(n)
        self.cycle = start_cycle             # newest published state
        self._start_cycle = start_cycle      # answers to earlier numbers are not to this run
        self._inbox: deque = deque(maxlen=64)   # (names, efforts, answers)
        self._limits_box: Mailbox[PlantLimits] = Mailbox()
        self._reset_box: Mailbox[bool] = Mailbox()
        self.ticks = 0                       # steps so far: the watchdog's clock
        self._published_at = array("q", bytes(8 * _TICK_RING))   # cycle -> ticks then
        self._publishers: tuple[str, ...] = ()
        self._mapping: tuple[list[str], tuple[int, ...]] = ([], ())   # cached names, index
        self._apply_limits(limits)
        self._ch = [_PlantChannel(Episode(self.events, quiet_period)) for _ in range(n)]
        self._bus_fault = ""
        self._conflict = ""
        self._wkc_errors = 0                 # consecutive
        self._fresh = True                   # the newest exchange was complete
        self._crowded_ep = Episode(self.events, quiet_period, severity=ERROR)
        self._reject_ep = {kind: Episode(self.events, quiet_period)
                           for kind in ("stale", "future", "malformed", "unknown")}
        self.rejected: dict[str, int] = {kind: 0 for kind in self._reject_ep}
        self.faults_latched = 0
        self.wkc_errors_total = 0

    # --- hand-over from other threads ------------------------------------------------------
    def command(self, names: Sequence[str], efforts: Sequence[float], answers: int) -> None:
        """Queue one command: efforts [N m] for ``names``, answering state ``answers``.
        Checked at the next :meth:`step`. ``efforts`` must not change afterwards."""
        self._inbox.append((names, efforts, answers))

    def set_publishers(self, names: Iterable[str]) -> None:
        """The publishers of ``actuator_command`` the ROS graph shows now (node names)."""
        self._publishers = tuple(names)

    def configure(self, limits: PlantLimits) -> None:
        """New :class:`PlantLimits`, effective at the start of the next step."""
        if not isinstance(limits, PlantLimits):
            raise TypeError("limits must be a PlantLimits")
        self._limits_box.put(limits)

    def request_reset(self) -> str:
        """Ask for a reset at the start of the next step; returns what it will clear."""
        self._reset_box.put(True)
        latched = self.latched_faults()
        return "; ".join(latched) if latched else "no fault was latched"

    # --- status for diagnostics ------------------------------------------------------------
    @property
    def limits(self) -> PlantLimits:
        """The :class:`PlantLimits` in force."""
        return self._limits

    @property
    def bus_fault(self) -> str:
        """The latched bus fault, or ''."""
        return self._bus_fault

    @property
    def conflict(self) -> str:
        """The latched conflict (with the publishers the graph lists now), else the graph's
        second publisher, else ''."""
        if self._conflict:
            if self._publishers:
                return f"{self._conflict}; publishers now: {', '.join(self._publishers)}"
            return self._conflict
        if len(self._publishers) > 1:
            return (f"{len(self._publishers)} publishers of actuator_command: "
                    + ", ".join(self._publishers))
        return ""

    def channel_fault(self, i: int) -> str:
        """The fault that zeroes channel ``i`` ('' when none)."""
        return self._ch[i].fault or self._bus_fault or self.conflict

    def latched_faults(self) -> list[str]:
        """Every latched fault as 'where: reason' strings."""
        out = [f"{c}: {ch.fault}" for c, ch in zip(self.channels, self._ch) if ch.fault]
        if self._bus_fault:
            out.append(f"bus: {self._bus_fault}")
        if self._conflict:
            out.append(f"commands: {self._conflict}")
        return out

    def timeouts(self, i: int) -> int:
        """Command-timeout episodes of channel ``i`` so far."""
        return self._ch[i].timeout_episode.count

    # --- the cycle -------------------------------------------------------------------------
    def step(self, now: float, velocity: Sequence[float] | None = None,
             drives: Sequence[tuple[bool, bool] | tuple[bool, bool, str]] | None = None
             ) -> PlantOutput:
        """Decide this cycle's torques.

        Parameters
        ----------
        now : float
            Monotonic time of the cycle's start [s].
        velocity : sequence of float, optional
            Newest measured motor velocity per channel [rad/s] (the velocity trip).
        drives : sequence of (bool, bool) or (bool, bool, str), optional
            Per channel ``(torque_allowed, faulted)`` of the drive (hardware), and what the
            fault is when the backend knows (the latched reason; else the statusword's);
            without it every channel may have torque and none is faulted.

        Returns
        -------
        PlantOutput
        """
        self._take_handovers(now)
        blocked = self._judge_sources(now)
        for i, ch in enumerate(self._ch):
            if velocity is not None and not ch.fault:
                self._check_velocity(i, velocity[i])
            allowed = True if drives is None else self._check_drive(i, ch, *drives[i])
            timed_out = self._watch_commands(i, ch, now)
            self._decide(i, ch, blocked or not allowed, timed_out)
        return self.out

    def exchange(self, wkc: int, expected_wkc: int) -> bool:
        """Result of this cycle's process-data exchange (hardware); True if complete."""
        self._fresh = wkc == expected_wkc
        if self._fresh:
            self._wkc_errors = 0
            return True
        self._wkc_errors += 1
        self.wkc_errors_total += 1
        if self._wkc_errors >= self._limits.wkc_error_limit and not self._bus_fault:
            self._bus_fault = (f"{self._wkc_errors} consecutive working-counter errors "
                               f"(got {wkc}, expected {expected_wkc})")
            self.faults_latched += 1
            self.events.add(ERROR, f"bus FAULT latched: {self._bus_fault}; zero torque, drives "
                                   "disabled; call ~/reset (std_srvs/Trigger) to retry")
        return False

    def state_published(self) -> int:
        """A fresh sample went out: it is the new current cycle; returns its number."""
        self.cycle += 1
        self._published_at[self.cycle % _TICK_RING] = self.ticks
        return self.cycle

    # --- stages of a step ------------------------------------------------------------------
    def _take_handovers(self, now: float) -> None:
        """New limits, a reset (or the end of the last one's fault-reset pulse), the commands
        received since the last step; the watchdog's clock advances."""
        limits = self._limits_box.take()
        if limits is not None:
            self._apply_limits(limits)
        self.ticks += 1
        if self._reset_box.take():
            self._reset(now)
        else:
            resets = self.out.fault_reset
            for i in range(len(resets)):
                resets[i] = False
        if self._inbox:
            self._take_commands(now)

    def _judge_sources(self, now: float) -> bool:
        """Whether no command may be applied this cycle: a bus fault, a latched conflict or
        more than one publisher of ``actuator_command`` in the graph (reported when that
        begins and ends; the commands are forgotten when it ends)."""
        crowded = len(self._publishers) > 1
        if crowded != self._crowded_ep.active:
            if crowded:
                self._crowded_ep.begin(now, f"{self.conflict}: zero torque on every channel "
                                            "while more than one can command (a process "
                                            "killed a moment ago stays listed until its DDS "
                                            "lease expires)")
            else:
                self._crowded_ep.end(now, "one publisher of actuator_command left: commands "
                                          "accepted again")
                self._forget_commands()
        return bool(self._bus_fault or self._conflict or crowded)

    def _check_velocity(self, i: int, v: float) -> None:
        """The velocity trip of channel ``i`` (not latched yet): ``v`` [rad/s] non-finite or
        beyond ``max_velocity`` latches its fault."""
        vmax = self._limits.max_velocity
        if not math.isfinite(v):
            self._latch(i, f"non-finite motor velocity {v!r}")
        elif vmax > 0.0 and not -vmax <= v <= vmax:
            self._latch(i, f"motor speed {v:.2f} rad/s beyond max_velocity {vmax:g}")

    def _check_drive(self, i: int, ch: _PlantChannel, allowed: bool, faulted: bool,
                     reason: str = "") -> bool:
        """Channel ``i``'s drive: a fault (after the reset's grace period) or leaving Operation
        enabled untold latches the channel's fault; returns whether it may have torque."""
        if faulted:
            if ch.grace > 0:
                ch.grace -= 1
            elif not ch.fault:
                self._latch(i, reason or "drive reports a fault (statusword bit 3)")
                ch.drive_fault = True
            elif ch.drive_fault and reason and reason != ch.fault:
                # what the drive's fault is came after its fault bit (its error code read)
                ch.fault = reason
                self.events.add(ERROR, f"{self.channels[i]}: the fault is {reason}")
        else:
            if self._fresh:                 # (a stale sample says nothing about the reset)
                ch.grace = 0
            if ch.was_allowed and not allowed and self.out.enable[i] and not ch.fault:
                self._latch(i, "drive left Operation enabled without being told to "
                               "(quick stop, safe torque off, mode change?)")
        ch.was_allowed = allowed
        return allowed

    def _watch_commands(self, i: int, ch: _PlantChannel, now: float) -> bool:
        """The command watchdog of channel ``i``: True while its newest accepted command
        answers a state more than ``command_timeout`` old (or there is none); the start and
        the end of a timeout are reported."""
        answer = ch.answer
        age = self.ticks - ch.answer_tick
        timed_out = answer < 0 or age > self._max_age
        episode = ch.timeout_episode
        if timed_out != episode.active:
            if timed_out:
                if answer >= 0:
                    episode.begin(now, f"{self.channels[i]}: no fresh actuator_command: the "
                                       f"newest answers a state {age} cycles old "
                                       f"(> command_timeout "
                                       f"{1e3 * self._limits.command_timeout:g} ms): zero "
                                       "torque")
            else:
                episode.end(now, f"{self.channels[i]}: commands back, torque re-enabled")
        return timed_out

    def _decide(self, i: int, ch: _PlantChannel, stopped: bool, timed_out: bool) -> None:
        """Channel ``i``'s torque, drive units, status and enable this cycle: zero when
        ``stopped`` (nothing may be applied), faulted or ``timed_out``, else the command
        clamped to ``torque_limit`` (and rounded to drive units within it)."""
        out = self.out
        lim = self._limits.torque_limit
        status = STATUS_COMMAND_TIMEOUT if timed_out else STATUS_OK
        u = ch.effort
        if stopped or ch.fault:
            status |= STATUS_FAULT     # the plant applies none of the controller's torque
            u = 0.0
        elif timed_out:
            u = 0.0
        elif u > lim:
            u, status = lim, status | STATUS_LIMIT
        elif u < -lim:
            u, status = -lim, status | STATUS_LIMIT
        upn = self._units_per_nm
        if upn is not None:
            k = upn[i]
            units = round(u * k)
            if units / k > lim:          # rounding must not cross the limit either
                units -= 1
            elif units / k < -lim:
                units += 1
            if units > INT16_MAX:
                units, status = INT16_MAX, status | STATUS_LIMIT
            elif units < INT16_MIN:
                units, status = INT16_MIN, status | STATUS_LIMIT
            out.units[i] = units
            u = units / k
        out.torque[i] = u
        out.status[i] = status
        out.enable[i] = not (self._bus_fault or ch.fault)

    # --- internals -------------------------------------------------------------------------
    def _apply_limits(self, limits: PlantLimits) -> None:
        self._limits = limits
        self._max_age = min(_TICK_RING // 2,
                            max(1, int(math.ceil(limits.command_timeout / self.dt))))

    def _forget_commands(self) -> None:
        """Forget every command (after a reset, and when a second publisher has gone)."""
        for ch in self._ch:
            ch.forget()

    def _latch(self, i: int, reason: str) -> None:
        self._ch[i].fault = reason
        self.faults_latched += 1
        self.events.add(ERROR, f"{self.channels[i]}: FAULT latched, zero torque: {reason}; "
                               "call ~/reset (std_srvs/Trigger) to clear")

    def _latch_conflict(self, reason: str) -> None:
        self._conflict = reason
        self.faults_latched += 1
        self.events.add(ERROR, f"two command sources: {reason}; zero torque on every channel "
                               "until one source is left and ~/reset is called")

    def _reject(self, kind: str, now: float, text: str) -> None:
        self.rejected[kind] += 1
        episode = self._reject_ep[kind]
        episode.begin(now, text)
        episode.end(now)

    def _reset(self, now: float) -> None:
        cleared = [f for f in self.latched_faults() if not f.startswith("commands: ")]
        for i, ch in enumerate(self._ch):
            ch.fault = ""
            ch.drive_fault = False
            ch.grace = RESET_GRACE_CYCLES
            ch.was_allowed = False           # the drive walks up to Operation enabled again
            self.out.fault_reset[i] = True
            self.out.enable[i] = True
        self._bus_fault = ""
        self._wkc_errors = 0
        kept = ""
        if self._conflict:
            if len(self._publishers) > 1:
                kept = (f"; the command conflict stays latched: {len(self._publishers)} "
                        f"publishers of actuator_command ({', '.join(self._publishers)})")
            else:
                cleared.append(f"commands: {self._conflict}")
                self._conflict = ""
        self._inbox.clear()
        self._forget_commands()
        self.events.add(INFO, "reset: " + ("cleared " + "; ".join(cleared) if cleared
                                           else "no fault was latched") + kept)

    def _take_commands(self, now: float) -> None:
        """Accept the queued commands that answer a fresh state this plant published, one
        source's answers only (a second source latches the conflict)."""
        inbox = self._inbox
        current = self.cycle
        ticks = self.ticks
        published_at = self._published_at
        max_age = self._max_age
        while inbox:
            names, efforts, answers = inbox.popleft()
            if len(efforts) != len(names):
                self._reject("malformed", now, f"actuator_command ignored: {len(names)} names "
                                                f"but {len(efforts)} efforts")
                continue
            mapping = self._map(names, now)
            if mapping is None:
                continue
            if answers > current:
                self._reject("future", now, f"actuator_command ignored: it answers cycle "
                                             f"{answers}, which this plant has not published "
                                             f"(newest {current}); a controller still "
                                             "answering an earlier plant?")
                continue
            age = (ticks - published_at[answers % _TICK_RING] if current - answers < _TICK_RING
                   else current - answers)
            if answers < self._start_cycle or age > max_age:
                self._reject("stale", now, f"actuator_command ignored: it answers cycle "
                                            f"{answers}, {age} cycles old (> command_timeout); "
                                            "a command must carry the cycle of the state it "
                                            "answers")
                continue
            for value, i in zip(efforts, mapping):
                if i >= 0:
                    self._accept(i, value, answers, published_at[answers % _TICK_RING])

    def _accept(self, i: int, value: float, answers: int, tick: int) -> None:
        """Channel ``i``'s command ``value`` [N m] answering cycle ``answers`` (published at
        step ``tick``): accepted when it answers a newer cycle than the last; the same answer
        again is ignored, a different one or an older cycle latches the conflict."""
        ch = self._ch[i]
        last = ch.answer
        if answers <= last:
            prev = ch.raw
            same = value == prev or (value != value and prev != prev)
            if (answers < last or not same) and not self._conflict:
                how = ("answered twice with different efforts" if answers == last
                       else f"answered after cycle {last}")
                who = (f" (publishers: {', '.join(self._publishers)})" if self._publishers
                       else "")
                self._latch_conflict(f"cycle {answers} {how} for {self.channels[i]}{who}")
            return      # the same answer again (a re-published state) or rejected
        ch.answer = answers
        ch.answer_tick = tick
        ch.raw = value
        if not math.isfinite(value):
            if not ch.fault:
                self._latch(i, f"non-finite torque command {value!r}")
            value = 0.0
        ch.effort = value

    def _map(self, names: Sequence[str], now: float) -> tuple[int, ...] | None:
        """Channel index per name of a command (-1: not a channel here); None if malformed."""
        cached_names, cached = self._mapping
        if names == cached_names:
            return cached
        index = self._index
        mapping = tuple(index.get(name, -1) for name in names)
        if len(set(names)) != len(names):
            self._reject("malformed", now, f"actuator_command ignored: repeated names "
                                            f"{list(names)}")
            return None
        unknown = [name for name, i in zip(names, mapping) if i < 0]
        if unknown:
            self._reject("unknown", now, f"actuator_command names unknown channel(s) "
                                          f"{unknown}: ignored for them (channels here: "
                                          f"{list(self.channels)})")
        self._mapping = (list(names), mapping)
        return mapping
