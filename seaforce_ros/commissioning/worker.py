"""A commissioning run's analysis in a child process, followed without blocking.

The identification, the prediction and the tuning take seconds of CPU. In the controller's
process they would hold Python's interpreter lock against the 2 kHz loop; in a child process
they take the other core. :class:`AnalysisProcess` starts the child, reads its progress lines
on a thread of its own and says, when polled, what it does and how it ended. The child is ended
by its own PID on a cancel, on :meth:`AnalysisProcess.close`, and by the kernel when the parent
dies (``PR_SET_PDEATHSIG``).

The child's protocol, one JSON object per line on its standard output:
``{"phase": str, "progress": float 0..1, "measuring": str}`` while it works, and
``{"result": {...}}`` once, last. Its standard error goes to a log file. It exits 0 when it
succeeded; otherwise its last line of standard error (or the last ``{"error": str}`` it
printed) is the reason.

The child's linear algebra runs on one thread (``OPENBLAS_NUM_THREADS=1`` unless the
environment says otherwise): its matrices are a few rows wide, and on a 2-core host beside the
2 kHz loop BLAS's worker threads spent most of the prediction waiting for each other (its
|Z| band took 7 s instead of 1.3 s).
"""
from __future__ import annotations

import ctypes
import json
import math
import os
import pathlib
import signal
import subprocess
import threading
from typing import Any, Callable, Sequence

__all__ = ["AnalysisProcess", "child_environment", "pdeathsig"]

_PR_SET_PDEATHSIG = 1


def child_environment() -> dict[str, str]:
    """The analysis child's environment: this process's, with BLAS on one thread unless the
    user set its thread count (module docstring)."""
    env = dict(os.environ)
    env.setdefault("OPENBLAS_NUM_THREADS", "1")
    return env


def pdeathsig() -> None:
    """(in the child, before exec) Have the kernel send SIGTERM to this process when its
    parent dies: a killed controller leaves no analysis behind."""
    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)
    except OSError:             # not Linux / no glibc: the parent's close() still ends it
        pass


class AnalysisProcess:
    """A child process that reports progress as JSON lines (module docstring); the
    :class:`~seaforce_ros.nodes.jobs.FollowUp` of the ``~/commission`` action.

    Parameters
    ----------
    argv : sequence of str
        The child's command line.
    log_path : path
        Its standard error goes here (appended).
    phase : str
        The phase the feedback shows until the child says another.
    progress_span : (float, float)
        The child's progress 0..1 is mapped onto this part of the goal's progress.
    prepare : callable () -> None, optional
        Run on the follower's thread before the child starts (writing its input files: no
        file I/O in the caller's thread); an exception from it aborts with its message.

    Attributes
    ----------
    outcome : str or None
        None while it runs, then ``succeeded``, ``canceled`` or ``aborted``.
    message : str
        What it does, or why it ended.
    result : dict or None
        The child's ``result`` object, once it succeeded.
    """

    def __init__(self, argv: Sequence[str], log_path: str | os.PathLike[str],
                 phase: str = "identify",
                 progress_span: tuple[float, float] = (0.0, 1.0),
                 prepare: Callable[[], None] | None = None) -> None:
        self.outcome: str | None = None
        self.message = "starting the analysis"
        self.result: dict[str, Any] | None = None
        self._argv = list(argv)
        self._span = progress_span
        self._prepare = prepare
        self._lock = threading.Lock()
        self._latest: dict[str, Any] = {"phase": phase, "progress": 0.0,
                                        "measuring": self.message}
        self._error = ""
        self._canceled = ""
        self._log_path = pathlib.Path(log_path)
        self._proc: subprocess.Popen[bytes] | None = None
        self._started = threading.Event()
        self._reader = threading.Thread(target=self._run, name="commission-analysis",
                                        daemon=True)
        self._reader.start()

    # --- the reader thread -------------------------------------------------------------
    def _run(self) -> None:
        """Prepare (write the record: no file I/O in the caller's thread), start the child,
        read its lines."""
        try:
            if self._prepare is not None:
                self._prepare()
            with self._lock:
                if self._canceled:
                    return
                with open(self._log_path, "ab") as log:
                    self._proc = subprocess.Popen(
                        self._argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                        stderr=log, env=child_environment(), preexec_fn=pdeathsig,
                        start_new_session=True)
        except Exception as exc:                # noqa: BLE001 -- any failure is the reason
            self._error = f"could not start the analysis: {exc}"
            return
        finally:
            self._started.set()
        self._read(self._proc)

    # --- the reader thread -------------------------------------------------------------
    def _read(self, proc: subprocess.Popen[bytes]) -> None:
        assert proc.stdout is not None
        for raw in proc.stdout:
            try:
                line = json.loads(raw)
            except ValueError:
                continue            # not a protocol line (a library printed something)
            if not isinstance(line, dict):
                continue
            with self._lock:
                if isinstance(line.get("result"), dict):
                    self.result = line["result"]
                elif isinstance(line.get("error"), str):
                    self._error = line["error"]
                else:
                    self._latest.update({k: line[k] for k in ("phase", "progress", "measuring")
                                         if k in line})

    # --- the FollowUp protocol -------------------------------------------------------------
    @property
    def pid(self) -> int | None:
        """The child's PID (None until it started, or if it never did)."""
        proc = self._proc
        return proc.pid if proc is not None else None

    def poll(self) -> bool:
        """True once the child has ended (and its output is read); never blocks."""
        if self.outcome is not None:
            return True
        if self._reader.is_alive():
            return False
        proc = self._proc
        rc = proc.wait() if proc is not None else None   # the reader saw its end of output
        if self._canceled:
            self._finish("canceled", self._canceled)
        elif rc == 0 and self.result is not None:
            self._finish("succeeded", str(self.result.get("message", "done")))
        else:
            self._finish("aborted", self._reason(rc))
        return True

    def cancel(self, reason: str) -> None:
        """End the child (SIGTERM to its PID); ``canceled`` once it is gone."""
        with self._lock:
            if self.outcome is not None or self._canceled:
                return
            self._canceled = reason
        self._signal(signal.SIGTERM)

    def close(self) -> None:
        """End the child now if it still runs (SIGKILL after a SIGTERM it ignored for 2 s)."""
        if self.outcome is not None:
            return
        with self._lock:
            self._canceled = self._canceled or "closed"
        self._started.wait(10.0)
        proc = self._proc
        if proc is not None:
            self._signal(signal.SIGTERM)
            try:
                proc.wait(2.0)
            except subprocess.TimeoutExpired:
                self._signal(signal.SIGKILL)
                proc.wait()
        self._reader.join(2.0)
        self.poll()

    def feedback(self) -> dict[str, float | str]:
        """The child's latest phase, progress (within ``progress_span``) and what it
        measures."""
        with self._lock:
            latest = dict(self._latest)
        try:
            fraction = min(1.0, max(0.0, float(latest.get("progress", 0.0))))
        except (TypeError, ValueError):
            fraction = 0.0
        if not math.isfinite(fraction):
            fraction = 0.0
        lo, hi = self._span
        return {"phase": str(latest.get("phase", "")), "progress": lo + (hi - lo) * fraction,
                "measuring": str(latest.get("measuring", ""))}

    # --- helpers -------------------------------------------------------------------------
    def _signal(self, sig: int) -> None:
        proc = self._proc
        if proc is not None and proc.poll() is None:
            try:
                os.kill(proc.pid, sig)
            except ProcessLookupError:
                pass

    def _reason(self, rc: int | None) -> str:
        if self._error:
            return self._error
        try:
            lines = self._log_path.read_text(errors="replace").strip().splitlines()
        except OSError:
            lines = []
        last = lines[-1] if lines else ""
        if rc is not None and rc < 0:
            return f"the analysis was ended by signal {-rc}" + (f": {last}" if last else "")
        return (last or f"the analysis exited with status {rc}") + \
            f" (its log: {self._log_path})"

    def _finish(self, outcome: str, message: str) -> None:
        self.outcome = outcome
        self.message = message
