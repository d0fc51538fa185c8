"""CANopen over EtherCAT, the slave's side: an object dictionary and its SDO server.

Written from ETG.1000.6 (CoE: SDO services, complete access, abort codes) and CiA 301 (object
dictionary, PDO mapping rules), and checked against what SOEM's client sends and accepts
(``ecx_SDOread`` / ``ecx_SDOwrite``, ``ecx_readPDOmap`` / ``ecx_readPDOmapCA``):

* **upload** (read): expedited (<= 4 bytes, command 0x43 | (4 - n) << 2), normal (0x41 with
  the complete size, the data that fits in one mailbox) and segmented (0x60 requests with a
  toggle bit; the last segment sets bit 0, a short one gives its unused bytes in bits 1-3);
* **download** (write): expedited (0x23 | (4 - n) << 2, or 0x22 without a size), normal (0x21
  with the size) and segmented (0x00 | toggle | last segments, answered 0x20 | toggle);
* **complete access** (bit 4 of the command: 0x50 upload, 0x31 download) from subindex 0 or
  1: subindex 0 travels as 8 bits plus 8 bits of padding, then the entries in subindex order
  (of an array whose subindex 0 counts its entries, entries 1..count);
* **abort** (command 0x80, CoE service *SDO request*, the abort code in the data), codes of
  ETG.1000.6 table 40 (``ABORT_TEXT``).

Objects know their access (read-only, read-write, writable in PRE-OP only) and whether they
may be mapped into an RxPDO or a TxPDO. PDO mapping (0x1600-0x17FF, 0x1A00-0x1BFF) and
assignment (0x1C12, 0x1C13) objects follow the CoE rules: an entry can be written only while
subindex 0 is 0 (0x06010003), writing subindex 0 = n checks entries 1..n (an object that
cannot be mapped 0x06040041, a bit length that is not the object's 0x06040043, too many bits
0x06040042), and a mapping that is assigned cannot be changed (0x08000022: unassign first).
Nothing here knows about a master's configuration.
"""

import struct

# CoE data types (ETG.1000.6 / CiA 301 table 44)
BOOLEAN, INTEGER8, INTEGER16, INTEGER32 = 0x01, 0x02, 0x03, 0x04
UNSIGNED8, UNSIGNED16, UNSIGNED32, REAL32 = 0x05, 0x06, 0x07, 0x08
VISIBLE_STRING, OCTET_STRING = 0x09, 0x0A
INTEGER64, UNSIGNED64 = 0x15, 0x1B

_FORMATS = {BOOLEAN: "<B", INTEGER8: "<b", INTEGER16: "<h", INTEGER32: "<i",
            UNSIGNED8: "<B", UNSIGNED16: "<H", UNSIGNED32: "<I", REAL32: "<f",
            INTEGER64: "<q", UNSIGNED64: "<Q"}
TYPE_NAMES = {BOOLEAN: "BOOL", INTEGER8: "INT8", INTEGER16: "INT16", INTEGER32: "INT32",
              UNSIGNED8: "UINT8", UNSIGNED16: "UINT16", UNSIGNED32: "UINT32", REAL32: "REAL32",
              VISIBLE_STRING: "STRING", OCTET_STRING: "OCTETS", INTEGER64: "INT64",
              UNSIGNED64: "UINT64"}

# SDO abort codes (ETG.1000.6 table 40)
ABORT_TOGGLE = 0x05030000
ABORT_TIMEOUT = 0x05040000
ABORT_COMMAND = 0x05040001
ABORT_UNSUPPORTED_ACCESS = 0x06010000
ABORT_WRITE_ONLY = 0x06010001
ABORT_READ_ONLY = 0x06010002
ABORT_SI0_NOT_ZERO = 0x06010003
ABORT_CA_UNSUPPORTED = 0x06010004
ABORT_NO_OBJECT = 0x06020000
ABORT_NOT_MAPPABLE = 0x06040041
ABORT_PDO_LENGTH = 0x06040042
ABORT_INCOMPATIBLE = 0x06040043
ABORT_LENGTH = 0x06070010
ABORT_TOO_LONG = 0x06070012
ABORT_TOO_SHORT = 0x06070013
ABORT_NO_SUBINDEX = 0x06090011
ABORT_VALUE_RANGE = 0x06090030
ABORT_VALUE_HIGH = 0x06090031
ABORT_VALUE_LOW = 0x06090032
ABORT_GENERAL = 0x08000000
ABORT_CANNOT_TRANSFER = 0x08000020
ABORT_DEVICE_STATE = 0x08000022

ABORT_TEXT = {
    ABORT_TOGGLE: "toggle bit not changed",
    ABORT_TIMEOUT: "SDO protocol timeout",
    ABORT_COMMAND: "client/server command specifier not valid or unknown",
    ABORT_UNSUPPORTED_ACCESS: "unsupported access to an object",
    ABORT_WRITE_ONLY: "attempt to read a write only object",
    ABORT_READ_ONLY: "attempt to write a read only object",
    ABORT_SI0_NOT_ZERO: "subindex cannot be written, SI0 must be 0 for write access",
    ABORT_CA_UNSUPPORTED: "complete access not supported for this object",
    ABORT_NO_OBJECT: "the object does not exist in the object dictionary",
    ABORT_NOT_MAPPABLE: "the object cannot be mapped into the PDO",
    ABORT_PDO_LENGTH: "the number and length of the objects would exceed the PDO length",
    ABORT_INCOMPATIBLE: "general parameter incompatibility",
    ABORT_LENGTH: "data type does not match, length of service parameter does not match",
    ABORT_TOO_LONG: "data type does not match, length of service parameter too high",
    ABORT_TOO_SHORT: "data type does not match, length of service parameter too low",
    ABORT_NO_SUBINDEX: "subindex does not exist",
    ABORT_VALUE_RANGE: "value range of parameter exceeded",
    ABORT_VALUE_HIGH: "value of parameter written too high",
    ABORT_VALUE_LOW: "value of parameter written too low",
    ABORT_GENERAL: "general error",
    ABORT_CANNOT_TRANSFER: "data cannot be transferred or stored to the application",
    ABORT_DEVICE_STATE: "data cannot be transferred because of the present device state",
}

# access
RO, RW, RW_PREOP, WO = "ro", "rw", "rw_preop", "wo"
# AL states (as esc.py)
_PREOP = 2

# SDO command bytes (the initiate/segment specifiers of CiA 301 with the EtherCAT CA bit)
CMD_ABORT = 0x80
CA_BIT = 0x10
COE_SDO_REQUEST, COE_SDO_RESPONSE = 2, 3
SDO_HEADER = 10           # CoE header 2 + command 1 + index 2 + subindex 1 + 4 data bytes
MAILBOX_HEADER = 6

MAPPING_RX = range(0x1600, 0x1800)
MAPPING_TX = range(0x1A00, 0x1C00)
ASSIGN_RX, ASSIGN_TX = 0x1C12, 0x1C13


class SdoAbort(Exception):
    """A request the server answers with an abort (``code``: ETG.1000.6 table 40)."""

    def __init__(self, code, what=""):
        super().__init__("SDO abort 0x%08X (%s)%s" % (code, ABORT_TEXT.get(code, "?"),
                                                      ": " + what if what else ""))
        self.code = code


def size_of(dtype, value=None):
    """Bytes of a value of ``dtype`` (strings: their length)."""
    if dtype in _FORMATS:
        return struct.calcsize(_FORMATS[dtype])
    return len(value or b"")


def encode(dtype, value):
    if dtype in _FORMATS:
        return struct.pack(_FORMATS[dtype], value)
    if isinstance(value, str):
        return value.encode("latin-1")
    return bytes(value)


def decode(dtype, data):
    if dtype in _FORMATS:
        fmt = _FORMATS[dtype]
        if len(data) != struct.calcsize(fmt):
            raise SdoAbort(ABORT_TOO_LONG if len(data) > struct.calcsize(fmt) else ABORT_TOO_SHORT)
        return struct.unpack(fmt, data)[0]
    if dtype == VISIBLE_STRING:
        return bytes(data).decode("latin-1")
    return bytes(data)


_LIMITS = {INTEGER8: (-128, 127), INTEGER16: (-2 ** 15, 2 ** 15 - 1),
           INTEGER32: (-2 ** 31, 2 ** 31 - 1), UNSIGNED8: (0, 255), UNSIGNED16: (0, 2 ** 16 - 1),
           UNSIGNED32: (0, 2 ** 32 - 1), BOOLEAN: (0, 1)}


class Entry:
    """One subindex: data type, access, PDO direction it may be mapped in, value.

    ``low``/``high``: the values a download may write (0x06090031/0x06090032 beyond them)."""

    __slots__ = ("sub", "name", "dtype", "access", "pdo", "value", "low", "high")

    def __init__(self, sub, name, dtype, value=0, access=RO, pdo=None, low=None, high=None):
        self.sub, self.name, self.dtype, self.access = sub, name, dtype, access
        self.pdo, self.value, self.low, self.high = pdo, value, low, high

    @property
    def bits(self):
        return 8 * size_of(self.dtype, encode(self.dtype, self.value))


class CoeObject:
    """An object: a variable (subindex 0 only), an array or a record.

    Parameters
    ----------
    index : int
    name : str
    entries : list of Entry
    counted : bool
        Subindex 0 is the number of entries in use (PDO mapping and assignment, arrays):
        the others can be written only while it is 0.
    on_write : callable, optional
        ``on_write(obj, sub, value, check)``: with ``check=True`` before a download of one
        subindex is stored (raise :class:`SdoAbort` to refuse it), with False after.
    on_read : callable, optional
        ``on_read(obj)`` before an upload (an object whose values the device keeps elsewhere).
    """

    def __init__(self, index, name, entries, counted=False, on_write=None, on_read=None):
        self.index, self.name = index, name
        self.entries = {e.sub: e for e in entries}
        self.counted = counted
        self.on_write = on_write
        self.on_read = on_read         # on_read(obj) before an upload (values kept elsewhere)

    def entry(self, sub):
        e = self.entries.get(sub)
        if e is None:
            raise SdoAbort(ABORT_NO_SUBINDEX, "0x%04X:%02X" % (self.index, sub))
        return e

    def subs_for_ca(self, start):
        """Subindices a complete access covers from ``start`` (0 or 1)."""
        if self.counted:
            n = int(self.entries[0].value)
            subs = [0] + list(range(1, n + 1))
        else:
            subs = sorted(self.entries)
        return [s for s in subs if s >= start]


def _check_range(e, value):
    if isinstance(value, int):
        low, high = _LIMITS.get(e.dtype, (None, None))
        if e.low is not None:
            low = e.low
        if e.high is not None:
            high = e.high
        if low is not None and value < low:
            raise SdoAbort(ABORT_VALUE_LOW, "%s = %d < %d" % (e.name, value, low))
        if high is not None and value > high:
            raise SdoAbort(ABORT_VALUE_HIGH, "%s = %d > %d" % (e.name, value, high))


class ObjectDictionary:
    """Objects by index; reads and writes with the access rules of the AL state they come in.

    ``state`` arguments are AL states (2 PRE-OP, 4 SAFE-OP, 8 OP).
    """

    def __init__(self, objects=()):
        self.objects = {}
        self.max_pdo_bits = 0x400          # per PDO (1024 bits, 128 bytes)
        for o in objects:
            self.add(o)

    def add(self, obj):
        self.objects[obj.index] = obj
        return obj

    def __contains__(self, index):
        return index in self.objects

    def obj(self, index):
        o = self.objects.get(index)
        if o is None:
            raise SdoAbort(ABORT_NO_OBJECT, "0x%04X" % index)
        return o

    def value(self, index, sub=0):
        return self.objects[index].entries[sub].value

    def set(self, index, sub, value):
        """Store ``value`` without the access rules (the device's own writes)."""
        self.objects[index].entries[sub].value = value

    # --- services --------------------------------------------------------------------------------
    def upload(self, index, sub, ca=False):
        """The bytes an upload of ``index:sub`` (complete access from ``sub``) returns."""
        o = self.obj(index)
        if o.on_read is not None:
            o.on_read(o)
        if not ca:
            e = o.entry(sub)
            if e.access == WO:
                raise SdoAbort(ABORT_WRITE_ONLY)
            return encode(e.dtype, e.value)
        if sub > 1:
            raise SdoAbort(ABORT_CA_UNSUPPORTED, "complete access starts at subindex 0 or 1")
        out = bytearray()
        for s in o.subs_for_ca(sub):
            e = o.entries.get(s)
            if e is None:
                continue
            out += encode(e.dtype, e.value)
            if s == 0:
                out += b"\x00"                       # SI0 padded to 16 bits
        return bytes(out)

    def download(self, index, sub, data, state, ca=False):
        """Write ``data`` to ``index:sub`` (complete access from ``sub``) in AL ``state``."""
        o = self.obj(index)
        if not ca:
            self._write(o, sub, decode(o.entry(sub).dtype, data), state)
            return
        if sub > 1:
            raise SdoAbort(ABORT_CA_UNSUPPORTED, "complete access starts at subindex 0 or 1")
        data = bytes(data)
        if o.counted and sub == 0:
            if len(data) < 2:
                raise SdoAbort(ABORT_TOO_SHORT)
            n = data[0]
            values, off = {}, 2
            for s in range(1, n + 1):
                e = o.entry(s)
                size = size_of(e.dtype, e.value)
                if off + size > len(data):
                    raise SdoAbort(ABORT_TOO_SHORT, "%d entries need more data" % n)
                values[s] = decode(e.dtype, data[off:off + size])
                off += size
            if off != len(data):
                raise SdoAbort(ABORT_TOO_LONG)
            self._write(o, 0, 0, state)
            for s, v in values.items():
                self._write(o, s, v, state)
            self._write(o, 0, n, state)
            return
        off = 0
        subs = [s for s in sorted(o.entries) if s >= sub]
        values = {}
        for s in subs:
            e = o.entries[s]
            size = size_of(e.dtype, e.value)
            if off + size > len(data):
                raise SdoAbort(ABORT_TOO_SHORT)
            values[s] = decode(e.dtype, data[off:off + size])
            off += size + (1 if s == 0 else 0)
        if off != len(data):
            raise SdoAbort(ABORT_TOO_LONG)
        for s, v in values.items():
            if o.entries[s].access != RO:
                self._write(o, s, v, state)

    def _write(self, o, sub, value, state):
        e = o.entry(sub)
        if e.access == RO:
            raise SdoAbort(ABORT_READ_ONLY, "0x%04X:%02X" % (o.index, sub))
        if e.access == RW_PREOP and state != _PREOP:
            raise SdoAbort(ABORT_DEVICE_STATE, "0x%04X:%02X is writable in PRE-OP only"
                           % (o.index, sub))
        if o.counted and sub > 0 and int(o.entries[0].value) != 0:
            raise SdoAbort(ABORT_SI0_NOT_ZERO, "0x%04X:00 is %d" % (o.index, o.entries[0].value))
        _check_range(e, value)
        if o.on_write is not None:
            o.on_write(o, sub, value, True)
        if o.counted and sub == 0 and value > len(o.entries) - 1:
            raise SdoAbort(ABORT_VALUE_HIGH, "0x%04X has %d entries"
                           % (o.index, len(o.entries) - 1))
        if o.index in MAPPING_RX or o.index in MAPPING_TX:
            self._check_mapping(o, sub, value)
        if o.index in (ASSIGN_RX, ASSIGN_TX):
            self._check_assignment(o, sub, value)
        e.value = value
        if o.on_write is not None:
            o.on_write(o, sub, value, False)

    # --- PDO mapping rules -----------------------------------------------------------------
    def assigned(self, assign_index):
        """The PDO mapping objects ``assign_index`` (0x1C12/0x1C13) assigns now."""
        o = self.objects.get(assign_index)
        if o is None:
            return []
        n = int(o.entries[0].value)
        return [int(o.entries[s].value) for s in range(1, n + 1)]

    def mapping(self, pdo_index):
        """``[(index, sub, bits)]`` a PDO mapping object maps now (index 0: a gap)."""
        o = self.objects[pdo_index]
        n = int(o.entries[0].value)
        out = []
        for s in range(1, n + 1):
            v = int(o.entries[s].value)
            out.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
        return out

    def _check_mapping(self, o, sub, value):
        direction = "rx" if o.index in MAPPING_RX else "tx"
        assign = ASSIGN_RX if direction == "rx" else ASSIGN_TX
        if o.index in self.assigned(assign):
            raise SdoAbort(ABORT_DEVICE_STATE, "0x%04X is assigned in 0x%04X: set 0x%04X:00 = 0 "
                           "first" % (o.index, assign, assign))
        if sub == 0 and value:
            bits = 0
            for s in range(1, value + 1):
                v = int(o.entries[s].value)
                index, esub, nbits = v >> 16, (v >> 8) & 0xFF, v & 0xFF
                bits += nbits
                if index == 0:
                    continue                     # a gap
                target = self.objects.get(index)
                entry = None if target is None else target.entries.get(esub)
                if entry is None or entry.pdo != direction:
                    raise SdoAbort(ABORT_NOT_MAPPABLE, "0x%04X:%02X in 0x%04X"
                                   % (index, esub, o.index))
                if entry.bits != nbits:
                    raise SdoAbort(ABORT_INCOMPATIBLE, "0x%04X:%02X is %d bits, not %d"
                                   % (index, esub, entry.bits, nbits))
            if bits > self.max_pdo_bits:
                raise SdoAbort(ABORT_PDO_LENGTH)

    def _check_assignment(self, o, sub, value):
        if sub == 0:
            return
        allowed = MAPPING_RX if o.index == ASSIGN_RX else MAPPING_TX
        if value not in allowed or value not in self.objects:
            raise SdoAbort(ABORT_VALUE_RANGE, "0x%04X is not a PDO of this device" % value)


class SdoServer:
    """One slave's SDO server: a CoE request in, the CoE reply out (both without the mailbox
    header). Keeps the state of one segmented transfer.

    Parameters
    ----------
    od : ObjectDictionary
    mailbox_size : int
        Bytes of the slave's mailboxes (the data one reply can carry follows from it).
    state : callable
        The slave's AL state now.
    log : callable, optional
        ``log(text)`` for every abort (the emulator's events).
    """

    def __init__(self, od, mailbox_size, state, log=None):
        self.od = od
        self.mailbox_size = int(mailbox_size)
        self.state = state
        self.log = log
        self._upload = None       # (index, sub, data, offset, toggle)
        self._download = None     # (index, sub, ca, size, data, toggle)
        self.requests = 0
        self.aborts = 0

    def handle(self, coe):
        """Answer one CoE SDO request (``coe``: CoE header + SDO bytes)."""
        self.requests += 1
        if len(coe) < SDO_HEADER:
            return self._abort(0, 0, ABORT_COMMAND)
        cmd = coe[2]
        index, sub = struct.unpack_from("<HB", coe, 3)
        ccs = cmd >> 5
        try:
            if ccs == 2:                                          # initiate upload
                return self._initiate_upload(index, sub, bool(cmd & CA_BIT))
            if ccs == 3:                                          # upload segment
                return self._upload_segment(cmd)
            if ccs == 1:                                          # initiate download
                return self._initiate_download(cmd, index, sub, coe)
            if ccs == 0:                                          # download segment
                return self._download_segment(cmd, coe)
            if ccs == 4:                                          # abort from the client
                self._upload = self._download = None
                return None
            raise SdoAbort(ABORT_COMMAND)
        except SdoAbort as abort:
            self._upload = self._download = None
            return self._abort(index, sub, abort.code, str(abort))

    def _abort(self, index, sub, code, text=""):
        self.aborts += 1
        if self.log is not None:
            self.log(text or "SDO abort 0x%08X" % code)
        return struct.pack("<HBHBI", COE_SDO_REQUEST << 12, CMD_ABORT, index, sub, code)

    def _reply(self, cmd, index, sub, data=b"\x00\x00\x00\x00"):
        return struct.pack("<HBHB", COE_SDO_RESPONSE << 12, cmd, index, sub) + data

    # --- upload ---------------------------------------------------------------------------------
    def _initiate_upload(self, index, sub, ca):
        data = self.od.upload(index, sub, ca)
        if len(data) <= 4 and not ca:
            cmd = 0x43 | ((4 - len(data)) << 2)
            return self._reply(cmd, index, sub, data + bytes(4 - len(data)))
        room = self.mailbox_size - MAILBOX_HEADER - SDO_HEADER
        first = data[:room]
        cmd = 0x41 | (CA_BIT if ca else 0)
        if len(data) > room:
            self._upload = (index, sub, data, len(first), 0)
        return self._reply(cmd, index, sub, struct.pack("<I", len(data)) + first)

    def _upload_segment(self, cmd):
        if self._upload is None:
            raise SdoAbort(ABORT_COMMAND, "no upload in progress")
        index, sub, data, off, toggle = self._upload
        if (cmd & 0x10) != toggle:
            raise SdoAbort(ABORT_TOGGLE)
        room = self.mailbox_size - MAILBOX_HEADER - 3
        chunk = data[off:off + room]
        last = off + len(chunk) >= len(data)
        out = 0x00 | toggle | (0x01 if last else 0)
        if len(chunk) < 7:
            out |= (7 - len(chunk)) << 1
            chunk = chunk + bytes(7 - len(chunk))
        self._upload = None if last else (index, sub, data, off + room, toggle ^ 0x10)
        return struct.pack("<HB", COE_SDO_RESPONSE << 12, out) + chunk

    # --- download ---------------------------------------------------------------------------------
    def _initiate_download(self, cmd, index, sub, coe):
        ca = bool(cmd & CA_BIT)
        if cmd & 0x02:                                            # expedited
            if ca:
                raise SdoAbort(ABORT_COMMAND, "complete access is never expedited")
            n = 4 - ((cmd >> 2) & 0x03) if cmd & 0x01 else None
            raw = bytes(coe[6:10])
            if n is None:
                e = self.od.obj(index).entry(sub)
                n = size_of(e.dtype, e.value)
            self.od.download(index, sub, raw[:n], self.state())
            return self._reply(0x60, index, sub)
        if len(coe) < SDO_HEADER:
            raise SdoAbort(ABORT_TOO_SHORT)
        size = struct.unpack_from("<I", coe, 6)[0]
        data = bytes(coe[SDO_HEADER:])
        if len(data) >= size:
            self.od.download(index, sub, data[:size], self.state(), ca)
            return self._reply(0x60 | (CA_BIT if ca else 0), index, sub)
        self._download = (index, sub, ca, size, bytearray(data), 0)
        return self._reply(0x60 | (CA_BIT if ca else 0), index, sub)

    def _download_segment(self, cmd, coe):
        if self._download is None:
            raise SdoAbort(ABORT_COMMAND, "no download in progress")
        index, sub, ca, size, data, toggle = self._download
        if (cmd & 0x10) != toggle:
            raise SdoAbort(ABORT_TOGGLE)
        chunk = bytes(coe[3:])
        last = bool(cmd & 0x01)
        if last and len(chunk) == 7:
            chunk = chunk[:7 - ((cmd >> 1) & 0x07)]
        data += chunk
        if last:
            self._download = None
            if len(data) < size:
                raise SdoAbort(ABORT_TOO_SHORT)
            self.od.download(index, sub, bytes(data[:size]), self.state(), ca)
        else:
            self._download = (index, sub, ca, size, data, toggle ^ 0x10)
        return struct.pack("<HB", COE_SDO_RESPONSE << 12, 0x20 | toggle) + bytes(7)


def emergency(error_code, error_register, data=b"\x00" * 5):
    """A CoE emergency message (CoE service 1): error code, error register, 5 data bytes."""
    return struct.pack("<HHB", 0x1000, error_code, error_register) + bytes(data)[:5].ljust(5, b"\0")
