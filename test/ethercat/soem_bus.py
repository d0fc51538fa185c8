"""Master side for the emulator tests and benchmarks: pysoem plus the documented PDO
layouts (written from README.md, independently of the emulator's code).

Drive outputs (5 bytes): controlword u16, target torque i16 [per-mille], mode i8.
Drive inputs (13 bytes): statusword u16, position i32 [counts], velocity i32 [counts/s],
torque i16 [per-mille], mode display i8.
Analog terminal inputs (8 bytes): per channel status u16, value i16.
"""

import struct
import time
from collections import namedtuple

import pysoem

DRIVE_OUT = struct.Struct("<Hhb")
DRIVE_IN = struct.Struct("<Hiihb")
AI_CHANNEL = struct.Struct("<Hh")

DriveInputs = namedtuple("DriveInputs", "statusword position velocity torque mode")

CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_FAULT_RESET = 0x0080
MODE_CST = 10
# The process-data period: 2 kHz, the hardware node's rate and the emulator's default
# cycle_time (one 0.5 ms plant step per frame).
CYCLE_PERIOD = 0.0005


def cia402_state(statusword):
    """CiA 402 state name from a statusword (CiA 402's state patterns)."""
    sw = statusword
    if sw & 0x4F == 0x00:
        return "not_ready_to_switch_on"
    if sw & 0x4F == 0x40:
        return "switch_on_disabled"
    if sw & 0x6F == 0x21:
        return "ready_to_switch_on"
    if sw & 0x6F == 0x23:
        return "switched_on"
    if sw & 0x6F == 0x27:
        return "operation_enabled"
    if sw & 0x6F == 0x07:
        return "quick_stop_active"
    if sw & 0x4F == 0x0F:
        return "fault_reaction_active"
    if sw & 0x4F == 0x08:
        return "fault"
    return "unknown(0x%04X)" % sw


class SoemBus:
    """A pysoem master with helpers for the default emulated bus.

    :meth:`cycle` paces the process data at :attr:`period` (default 2 kHz) with absolute
    deadlines, as a hardware master does; ``period = 0`` sends back to back."""

    def __init__(self, master, period=CYCLE_PERIOD):
        self.master = master
        self.slaves = []
        self.iomap_size = None
        self.drives = []          # slave indexes with 5-byte outputs
        self.receive_timeout_us = 100000
        self.period = period
        self._deadline = None     # start of the next cycle (time.monotonic())

    def configure(self):
        """config_init + config_map; returns (slave count, IOmap size)."""
        n = self.master.config_init()
        self.slaves = list(self.master.slaves) if n > 0 else []
        self.iomap_size = self.master.config_map() if n > 0 else 0
        self.drives = [i for i, s in enumerate(self.slaves) if len(s.output) == DRIVE_OUT.size]
        return n, self.iomap_size

    def request_state(self, state, timeout_us=500000):
        self.master.state = state
        self.master.write_state()
        return self.master.state_check(state & 0x0F, timeout_us)

    def bring_up(self):
        """Configure and go to OP; returns the state reached."""
        self.configure()
        if self.master.state_check(pysoem.SAFEOP_STATE, 500000) != pysoem.SAFEOP_STATE:
            return self.master.read_state()
        self.cycle()
        return self.request_state(pysoem.OP_STATE)

    def set_drive(self, i, controlword, torque=0, mode=MODE_CST):
        self.slaves[i].output = DRIVE_OUT.pack(controlword, torque, mode)

    def drive(self, i):
        return DriveInputs(*DRIVE_IN.unpack(self.slaves[i].input[:DRIVE_IN.size]))

    def analog(self, i):
        data = self.slaves[i].input
        return [AI_CHANNEL.unpack_from(data, 4 * k) for k in range(2)]

    def cycle(self, n=1, timeout_us=None):
        """``n`` send/receive cycles, one per :attr:`period`; returns the working counters.

        Cycle k starts at the previous cycle's start + ``period``; a cycle that would start
        more than a period late starts now instead (no catch-up burst), and so does the
        first cycle after a pause of the master (a test's own work between calls).
        ``timeout_us`` defaults to :attr:`receive_timeout_us` (100 ms: the tests check
        correctness, not timing, and the emulator shares a loaded host)."""
        if timeout_us is None:
            timeout_us = self.receive_timeout_us
        wkcs = []
        m = self.master
        period = self.period
        for _ in range(n):
            if period:
                now = time.monotonic()
                deadline = self._deadline
                if deadline is None or now > deadline + period:
                    deadline = now
                elif deadline > now:
                    time.sleep(deadline - now)
                self._deadline = deadline + period
            m.send_processdata()
            wkcs.append(m.receive_processdata(timeout_us))
        return wkcs

    def command(self, i, controlword, torque=0, mode=MODE_CST, cycles=3):
        """Send ``controlword`` for ``cycles`` cycles; returns the drive's inputs."""
        self.set_drive(i, controlword, torque, mode)
        self.cycle(cycles)
        return self.drive(i)

    def enable(self, i, torque=0):
        """shutdown -> switch on -> enable operation; returns the states seen."""
        seen = []
        for cw in (CW_SHUTDOWN, CW_SWITCH_ON, CW_ENABLE_OPERATION):
            seen.append(cia402_state(self.command(i, cw, torque if cw == CW_ENABLE_OPERATION
                                                  else 0).statusword))
        return seen
