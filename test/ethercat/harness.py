"""Run the EtherCAT slave emulator on a veth pair for a test or a benchmark.

:class:`EmulatorHarness` creates (names unique per process and instance)

* a network namespace ``sfecat-<pid>-<n>``,
* a veth pair: master end ``ecm<pid>x<n>`` in the root namespace (what pysoem opens),
  slave end ``ecs<pid>x<n>`` created directly inside the namespace, both up,
* the emulator process ``ip netns exec <ns> python -m ethercat.emulator ...`` (its own
  session; ``ip netns exec`` execs, so the PID is the emulator's),

waits until the control socket answers, and :meth:`stop` undoes all of it in reverse
order even when something failed: side-channel ``shutdown``, SIGTERM then SIGKILL by PID,
``ip link del`` of the master end (removes the pair), ``ip netns del``.  Nothing else on
the host is touched.  Requires root (CAP_NET_ADMIN, CAP_NET_RAW).
"""

import atexit
import itertools
import json
import os
import pathlib
import signal
import subprocess
import sys
import tempfile
import time

from ethercat.emulator.client import EmulatorClient
from ethercat.emulator.config import default_config

TEST_DIR = pathlib.Path(__file__).resolve().parent.parent      # .../test
ROOT = TEST_DIR.parent
_counter = itertools.count()
_running = set()          # harnesses started and not yet stopped (atexit safety net)


@atexit.register
def _stop_leftovers():
    for harness in list(_running):
        harness.stop()


class HarnessError(RuntimeError):
    """The veth pair, namespace or emulator process could not be set up."""


def _ip(*args, check=True):
    proc = subprocess.run(("ip",) + args, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                          text=True, timeout=10)
    if check and proc.returncode != 0:
        raise HarnessError("ip %s failed: %s" % (" ".join(args), proc.stderr.strip()))
    return proc


class EmulatorHarness:
    """One emulator on its own veth pair.

    Parameters
    ----------
    config : dict, optional
        Emulator configuration (:mod:`ethercat.emulator.config`); default: wrist drive,
        pinch drive, pressure terminal.
    workdir : path, optional
        Where the config, control socket and log go (default: a new temporary directory).
    python : str
        Interpreter for the emulator (default: this one).
    realtime : int
        SCHED_FIFO priority of the emulator process (0, the default: normal scheduling).

    Attributes
    ----------
    master_interface : str
        The interface pysoem opens (root namespace).
    slave_interface, netns : str
    control_path : pathlib.Path
    pid : int or None
        Emulator process id.
    client : EmulatorClient
        Side channel (connected after :meth:`start`).
    log_path : pathlib.Path
    """

    def __init__(self, config=None, workdir=None, python=sys.executable, realtime=0):
        n = next(_counter)
        pid = os.getpid()
        self.config = default_config() if config is None else config
        self.netns = "sfecat-%d-%d" % (pid, n)
        self.master_interface = "ecm%dx%d" % (pid, n)
        self.slave_interface = "ecs%dx%d" % (pid, n)
        if len(self.master_interface) > 15:
            raise HarnessError("interface name %r too long" % self.master_interface)
        self._tmp = None
        if workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="sfecat-")
            workdir = self._tmp.name
        self.workdir = pathlib.Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.control_path = self.workdir / ("emulator-%d-%d.sock" % (pid, n))
        self.config_path = self.workdir / ("emulator-%d-%d.json" % (pid, n))
        self.log_path = self.workdir / ("emulator-%d-%d.log" % (pid, n))
        self.python = python
        self.realtime = int(realtime)
        self.process = None
        self.client = None
        self._netns_created = False
        self._link_created = False

    @property
    def pid(self):
        return None if self.process is None else self.process.pid

    # --- set-up ----------------------------------------------------------------------------------
    def start(self, timeout=20.0):
        """Create namespace + veth pair, start the emulator, wait for its side channel."""
        _running.add(self)
        try:
            self._create_network()
            self._start_process()
            self._wait_ready(timeout)
        except BaseException:
            self.stop()
            raise
        return self

    def _create_network(self):
        _ip("netns", "add", self.netns)
        self._netns_created = True
        _ip("link", "add", self.master_interface, "type", "veth", "peer", "name",
            self.slave_interface, "netns", self.netns)
        self._link_created = True
        for iface in (self.master_interface,):
            self._disable_ipv6(iface, None)
        self._disable_ipv6(self.slave_interface, self.netns)
        _ip("link", "set", self.master_interface, "up")
        _ip("-n", self.netns, "link", "set", self.slave_interface, "up")

    @staticmethod
    def _disable_ipv6(iface, netns):
        """Keep IPv6 neighbour discovery noise off our own veth ends (best effort)."""
        cmd = ["sysctl", "-q", "-w", "net.ipv6.conf.%s.disable_ipv6=1" % iface]
        if netns:
            cmd = ["ip", "netns", "exec", netns] + cmd
        subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=10)

    def _start_process(self):
        self.config_path.write_text(json.dumps(self.config, indent=1))
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(
            [str(TEST_DIR)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
        env["PYTHONUNBUFFERED"] = "1"
        argv = ["ip", "netns", "exec", self.netns, self.python, "-m", "ethercat.emulator",
                "--interface", self.slave_interface, "--control", str(self.control_path),
                "--config", str(self.config_path)]
        if self.realtime:
            argv += ["--realtime", str(self.realtime)]
        self._log = open(self.log_path, "wb")
        self.process = subprocess.Popen(argv, stdout=self._log, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, env=env, cwd=str(ROOT),
                                        start_new_session=True)

    def _wait_ready(self, timeout):
        deadline = time.monotonic() + timeout
        while True:
            if self.process.poll() is not None:
                raise HarnessError("emulator exited with %s before it was ready:\n%s"
                                   % (self.process.returncode, self.log()))
            if self.control_path.exists():
                try:
                    self.client = EmulatorClient(self.control_path).connect()
                    self.client.ping()
                    return
                except OSError:
                    if self.client is not None:
                        self.client.close()
                    self.client = None
            if time.monotonic() > deadline:
                raise HarnessError("emulator not ready after %.0f s:\n%s" % (timeout, self.log()))
            time.sleep(0.02)

    def log(self):
        """The emulator's output so far."""
        try:
            return self.log_path.read_text(errors="replace")
        except OSError:
            return ""

    # --- tear-down ----------------------------------------------------------------------------------
    def stop(self):
        """Stop the emulator and delete the veth pair and the namespace (idempotent; every
        step runs even if an earlier one failed).  Returns the emulator's exit code."""
        code = None
        if self.client is not None:
            try:
                self.client.shutdown()
            except Exception:
                pass
            self.client.close()
            self.client = None
        if self.process is not None:
            try:
                code = self.process.wait(timeout=3.0)
            except subprocess.TimeoutExpired:
                try:
                    os.kill(self.process.pid, signal.SIGTERM)
                    code = self.process.wait(timeout=3.0)
                except (ProcessLookupError, subprocess.TimeoutExpired):
                    try:
                        os.kill(self.process.pid, signal.SIGKILL)
                    except ProcessLookupError:
                        pass
                    code = self.process.wait(timeout=5.0)
            self._log.close()
        if self._link_created:
            _ip("link", "del", self.master_interface, check=False)
            self._link_created = False
        if self._netns_created:
            _ip("netns", "del", self.netns, check=False)
            self._netns_created = False
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        _running.discard(self)
        if code is None and self.process is not None:
            code = self.process.returncode
        return code

    def __enter__(self):
        return self.start() if self.process is None else self

    def __exit__(self, *exc):
        self.stop()


def open_master(interface):
    """A ``pysoem.Master`` opened on ``interface`` (close it when done)."""
    import pysoem
    master = pysoem.Master()
    master.open(interface)
    return master
