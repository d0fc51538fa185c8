"""The harness leaves nothing behind: processes, veth links and namespaces are removed
after a normal stop and after a failed start."""

import os
import subprocess

import pytest

from ethercat.emulator.config import default_config
from ethercat.harness import EmulatorHarness, HarnessError


def link_exists(name, netns=None):
    cmd = ["ip"] + (["-n", netns] if netns else []) + ["link", "show", "dev", name]
    return subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode == 0


def netns_exists(name):
    out = subprocess.run(["ip", "netns", "list"], stdout=subprocess.PIPE, text=True).stdout
    return any(line.split()[0] == name for line in out.splitlines() if line.strip())


def pid_alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_start_and_stop_remove_everything(tmp_path):
    h = EmulatorHarness(workdir=tmp_path)
    assert str(os.getpid()) in h.master_interface and len(h.master_interface) <= 15
    h.start()
    try:
        pid = h.pid
        assert h.client.ping()["pid"] == pid          # ip netns exec execs the emulator
        assert link_exists(h.master_interface)
        assert not link_exists(h.slave_interface)     # the slave end lives in the namespace
        assert link_exists(h.slave_interface, h.netns)
        assert netns_exists(h.netns)
    finally:
        code = h.stop()
    assert code == 0
    assert not pid_alive(pid)
    assert not link_exists(h.master_interface) and not netns_exists(h.netns)
    assert not h.control_path.exists()
    assert h.stop() == 0                              # idempotent: nothing left to undo


def test_failed_start_cleans_up(tmp_path):
    config = default_config()
    config["slaves"][0]["type"] = "servo"
    h = EmulatorHarness(config, workdir=tmp_path)
    with pytest.raises(HarnessError, match="slaves\\[0\\].type"):
        h.start()
    assert h.process.poll() is not None
    assert not link_exists(h.master_interface) and not netns_exists(h.netns)


def test_two_harnesses_run_side_by_side(tmp_path):
    with EmulatorHarness(workdir=tmp_path / "a") as a, EmulatorHarness(workdir=tmp_path / "b") as b:
        assert a.master_interface != b.master_interface and a.netns != b.netns
        assert a.client.ping()["pid"] != b.client.ping()["pid"]
    assert not netns_exists(a.netns) and not netns_exists(b.netns)
