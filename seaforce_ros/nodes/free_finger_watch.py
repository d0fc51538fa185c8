"""The free-finger check of a running controller: after a parameter change, in a child process.

At start-up ``controller_node`` checks each channel's ``feedforward.damping_reserve`` against
its model's band (:func:`~seaforce_ros.commissioning.free_finger.reserve_verdict`) in its own
thread: 0.1 s per channel before the loop runs. A parameter set that changes what the check
depends on -- the model (``plant.*``, ``dahl.*``), the feed-forward (its margin, share,
reserve, band) or the DOB -- is checked here instead, in a child process
(:class:`~seaforce_ros.commissioning.worker.AnalysisProcess`): in the node's process the
check's 0.1-2 s of CPU would hold the interpreter lock against the 2 kHz loop. The set itself
is not held up and not refused (the start-up check only warns too; the runaway monitor is what
acts on a finger that does move away): the verdict is logged when it comes, a warning when the
reserve does not hold the band, an info line when a channel warned about before is held
again.

One child runs at a time; a channel changed again while its check runs is checked once more
with its newest configuration when the child ends, and the verdict on the replaced one is
dropped (sets in quick succession cost two checks, not one each, and nothing is said of a
configuration no longer in force). A check that could not run is a warning too, and the next
one that passes says so. :meth:`FreeFingerWatch.close` ends a running child by its PID. The
child runs ``python -P``: the node's working directory is not on its import path.
"""
from __future__ import annotations

import json
import os
import pathlib
import sys
import tempfile
from typing import Any, Callable, Dict, Optional, Tuple

from ..commissioning.worker import AnalysisProcess
from ..core.params import ControllerConfig

__all__ = ["FreeFingerWatch", "checked_parts", "UNCHECKED"]

#: What a channel whose last check could not run is remembered as.
UNCHECKED = "(unchecked)"


def checked_parts(config: ControllerConfig) -> Tuple[Any, ...]:
    """What the free-finger check of ``config`` depends on (a change elsewhere -- the mode, the
    targets, the limits -- needs no new check)."""
    return (config.plant, config.dahl, config.feedforward, config.dob)


class FreeFingerWatch:
    """Checks changed channel configurations in a child process, one at a time (module
    docstring).

    Parameters
    ----------
    delay : int
        Samples from a state to the sample its command acts from (the layout's).
    dt : float
        Sample period [s].
    warn, info : callable (str) -> None
        Where the verdicts go (the node's logger).
    """

    def __init__(self, delay: int, dt: float, warn: Callable[[str], None],
                 info: Callable[[str], None]) -> None:
        self._delay = delay
        self._dt = dt
        self._warn = warn
        self._info = info
        self._pending: Dict[str, ControllerConfig] = {}
        self._running: Optional[Tuple[str, AnalysisProcess]] = None
        self._warned: Dict[str, str] = {}       # channel -> the verdict last logged
        self.checks = 0                         # children started (diagnostics, tests)
        # the children's standard error (the reason of one that fails before it answers): a
        # file of this node's own, made at the first check
        self._log: Optional[pathlib.Path] = None

    def started(self, channel: str, verdict: Optional[str]) -> None:
        """The start-up check's verdict of ``channel`` (what a later one is compared with)."""
        if verdict:
            self._warned[channel] = verdict

    def changed(self, channel: str, old: ControllerConfig, new: ControllerConfig) -> None:
        """``channel``'s accepted configuration went from ``old`` to ``new``: check it (when
        what the check depends on changed)."""
        if checked_parts(old) != checked_parts(new):
            self._pending[channel] = new
            self.poll()

    def poll(self) -> None:
        """Log a finished check's verdict; start the next one. Never blocks."""
        if self._running is not None:
            channel, child = self._running
            if not child.poll():
                return
            self._running = None
            if channel not in self._pending:        # (else replaced meanwhile: say nothing)
                self._report(channel, child)
        if self._pending:
            channel = next(iter(self._pending))
            config = self._pending.pop(channel)
            request = json.dumps({"config": config.to_dict(), "delay": self._delay,
                                  "dt": self._dt})
            if self._log is None:
                handle, name = tempfile.mkstemp(prefix="seaforce-free-finger-", suffix=".log")
                os.close(handle)
                self._log = pathlib.Path(name)
            self._running = (channel, AnalysisProcess(
                [sys.executable, "-P", "-m", "seaforce_ros.commissioning.free_finger",
                 request], self._log, phase="free finger"))
            self.checks += 1

    @property
    def busy(self) -> bool:
        """A check runs or waits."""
        return self._running is not None or bool(self._pending)

    def _report(self, channel: str, child: AnalysisProcess) -> None:
        if child.outcome != "succeeded" or child.result is None:
            self._warn(f"{channel}: the free-finger check after the parameter change did not "
                       f"run ({child.message}); the damping reserve is unchecked")
            self._warned[channel] = UNCHECKED
            return
        verdict = str(child.result.get("verdict", ""))
        if verdict:
            if self._warned.get(channel) != verdict:
                self._warn(f"{channel}: after the parameter change: {verdict}")
            self._warned[channel] = verdict
        else:
            before = self._warned.pop(channel, None)
            if before is not None:
                self._info(f"{channel}: after the parameter change the damping reserve holds "
                           "a free finger over the model's band" +
                           (" (checked)" if before == UNCHECKED else " again"))

    def close(self) -> None:
        """End a running check (by its PID); forget the waiting ones; remove the log."""
        self._pending.clear()
        if self._running is not None:
            self._running[1].close()
            self._running = None
        if self._log is not None:
            try:
                self._log.unlink()
            except OSError:
                pass
