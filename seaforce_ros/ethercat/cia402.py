"""CiA 402 drive state machine, master side (no ROS, no pysoem).

:func:`state_of` decodes the statusword (0x6041); :class:`DriveSequencer` chooses the
controlword (0x6040) that walks a drive to *Operation enabled* for cyclic synchronous torque
(mode 10) — shutdown, switch on, enable operation — or back down, and performs a fault reset
(a rising edge of bit 7) only when asked. Torque may be commanded only while
:attr:`DriveSequencer.torque_allowed` is true (Operation enabled and mode display = 10).
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
    """Per-drive controlword logic, called once per cycle with the newest statusword.

    ``enable`` (bool) says whether the drive should be in Operation enabled. A fault is never
    reset automatically: :meth:`request_fault_reset` sends one rising edge of bit 7.
    """

    def __init__(self):
        self.enable = False
        self.state = DriveState.NOT_READY
        self.mode_display = 0
        self._reset_phase = 0     # 0 idle, 1 send bit 7 low, 2 send bit 7 high

    def request_fault_reset(self) -> None:
        self._reset_phase = 1

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
        if state in (DriveState.FAULT, DriveState.FAULT_REACTION_ACTIVE):
            if self._reset_phase == 1:
                self._reset_phase = 2
                return CW_DISABLE_VOLTAGE
            if self._reset_phase == 2:
                self._reset_phase = 0
                return CW_FAULT_RESET
            return CW_DISABLE_VOLTAGE
        self._reset_phase = 0
        if not self.enable:
            if state is DriveState.OPERATION_ENABLED:
                return CW_SWITCH_ON            # disable operation (5)
            return CW_DISABLE_VOLTAGE          # -> switch on disabled (7, 9, 10, 12)
        if state is DriveState.SWITCH_ON_DISABLED:
            return CW_SHUTDOWN                 # (2)
        if state is DriveState.READY_TO_SWITCH_ON:
            return CW_SWITCH_ON                # (3)
        if state in (DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED):
            return CW_ENABLE_OPERATION         # (4) / stay
        if state is DriveState.QUICK_STOP_ACTIVE:
            return CW_DISABLE_VOLTAGE          # (12): leave quick stop through disabled
        return CW_DISABLE_VOLTAGE
