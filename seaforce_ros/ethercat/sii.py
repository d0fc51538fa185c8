"""A slave's SII (its EEPROM, ETG.2010) as the master reads it: identity, mailbox and its
protocols, the name and the PDOs it lists (no ROS, no pysoem).

:func:`read_sii` pulls the words it needs through a ``read(word_address) -> bytes`` function
(pysoem's ``slave.eeprom_read``, 4 bytes a call) and stops at the end category; :class:`Sii`
holds what it found. Nothing is written.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Tuple

from .errors import BusError

WORD_VENDOR, WORD_MAILBOX, WORD_CATEGORIES = 0x08, 0x18, 0x40
CAT_STRINGS, CAT_GENERAL, CAT_FMMU, CAT_SM, CAT_TXPDO, CAT_RXPDO, CAT_END = (
    10, 30, 40, 41, 50, 51, 0xFFFF)
MBX_PROTO_COE = 0x0004
#: GENERAL category byte 5 (CoE details): bit 5 = SDO complete access
COE_DETAILS_COMPLETE_ACCESS = 0x20
#: Largest image read (SOEM caches 4096 bytes of it too).
MAX_WORDS = 2048


@dataclass(frozen=True)
class SiiPdo:
    """A PDO the SII lists: index, the SM it is assigned to (>= 8: not assigned by
    default) and its entries ``(index, subindex, bits)``."""

    index: int
    sm: int
    entries: Tuple[Tuple[int, int, int], ...]
    name: str = ''
    types: Tuple[int, ...] = ()           # each entry's CoE data type (0: none given)

    @property
    def assigned(self) -> bool:
        return self.sm < 8


@dataclass
class Sii:
    """What a slave's SII says."""

    vendor_id: int = 0
    product_code: int = 0
    revision: int = 0
    serial: int = 0
    mailbox: Tuple[int, int, int, int] = (0, 0, 0, 0)   # receive offset/size, send offset/size
    protocols: int = 0
    strings: List[str] = field(default_factory=list)
    name: str = ''
    group: str = ''
    coe_details: int = 0
    sync_managers: List[Tuple[int, int, int, int, int]] = field(default_factory=list)
    tx_pdos: List[SiiPdo] = field(default_factory=list)
    rx_pdos: List[SiiPdo] = field(default_factory=list)

    @property
    def has_coe(self) -> bool:
        return bool(self.mailbox[1]) and bool(self.protocols & MBX_PROTO_COE)

    @property
    def complete_access(self) -> bool:
        return self.has_coe and bool(self.coe_details & COE_DETAILS_COMPLETE_ACCESS)

    def mapping(self, direction: str) -> List[Tuple[int, int, int]]:
        """The entries ``(index, subindex, bits)`` of the PDOs assigned by default, in order
        (``rx`` outputs, ``tx`` inputs)."""
        pdos = self.rx_pdos if direction == 'rx' else self.tx_pdos
        return [e for p in pdos if p.assigned for e in p.entries]


class _Words:
    """Word access to the EEPROM through ``read`` (4 bytes from a word address), cached."""

    def __init__(self, read: Callable[[int], bytes]) -> None:
        self._read = read
        self._cache: Dict[int, int] = {}

    def word(self, address: int) -> int:
        if address not in self._cache:
            if address >= MAX_WORDS:
                raise BusError(f'SII longer than {MAX_WORDS} words: no end category')
            data = bytes(self._read(address))
            if len(data) < 2:
                raise BusError(f'SII word 0x{address:04X} could not be read')
            for k in range(len(data) // 2):
                self._cache[address + k] = struct.unpack_from('<H', data, 2 * k)[0]
        return self._cache[address]

    def u32(self, address: int) -> int:
        return self.word(address) | (self.word(address + 1) << 16)

    def bytes_(self, address: int, count: int) -> bytes:
        words = [self.word(address + k) for k in range((count + 1) // 2)]
        return struct.pack(f'<{len(words)}H', *words)[:count]


def _strings(data: bytes) -> List[str]:
    out, off = [], 1
    for _ in range(data[0] if data else 0):
        if off >= len(data):
            break
        n = data[off]
        out.append(data[off + 1:off + 1 + n].decode('latin-1', 'replace'))
        off += 1 + n
    return out


def _pdos(data: bytes, strings: List[str]) -> List[SiiPdo]:
    out, off = [], 0
    while off + 8 <= len(data):
        index, n, sm, _, name_idx, _ = struct.unpack_from('<HBBBBH', data, off)
        off += 8
        entries, types = [], []
        for _ in range(n):
            if off + 8 > len(data):
                break
            e_index, e_sub, _, dtype, bits, _ = struct.unpack_from('<HBBBBH', data, off)
            entries.append((e_index, e_sub, bits))
            types.append(dtype)
            off += 8
        name = strings[name_idx - 1] if 0 < name_idx <= len(strings) else ''
        out.append(SiiPdo(index, sm, tuple(entries), name, tuple(types)))
    return out


def read_sii(read: Callable[[int], bytes], categories: bool = True) -> Sii:
    """Read a slave's SII through ``read`` (header; the categories too unless
    ``categories`` is False: mailbox and identity only)."""
    w = _Words(read)
    sii = Sii(vendor_id=w.u32(WORD_VENDOR), product_code=w.u32(WORD_VENDOR + 2),
              revision=w.u32(WORD_VENDOR + 4), serial=w.u32(WORD_VENDOR + 6),
              mailbox=(w.word(WORD_MAILBOX), w.word(WORD_MAILBOX + 1),
                       w.word(WORD_MAILBOX + 2), w.word(WORD_MAILBOX + 3)),
              protocols=w.word(WORD_MAILBOX + 4))
    if not categories:
        return sii
    address = WORD_CATEGORIES
    raw: Dict[int, bytes] = {}
    while address + 1 < MAX_WORDS:
        kind = w.word(address)
        if kind == CAT_END:
            break
        length = w.word(address + 1)
        raw.setdefault(kind, w.bytes_(address + 2, 2 * length))
        address += 2 + length
    sii.strings = _strings(raw.get(CAT_STRINGS, b''))
    general = raw.get(CAT_GENERAL, b'')
    if len(general) >= 6:
        sii.group = _string(sii.strings, general[0])
        sii.name = _string(sii.strings, general[3])
        sii.coe_details = general[5]
    if not sii.name and sii.strings:
        sii.name = sii.strings[0]
    sm = raw.get(CAT_SM, b'')
    sii.sync_managers = [struct.unpack_from('<HHBxBB', sm, 8 * k) for k in range(len(sm) // 8)]
    sii.tx_pdos = _pdos(raw.get(CAT_TXPDO, b''), sii.strings)
    sii.rx_pdos = _pdos(raw.get(CAT_RXPDO, b''), sii.strings)
    return sii


def _string(strings: List[str], index: int) -> str:
    return strings[index - 1] if 0 < index <= len(strings) else ''


def describe(entries: List[Tuple[int, int, int]]) -> str:
    """``0x6040:00/16, 0x6071:00/16`` (for messages and the scan's comments)."""
    return ', '.join(f'0x{i:04X}:{s:02X}/{b}' for i, s, b in entries) or 'nothing'


__all__ = ['Sii', 'SiiPdo', 'read_sii', 'describe']
