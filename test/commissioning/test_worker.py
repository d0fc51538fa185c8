"""The commissioning analysis runs in a child process that the node follows without blocking:
progress, result, failure reasons, cancel and close end the child by its own PID."""
import os
import sys
import time

import pytest

from seaforce_ros.commissioning.worker import AnalysisProcess


def _child(tmp_path, body):
    script = tmp_path / 'child.py'
    script.write_text('import json, sys, time\n'
                      'def say(**kw):\n'
                      '    print(json.dumps(kw), flush=True)\n' + body)
    return [sys.executable, str(script)]


def _wait(proc, timeout=20.0):
    deadline = time.monotonic() + timeout
    while not proc.poll():
        assert time.monotonic() < deadline, 'the child did not end'
        time.sleep(0.01)


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    # a zombie not yet reaped counts as gone
    with open(f'/proc/{pid}/stat') as f:
        return f.read().split(')')[-1].split()[0] != 'Z'


def test_progress_and_result(tmp_path):
    argv = _child(tmp_path, 'say(phase="identify", progress=0.5, measuring="F_p/X")\n'
                            'time.sleep(0.3)\n'
                            'print("a library printing something")\n'
                            'say(result={"message": "tuned", "z": 1.5})\n')
    proc = AnalysisProcess(argv, tmp_path / 'log.txt', progress_span=(0.6, 1.0))
    seen = []
    deadline = time.monotonic() + 20.0
    while not proc.poll():
        seen.append(proc.feedback())
        assert time.monotonic() < deadline
        time.sleep(0.01)
    assert proc.outcome == 'succeeded'
    assert proc.message == 'tuned'
    assert proc.result == {'message': 'tuned', 'z': 1.5}
    mid = [f for f in seen if f['measuring'] == 'F_p/X']
    assert mid and mid[-1]['progress'] == pytest.approx(0.8)      # 0.6 + 0.4 * 0.5
    assert all(0.6 <= f['progress'] <= 1.0 for f in seen)


def test_a_failing_child_gives_its_reason(tmp_path):
    argv = _child(tmp_path, 'sys.stderr.write("Traceback ...\\nValueError: no band\\n")\n'
                            'sys.exit(3)\n')
    proc = AnalysisProcess(argv, tmp_path / 'log.txt')
    _wait(proc)
    assert proc.outcome == 'aborted'
    assert 'ValueError: no band' in proc.message and 'log.txt' in proc.message
    argv = _child(tmp_path, 'say(error="the record holds no excitation above 3 Hz")\n'
                            'sys.exit(2)\n')
    proc = AnalysisProcess(argv, tmp_path / 'log2.txt')
    _wait(proc)
    assert (proc.outcome, proc.message) == ('aborted', 'the record holds no excitation '
                                            'above 3 Hz')


def test_exit_zero_without_a_result_is_not_success(tmp_path):
    proc = AnalysisProcess(_child(tmp_path, 'say(phase="x", progress=float("nan"))\n'),
                           tmp_path / 'log.txt')
    _wait(proc)
    assert proc.outcome == 'aborted'
    assert proc.feedback()['progress'] == 0.0          # NaN progress is shown as 0


def test_cancel_ends_the_child_by_its_pid(tmp_path):
    proc = AnalysisProcess(_child(tmp_path, 'say(phase="tune", progress=0.1)\n'
                                            'time.sleep(60)\n'), tmp_path / 'log.txt')
    deadline = time.monotonic() + 20.0
    while proc.feedback()['phase'] != 'tune':
        assert time.monotonic() < deadline
        time.sleep(0.01)
    pid = proc.pid
    assert pid is not None and _alive(pid)
    proc.cancel('canceled by the client')
    _wait(proc)
    assert (proc.outcome, proc.message) == ('canceled', 'canceled by the client')
    assert not _alive(pid)


def test_close_ends_a_child_that_ignores_sigterm(tmp_path):
    proc = AnalysisProcess(_child(tmp_path, 'import signal\n'
                                            'signal.signal(signal.SIGTERM, signal.SIG_IGN)\n'
                                            'say(phase="ready")\n'
                                            'time.sleep(60)\n'), tmp_path / 'log.txt')
    deadline = time.monotonic() + 20.0
    while proc.feedback()['phase'] != 'ready':        # SIGTERM is ignored from here on
        assert time.monotonic() < deadline
        time.sleep(0.01)
    pid = proc.pid
    proc.close()
    assert proc.outcome == 'canceled'
    assert not _alive(pid)


def test_a_command_that_cannot_start(tmp_path):
    proc = AnalysisProcess([str(tmp_path / 'missing')], tmp_path / 'log.txt')
    _wait(proc)
    assert proc.outcome == 'aborted'
    assert 'could not start' in proc.message
    proc.close()                                        # nothing to end; no error
    proc.cancel('x')
    assert proc.outcome == 'aborted'


def test_prepare_runs_first_and_its_failure_is_the_reason(tmp_path):
    marker = tmp_path / 'input.txt'
    argv = _child(tmp_path, f'say(result={{"message": open({str(marker)!r}).read()}})\n')
    proc = AnalysisProcess(argv, tmp_path / 'log.txt', prepare=lambda: marker.write_text('in'))
    _wait(proc)
    assert (proc.outcome, proc.message) == ('succeeded', 'in')

    def full_disk():
        raise OSError(28, 'No space left on device')
    proc = AnalysisProcess(argv, tmp_path / 'log.txt', prepare=full_disk)
    _wait(proc)
    assert proc.outcome == 'aborted' and 'No space left on device' in proc.message
    assert proc.pid is None                              # the child never started


def test_a_cancel_before_the_child_starts_starts_none(tmp_path):
    import threading
    gate = threading.Event()
    proc = AnalysisProcess(_child(tmp_path, 'say(result={})\n'), tmp_path / 'log.txt',
                           prepare=gate.wait)
    proc.cancel('canceled early')
    gate.set()
    _wait(proc)
    assert (proc.outcome, proc.message, proc.pid) == ('canceled', 'canceled early', None)


@pytest.mark.parametrize('user, seen', [(None, '1'), ('3', '3')])
def test_the_child_runs_blas_on_one_thread_unless_told(tmp_path, monkeypatch, user, seen):
    """The analysis' matrices are small: BLAS threads on a busy 2-core host only wait for each
    other. The child gets OPENBLAS_NUM_THREADS=1, a count the user set is kept."""
    if user is None:
        monkeypatch.delenv('OPENBLAS_NUM_THREADS', raising=False)
    else:
        monkeypatch.setenv('OPENBLAS_NUM_THREADS', user)
    argv = _child(tmp_path, 'import os\n'
                            'say(result={"threads": os.environ.get("OPENBLAS_NUM_THREADS")})\n')
    proc = AnalysisProcess(argv, tmp_path / 'log.txt')
    _wait(proc)
    assert proc.outcome == 'succeeded', proc.message
    assert proc.result == {'threads': seen}
