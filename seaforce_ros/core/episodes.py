"""Episodes of a repeated condition: counted always, reported once per episode, throttled.

A condition such as "no fresh command for pinch" comes and goes; at 2 kHz on a loaded host it
can come and go hundreds of times a minute. :class:`Episode` turns its on/off edges into at
most one report per ``quiet_period`` (the first episode, then a summary naming how many more
happened meanwhile), and keeps counts and the longest duration for ``/diagnostics``. No ROS,
no clock of its own: the caller passes monotonic times [s].

The reports go to a shared :class:`EventLog`, which the node drains from its cycle thread and
passes to the ROS logger; the pure cycle classes never log themselves.
"""

from collections import deque
from typing import Deque, List, Optional, Tuple

__all__ = ["Episode", "EventLog", "ERROR", "WARNING", "INFO"]

ERROR, WARNING, INFO = "error", "warning", "info"


class EventLog:
    """Reports waiting to be logged: ``(severity, text)`` pairs, oldest first (bounded)."""

    def __init__(self, capacity: int = 256) -> None:
        self._events: Deque[Tuple[str, str]] = deque(maxlen=capacity)

    def add(self, severity: str, text: str) -> None:
        self._events.append((severity, text))

    def __bool__(self) -> bool:
        return bool(self._events)

    def drain(self) -> List[Tuple[str, str]]:
        """Remove and return every waiting report."""
        out: List[Tuple[str, str]] = []
        events = self._events
        while events:
            out.append(events.popleft())
        return out


class Episode:
    """One named condition: its on/off edges, counts and throttled reports.

    Parameters
    ----------
    log : EventLog
        Where reports go.
    quiet_period : float >= 0
        Minimum time between two reported episodes [s]; episodes in between are counted
        and named in the next report.
    severity : str
        Severity of the "began" report (the "ended" report is INFO).

    Attributes
    ----------
    active : bool
    count : int
        Episodes begun so far.
    longest : float
        Longest finished episode [s].
    """

    def __init__(self, log: EventLog, quiet_period: float = 10.0,
                 severity: str = WARNING) -> None:
        self._log = log
        self.quiet_period = float(quiet_period)
        self.severity = severity
        self.active = False
        self.count = 0
        self.longest = 0.0
        self._since = 0.0
        self._last_report: Optional[float] = None
        self._unreported = 0
        self._reported = False

    def begin(self, now: float, text: str) -> bool:
        """The condition holds at ``now``; report ``text`` unless throttled. Idempotent while
        active. Returns True when this call began an episode."""
        if self.active:
            return False
        self.active = True
        self.count += 1
        self._since = now
        last = self._last_report
        if last is None or now - last >= self.quiet_period:
            if self._unreported:
                text += f" ({self._unreported} more such episode(s) since the last report)"
            self._log.add(self.severity, text)
            self._last_report = now
            self._unreported = 0
            self._reported = True
        else:
            self._unreported += 1
            self._reported = False
        return True

    def end(self, now: float, text: Optional[str] = None) -> Optional[float]:
        """The condition no longer holds; ``text`` is reported (INFO) only if the episode's
        beginning was. Returns the episode's duration [s], or None if none was active."""
        if not self.active:
            return None
        self.active = False
        duration = now - self._since
        if duration > self.longest:
            self.longest = duration
        if text and self._reported:
            self._log.add(INFO, f"{text} after {1e3 * duration:.1f} ms")
        return duration
