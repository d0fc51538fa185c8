"""Start node processes for tests and make sure each one ends, by its own PID."""
import itertools
import os
import pathlib
import signal
import subprocess
import sys
import time
from typing import List, Optional, Sequence

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[2]
INSTALL_LIB = ROOT / 'install' / 'seaforce_ros' / 'lib' / 'seaforce_ros'
_log_counter = itertools.count()
_live: 'set[ManagedProcess]' = set()   # started and not yet stopped: see stop_leftovers()
#: Stops that took longer than SLOW_STOP s: (what, seconds, how it ended), for the session's
#: summary (a slow teardown is time every run pays; conftest prints them).
slow_stops: List[tuple] = []
SLOW_STOP = 2.0


def _signal_masks(pid: int) -> str:
    """The blocked and ignored signal masks of a running process ('' when unreadable)."""
    try:
        lines = pathlib.Path(f'/proc/{pid}/status').read_text().splitlines()
    except OSError:
        return ''
    return ' '.join(line.replace('\t', '') for line in lines
                    if line.startswith(('SigBlk', 'SigIgn')))


def stop_leftovers() -> int:
    """End every process a test started and did not stop (safety net at session end)."""
    leftovers = list(_live)
    for proc in leftovers:
        proc.stop(timeout=2.0)
    return len(leftovers)


def executable(name: str) -> pathlib.Path:
    """Path of an installed executable: what `ros2 run seaforce_ros <name>` runs."""
    path = INSTALL_LIB / name
    if not path.is_file():
        raise FileNotFoundError(f'{path} is not installed; run scripts/setup.sh (colcon build)')
    return path


class ManagedProcess:
    """A child in its own session, with stdout+stderr captured to a log file."""

    def __init__(self, argv: Sequence[str], log_path: pathlib.Path, env=None, preexec_fn=None):
        self.argv = list(argv)
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.popen = subprocess.Popen(self.argv, stdout=self._log, stderr=subprocess.STDOUT,
                                      stdin=subprocess.DEVNULL, env=env, start_new_session=True,
                                      preexec_fn=preexec_fn)
        _live.add(self)

    @property
    def pid(self) -> int:
        return self.popen.pid

    def output(self) -> str:
        self._log.flush()
        return self.log_path.read_text(errors='replace')

    def wait_for_output(self, text: str, timeout: float = 20.0) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if text in self.output():
                return True
            if self.popen.poll() is not None:
                return text in self.output()
            time.sleep(0.05)
        return False

    def send_signal(self, sig: int) -> None:
        if self.popen.poll() is None:
            os.kill(self.popen.pid, sig)

    def wait(self, timeout: float) -> Optional[int]:
        try:
            return self.popen.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def stop(self, timeout: float = 5.0) -> Optional[int]:
        """SIGINT, then SIGKILL after `timeout`; returns the exit code."""
        started = time.monotonic()
        how = 'had exited'
        if self.popen.poll() is None:
            masks = _signal_masks(self.popen.pid)
            self.send_signal(signal.SIGINT)
            how = 'SIGINT'
            if self.wait(timeout) is None:
                self.send_signal(signal.SIGKILL)
                how = f'SIGKILL after SIGINT was not enough ({masks})'
                self.wait(5.0)
        self._log.close()
        _live.discard(self)
        took = time.monotonic() - started
        if took > SLOW_STOP:
            slow_stops.append((pathlib.Path(self.argv[0]).name, round(took, 1), how))
        return self.popen.returncode


class ProcessGroup:
    """The processes one test started; `stop_all` ends each by PID."""

    def __init__(self):
        self._procs: List[ManagedProcess] = []
        self._logdir = ROOT / 'log' / 'test-processes'
        self._logdir.mkdir(parents=True, exist_ok=True)

    def start(self, argv: Sequence[str], name: Optional[str] = None, env=None,
              preexec_fn=None) -> ManagedProcess:
        """``preexec_fn`` runs in the child before exec (e.g. resource limits)."""
        name = name or pathlib.Path(argv[0]).name
        log_path = self._logdir / f'{name}-{os.getpid()}-{next(_log_counter)}.log'
        proc = ManagedProcess(argv, log_path, env=env, preexec_fn=preexec_fn)
        self._procs.append(proc)
        return proc

    def start_python(self, script: pathlib.Path, *args: str, name: Optional[str] = None,
                     env=None) -> ManagedProcess:
        return self.start([sys.executable, str(script), *args], name=name or script.stem, env=env)

    def stop_all(self) -> None:
        for proc in reversed(self._procs):
            proc.stop()


def run_until_exit(argv, timeout=60, cwd=None):
    """Run an installed executable to its end; (exit code, stdout + stderr). Ended by its own
    PID if it outlives ``timeout`` (it must not: a bad configuration stops it at once)."""
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL, start_new_session=True, text=True,
                            cwd=cwd)
    try:
        out, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, _ = proc.communicate()
        pytest.fail(f'{argv} still ran after {timeout} s:\n{out}')
    return proc.returncode, out
