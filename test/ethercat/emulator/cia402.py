"""CiA 402 drive without mailbox, PDOs from the SII (as SOEM's config_map reads them).

Process image (fixed mapping, from the SII):

RxPDO 0x1600 on SM2 (phys 0x1100, 5 bytes, control 0x64 = 3-buffer, master writes,
watchdog trigger):

====== ======= ===== =========================================================
offset object  type  meaning
====== ======= ===== =========================================================
0      0x6040  u16   controlword
2      0x6071  i16   target torque [per-mille of rated torque 0x6076]
4      0x6060  i8    modes of operation (10 = cyclic synchronous torque)
====== ======= ===== =========================================================

TxPDO 0x1A00 on SM3 (phys 0x1180, 13 bytes, control 0x20):

====== ======= ===== =========================================================
offset object  type  meaning
====== ======= ===== =========================================================
0      0x6041  u16   statusword
2      0x6064  i32   position actual [encoder counts]
6      0x606C  i32   velocity actual [counts/s]
10     0x6077  i16   torque actual [per-mille of rated torque]
12     0x6061  i8    modes of operation display
====== ======= ===== =========================================================

State machine: the CiA 402 power state machine (start-up -> Switch on disabled;
shutdown 0x06, switch on 0x07, enable operation 0x0F (also straight from Ready to switch
on), disable operation, disable voltage, quick stop, fault reset on the rising edge of
bit 7).  Quick stop active holds zero torque until disable voltage (-> Switch on
disabled) or enable operation (-> Operation enabled, transition 16).  Fault reaction
active lasts one cycle, then Fault.  Controlwords are evaluated only from process data
written while the slave is in AL OP.

Torque is applied only in Operation enabled with modes display 10 and AL OP; anything
else applies 0 N m.  Torque is clamped to +-max_torque_permille (statusword bit 11
"internal limit active" while clamped).

Faults: injected through the side channel (optionally latched: fault reset is refused
until cleared), the process-data watchdog (100 ms without SM2 writes in OP), and leaving
AL OP while the power stage is on (Switched on, Operation enabled, Quick stop active).
"""

import struct

from .esc import EscSlave, OP
from .sii import (Identity, Pdo, PdoEntry, SiiSpec, SyncManagerSpec, DT_INT8, DT_INT16,
                  DT_INT32, DT_UINT16, SM_TYPE_INPUTS, SM_TYPE_OUTPUTS, SM_TYPE_UNUSED)

TWO_PI = 6.283185307179586

# states
NOT_READY = "not_ready_to_switch_on"
SWITCH_ON_DISABLED = "switch_on_disabled"
READY_TO_SWITCH_ON = "ready_to_switch_on"
SWITCHED_ON = "switched_on"
OPERATION_ENABLED = "operation_enabled"
QUICK_STOP_ACTIVE = "quick_stop_active"
FAULT_REACTION_ACTIVE = "fault_reaction_active"
FAULT = "fault"

#: statusword bits 0-6 of each state (bit 4 voltage enabled and bit 9 remote are always set)
STATUSWORD = {
    NOT_READY: 0x0000,
    SWITCH_ON_DISABLED: 0x0040,
    READY_TO_SWITCH_ON: 0x0021,
    SWITCHED_ON: 0x0023,
    OPERATION_ENABLED: 0x0027,
    QUICK_STOP_ACTIVE: 0x0007,
    FAULT_REACTION_ACTIVE: 0x000F,
    FAULT: 0x0008,
}
SW_VOLTAGE_ENABLED = 0x0010
SW_REMOTE = 0x0200
SW_INTERNAL_LIMIT = 0x0800
SW_FOLLOWING_TARGET = 0x1000     # CST: drive follows the target torque

CW_FAULT_RESET = 0x0080
MODE_CST = 10
SUPPORTED_MODES = (8, 9, 10)
POWERED = (SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE)

RX_SM, TX_SM = 2, 3
RX_START, TX_START = 0x1100, 0x1180
RX_FORMAT = struct.Struct("<Hhb")      # controlword, target torque, modes of operation
TX_FORMAT = struct.Struct("<Hiihb")    # statusword, position, velocity, torque, modes display

DEFAULT_IDENTITY = Identity(vendor_id=0x00005EA0, product_code=0x00000402,
                            revision=0x00010000, serial=1)


def decode_command(controlword):
    """Name of the CiA 402 device-control command in ``controlword`` (bits 7, 3-0)."""
    if controlword & 0x0082 == 0x0000:
        return "disable_voltage"
    if controlword & 0x0086 == 0x0002:
        return "quick_stop"
    if controlword & 0x0087 == 0x0006:
        return "shutdown"
    if controlword & 0x008F == 0x0007:
        return "switch_on"          # also "disable operation" in Operation enabled
    if controlword & 0x008F == 0x000F:
        return "enable_operation"
    return "none"


class Cia402StateMachine:
    """The power state machine of one axis (no I/O)."""

    def __init__(self):
        self.state = SWITCH_ON_DISABLED       # transitions 0 and 1 happen at power-up
        self.fault_code = 0
        self.fault_reason = ""
        self.fault_latched = False
        self._last_cw = 0
        self.transitions = 0

    def _go(self, state):
        if state != self.state:
            self.state = state
            self.transitions += 1

    def fault(self, code, reason, latched=False):
        """Enter Fault reaction active (unless already faulted)."""
        self.fault_latched = self.fault_latched or latched
        if self.state in (FAULT, FAULT_REACTION_ACTIVE):
            return
        self.fault_code = code
        self.fault_reason = reason
        self._go(FAULT_REACTION_ACTIVE)

    def clear_latch(self):
        self.fault_latched = False

    def tick(self):
        """Automatic transitions (Fault reaction active -> Fault, transition 14)."""
        if self.state == FAULT_REACTION_ACTIVE:
            self._go(FAULT)

    def update(self, controlword):
        """Apply ``controlword`` (one cycle of fresh process data)."""
        self.tick()
        rising_reset = controlword & CW_FAULT_RESET and not self._last_cw & CW_FAULT_RESET
        self._last_cw = controlword
        s = self.state
        if s == FAULT:
            if rising_reset and not self.fault_latched:
                self.fault_code = 0
                self.fault_reason = ""
                self._go(SWITCH_ON_DISABLED)                    # 15
            return
        if controlword & CW_FAULT_RESET:
            return                   # bit 7 set outside Fault: no command (CiA 402 table)
        cmd = decode_command(controlword)
        if s == SWITCH_ON_DISABLED:
            if cmd == "shutdown":
                self._go(READY_TO_SWITCH_ON)                    # 2
        elif s == READY_TO_SWITCH_ON:
            if cmd == "switch_on":
                self._go(SWITCHED_ON)                           # 3
            elif cmd == "enable_operation":
                self._go(OPERATION_ENABLED)                     # 3 + 4
            elif cmd in ("disable_voltage", "quick_stop"):
                self._go(SWITCH_ON_DISABLED)                    # 7
        elif s == SWITCHED_ON:
            if cmd == "enable_operation":
                self._go(OPERATION_ENABLED)                     # 4
            elif cmd == "shutdown":
                self._go(READY_TO_SWITCH_ON)                    # 6
            elif cmd in ("disable_voltage", "quick_stop"):
                self._go(SWITCH_ON_DISABLED)                    # 10
        elif s == OPERATION_ENABLED:
            if cmd == "switch_on":
                self._go(SWITCHED_ON)                           # 5
            elif cmd == "shutdown":
                self._go(READY_TO_SWITCH_ON)                    # 8
            elif cmd == "disable_voltage":
                self._go(SWITCH_ON_DISABLED)                    # 9
            elif cmd == "quick_stop":
                self._go(QUICK_STOP_ACTIVE)                     # 11
        elif s == QUICK_STOP_ACTIVE:
            if cmd == "disable_voltage":
                self._go(SWITCH_ON_DISABLED)                    # 12
            elif cmd == "enable_operation":
                self._go(OPERATION_ENABLED)                     # 16

    def statusword(self):
        return STATUSWORD[self.state] | SW_VOLTAGE_ENABLED | SW_REMOTE


def drive_sii_spec(identity=DEFAULT_IDENTITY, name="SEAforce CiA402 drive (emulated)"):
    """SII of the drive: no mailbox, SM0/SM1 unused (start 0), SM2 outputs, SM3 inputs."""
    rx = Pdo(0x1600, RX_SM, (
        PdoEntry(0x6040, 0, 16, DT_UINT16, "Controlword"),
        PdoEntry(0x6071, 0, 16, DT_INT16, "Target torque"),
        PdoEntry(0x6060, 0, 8, DT_INT8, "Modes of operation"),
    ), "RxPDO 1")
    tx = Pdo(0x1A00, TX_SM, (
        PdoEntry(0x6041, 0, 16, DT_UINT16, "Statusword"),
        PdoEntry(0x6064, 0, 32, DT_INT32, "Position actual value"),
        PdoEntry(0x606C, 0, 32, DT_INT32, "Velocity actual value"),
        PdoEntry(0x6077, 0, 16, DT_INT16, "Torque actual value"),
        PdoEntry(0x6061, 0, 8, DT_INT8, "Modes of operation display"),
    ), "TxPDO 1")
    sms = [SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED),
           SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED),
           SyncManagerSpec(RX_START, 0, 0x64, 1, SM_TYPE_OUTPUTS),
           SyncManagerSpec(TX_START, 0, 0x20, 1, SM_TYPE_INPUTS)]
    return SiiSpec(identity=identity, name=name, sync_managers=sms, fmmus=[1, 2],
                   rx_pdos=[rx], tx_pdos=[tx], group="Drives")


class Cia402Drive(EscSlave):
    """A cyclic-synchronous-torque drive on one physics channel.

    Parameters
    ----------
    channel : str
        Physics channel whose motor this drive powers.
    rated_torque : float > 0
        0x6076 [N m]: 1000 per-mille.  Default 0.5 N m (1 unit = 0.5 mN m).
    counts_per_rev : int > 0
        Encoder resolution [counts/rev] (default 2**20), gear ratio 1.
    max_torque_permille : int
        Clamp of the target torque (default 32767, the i16 range).
    """

    kind = "cia402_drive"

    def __init__(self, name, channel, identity=DEFAULT_IDENTITY, rated_torque=0.5,
                 counts_per_rev=2 ** 20, max_torque_permille=32767, **kwargs):
        if not rated_torque > 0:
            raise ValueError("rated_torque must be > 0 N m, got %r" % (rated_torque,))
        if int(counts_per_rev) <= 0:
            raise ValueError("counts_per_rev must be > 0, got %r" % (counts_per_rev,))
        super().__init__(name, drive_sii_spec(identity), **kwargs)
        self.channel = channel
        self.rated_torque = float(rated_torque)
        self.counts_per_rev = int(counts_per_rev)
        self.max_torque_permille = int(max_torque_permille)
        self.sm402 = Cia402StateMachine()
        self.controlword = 0
        self.target_torque = 0           # per-mille, as received
        self.mode_command = 0
        self.mode_display = 0
        self.limited = False
        self.applied_permille = 0        # torque applied this cycle [per-mille]
        self.cycles_enabled = 0

    # --- application ---------------------------------------------------------------------------
    def torque_enabled(self):
        return (self.al_state == OP and self.sm402.state == OPERATION_ENABLED
                and self.mode_display == MODE_CST)

    def process_outputs(self):
        fresh = self.outputs_fresh
        self.outputs_fresh = False
        self.sm402.tick()
        if self.al_state == OP and fresh:
            cw, tt, mode = RX_FORMAT.unpack_from(self.mem, RX_START)
            self.controlword, self.target_torque, self.mode_command = cw, tt, mode
            if mode in SUPPORTED_MODES:
                self.mode_display = mode
            self.sm402.update(cw)
        if self.torque_enabled():
            lim = self.max_torque_permille
            tt = self.target_torque
            self.limited = tt > lim or tt < -lim
            self.applied_permille = lim if tt > lim else (-lim if tt < -lim else tt)
            self.cycles_enabled += 1
        else:
            self.limited = False
            self.applied_permille = 0

    def torque_command(self):
        """Torque [N m] the drive applies during the next physics step."""
        return self.applied_permille * 1e-3 * self.rated_torque

    def statusword(self):
        sw = self.sm402.statusword()
        if self.limited:
            sw |= SW_INTERNAL_LIMIT
        if self.sm402.state == OPERATION_ENABLED and self.mode_display == MODE_CST:
            sw |= SW_FOLLOWING_TARGET
        return sw

    def update_inputs(self, physics):
        m = physics.channel(self.channel).measurement
        scale = self.counts_per_rev / TWO_PI
        pos = int(round(m.x * scale))
        pos = ((pos + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        vel = int(round(m.v * scale))
        vel = max(-0x80000000, min(0x7FFFFFFF, vel))
        TX_FORMAT.pack_into(self.mem, TX_START, self.statusword(), pos, vel,
                            self.applied_permille, self.mode_display)

    def refresh_inputs(self):
        """Rewrite the statusword (after a state change without a physics step)."""
        struct.pack_into("<H", self.mem, TX_START, self.statusword())
        struct.pack_into("<h", self.mem, TX_START + 10, self.applied_permille)

    def tick(self, now):
        if self.sm402.state == FAULT_REACTION_ACTIVE:
            self.sm402.tick()
            self.refresh_inputs()

    # --- faults --------------------------------------------------------------------------------
    def inject_fault(self, code=0x5400, reason="injected", latched=False):
        """Drive fault (default error code 0x5400 power section)."""
        self.sm402.fault(code, reason, latched)
        self.applied_permille = 0
        self.refresh_inputs()

    def clear_fault(self):
        self.sm402.clear_latch()

    def on_state_change(self, old, new):
        if old == OP and new != OP:
            if self.sm402.state in POWERED:
                self.sm402.fault(0x8700, "AL left OP with the power stage on")
            self.applied_permille = 0
            self.refresh_inputs()

    def on_watchdog_expired(self):
        if self.sm402.state in POWERED:
            self.sm402.fault(0x8700, "process-data watchdog expired")
        self.applied_permille = 0
        self.refresh_inputs()

    def status(self):
        st = super().status()
        st.update({
            "channel": self.channel,
            "cia402_state": self.sm402.state,
            "statusword": self.statusword(),
            "controlword": self.controlword,
            "target_torque": self.target_torque,
            "mode_command": self.mode_command,
            "mode_display": self.mode_display,
            "torque_enabled": self.torque_enabled(),
            "torque_applied": self.applied_permille != 0,
            "applied_torque_permille": self.applied_permille,
            "applied_torque": self.torque_command(),
            "fault_code": self.sm402.fault_code,
            "fault_reason": self.sm402.fault_reason,
            "fault_latched": self.sm402.fault_latched,
            "rated_torque": self.rated_torque,
            "counts_per_rev": self.counts_per_rev,
            "cycles_enabled": self.cycles_enabled,
        })
        return st
