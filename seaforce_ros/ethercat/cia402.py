"""CiA 402 drive state machine, master side (no ROS, no pysoem).

:func:`state_of` decodes the statusword (0x6041); :class:`DriveSequencer` chooses the
controlword (0x6040) that walks a drive to *Operation enabled* for cyclic synchronous torque
(mode 10) -- shutdown, switch on, enable operation -- or back down, and performs a fault reset
(bit 7 low, then high, each held ``reset_cycles`` cycles: a drive that samples the
controlword slower than the cycle still sees the edge) only when asked.

The mode is part of the gate: *enable operation* is sent only while the drive shows mode 10
(0x6061, read every cycle when mapped, else what the master last read over CoE); a drive in
another mode is held in *Switched on*. Torque may be commanded only while
:attr:`DriveSequencer.torque_allowed` is true: Operation enabled and mode 10.
"""
from __future__ import annotations

import enum

MODE_CST = 10

CW_SHUTDOWN = 0x0006
CW_SWITCH_ON = 0x0007
CW_ENABLE_OPERATION = 0x000F
CW_DISABLE_VOLTAGE = 0x0000
CW_QUICK_STOP = 0x0002
CW_FAULT_RESET = 0x0080

SW_FAULT = 0x0008

#: CiA 402 / CiA 301 error codes (0x603F, emergencies) and what they mean: the common ones;
#: :func:`error_text` names the class of the others.
ERROR_CODES = {
    0x0000: 'no error',
    0x1000: 'generic error',
    0x2310: 'continuous over current',
    0x2320: 'short circuit',
    0x3110: 'mains over voltage',
    0x3210: 'DC link over voltage',
    0x3220: 'DC link under voltage',
    0x4210: 'excess temperature device',
    0x4310: 'excess temperature drive',
    0x5400: 'power section',
    0x5441: 'safe torque off (STO input)',
    0x6010: 'software reset (watchdog)',
    0x7121: 'motor blocked',
    0x7300: 'sensor',
    0x7305: 'incremental sensor 1 fault',
    0x8130: 'life guard or heartbeat error',
    0x8400: 'velocity speed controller',
    0x8611: 'following error',
    0x8612: 'reference limit',
    0x8700: 'sync controller (process data or SYNC missing)',
    0xFF00: 'manufacturer specific',
}
_CLASSES = {0x1: 'generic', 0x2: 'current', 0x3: 'voltage', 0x4: 'temperature',
            0x5: 'device hardware', 0x6: 'device software', 0x7: 'additional modules',
            0x8: 'monitoring', 0x9: 'external error', 0xF: 'additional functions'}


def error_text(code: int) -> str:
    """``0x2310 (continuous over current)``."""
    text = ERROR_CODES.get(code)
    if text is None:
        text = (('manufacturer specific' if code >= 0xFF00 else
                 _CLASSES.get(code >> 12, 'unknown class')) + ' error')
    return f'0x{code:04X} ({text})'


class DriveState(enum.Enum):
    NOT_READY = 'not ready to switch on'
    SWITCH_ON_DISABLED = 'switch on disabled'
    READY_TO_SWITCH_ON = 'ready to switch on'
    SWITCHED_ON = 'switched on'
    OPERATION_ENABLED = 'operation enabled'
    QUICK_STOP_ACTIVE = 'quick stop active'
    FAULT_REACTION_ACTIVE = 'fault reaction active'
    FAULT = 'fault'


def state_of(statusword: int) -> DriveState:
    """Decode a statusword (CiA 402 patterns over bits 0-3, 5, 6)."""
    sw = statusword & 0x006F
    if sw & 0x004F == 0x0000:
        return DriveState.NOT_READY
    if sw & 0x004F == 0x0040:
        return DriveState.SWITCH_ON_DISABLED
    if sw == 0x0021:
        return DriveState.READY_TO_SWITCH_ON
    if sw == 0x0023:
        return DriveState.SWITCHED_ON
    if sw == 0x0027:
        return DriveState.OPERATION_ENABLED
    if sw == 0x0007:
        return DriveState.QUICK_STOP_ACTIVE
    if sw & 0x004F == 0x000F:
        return DriveState.FAULT_REACTION_ACTIVE
    if sw & 0x004F == 0x0008:
        return DriveState.FAULT
    return DriveState.NOT_READY


class DriveSequencer:
    """Per-drive controlword logic, called once per cycle with the newest statusword and
    mode display.

    ``enable`` (bool) says whether the drive should be in Operation enabled. A fault is never
    reset automatically: :meth:`request_fault_reset` sends bit 7 low for ``reset_cycles``
    cycles, then high for as many (the rising edge), then low again.

    Parameters
    ----------
    reset_cycles : int >= 1
        Cycles each half of the fault-reset pulse is held.
    """

    def __init__(self, reset_cycles: int = 1) -> None:
        self.enable = False
        self.state = DriveState.NOT_READY
        self.mode_display = 0
        self.reset_cycles = max(1, int(reset_cycles))
        self._reset_left = 0       # cycles of the reset pulse left (low half, then high half)
        self.held_for_mode = False  # switched on, waiting for mode 10 to enable operation

    def request_fault_reset(self) -> None:
        self._reset_left = 2 * self.reset_cycles

    @property
    def resetting(self) -> bool:
        return self._reset_left > 0

    @property
    def torque_allowed(self) -> bool:
        return self.state is DriveState.OPERATION_ENABLED and self.mode_display == MODE_CST

    @property
    def faulted(self) -> bool:
        return self.state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE)

    def controlword(self, statusword: int, mode_display: int) -> int:
        """The controlword for this cycle."""
        self.state = state = state_of(statusword)
        self.mode_display = mode_display
        self.held_for_mode = False
        if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            if self._reset_left > 0:
                self._reset_left -= 1
                return CW_FAULT_RESET if self._reset_left < self.reset_cycles else \
                    CW_DISABLE_VOLTAGE
            return CW_DISABLE_VOLTAGE
        self._reset_left = 0
        if not self.enable:
            if state is DriveState.OPERATION_ENABLED:
                return CW_SWITCH_ON            # disable operation (5)
            return CW_DISABLE_VOLTAGE          # -> switch on disabled (7, 9, 10, 12)
        if state is DriveState.SWITCH_ON_DISABLED:
            return CW_SHUTDOWN                 # (2)
        if state is DriveState.READY_TO_SWITCH_ON:
            return CW_SWITCH_ON                # (3)
        if state is DriveState.SWITCHED_ON:
            if mode_display != MODE_CST:       # never enable in another mode
                self.held_for_mode = True
                return CW_SWITCH_ON
            return CW_ENABLE_OPERATION         # (4)
        if state is DriveState.OPERATION_ENABLED:
            if mode_display != MODE_CST:       # the mode changed under us: disable operation
                self.held_for_mode = True
                return CW_SWITCH_ON            # (5)
            return CW_ENABLE_OPERATION         # stay
        if state is DriveState.QUICK_STOP_ACTIVE:
            return CW_DISABLE_VOLTAGE          # (12): leave quick stop through disabled
        return CW_DISABLE_VOLTAGE
