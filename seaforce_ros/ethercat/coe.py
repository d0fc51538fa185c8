"""A slave's configuration over CoE at PRE-OP, and what the master reads back (no ROS, no
pysoem: everything goes through an :class:`SdoPort`).

:func:`configure_slave` does, in this order, what a slave's bus YAML entry asks:

1. the start-up SDOs, in list order, each read back and compared;
2. the PDO mapping (``pdo_mapping: write``): 0x1C12:00 = 0 and 0x1C13:00 = 0 (unassign), the
   mapping object's subindex 0 = 0, its entries, subindex 0 = n (or one complete-access
   transfer), then the assignment, subindex 0 last -- the order CoE demands. Then (``write``
   and ``check``) the assignment and mapping are read back and compared entry by entry:
   index, subindex, bit length, order (:func:`match_entries`);
3. for a drive: 0x6060 = 10 (cyclic synchronous torque) by SDO, whether or not it is mapped,
   and 0x6061 read; 0x6076 (rated torque, mN m) and 0x6072 (max torque, per mille) read.

Every refusal is one :class:`CoeError` line naming the slave, the object, the SDO abort code
with its meaning (:data:`ABORTS`, ETG.1000.6) and what to change.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import List, Optional, Protocol, Sequence, Tuple

from .bus_config import PdoLayout, SlaveConfig
from .errors import BusError

MODE_CST = 10

#: SDO abort codes and their meaning (ETG.1000.6 table 40, CiA 301).
ABORTS = {
    0x05030000: 'toggle bit not changed',
    0x05040000: 'SDO protocol timeout',
    0x05040001: 'client/server command specifier not valid or unknown',
    0x05040005: 'out of memory',
    0x06010000: 'unsupported access to an object',
    0x06010001: 'attempt to read a write-only object',
    0x06010002: 'attempt to write a read-only object',
    0x06010003: 'subindex cannot be written, subindex 0 must be 0 for write access',
    0x06010004: 'complete access not supported for this object',
    0x06010005: 'object length exceeds the mailbox size',
    0x06010006: 'object mapped to an RxPDO, SDO download blocked',
    0x06020000: 'the object does not exist in the object dictionary',
    0x06040041: 'the object cannot be mapped into the PDO',
    0x06040042: 'the number and length of the objects would exceed the PDO length',
    0x06040043: 'general parameter incompatibility',
    0x06040047: 'general internal incompatibility in the device',
    0x06060000: 'access failed due to a hardware error',
    0x06070010: 'data type does not match, length of service parameter does not match',
    0x06070012: 'data type does not match, length of service parameter too high',
    0x06070013: 'data type does not match, length of service parameter too low',
    0x06090011: 'subindex does not exist',
    0x06090030: 'value range of parameter exceeded',
    0x06090031: 'value of parameter written too high',
    0x06090032: 'value of parameter written too low',
    0x06090036: 'maximum value is less than minimum value',
    0x08000000: 'general error',
    0x08000020: 'data cannot be transferred or stored to the application',
    0x08000021: 'data cannot be transferred or stored because of local control',
    0x08000022: 'data cannot be transferred or stored in the present device state',
    0x08000023: 'object dictionary dynamic generation failed or no object dictionary',
}
NO_OBJECT = 0x06020000
NO_SUBINDEX = 0x06090011


def abort_text(code: int) -> str:
    """``0x06020000 (the object does not exist ...)``."""
    return f'0x{code:08X} ({ABORTS.get(code, "unknown abort code")})'


class CoeError(BusError):
    """A slave refused or failed its CoE configuration; the message names the slave, the
    object and the fix."""


class SdoAbortError(CoeError):
    """An SDO transfer the slave aborted (``code``, ``index``, ``subindex``)."""

    def __init__(self, message: str, code: int, index: int, subindex: int) -> None:
        super().__init__(message)
        self.code, self.index, self.subindex = code, index, subindex


class SdoPort(Protocol):
    """SDO access to one slave. ``name`` says which (``slave 2 (pinch_drive)``); errors are
    :class:`SdoAbortError` (an abort) or :class:`CoeError` (no answer)."""

    name: str

    def read(self, index: int, subindex: int, size: int = 0, ca: bool = False) -> bytes:
        ...

    def write(self, index: int, subindex: int, data: bytes, ca: bool = False) -> None:
        ...


@dataclass
class DriveFindings:
    """What a drive's object dictionary said at configure."""

    rated_torque_mnm: Optional[int] = None      # 0x6076 (None: the drive has no such object)
    max_torque_permille: Optional[int] = None   # 0x6072
    mode_display: Optional[int] = None          # 0x6061 after 0x6060 = 10


def _u(port: SdoPort, index: int, sub: int, fmt: str) -> int:
    data = port.read(index, sub)
    size = struct.calcsize(fmt)
    if len(data) < size:
        raise CoeError(f'{port.name}: 0x{index:04X}:{sub:02X} answered {len(data)} byte(s), '
                       f'expected {size}')
    return int(struct.unpack_from(fmt, data)[0])


def _optional(port: SdoPort, index: int, sub: int, fmt: str) -> Optional[int]:
    """The object's value, or None when the slave does not have it."""
    try:
        return _u(port, index, sub, fmt)
    except SdoAbortError as exc:
        if exc.code in (NO_OBJECT, NO_SUBINDEX):
            return None
        raise


def _write(port: SdoPort, index: int, sub: int, data: bytes, what: str, fix: str,
           ca: bool = False) -> None:
    try:
        port.write(index, sub, data, ca)
    except SdoAbortError as exc:
        raise CoeError(f'{port.name}: {what} refused: SDO abort {abort_text(exc.code)}; '
                       f'{fix}') from None


# --- start-up SDOs ------------------------------------------------------------------------------
def apply_startup_sdos(port: SdoPort, slave: SlaveConfig) -> None:
    """The slave's ``sdo:`` list, in order, each read back (unless ``verify: false``)."""
    for k, sdo in enumerate(slave.sdo):
        what = f'start-up SDO {k + 1} {sdo.describe()}'
        _write(port, sdo.index, sdo.subindex, sdo.encode(), what,
               'fix or remove it in the slave\'s sdo: list of the bus YAML')
        if not sdo.verify:
            continue
        try:
            back = sdo.decode(port.read(sdo.index, sdo.subindex))
        except SdoAbortError as exc:
            raise CoeError(f'{port.name}: {what} cannot be read back: SDO abort '
                           f'{abort_text(exc.code)}; add verify: false to it if it is a '
                           'command object') from None
        except ValueError as exc:
            raise CoeError(f'{port.name}: {what} reads back {exc}: is the type right?') from None
        if back != sdo.value and not (isinstance(back, float)
                                      and abs(back - sdo.value) <= 1e-6 * abs(sdo.value)):
            raise CoeError(f'{port.name}: {what} reads back {back!r}: the slave did not keep '
                           'it (writable at PRE-OP? in range?)')


# --- PDO mapping ------------------------------------------------------------------------------
def match_entries(found: Sequence[Tuple[int, int, int]], layout: PdoLayout) -> Optional[str]:
    """Compare what a slave maps (``(index, subindex, bits)``, gaps as index 0) with a
    YAML layout, entry by entry: each YAML entry must start at an entry with its
    index:subindex and cover whole entries of exactly its bits (a u16 ``status`` may stand
    for the 16 bit entries from its subindex on); None when they agree, else what differs."""
    k = 0
    for n, e in enumerate(layout.entries, start=1):
        if k >= len(found):
            return (f'entry {n} ({e.name} 0x{e.index:04X}:{e.subindex:02X}, {e.bits} bits) is '
                    'not mapped: the slave maps fewer entries')
        index, sub, bits = found[k]
        if (index, sub) != (e.index, e.subindex):
            return (f'entry {n} is 0x{index:04X}:{sub:02X} ({bits} bits) where the YAML has '
                    f'{e.name} 0x{e.index:04X}:{e.subindex:02X} ({e.bits} bits)')
        total = bits
        k += 1
        while total < e.bits and k < len(found):
            total += found[k][2]
            k += 1
        if total != e.bits:
            return (f'entry {n} 0x{index:04X}:{sub:02X} spans {total} bits where the YAML\'s '
                    f'{e.name} is a {e.dtype} ({e.bits} bits)')
    if k < len(found):
        extra = found[k]
        return (f'it maps more than the YAML: entry {len(layout.entries) + 1} is '
                f'0x{extra[0]:04X}:{extra[1]:02X} ({extra[2]} bits)')
    return None


def _layouts(slave: SlaveConfig) -> List[Tuple[str, int, int, PdoLayout]]:
    """(direction, assignment object, PDO, layout) of the slave's outputs and inputs."""
    return [('outputs', 0x1C12, slave.rx_pdo, slave.outputs),
            ('inputs', 0x1C13, slave.tx_pdo, slave.inputs)]


def write_mapping(port: SdoPort, slave: SlaveConfig, complete_access: bool = False) -> None:
    """Write the YAML's mapping: unassign both directions, write each mapping object, assign
    it -- each object's subindex 0 last (CoE's rule)."""
    fix = ('map only objects the drive can map in that direction (its ESI lists them), or '
           'set pdo_mapping: check or sii for this slave')
    for _, assign, _, _ in _layouts(slave):
        _write(port, assign, 0, b'\x00', f'unassigning the PDOs (0x{assign:04X}:00 = 0)', fix)
    for direction, assign, pdo, layout in _layouts(slave):
        entries = layout.entries
        if complete_access:
            data = struct.pack(f'<Bx{len(entries)}I', len(entries), *(e.mapping for e in entries))
            _write(port, pdo, 0, data, f'writing the {direction} mapping 0x{pdo:04X} (complete '
                   'access)', fix, ca=True)
        else:
            _write(port, pdo, 0, b'\x00', f'clearing the mapping 0x{pdo:04X}:00', fix)
            for n, e in enumerate(entries, start=1):
                _write(port, pdo, n, struct.pack('<I', e.mapping),
                       f'mapping 0x{pdo:04X}:{n:02X} = 0x{e.mapping:08X} ({e.name})', fix)
            _write(port, pdo, 0, bytes([len(entries)]),
                   f'mapping 0x{pdo:04X}:00 = {len(entries)} ({direction})', fix)
        if not entries:
            continue
        if complete_access:
            _write(port, assign, 0, struct.pack('<BxH', 1, pdo),
                   f'assigning 0x{pdo:04X} in 0x{assign:04X} (complete access)', fix, ca=True)
        else:
            _write(port, assign, 1, struct.pack('<H', pdo),
                   f'assigning 0x{assign:04X}:01 = 0x{pdo:04X}', fix)
            _write(port, assign, 0, b'\x01', f'assigning 0x{assign:04X}:00 = 1', fix)


def _entries(port: SdoPort, index: int, fmt: str, complete_access: bool) -> List[int]:
    """Subindices 1..n of a list object (its count at subindex 0), each unpacked as ``fmt``
    (``H`` or ``I``): in one complete-access transfer, or one upload per entry."""
    if complete_access:
        data = port.read(index, 0, ca=True)
        return list(struct.unpack_from(f'<{data[0]}{fmt}', data, 2)) if data else []
    count = _u(port, index, 0, '<B')
    return [_u(port, index, k, '<' + fmt) for k in range(1, count + 1)]


def read_mapping(port: SdoPort, assign: int,
                 complete_access: bool = False) -> List[Tuple[int, List[Tuple[int, int, int]]]]:
    """``[(pdo, [(index, subindex, bits)])]`` an assignment object (0x1C12/0x1C13) assigns."""
    return [(pdo, [(v >> 16, (v >> 8) & 0xFF, v & 0xFF)
                   for v in _entries(port, pdo, 'I', complete_access)])
            for pdo in _entries(port, assign, 'H', complete_access)]


def check_mapping(port: SdoPort, slave: SlaveConfig, complete_access: bool = False) -> None:
    """Read the assignment and mapping back and compare them with the YAML, entry by entry."""
    for direction, assign, pdo, layout in _layouts(slave):
        try:
            mapped = read_mapping(port, assign, complete_access)
        except SdoAbortError as exc:
            raise CoeError(f'{port.name}: reading the {direction} mapping back '
                           f'(0x{exc.index:04X}:{exc.subindex:02X}) failed: SDO abort '
                           f'{abort_text(exc.code)}; set pdo_mapping: sii for a slave whose '
                           'mapping is not in its object dictionary') from None
        found = [e for _, entries in mapped for e in entries]
        problem = match_entries(found, layout)
        if problem is not None:
            where = ', '.join(f'0x{p:04X}' for p, _ in mapped) or 'no PDO'
            raise CoeError(f'{port.name}: its {direction} ({where}, assigned in '
                           f'0x{assign:04X}) disagree with the YAML: {problem}; fix the '
                           f'{direction} list in the bus YAML (order, type), or let the master '
                           'write the mapping (pdo_mapping: write)')


# --- drives -----------------------------------------------------------------------------------
def set_cst(port: SdoPort) -> int:
    """0x6060 = 10 by SDO, then 0x6061 read: the mode the drive shows."""
    _write(port, 0x6060, 0, struct.pack('<b', MODE_CST), 'modes of operation 0x6060 = 10 (CST)',
           'the drive must support cyclic synchronous torque (0x6502 bit 9)')
    return read_mode(port)


def read_mode(port: SdoPort) -> int:
    """0x6061, the mode the drive is in."""
    return _u(port, 0x6061, 0, '<b')


def read_drive(port: SdoPort) -> DriveFindings:
    """0x6076 (rated torque, mN m) and 0x6072 (max torque, per mille), None where the drive
    has no such object."""
    return DriveFindings(rated_torque_mnm=_optional(port, 0x6076, 0, '<I'),
                         max_torque_permille=_optional(port, 0x6072, 0, '<H'))


def read_error_code(port: SdoPort) -> int:
    """0x603F, the drive's last error code (CiA 402)."""
    return _u(port, 0x603F, 0, '<H')


#: ETG.1020 sync manager parameter subindices read for /diagnostics.
SYNC_COUNTERS = ((0x0B, 'sm_event_missed', '<H'), (0x0C, 'cycle_time_too_small', '<H'),
                 (0x20, 'sync_error', '<B'))
#: The sync manager parameter objects and the prefix of their counters' names: 0x1C32 the
#: outputs' (SM2), 0x1C33 the inputs' (SM3).
SYNC_OBJECTS = ((0x1C32, ''), (0x1C33, 'input_'))


def read_sync_counters(port: SdoPort) -> dict:
    """0x1C32:0B/:0C/:20 (SM events missed, cycle time too small, sync error) and the same
    of 0x1C33 (``input_``...), those the slave has."""
    out = {}
    for index, prefix in SYNC_OBJECTS:
        for sub, name, fmt in SYNC_COUNTERS:
            value = _optional(port, index, sub, fmt)
            if value is not None:
                out[prefix + name] = value
    return out


def configure_slave(port: SdoPort, slave: SlaveConfig, mapping: str,
                    complete_access: bool = False) -> Optional[DriveFindings]:
    """Configure one slave at PRE-OP (module docstring). ``mapping`` is the effective
    ``pdo_mapping`` (``write``, ``check`` or ``sii``: the last is checked elsewhere).
    Returns the drive's findings (None for other kinds)."""
    apply_startup_sdos(port, slave)
    if mapping == 'write':
        write_mapping(port, slave, complete_access)
    if mapping in ('write', 'check'):
        check_mapping(port, slave, complete_access)
    if slave.kind != 'cia402_drive':
        return None
    findings = read_drive(port)
    findings.mode_display = set_cst(port)
    return findings


__all__ = ['ABORTS', 'abort_text', 'CoeError', 'SdoAbortError', 'SdoPort', 'DriveFindings',
           'apply_startup_sdos', 'match_entries', 'write_mapping', 'read_mapping',
           'check_mapping', 'set_cst', 'read_mode', 'read_drive', 'read_error_code',
           'read_sync_counters', 'configure_slave', 'MODE_CST']
