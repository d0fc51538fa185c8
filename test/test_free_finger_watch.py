"""FreeFingerWatch (the running controller's free-finger check in a child process), without
ROS: what starts a check, one child at a time with the newest configuration, the verdicts
logged once, the child ended by close()."""
import dataclasses
import time

import pytest

from seaforce_ros.commissioning.free_finger import reserve_verdict, with_reserve
from seaforce_ros.core.params import ControllerConfig
from seaforce_ros.nodes.free_finger_watch import FreeFingerWatch

BASE = ControllerConfig()


_WATCHES = []


@pytest.fixture(autouse=True)
def _closed():
    """Every watch a test made is closed after it (its child ended, its log removed)."""
    yield
    while _WATCHES:
        _WATCHES.pop().close()


def _watch():
    log = []
    watch = FreeFingerWatch(2, 5e-4, lambda m: log.append(('warn', m)),
                            lambda m: log.append(('info', m)))
    _WATCHES.append(watch)
    return watch, log


def _settle(watch, timeout=60.0):
    end = time.monotonic() + timeout
    while watch.busy and time.monotonic() < end:
        watch.poll()
        time.sleep(0.05)
    assert not watch.busy, 'the check did not end'


def test_only_what_the_check_depends_on_starts_one():
    watch, log = _watch()
    watch.changed('pinch', BASE, BASE.replace(mode='hold', max_torque=5.0))
    assert watch.checks == 0 and not watch.busy and log == []


def test_the_newest_configuration_is_checked_and_each_verdict_logged_once():
    """Three sets while the first check runs: two checks in all, the second of the newest
    configuration (reserve 0: warned), which the child and the in-process check agree on;
    the same verdict again is not logged again; back to the shipped reserve: one info."""
    watch, log = _watch()
    unheld = with_reserve(BASE, 0.0)
    watch.changed('pinch', BASE, with_reserve(BASE, 0.02))
    watch.changed('pinch', BASE, with_reserve(BASE, 0.05))
    watch.changed('pinch', BASE, unheld)
    _settle(watch)
    assert watch.checks == 2
    expected = reserve_verdict(unheld, delay=2, dt=5e-4)
    assert expected and log == [('warn', f'pinch: after the parameter change: {expected}')]
    watch.changed('pinch', unheld, dataclasses.replace(unheld, max_torque=5.0))
    watch.changed('pinch', with_reserve(BASE, 0.02), unheld)
    _settle(watch)
    assert watch.checks == 3 and len(log) == 1
    watch.changed('pinch', unheld, BASE)
    _settle(watch)
    assert log[-1][0] == 'info' and 'holds a free finger' in log[-1][1] and len(log) == 2


def test_a_start_up_warning_is_what_a_later_check_is_compared_with():
    watch, log = _watch()
    watch.started('wrist', 'some verdict')
    watch.changed('wrist', with_reserve(BASE, 0.0), BASE)
    _settle(watch)
    assert log == [('info', 'wrist: after the parameter change the damping reserve holds a '
                    'free finger over the model\'s band again')]


def test_close_ends_the_running_child():
    watch, _ = _watch()
    watch.changed('pinch', BASE, with_reserve(BASE, 0.0))
    child = watch._running[1]
    watch.close()
    assert not watch.busy and child.outcome is not None
    pid = child.pid
    if pid is not None:
        try:
            with open(f'/proc/{pid}/stat') as f:
                state = f.read().split()[2]
        except FileNotFoundError:
            state = 'gone'
        assert state in ('gone', 'Z'), state


def test_a_check_that_could_not_run_is_said_and_so_is_the_next_that_passes(monkeypatch):
    """A child that cannot start: a warning that the reserve is unchecked (with the reason);
    the next check that passes says so; the children's log is removed at close()."""
    watch, log = _watch()
    monkeypatch.setattr('sys.executable', '/nonexistent/python')
    watch.changed('pinch', BASE, with_reserve(BASE, 0.02))
    _settle(watch)
    assert len(log) == 1 and log[0][0] == 'warn' and 'did not run' in log[0][1] \
        and '/nonexistent/python' in log[0][1] and 'unchecked' in log[0][1], log
    monkeypatch.undo()
    watch.changed('pinch', with_reserve(BASE, 0.02), BASE)
    _settle(watch)
    assert log[-1] == ('info', "pinch: after the parameter change the damping reserve holds "
                       "a free finger over the model's band (checked)"), log
    assert watch._log.exists()
    watch.close()
    assert not watch._log.exists()


def test_the_child_does_not_import_from_the_working_directory(tmp_path, monkeypatch):
    """A folder holding a ``seaforce_ros`` package as the node's working directory: the check
    still runs the installed code (``python -P``)."""
    fake = tmp_path / 'seaforce_ros' / 'commissioning'
    fake.mkdir(parents=True)
    (tmp_path / 'seaforce_ros' / '__init__.py').write_text('')
    (fake / '__init__.py').write_text('')
    (fake / 'free_finger.py').write_text(
        'import json\nprint(json.dumps({"result": {"verdict": "IMPOSTOR"}}))\n')
    monkeypatch.chdir(tmp_path)
    watch, log = _watch()
    watch.changed('pinch', BASE, with_reserve(BASE, 0.0))
    _settle(watch)
    assert len(log) == 1 and 'IMPOSTOR' not in log[0][1] and 'may oscillate' in log[0][1], log
