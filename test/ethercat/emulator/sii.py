"""SII EEPROM image builder (ETG.2010).

The image is a ``bytearray`` of 16-bit words: a 64-word header (configuration area,
identity at words 0x08-0x0F, mailbox words 0x18-0x1C) and categories from word 0x40,
each ``type u16, length u16 (words), data``, ending with type 0xFFFF.  Without a mailbox
words 0x18-0x1C are 0; with one they give its SM0/SM1 offsets and sizes and the protocols
(CoE), and GENERAL byte 5 the CoE details.  SOEM caches at most 4096 bytes, so images stay below that.
"""

import struct
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

CAT_STRINGS = 10
CAT_GENERAL = 30
CAT_FMMU = 40
CAT_SM = 41
CAT_TXPDO = 50
CAT_RXPDO = 51
CAT_END = 0xFFFF

# word addresses of the identity
WORD_VENDOR = 0x08
WORD_PRODUCT = 0x0A
WORD_REVISION = 0x0C
WORD_SERIAL = 0x0E
WORD_MAILBOX = 0x18          # receive offset, receive size, send offset, send size, protocols
MBX_PROTO_COE = 0x0004

# GENERAL byte 5, CoE details
COE_SDO, COE_SDO_INFO, COE_PDO_ASSIGN, COE_PDO_CONFIG, COE_UPLOAD, COE_COMPLETE_ACCESS = (
    0x01, 0x02, 0x04, 0x08, 0x10, 0x20)

# SII SM category entry types
SM_TYPE_UNUSED, SM_TYPE_MBX_OUT, SM_TYPE_MBX_IN, SM_TYPE_OUTPUTS, SM_TYPE_INPUTS = range(5)

# CoE data types (SII DataType byte)
DT_INT8, DT_INT16, DT_INT32 = 0x02, 0x03, 0x04
DT_UINT8, DT_UINT16, DT_UINT32 = 0x05, 0x06, 0x07
DT_BOOLEAN, DT_BIT2 = 0x01, 0x31


@dataclass(frozen=True)
class Identity:
    """Vendor id, product code, revision and serial number (u32 each)."""

    vendor_id: int
    product_code: int
    revision: int
    serial: int = 0

    def as_dict(self):
        return {"vendor_id": self.vendor_id, "product_code": self.product_code,
                "revision": self.revision, "serial": self.serial}


@dataclass(frozen=True)
class SyncManagerSpec:
    """One SII SM entry: physical start, default length, control byte, enable, type."""

    start: int
    length: int
    control: int
    enable: int
    sm_type: int


@dataclass(frozen=True)
class PdoEntry:
    """One PDO entry: object index, subindex, bit length, CoE data type, name."""

    index: int
    subindex: int
    bits: int
    data_type: int = 0
    name: str = ""


@dataclass(frozen=True)
class Pdo:
    """A PDO (0x16xx RxPDO / 0x1Axx TxPDO) assigned to sync manager ``sm``."""

    index: int
    sm: int
    entries: Tuple[PdoEntry, ...]
    name: str = ""

    @property
    def bits(self):
        return sum(e.bits for e in self.entries)


@dataclass
class SiiSpec:
    """Everything the SII image of one slave says."""

    identity: Identity
    name: str
    sync_managers: List[SyncManagerSpec]
    fmmus: List[int]                      # 1 outputs, 2 inputs, 3 SM status, 0xFF unused
    rx_pdos: List[Pdo] = field(default_factory=list)    # outputs (master -> slave)
    tx_pdos: List[Pdo] = field(default_factory=list)    # inputs (slave -> master)
    block_lrw: bool = False
    group: Optional[str] = None
    #: (receive offset, receive size, send offset, send size) of the standard mailbox, or None
    mailbox: Optional[Tuple[int, int, int, int]] = None
    #: GENERAL byte 5: bit 0 SDO, 1 SDO info, 2 PDO assign, 3 PDO config, 4 upload at start-up,
    #: 5 SDO complete access
    coe_details: int = 0


def _pad_words(data):
    return data + b"\x00" if len(data) % 2 else data


def _category(cat_type, data):
    data = _pad_words(bytes(data))
    return struct.pack("<HH", cat_type, len(data) // 2) + data


def _pdo_category(pdos, strings):
    out = bytearray()
    for pdo in pdos:
        out += struct.pack("<HBBBBH", pdo.index, len(pdo.entries), pdo.sm, 0,
                           strings.index_of(pdo.name), 0)
        for e in pdo.entries:
            out += struct.pack("<HBBBBH", e.index, e.subindex, strings.index_of(e.name),
                               e.data_type, e.bits, 0)
    return out


class _Strings:
    def __init__(self):
        self.items = []

    def index_of(self, text):
        if not text:
            return 0
        text = text[:255]
        if text not in self.items:
            self.items.append(text)
        return self.items.index(text) + 1

    def encode(self):
        out = bytearray([len(self.items)])
        for s in self.items:
            b = s.encode("ascii", "replace")
            out.append(len(b))
            out += b
        return out


def build_image(spec):
    """Return the SII image (``bytearray``, even length) of ``spec``.

    Raises
    ------
    ValueError
        The image would exceed the 4096 bytes SOEM caches.
    """
    ident = spec.identity
    header = bytearray(128)
    # words 0x00-0x07: configuration area (PDI control, ...); SOEM never checks it.
    header[0:2] = struct.pack("<H", 0x0080)
    struct.pack_into("<IIII", header, WORD_VENDOR * 2, ident.vendor_id & 0xFFFFFFFF,
                     ident.product_code & 0xFFFFFFFF, ident.revision & 0xFFFFFFFF,
                     ident.serial & 0xFFFFFFFF)
    # words 0x18-0x1C: the standard mailbox (receive = master -> slave, send) and its
    # protocols (bit 2 CoE); no mailbox -> 0.  word 0x3E: EEPROM size (KiBit - 1), 0x3F: version.
    if spec.mailbox is not None:
        struct.pack_into("<HHHHH", header, WORD_MAILBOX * 2, *spec.mailbox, MBX_PROTO_COE)
    struct.pack_into("<HH", header, 0x3E * 2, 31, 1)

    strings = _Strings()
    name_idx = strings.index_of(spec.name)          # string 1 is the device name
    group_idx = strings.index_of(spec.group or "")
    txcat = _pdo_category(spec.tx_pdos, strings)
    rxcat = _pdo_category(spec.rx_pdos, strings)

    general = bytearray(32)
    general[0] = group_idx
    general[1] = 0                                   # image
    general[2] = name_idx                            # order
    general[3] = name_idx                            # name
    general[5] = spec.coe_details if spec.mailbox else 0   # CoE details
    general[11] = 0x02 if spec.block_lrw else 0x00   # flags: bit 1 blockLRW
    sm = bytearray()
    for s in spec.sync_managers:
        sm += struct.pack("<HHBBBB", s.start, s.length, s.control, 0, s.enable, s.sm_type)
    fmmu = bytes(spec.fmmus)

    body = bytearray()
    body += _category(CAT_STRINGS, strings.encode())
    body += _category(CAT_GENERAL, general)
    if fmmu:                                         # a coupler has neither
        body += _category(CAT_FMMU, fmmu)
    if sm:
        body += _category(CAT_SM, sm)
    if spec.tx_pdos:
        body += _category(CAT_TXPDO, txcat)
    if spec.rx_pdos:
        body += _category(CAT_RXPDO, rxcat)
    body += struct.pack("<H", CAT_END)
    image = header + body
    if len(image) > 4096:
        raise ValueError("SII image of %r is %d bytes; SOEM caches only 4096"
                         % (spec.name, len(image)))
    return bytearray(image)


def set_identity(image, identity):
    """Overwrite the identity words 0x08-0x0F of ``image`` in place."""
    struct.pack_into("<IIII", image, WORD_VENDOR * 2, identity.vendor_id & 0xFFFFFFFF,
                     identity.product_code & 0xFFFFFFFF, identity.revision & 0xFFFFFFFF,
                     identity.serial & 0xFFFFFFFF)


def parse_categories(image):
    """Return ``{type: data bytes}`` of the categories of ``image`` (for tests)."""
    cats = {}
    off = 0x40 * 2
    while off + 4 <= len(image):
        cat_type, words = struct.unpack_from("<HH", image, off)
        if cat_type == CAT_END:
            break
        cats[cat_type] = bytes(image[off + 4: off + 4 + 2 * words])
        off += 4 + 2 * words
    return cats
