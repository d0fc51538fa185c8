"""CiA 402 servo drive with a CoE mailbox, an object dictionary and the PDO mapping it holds.

Written from CiA 402 (drive profile: power state machine, modes, objects 0x6040-0x60FF),
CiA 301 / ETG.1000.6 (object dictionary, PDO mapping and assignment, emergencies), ETG.1020
(0x1C32/0x1C33 synchronisation objects, 0x10F1 sync error limit) and the AL status codes of
ETG.1000.6 table 11 -- not from any master's code. What a :class:`DriveProfile` can make a
drive enforce, as real drives do:

* **mapping**: the process image is the one 0x1C12/0x1C13 assign and 0x16xx/0x1Axx map when
  the drive goes to SAFE-OP (a default mapping, say one with target position and no target
  torque, stays until a master writes another at PRE-OP); SM2/SM3 must be programmed with
  exactly its lengths (AL 0x001D/0x001E);
* **mode**: 0x6060 written by SDO or PDO, shown in 0x6061 at once if the mode is supported
  (8 CSP, 9 CSV, 10 CST; 0 none). The drive follows the mode it is in: CST applies target
  torque 0x6071; CSP servos the motor to target position 0x607A (a drive left in CSP with
  0x607A = 0 moves to 0 when enabled); CSV to target velocity 0x60FF;
* **scaling**: 0x6071/0x6077 in per mille of 0x6076 (rated torque, mN m), clamped to 0x6072
  (max torque, per mille);
* **distributed clocks** (``requires_dc``): SAFE-OP -> OP refused with AL 0x0030 unless SYNC0
  runs at the required cycle; with SYNC0, every SYNC0 without fresh outputs since the last
  counts in 0x1C32:0B, two frames in one cycle in 0x1C32:0C, and beyond the sync error
  counter limit 0x10F1:02 (+3 per missed event, -1 per good one) the drive drops to SAFE-OP
  with AL 0x001A;
* **start-up objects** (``required``): SAFE-OP -> OP refused with AL 0x0035 unless they hold
  the values the drive needs (0x60C2, the interpolation time period = the cycle);
* **controlword sampling** (``controlword_period``): the state machine looks at 0x6040 only
  every so often (a fault-reset edge shorter than that is missed);
* **faults**: 0x603F holds the error code, 0x1001 the error register, an emergency message
  (CoE service 1) goes out through the mailbox on entering Fault and an error-reset one (code
  0) when the fault is reset.

Evidence for the tests, counted by the drive: ``unsafe_torque_frames`` -- outputs with a
non-zero target torque that arrived when the newest inputs the master had received did not
show *Operation enabled* in CST (what a master must never send), and ``enables_outside_cst``
-- entries into *Operation enabled* (in OP) in another mode than CST (``frames_outside_cst``
counts the frames spent so, whoever changed the mode).
"""

import struct
from dataclasses import dataclass, field, replace
from typing import Dict, Tuple

from . import coe as C
from .esc import (AL_CODE_INVALID_DC_SYNC_CONFIG, AL_CODE_INVALID_SYNC_CYCLE_TIME, AL_CODE_NONE,
                  AL_CODE_SYNC_ERROR, OP, PREOP, SAFEOP, EscSlave)
from .mailbox import MBX_COE, Mailbox
from .sii import (COE_COMPLETE_ACCESS, COE_PDO_ASSIGN, COE_PDO_CONFIG, COE_SDO, DT_INT8,
                  DT_INT16, DT_INT32, Identity, Pdo, PdoEntry,
                  SiiSpec, SyncManagerSpec, SM_TYPE_INPUTS, SM_TYPE_MBX_IN, SM_TYPE_MBX_OUT,
                  SM_TYPE_OUTPUTS, SM_TYPE_UNUSED)

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
SW_FOLLOWING_TARGET = 0x1000     # CSx: the drive follows the target

CW_FAULT_RESET = 0x0080
MODE_CSP, MODE_CSV, MODE_CST = 8, 9, 10
SUPPORTED_MODES = (0, MODE_CSP, MODE_CSV, MODE_CST)
POWERED = (SWITCHED_ON, OPERATION_ENABLED, QUICK_STOP_ACTIVE)

# process RAM
MBX_OUT_START, MBX_IN_START = 0x1000, 0x1080
RX_SM, TX_SM = 2, 3
RX_START, TX_START = 0x1100, 0x1180

#: fault codes (CiA 402 / CiA 301 error code table)
FAULT_WATCHDOG = 0x8700          # sync controller (process data stopped)
FAULT_LEFT_OP = 0x8700
FAULT_SYNC = 0x8700
FAULT_GENERIC = 0x1000

DEFAULT_IDENTITY = Identity(vendor_id=0x00005EA0, product_code=0x00000402,
                            revision=0x00010000, serial=1)

Mapping = Tuple[Tuple[int, int, int], ...]          # (index, subindex, bits)

#: the CST mapping the emulator's drives come with by default (the test YAML's order)
CST_RX: Mapping = ((0x6040, 0, 16), (0x6071, 0, 16), (0x6060, 0, 8))
CST_TX: Mapping = ((0x6041, 0, 16), (0x6064, 0, 32), (0x606C, 0, 32), (0x6077, 0, 16),
                   (0x6061, 0, 8))


@dataclass(frozen=True)
class DriveProfile:
    """What a drive model does at power-up and enforces (see the module docstring).

    rx, tx : {pdo index: mapping}
        The PDO mapping objects' contents at power-up (0x1600.. / 0x1A00..).
    rx_assign, tx_assign : tuple of int
        0x1C12 / 0x1C13 at power-up (empty: nothing assigned).
    initial_mode : int
        0x6060 (and 0x6061) at power-up.
    mailbox_size : int
        Bytes of each mailbox (0: no mailbox; the mapping then is the SII's, fixed).
    complete_access : bool
        The SII's CoE details announce SDO complete access (SOEM then reads the mapping so).
    sii_pdos : bool
        The SII lists the power-up mapping (an empty one lists nothing).
    dc : bool
        The ESC has distributed clocks.
    requires_dc : bool
        SAFE-OP -> OP needs SYNC0 running at ``sync0_cycle_ns`` (AL 0x0030).
    required : {(index, subindex): value}
        Objects that must hold these values for SAFE-OP -> OP (AL 0x0035).
    controlword_period : float
        The state machine looks at 0x6040 every this many seconds of drive time (0: every
        frame).
    rated_torque_mnm, max_torque_permille : int
        0x6076 [mN m], 0x6072 [per mille].
    sync_error_limit : int
        0x10F1:02 at power-up (0: no sync supervision).
    device_name : str
        0x1008 (and the SII name).
    product_code : int
        The default product code: another model, another code (SOEM copies the SII data of
        an earlier slave with the same identity instead of reading it).
    """

    name: str = "standard"
    product_code: int = 0x00000402
    rx: Dict[int, Mapping] = field(default_factory=lambda: {0x1600: CST_RX})
    tx: Dict[int, Mapping] = field(default_factory=lambda: {0x1A00: CST_TX})
    rx_assign: Tuple[int, ...] = (0x1600,)
    tx_assign: Tuple[int, ...] = (0x1A00,)
    initial_mode: int = 0
    mailbox_size: int = 128
    complete_access: bool = True
    sii_pdos: bool = True
    dc: bool = True
    requires_dc: bool = False
    sync0_cycle_ns: int = 500000
    required: Dict[Tuple[int, int], int] = field(default_factory=dict)
    controlword_period: float = 0.0
    rated_torque_mnm: int = 500
    max_torque_permille: int = 32767
    sync_error_limit: int = 4
    device_name: str = "SEAforce CiA402 drive (emulated)"


#: The profiles, each standing for a family of real drives (test/ethercat/README.md).
PROFILES = {
    # a CoE CST drive whose power-up mapping is already the CST one (no mode set yet)
    "standard": DriveProfile(),
    # default RxPDO with target position and digital outputs, no target torque; starts in CSP
    "elmo_like": DriveProfile(
        name="elmo_like", product_code=0x00001402,
        rx={0x1600: ((0x607A, 0, 32), (0x60FE, 1, 32), (0x6040, 0, 16)),
            0x1601: ((0x6071, 0, 16), (0x6060, 0, 8))},
        tx={0x1A00: ((0x6064, 0, 32), (0x60FD, 0, 32), (0x6041, 0, 16)),
            0x1A01: ((0x606C, 0, 32), (0x6077, 0, 16), (0x6061, 0, 8))},
        initial_mode=MODE_CSP, device_name="SEAforce CiA402 drive, CSP mapping (emulated)"),
    # nothing assigned, nothing mapped at power-up; a small mailbox (segmented transfers)
    "ingenia_like": DriveProfile(
        name="ingenia_like", product_code=0x00002402, rx={0x1600: (), 0x1601: ()}, tx={0x1A00: (), 0x1A01: ()},
        rx_assign=(), tx_assign=(), sii_pdos=False, mailbox_size=48, complete_access=False,
        device_name="SEAforce CiA402 drive with no default mapping (emulated)"),
    # starts in CSP with 0x607A = 0; its default mapping has neither 0x6060 nor 0x6061
    "csp_start": DriveProfile(
        name="csp_start", product_code=0x00003402,
        rx={0x1600: ((0x6040, 0, 16), (0x6071, 0, 16))},
        tx={0x1A00: ((0x6041, 0, 16), (0x6064, 0, 32), (0x606C, 0, 32), (0x6077, 0, 16))},
        initial_mode=MODE_CSP, device_name="SEAforce CiA402 drive in CSP (emulated)"),
    # refuses OP (AL 0x0030) unless SYNC0 runs at 0.5 ms
    "requires_dc": DriveProfile(name="requires_dc", product_code=0x00004402, requires_dc=True,
                                device_name="SEAforce CiA402 drive, DC only (emulated)"),
    # refuses OP (AL 0x0035) unless 0x60C2 (interpolation time period) is 0.5 ms
    "requires_60c2": DriveProfile(
        name="requires_60c2", product_code=0x00005402, required={(0x60C2, 1): 5, (0x60C2, 2): -4},
        device_name="SEAforce CiA402 drive needing 0x60C2 (emulated)"),
    # looks at the controlword every 2 ms
    "slow_controlword": DriveProfile(
        name="slow_controlword", product_code=0x00006402, controlword_period=0.002,
        device_name="SEAforce CiA402 drive, 2 ms controlword (emulated)"),
    # no mailbox: the fixed SII mapping, no CoE (the emulator's first drive)
    "no_mailbox": DriveProfile(name="no_mailbox", mailbox_size=0, dc=False,
                               device_name="SEAforce CiA402 drive (emulated)"),
}


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
        """Enter Fault reaction active (unless already faulted); True if it did."""
        self.fault_latched = self.fault_latched or latched
        if self.state in (FAULT, FAULT_REACTION_ACTIVE):
            return False
        self.fault_code = code
        self.fault_reason = reason
        self._go(FAULT_REACTION_ACTIVE)
        return True

    def clear_latch(self):
        self.fault_latched = False

    def tick(self):
        """Automatic transitions (Fault reaction active -> Fault, transition 14)."""
        if self.state == FAULT_REACTION_ACTIVE:
            self._go(FAULT)

    def update(self, controlword):
        """Apply ``controlword`` (one sample of it)."""
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


# --- the object dictionary ---------------------------------------------------------------
def _var(index, name, dtype, value=0, access=C.RO, pdo=None, **kw):
    return C.CoeObject(index, name, [C.Entry(0, name, dtype, value, access, pdo, **kw)])


def _record(index, name, entries, **kw):
    return C.CoeObject(index, name, entries, **kw)


def _mapping_object(index, name, mapping, slots=8):
    entries = [C.Entry(0, "number of entries", C.UNSIGNED8, len(mapping), C.RW_PREOP)]
    for s in range(1, slots + 1):
        v = mapping[s - 1] if s <= len(mapping) else (0, 0, 0)
        entries.append(C.Entry(s, "entry %d" % s, C.UNSIGNED32, (v[0] << 16) | (v[1] << 8) | v[2],
                               C.RW_PREOP))
    return C.CoeObject(index, name, entries, counted=True)


def _assign_object(index, name, pdos, slots=4):
    entries = [C.Entry(0, "number of PDOs", C.UNSIGNED8, len(pdos), C.RW_PREOP)]
    for s in range(1, slots + 1):
        entries.append(C.Entry(s, "PDO %d" % s, C.UNSIGNED16, pdos[s - 1] if s <= len(pdos) else 0,
                               C.RW_PREOP))
    return C.CoeObject(index, name, entries, counted=True)


def _sync_object(index, name, dc):
    E = C.Entry
    return _record(index, name, [
        E(0, "number of entries", C.UNSIGNED8, 0x20),
        E(1, "sync mode", C.UNSIGNED16, 0, C.RW_PREOP),
        E(2, "cycle time", C.UNSIGNED32, 0),
        E(3, "shift time", C.UNSIGNED32, 0),
        E(4, "sync modes supported", C.UNSIGNED16, 0x0005 if dc else 0x0001),
        E(5, "minimum cycle time", C.UNSIGNED32, 125000),
        E(6, "calc and copy time", C.UNSIGNED32, 20000),
        E(9, "delay time", C.UNSIGNED32, 0),
        E(0x0A, "sync0 cycle time", C.UNSIGNED32, 0),
        E(0x0B, "SM event missed", C.UNSIGNED16, 0),
        E(0x0C, "cycle time too small", C.UNSIGNED16, 0),
        E(0x0D, "shift time too short", C.UNSIGNED16, 0),
        E(0x20, "sync error", C.BOOLEAN, 0),
    ])


def drive_dictionary(profile, identity):
    """The object dictionary of a drive of ``profile`` at power-up."""
    RX, TX, E = "rx", "tx", C.Entry
    od = C.ObjectDictionary([
        _var(0x1000, "device type", C.UNSIGNED32, 0x00020192),
        _var(0x1001, "error register", C.UNSIGNED8, 0, pdo=TX),
        _var(0x1008, "manufacturer device name", C.VISIBLE_STRING, profile.device_name),
        _record(0x1018, "identity", [
            E(0, "number of entries", C.UNSIGNED8, 4),
            E(1, "vendor id", C.UNSIGNED32, identity.vendor_id),
            E(2, "product code", C.UNSIGNED32, identity.product_code),
            E(3, "revision", C.UNSIGNED32, identity.revision),
            E(4, "serial number", C.UNSIGNED32, identity.serial)]),
        _record(0x10F1, "error settings", [
            E(0, "number of entries", C.UNSIGNED8, 2),
            E(1, "local error reaction", C.UNSIGNED32, 1, C.RW),
            E(2, "sync error counter limit", C.UNSIGNED16, profile.sync_error_limit, C.RW)]),
        _record(0x1C00, "sync manager communication type", [
            E(0, "number of SMs", C.UNSIGNED8, 4),
            E(1, "SM0", C.UNSIGNED8, 1), E(2, "SM1", C.UNSIGNED8, 2),
            E(3, "SM2", C.UNSIGNED8, 3), E(4, "SM3", C.UNSIGNED8, 4)]),
        _assign_object(C.ASSIGN_RX, "RxPDO assign", profile.rx_assign),
        _assign_object(C.ASSIGN_TX, "TxPDO assign", profile.tx_assign),
        _sync_object(0x1C32, "SM output parameter", profile.dc),
        _sync_object(0x1C33, "SM input parameter", profile.dc),
        _var(0x603F, "error code", C.UNSIGNED16, 0, pdo=TX),
        _var(0x6040, "controlword", C.UNSIGNED16, 0, C.RW, RX),
        _var(0x6041, "statusword", C.UNSIGNED16, 0, pdo=TX),
        _var(0x6060, "modes of operation", C.INTEGER8, profile.initial_mode, C.RW, RX),
        _var(0x6061, "modes of operation display", C.INTEGER8, profile.initial_mode, pdo=TX),
        _var(0x6064, "position actual value", C.INTEGER32, 0, pdo=TX),
        _var(0x606C, "velocity actual value", C.INTEGER32, 0, pdo=TX),
        _var(0x6071, "target torque", C.INTEGER16, 0, C.RW, RX),
        _var(0x6072, "max torque", C.UNSIGNED16, profile.max_torque_permille, C.RW, RX),
        _var(0x6076, "motor rated torque", C.UNSIGNED32, profile.rated_torque_mnm, C.RW),
        _var(0x6077, "torque actual value", C.INTEGER16, 0, pdo=TX),
        _var(0x607A, "target position", C.INTEGER32, 0, C.RW, RX),
        _var(0x60B2, "torque offset", C.INTEGER16, 0, C.RW, RX),
        _record(0x60C2, "interpolation time period", [
            E(0, "highest subindex", C.UNSIGNED8, 2),
            E(1, "interpolation time period value", C.UNSIGNED8, 1, C.RW),
            E(2, "interpolation time index", C.INTEGER8, -3, C.RW, low=-6, high=0)]),
        _var(0x60FD, "digital inputs", C.UNSIGNED32, 0, pdo=TX),
        _record(0x60FE, "digital outputs", [
            E(0, "highest subindex", C.UNSIGNED8, 1),
            E(1, "physical outputs", C.UNSIGNED32, 0, C.RW, RX)]),
        _var(0x60FF, "target velocity", C.INTEGER32, 0, C.RW, RX),
        _var(0x6502, "supported drive modes", C.UNSIGNED32, 0x0380),
    ])
    for index, mapping in profile.rx.items():
        od.add(_mapping_object(index, "RxPDO %d mapping" % (index - 0x15FF), mapping))
    for index, mapping in profile.tx.items():
        od.add(_mapping_object(index, "TxPDO %d mapping" % (index - 0x19FF), mapping))
    return od


_FMT = {8: "b", 16: "h", 32: "i"}
_UFMT = {8: "B", 16: "H", 32: "I"}


def _layout(od, assign_index):
    """``(struct, [(index, sub)] or None per field, bytes)`` of what ``assign_index``
    assigns: one compiled format for the whole PDO image (gaps are pad bytes)."""
    fmt, keys = "<", []
    for pdo in od.assigned(assign_index):
        for index, sub, bits in od.mapping(pdo):
            if index == 0 or bits % 8:
                fmt += "x" * (bits // 8)
                continue
            entry = od.objects[index].entries[sub]
            signed = entry.dtype in (C.INTEGER8, C.INTEGER16, C.INTEGER32)
            fmt += (_FMT if signed else _UFMT)[bits]
            keys.append((index, sub))
    s = struct.Struct(fmt)
    return s, keys, s.size


def drive_sii_spec(identity=DEFAULT_IDENTITY, profile=PROFILES["standard"]):
    """SII of a drive: the mailbox (if any) on SM0/SM1, SM2 outputs, SM3 inputs, and the
    power-up mapping as PDO categories (unless the profile lists none)."""
    def pdos(mappings, assign, sm):
        out = []
        for index in assign:
            entries = tuple(PdoEntry(i, s, b, {8: DT_INT8, 16: DT_INT16, 32: DT_INT32}.get(b, 0),
                                     "0x%04X:%02X" % (i, s)) for i, s, b in mappings[index])
            out.append(Pdo(index, sm, entries, "PDO 0x%04X" % index))
        return out

    size = profile.mailbox_size
    if size:
        sms = [SyncManagerSpec(MBX_OUT_START, size, 0x26, 1, SM_TYPE_MBX_OUT),
               SyncManagerSpec(MBX_IN_START, size, 0x22, 1, SM_TYPE_MBX_IN)]
    else:
        sms = [SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED),
               SyncManagerSpec(0, 0, 0x00, 0, SM_TYPE_UNUSED)]
    sms += [SyncManagerSpec(RX_START, 0, 0x64, 1, SM_TYPE_OUTPUTS),
            SyncManagerSpec(TX_START, 0, 0x20, 1, SM_TYPE_INPUTS)]
    details = COE_SDO | COE_PDO_ASSIGN | COE_PDO_CONFIG | (
        COE_COMPLETE_ACCESS if profile.complete_access else 0)
    return SiiSpec(identity=identity, name=profile.device_name, sync_managers=sms, fmmus=[1, 2],
                   rx_pdos=pdos(profile.rx, profile.rx_assign, RX_SM) if profile.sii_pdos else [],
                   tx_pdos=pdos(profile.tx, profile.tx_assign, TX_SM) if profile.sii_pdos else [],
                   group="Drives",
                   mailbox=(MBX_OUT_START, size, MBX_IN_START, size) if size else None,
                   coe_details=details)


class Cia402Drive(EscSlave):
    """A cyclic-synchronous drive on one physics channel (module docstring).

    Parameters
    ----------
    channel : str
        Physics channel whose motor this drive powers.
    profile : DriveProfile
    rated_torque : float > 0, optional
        0x6076 [N m] (default: the profile's).
    counts_per_rev : int > 0
        Encoder resolution [counts/rev] (default 2**20), gear ratio 1.
    max_torque_permille : int, optional
        0x6072 (default: the profile's).
    cycle_time : float > 0
        The drive's time per process-data frame [s] (the physics step; sets how many frames
        a ``controlword_period`` is).
    """

    kind = "cia402_drive"

    def __init__(self, name, channel, identity=DEFAULT_IDENTITY, profile=PROFILES["standard"],
                 rated_torque=None, counts_per_rev=2 ** 20, max_torque_permille=None,
                 cycle_time=0.0005, **kwargs):
        if rated_torque is not None:
            if not rated_torque > 0:
                raise ValueError("rated_torque must be > 0 N m, got %r" % (rated_torque,))
            profile = replace(profile, rated_torque_mnm=int(round(rated_torque * 1000)))
        if max_torque_permille is not None:
            profile = replace(profile, max_torque_permille=int(max_torque_permille))
        if int(counts_per_rev) <= 0:
            raise ValueError("counts_per_rev must be > 0, got %r" % (counts_per_rev,))
        self.profile = profile
        self.od = drive_dictionary(profile, identity)
        mailbox = None
        if profile.mailbox_size:
            self.sdo = C.SdoServer(self.od, profile.mailbox_size, lambda: self.al_state,
                                   log=lambda text: self._event(text))
            mailbox = Mailbox(self.sdo.handle)
        super().__init__(name, drive_sii_spec(identity, profile), mailbox=mailbox, dc=profile.dc,
                         **kwargs)
        self.channel = channel
        self.counts_per_rev = int(counts_per_rev)
        self.cycle_time = float(cycle_time)
        self.sm402 = Cia402StateMachine()
        self.od.objects[0x6060].on_write = self._mode_written
        for index in (0x1C32, 0x1C33):
            self.od.objects[index].on_read = self._refresh_sync_objects
        self.limited = False
        self.applied_permille = 0        # torque applied this cycle [per mille]
        self.cycles_enabled = 0
        self.unsafe_torque_frames = 0
        self.enables_outside_cst = 0
        self.emergencies = 0
        self._x = self._v = 0.0          # the newest measured motor state (CSP/CSV servo)
        self._inputs_ok = False          # the inputs in SM3 show Operation enabled in CST
        self._master_knows_ok = False    # ... in the newest reply the master received
        self._delivered_ok = None        # ... in the reply of the frame being taken now
        self._was_enabled = False
        self.frames_outside_cst = 0
        self._cw_frames = 0              # frames since the controlword was last sampled
        self._sync_last = None           # SYNC0 period index of the last fresh frame
        self._sync_errors = 0            # the sync error counter (+3 missed, -1 good)
        self._last_frame_ns = None
        self._compile()

    # --- the process image ---------------------------------------------------------------------
    def _compile(self):
        self._rx, self._rx_keys, self._rx_size = _layout(self.od, C.ASSIGN_RX)
        self._tx, self._tx_keys, self._tx_size = _layout(self.od, C.ASSIGN_TX)
        self._rx_index = {k: i for i, k in enumerate(self._rx_keys)}

    def expected_sync_managers(self):
        """``{sm: (start, bytes, is_output)}`` the PDO assignment requires now."""
        out = {}
        for sm, assign, start in ((RX_SM, C.ASSIGN_RX, RX_START), (TX_SM, C.ASSIGN_TX, TX_START)):
            bits = sum(b for pdo in self.od.assigned(assign) for _, _, b in self.od.mapping(pdo))
            out[sm] = (start, (bits + 7) // 8, sm == RX_SM)
        return out

    def value(self, index, sub=0):
        return self.od.value(index, sub)

    @property
    def mode_command(self):
        return self.od.value(0x6060)

    @property
    def mode_display(self):
        return self.od.value(0x6061)

    @property
    def controlword(self):
        return self.od.value(0x6040)

    @property
    def target_torque(self):
        return self.od.value(0x6071)

    @property
    def rated_torque(self):
        return self.od.value(0x6076) * 1e-3

    def _mode_written(self, obj, sub, value, check):
        if check:
            if value not in SUPPORTED_MODES:
                raise C.SdoAbort(C.ABORT_VALUE_RANGE, "mode %d is not supported" % value)
            return
        self.od.set(0x6061, 0, value)

    # --- AL ----------------------------------------------------------------------------------
    def check_transition(self, current, requested):
        code = super().check_transition(current, requested)
        if code or (current, requested) != (SAFEOP, OP):
            return code
        p = self.profile
        if p.requires_dc and not (self.sync0_active()
                                  and self.sync0_cycle_ns() == p.sync0_cycle_ns):
            self._event("OP refused: SYNC0 %s (needs %d ns)"
                        % ("off" if not self.sync0_active() else
                           "at %d ns" % self.sync0_cycle_ns(), p.sync0_cycle_ns))
            return AL_CODE_INVALID_DC_SYNC_CONFIG
        for (index, sub), want in p.required.items():
            have = self.od.value(index, sub)
            if have != want:
                self._event("OP refused: 0x%04X:%02X is %r, needs %r" % (index, sub, have, want))
                return AL_CODE_INVALID_SYNC_CYCLE_TIME
        return AL_CODE_NONE

    def on_state_change(self, old, new):
        if new == SAFEOP and old == PREOP:
            self._compile()                  # the mapping written at PRE-OP is the image now
            self._sync_last = None
            self._sync_errors = 0
        if old == OP and new != OP:
            if self.sm402.state in POWERED:
                self._fault(FAULT_LEFT_OP, "AL left OP with the power stage on")
            self.applied_permille = 0
            self.refresh_inputs()

    def on_watchdog_expired(self):
        if self.sm402.state in POWERED:
            self._fault(FAULT_WATCHDOG, "process-data watchdog expired")
        self.applied_permille = 0
        self.refresh_inputs()

    # --- the application, once per process-data frame ------------------------------------------
    def torque_enabled(self):
        return (self.al_state == OP and self.sm402.state == OPERATION_ENABLED
                and self.mode_display == MODE_CST)

    def reply_delivered(self):
        """The reply of a process-data frame reaches the master: once this frame's outputs
        are taken (they were decided without it), the master knows these inputs."""
        self._delivered_ok = self._inputs_ok

    def process_outputs(self):
        fresh = self.outputs_fresh
        self.outputs_fresh = False
        self.sm402.tick()
        od = self.od
        if fresh and self.al_state in (SAFEOP, OP):
            values = self._rx.unpack_from(self.mem, RX_START) if self._rx_size else ()
            i = self._rx_index.get((0x6071, 0))
            torque = 0 if i is None else values[i]
            if self.al_state == OP:              # in SAFE-OP the outputs stay safe
                objects = od.objects
                for key, value in zip(self._rx_keys, values):
                    objects[key[0]].entries[key[1]].value = value
            if torque and not self._master_knows_ok:
                self.unsafe_torque_frames += 1
                if self.unsafe_torque_frames <= 3:
                    self._event("torque %d received while the master's newest inputs did not "
                                "show Operation enabled in CST" % torque)
            if self.al_state == OP:
                self._sync_check()
                mode = od.value(0x6060)
                if (0x6060, 0) in self._rx_index and mode in SUPPORTED_MODES:
                    od.set(0x6061, 0, mode)
                self._sample_controlword()
        if self._delivered_ok is not None:
            self._master_knows_ok, self._delivered_ok = self._delivered_ok, None
        enabled = self.sm402.state == OPERATION_ENABLED and self.al_state == OP
        if enabled and not self._was_enabled and self.mode_display != MODE_CST:
            self.enables_outside_cst += 1
            self._event("Operation enabled in mode %d (not CST)" % self.mode_display)
        if enabled and self.mode_display != MODE_CST:
            self.frames_outside_cst += 1
        self._was_enabled = enabled
        self.applied_permille = self._torque() if enabled else 0
        if self.torque_enabled():
            self.cycles_enabled += 1

    def _sample_controlword(self):
        period = self.profile.controlword_period
        if period > 0:
            n = max(1, int(round(period / self.cycle_time)))
            self._cw_frames = (self._cw_frames + 1) % n
            if self._cw_frames != 1 % n:
                return
        before = self.sm402.state
        self.sm402.update(self.od.value(0x6040))
        if before == FAULT and self.sm402.state != FAULT:
            self._fault_cleared()

    def _torque(self):
        """The torque [per mille] the drive applies in its mode, clamped to 0x6072."""
        od = self.od
        mode = self.mode_display
        lim = min(od.value(0x6072), 32767)
        if mode == MODE_CST:
            t = od.value(0x6071) + od.value(0x60B2)
        elif mode == MODE_CSP:           # a stiff servo to the target position
            target = od.value(0x607A) * TWO_PI / self.counts_per_rev
            t = 1000.0 * (5.0 * (target - self._x) - 0.1 * self._v) / self.rated_torque
        elif mode == MODE_CSV:
            target = od.value(0x60FF) * TWO_PI / self.counts_per_rev
            t = 1000.0 * 0.05 * (target - self._v) / self.rated_torque
        else:
            t = 0
        t = int(round(t))
        self.limited = t > lim or t < -lim
        return lim if t > lim else (-lim if t < -lim else t)

    def torque_command(self):
        """Torque [N m] the drive applies during the next physics step."""
        return self.applied_permille * 1e-3 * self.rated_torque

    # --- distributed clocks --------------------------------------------------------------------
    def _sync_check(self):
        """Per fresh frame in OP: SYNC0 events without outputs, frames within one cycle, the
        sync error counter and its limit."""
        od = self.od
        # when the outputs reached the ESC (the SM buffer fills as the frame passes), not
        # when this application got round to them
        now = self.system_time_ns(int(self._wd_last * 1e9) + self._dc_base)
        if self._last_frame_ns is not None:
            od.set(0x1C32, 2, now - self._last_frame_ns if not self.sync0_active()
                   else self.sync0_cycle_ns())
        self._last_frame_ns = now
        if not self.sync0_active():
            return
        cycle = self.sync0_cycle_ns()
        k = (now - self.sync0_start_ns()) // cycle
        last, self._sync_last = self._sync_last, k
        if last is None:
            return
        missed = k - last - 1
        if missed > 0:
            od.set(0x1C32, 0x0B, min(0xFFFF, od.value(0x1C32, 0x0B) + missed))
            self._sync_errors += 3 * missed
        elif missed < 0:
            od.set(0x1C32, 0x0C, min(0xFFFF, od.value(0x1C32, 0x0C) + 1))
        else:
            self._sync_errors = max(0, self._sync_errors - 1)
        limit = od.value(0x10F1, 2)
        if limit and self._sync_errors > limit:
            od.set(0x1C32, 0x20, 1)
            self._event("sync error: %d SYNC0 events without outputs" % max(missed, 0))
            if self.sm402.state in POWERED:
                self._fault(FAULT_SYNC, "sync error (SYNC0 without outputs)")
            self.inject_al_error(AL_CODE_SYNC_ERROR)
            self._sync_errors = 0

    def _refresh_sync_objects(self, obj=None):
        od = self.od
        active = self.sync0_active()
        for index in (0x1C32, 0x1C33):
            od.set(index, 1, 2 if active else 0)
            od.set(index, 0x0A, self.sync0_cycle_ns() if self.dc else 0)
        for sub in (0x0B, 0x0C, 0x20):
            od.set(0x1C33, sub, od.value(0x1C32, sub))

    # --- inputs ---------------------------------------------------------------------------------
    def statusword(self):
        sw = self.sm402.statusword()
        if self.limited:
            sw |= SW_INTERNAL_LIMIT
        if self.sm402.state == OPERATION_ENABLED and self.mode_display in (
                MODE_CSP, MODE_CSV, MODE_CST):
            sw |= SW_FOLLOWING_TARGET
        return sw

    def update_inputs(self, physics):
        m = physics.channel(self.channel).measurement
        self._x, self._v = m.x, m.v
        scale = self.counts_per_rev / TWO_PI
        pos = int(round(m.x * scale))
        pos = ((pos + 0x80000000) & 0xFFFFFFFF) - 0x80000000
        vel = max(-0x80000000, min(0x7FFFFFFF, int(round(m.v * scale))))
        od = self.od
        od.set(0x6064, 0, pos)
        od.set(0x606C, 0, vel)
        self.refresh_inputs()

    def refresh_inputs(self):
        """Write the inputs of the newest state into SM3 (also after a change without a
        physics step)."""
        od = self.od
        sw = self.statusword()
        od.set(0x6041, 0, sw)
        od.set(0x6077, 0, self.applied_permille)
        self._inputs_ok = (sw & 0x6F) == 0x27 and self.mode_display == MODE_CST
        if self._tx_size:
            objects = od.objects
            self._tx.pack_into(self.mem, TX_START, *[objects[i].entries[s].value
                                                     for i, s in self._tx_keys])

    def tick(self, now):
        if self.sm402.state == FAULT_REACTION_ACTIVE:
            self.sm402.tick()
            self.refresh_inputs()

    # --- faults ---------------------------------------------------------------------------------
    def _fault(self, code, reason, latched=False):
        if self.sm402.fault(code, reason, latched):
            register = 0x01 | {0x2: 0x02, 0x3: 0x04, 0x4: 0x08}.get(code >> 12, 0)
            self.od.set(0x603F, 0, code)
            self.od.set(0x1001, 0, register)
            self.emergencies += 1
            self.post_mailbox(MBX_COE, C.emergency(code, register, reason.encode()[:5]))
            self._event("fault 0x%04X: %s" % (code, reason))

    def _fault_cleared(self):
        self.od.set(0x603F, 0, 0)
        self.od.set(0x1001, 0, 0)
        self.post_mailbox(MBX_COE, C.emergency(0x0000, 0x00))

    def inject_fault(self, code=0x5400, reason="injected", latched=False):
        """Drive fault (default error code 0x5400 power section)."""
        self._fault(code, reason, latched)
        self.applied_permille = 0
        self.refresh_inputs()

    def clear_fault(self):
        self.sm402.clear_latch()

    def status(self):
        st = super().status()
        st.update({
            "channel": self.channel,
            "profile": self.profile.name,
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
            "error_code": self.od.value(0x603F),
            "rated_torque": self.rated_torque,
            "max_torque_permille": self.od.value(0x6072),
            "counts_per_rev": self.counts_per_rev,
            "cycles_enabled": self.cycles_enabled,
            "unsafe_torque_frames": self.unsafe_torque_frames,
            "enables_outside_cst": self.enables_outside_cst,
            "frames_outside_cst": self.frames_outside_cst,
            "emergencies": self.emergencies,
            "rx_mapping": [[pdo, self.od.mapping(pdo)] for pdo in self.od.assigned(C.ASSIGN_RX)],
            "tx_mapping": [[pdo, self.od.mapping(pdo)] for pdo in self.od.assigned(C.ASSIGN_TX)],
            "image_bytes": [self._rx_size, self._tx_size],
            "sync0_active": self.sync0_active(),
            "sync0_cycle_ns": self.sync0_cycle_ns() if self.dc else 0,
            "dc_activation": self.mem[0x0981],
            "sm_event_missed": self.od.value(0x1C32, 0x0B),
            "cycle_time_too_small": self.od.value(0x1C32, 0x0C),
            "sdo_requests": self.sdo.requests if self.mailbox is not None else 0,
            "sdo_aborts": self.sdo.aborts if self.mailbox is not None else 0,
        })
        return st


def od_value(drive, index, sub=0):
    """(for tests) a drive's object value."""
    return drive.od.value(index, sub)


def mapping_of(drive, direction):
    """(for tests) ``[(pdo, [(index, sub, bits)])]`` assigned now (``rx`` or ``tx``)."""
    assign = C.ASSIGN_RX if direction == "rx" else C.ASSIGN_TX
    return [(pdo, drive.od.mapping(pdo)) for pdo in drive.od.assigned(assign)]


__all__ = ["Cia402Drive", "Cia402StateMachine", "DriveProfile", "PROFILES", "drive_sii_spec",
           "decode_command", "od_value", "mapping_of"]
