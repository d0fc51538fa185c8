"""pytest fixtures for tests that need the EtherCAT emulator.

``test/ethercat/conftest.py`` imports them; a test elsewhere can do the same
(``from ethercat.fixtures import ecat_emulator, ecat_bus, soem_master``), since
``test/conftest.py`` puts ``test/`` on ``sys.path``.

* ``ecat_emulator`` -- factory ``start(config=None) -> EmulatorHarness`` (running: veth
  pair, namespace, emulator process, connected side channel ``.client``).  Every harness
  it started is stopped at teardown, pass or fail; if a test failed, the emulator's log is
  printed.
* ``ecat_bus`` -- the default bus (wrist drive, pinch drive, pressure terminal), started.
* ``soem_master`` -- factory ``open(interface) -> pysoem.Master``; each master is closed
  at teardown.
"""

import pytest

from ethercat.harness import EmulatorHarness, open_master


@pytest.fixture
def ecat_emulator(tmp_path):
    harnesses = []

    def start(config=None):
        h = EmulatorHarness(config, workdir=tmp_path / ("emulator%d" % len(harnesses)))
        harnesses.append(h)
        return h.start()

    try:
        yield start
    finally:
        for h in harnesses:
            log = h.log()
            h.stop()
            print("---- emulator %s log ----\n%s" % (h.master_interface, log))


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
