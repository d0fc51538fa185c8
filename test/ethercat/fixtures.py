"""pytest fixtures for tests that need the EtherCAT emulator.

``test/ethercat/conftest.py`` imports them; a test elsewhere can do the same
(``from ethercat.fixtures import ecat_emulator, ecat_bus, soem_master``), since
``test/conftest.py`` puts ``test/`` on ``sys.path``.

* ``ecat_emulator`` -- factory ``start(config=None, realtime=EMULATOR_PRIORITY) ->
  EmulatorHarness`` (running: veth pair, namespace, emulator process at SCHED_FIFO
  ``realtime``, connected side channel ``.client``).  Every harness it started is stopped at
  teardown, pass or fail; the emulator's log and its last events (AL changes and errors,
  watchdog expiries) are printed, which pytest shows when a test failed.
  ``evidence`` (default True): at teardown, every drive must report that no frame carried
  torque to it unless the newest inputs its master had showed Operation enabled in CST, and
  that it never entered Operation enabled in another mode (:func:`torque_evidence`);
  emulator tests driving pysoem by hand pass False.
* ``ecat_bus`` -- the default bus (wrist drive, pinch drive, pressure terminal), for a bare
  pysoem master: one emulator per test module, reset to power-up before each test (the
  ``reset`` command).
* ``soem_master`` -- factory ``open(interface) -> pysoem.Master``; each master is closed
  at teardown.
"""

import functools
import subprocess
import time
import warnings

import pytest

from ethercat.harness import EmulatorHarness, open_master
from helpers.processes import SLOW_STOP, slow_stops

# The emulator is a slave line: like an ESC it must answer every frame within the master's
# timeout, whatever else the host runs.  SOEM's blocking calls give it 2 ms per try, and
# pysoem's ``_fprd``/``_fpwr`` (which ``set_watchdog`` uses) make a single try.  At normal
# priority, with a busy process per core, a few frames in 10^4 were answered later than
# that (16 of 40 000 single-try FPRDs failed; 0 of 40 000 at SCHED_FIFO 50) and a test
# failed in ``set_watchdog`` with a WkcError.  The emulator sleeps in poll() between frames,
# so the priority only decides who runs when a frame arrives.  50 is above the hardware
# node's 40 in test_hardware_node, like an ESC, which never waits for its master.
EMULATOR_PRIORITY = 50


@functools.lru_cache(maxsize=None)
def realtime_allowed(priority=EMULATOR_PRIORITY):
    """Whether this host lets us run a process at SCHED_FIFO ``priority`` (root without
    CAP_SYS_NICE, or a cgroup without real-time budget, does not)."""
    try:
        return subprocess.run(["chrt", "-f", str(priority), "true"], stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, timeout=10).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def torque_evidence(client):
    """The drives' count of frames that carried torque to a drive whose newest inputs at the
    master did not show Operation enabled in CST, and of entries into Operation enabled in
    another mode (ethercat/emulator/cia402.py): ``[(drive, unsafe, enables)]`` of those not 0."""
    bad = []
    for s in client.status()["slaves"]:
        if s["kind"] == "cia402_drive" and (s["unsafe_torque_frames"] or
                                            s["enables_outside_cst"]):
            bad.append((s["name"], s["unsafe_torque_frames"], s["enables_outside_cst"]))
    return bad


@pytest.fixture
def ecat_emulator(tmp_path):
    """Factory of running emulators (see module docstring). ``evidence=True`` (the default:
    the project's master drives the bus) makes the test fail at teardown if a drive counted
    torque it should never have received; tests of the emulator with a bare pysoem master,
    which break that rule on purpose, pass False."""
    harnesses = []

    def start(config=None, realtime=EMULATOR_PRIORITY, evidence=True):
        if realtime and not realtime_allowed(realtime):
            warnings.warn("SCHED_FIFO %d not permitted here: the EtherCAT emulator runs at "
                          "normal priority and may miss frames on a loaded host" % realtime)
            realtime = 0
        h = EmulatorHarness(config, workdir=tmp_path / ("emulator%d" % len(harnesses)),
                            realtime=realtime)
        h.evidence = evidence
        harnesses.append(h)
        return h.start()

    violations = []
    try:
        yield start
    finally:
        for h in harnesses:
            try:
                events = h.client.events() if h.client is not None else []
                if h.evidence and h.client is not None:
                    violations += torque_evidence(h.client)
            except Exception as exc:          # e.g. the emulator died: its log says why
                events = ["(no events: %s)" % exc]
            log = h.log()
            started = time.monotonic()
            h.stop()
            took = time.monotonic() - started
            if took > SLOW_STOP:
                slow_stops.append(("EtherCAT emulator harness", round(took, 1), "stop()"))
            print("---- emulator %s log ----\n%s" % (h.master_interface, log))
            print("---- emulator %s events (last 40) ----" % h.master_interface)
            for event in events[-40:]:
                print(event)
    assert not violations, ("torque reached a drive not in Operation enabled in CST, or a "
                            "drive was enabled in another mode (drive, frames, enables): %s"
                            % violations)


@pytest.fixture(scope="module")
def _shared_line(tmp_path_factory):
    """One default line per test module (``ecat_bus`` resets it before each test)."""
    priority = EMULATOR_PRIORITY if realtime_allowed() else 0
    h = EmulatorHarness(None, workdir=tmp_path_factory.mktemp("ecat_line"), realtime=priority)
    h.start()
    try:
        yield h
    finally:
        log = h.log()
        h.stop()
        print("---- shared emulator %s log ----\n%s" % (h.master_interface, log))


@pytest.fixture
def ecat_bus(_shared_line):
    """The default line for a bare pysoem master (no torque evidence asked), shared by the
    tests of a module: reset to power-up (every slave, the physics, the counters) before
    each test -- a veth pair, a namespace and a process less per test."""
    _shared_line.client.reset()
    _shared_line.client.clear_history()
    try:
        yield _shared_line
    finally:
        try:
            events = _shared_line.client.events()
        except Exception as exc:
            events = ["(no events: %s)" % exc]
        print("---- emulator %s events (last 40) ----" % _shared_line.master_interface)
        for event in events[-40:]:
            print(event)


@pytest.fixture
def soem_master():
    masters = []

    def open_(interface):
        m = open_master(interface)
        masters.append(m)
        return m

    try:
        yield open_
    finally:
        for m in masters:
            try:
                m.close()
            except Exception:
                pass
