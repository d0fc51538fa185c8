"""pytest fixtures for tests that need the EtherCAT emulator.

``test/ethercat/conftest.py`` imports them; a test elsewhere can do the same
(``from ethercat.fixtures import ecat_emulator, ecat_bus, soem_master``), since
``test/conftest.py`` puts ``test/`` on ``sys.path``.

* ``ecat_emulator`` -- factory ``start(config=None, realtime=EMULATOR_PRIORITY) ->
  EmulatorHarness`` (running: veth pair, namespace, emulator process at SCHED_FIFO
  ``realtime``, connected side channel ``.client``).  Every harness it started is stopped at
  teardown, pass or fail; the emulator's log and its last events (AL changes and errors,
  watchdog expiries) are printed, which pytest shows when a test failed.
* ``ecat_bus`` -- the default bus (wrist drive, pinch drive, pressure terminal), started.
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


@pytest.fixture
def ecat_emulator(tmp_path):
    harnesses = []

    def start(config=None, realtime=EMULATOR_PRIORITY):
        if realtime and not realtime_allowed(realtime):
            warnings.warn("SCHED_FIFO %d not permitted here: the EtherCAT emulator runs at "
                          "normal priority and may miss frames on a loaded host" % realtime)
            realtime = 0
        h = EmulatorHarness(config, workdir=tmp_path / ("emulator%d" % len(harnesses)),
                            realtime=realtime)
        harnesses.append(h)
        return h.start()

    try:
        yield start
    finally:
        for h in harnesses:
            try:
                events = h.client.events() if h.client is not None else []
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


@pytest.fixture
def ecat_bus(ecat_emulator):
    return ecat_emulator()


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
