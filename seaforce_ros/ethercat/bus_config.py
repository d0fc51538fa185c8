"""The EtherCAT bus description the hardware node works from (no ROS, no pysoem).

A bus YAML (``config/ethercat_bus.yaml`` is the template; ``ethercat_scan`` writes one from a
bus) is the one source of a rig's bus: the slaves in bus order with the identity each must
have, their process-data entries in IOmap order, how each is configured at PRE-OP (the PDO
mapping written over CoE, start-up SDOs, distributed clocks), and per channel where its
signals live and how raw values scale to SI units:

.. code-block:: yaml

    slaves:                          # bus order
      - name: pinch_drive
        kind: cia402_drive           # or analog_input, encoder, coupler, passive
        vendor_id: 0x00000A5B
        product_code: 0x00001402
        revision: 0x00000001
        pdo_mapping: auto            # write the mapping below over CoE at PRE-OP (auto/write),
                                     # only check it (check), or take the SII's (sii)
        rx_pdo: 0x1600               # the RxPDO the outputs are mapped into
        tx_pdo: 0x1A00
        outputs: [[controlword, 0x6040, 0, u16], [target_torque, 0x6071, 0, i16],
                  [mode_of_operation, 0x6060, 0, i8]]
        inputs:  [[statusword, 0x6041, 0, u16], [position, 0x6064, 0, i32],
                  [velocity, 0x606C, 0, i32], [torque, 0x6077, 0, i16],
                  [mode_display, 0x6061, 0, i8], [error_code, 0x603F, 0, u16]]
        sdo:                         # start-up SDOs, in this order at PRE-OP, read back
          - [0x60C2, 1, u8, 5]       # interpolation time period: 5 x 10^-4 s
          - [0x60C2, 2, i8, -4]
        dc: {assign_activate: 0x0300, sync0_shift_ns: 250000}   # absent: free run
      - {name: coupler, kind: coupler, vendor_id: 0x2, product_code: 0x044C2C52}
    channels:
      pinch:
        drive: pinch_drive
        rated_torque: 1.0            # N m (0x6076); omit it to use the drive's
        position: [{factor: 5.992e-6}]               # counts -> rad (2 pi / 2^20)
        velocity: [{factor: 5.992e-6}]               # counts/s -> rad/s
        pressure:                                     # ADC counts -> V -> Pa -> N m
          source: {slave: pressure_adc, entry: value1}
          steps: [{factor: 3.0518e-4}, {factor: 1.0e5, offset: 0.0}, {factor: 2.0e-5}]
        endpoint_position: null      # optional {source: {...}, steps: [...]}
        external_force: null         # optional {source: ...} or {from_channel: wrist, sign: -1}

Every key is a row of :data:`KEYS` (what ``docs/parameters.md`` lists under *Bus YAML*); a
mistake (an unknown or misspelt key, an unknown kind, an entry a channel names that no slave
has, a bad type, a missing identity) raises :class:`BusConfigError` naming the item and what
to write instead.
"""
from __future__ import annotations

import math
import pathlib
import struct
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Tuple

from .errors import BusConfigError

#: What a slave is to the node: a drive, a terminal it reads, or a slave it only passes
#: (a coupler, or one whose process data nobody reads).
KINDS = ('cia402_drive', 'analog_input', 'encoder', 'coupler', 'passive')
#: Process-data entry types (and their struct formats).
DTYPES = {'u8': 'B', 'i8': 'b', 'u16': 'H', 'i16': 'h', 'u32': 'I', 'i32': 'i'}
#: Start-up SDO value types: the entry types and these.
SDO_TYPES = {**DTYPES, 'u64': 'Q', 'i64': 'q', 'f32': 'f', 'str': 's'}
DRIVE_OUTPUTS = ('controlword', 'target_torque')
DRIVE_INPUTS = ('statusword', 'position', 'velocity')
#: How a slave's PDO mapping is set: ``auto`` (``write`` when it has CoE, else ``sii``),
#: ``write`` (0x1C12/0x1C13 and 0x16xx/0x1Axx written at PRE-OP, read back), ``check`` (read
#: over CoE and compared, not written), ``sii`` (the SII's, compared with it).
PDO_MAPPINGS = ('auto', 'write', 'check', 'sii')
#: DC activation words (0x0980-0x0981, as an ESI's AssignActivate): SYNC0, SYNC0 + SYNC1.
DC_ACTIVATIONS = (0x0300, 0x0700)
#: The objects a drive entry name stands for, by CiA 402 (what ``ethercat_scan`` names).
DRIVE_OBJECTS = {0x6040: 'controlword', 0x6071: 'target_torque', 0x6060: 'mode_of_operation',
                 0x6041: 'statusword', 0x6064: 'position', 0x606C: 'velocity',
                 0x6077: 'torque', 0x6061: 'mode_display', 0x603F: 'error_code'}


@dataclass(frozen=True)
class Key:
    """One key of the bus YAML: where it goes, its type, default and meaning (the docs'
    row and the unknown-key check)."""

    name: str
    where: str            # 'slave', 'dc', 'sdo', 'channel', 'signal'
    type: str
    default: str
    description: str


KEYS: Tuple[Key, ...] = (
    Key('name', 'slave', 'string', 'required', 'the slave\'s name (channels refer to it)'),
    Key('kind', 'slave', 'string', 'required', 'one of ' + ', '.join(KINDS) + ': a coupler or '
        'passive slave is only checked (identity) and kept in its state'),
    Key('vendor_id', 'slave', 'integer', 'required', 'vendor id it must report (ESI, or what '
        'ethercat_scan found)'),
    Key('product_code', 'slave', 'integer', 'required', 'product code it must report'),
    Key('revision', 'slave', 'integer', 'null', 'revision it must report; null: any'),
    Key('outputs', 'slave', '[[name, index, subindex, type]]', '[]', 'RxPDO entries in mapping '
        'order (a drive needs controlword and target_torque; mode_of_operation 0x6060 is sent '
        '= 10 every cycle); types ' + ', '.join(DTYPES)),
    Key('inputs', 'slave', '[[name, index, subindex, type]]', '[]', 'TxPDO entries in mapping '
        'order (a drive needs statusword, position, velocity; mode_display 0x6061 and '
        'error_code 0x603F are read every cycle when mapped, else over CoE)'),
    Key('pdo_mapping', 'slave', 'string', 'auto', 'one of ' + ', '.join(PDO_MAPPINGS) + ': auto '
        'writes the mapping at PRE-OP over CoE when the slave has CoE (0x1C12/0x1C13, '
        '0x16xx/0x1Axx) and reads it back entry by entry; check only compares; sii compares '
        'with the SII\'s'),
    Key('rx_pdo', 'slave', 'integer', '0x1600', 'the RxPDO (0x1600-0x17FF) the outputs are '
        'written into'),
    Key('tx_pdo', 'slave', 'integer', '0x1A00', 'the TxPDO (0x1A00-0x1BFF) the inputs are '
        'written into'),
    Key('complete_access', 'slave', 'bool', 'false', 'write and read the mapping with SDO '
        'complete access (one transfer per object)'),
    Key('sdo', 'slave', '[[index, subindex, type, value]]', '[]', 'start-up SDOs, written in '
        'this order at PRE-OP (before the mapping) and read back; types '
        + ', '.join(SDO_TYPES) + '; an entry may be a mapping with verify: false (a command '
        'object that does not read back)'),
    Key('dc', 'slave', 'mapping', 'null', 'distributed clocks for this slave (null: free run); '
        'the node then locks its cycle to the reference clock'),
    Key('assign_activate', 'dc', 'integer', 'required', 'the ESI\'s AssignActivate: 0x0300 '
        'SYNC0, 0x0700 SYNC0 + SYNC1'),
    Key('sync0_shift_ns', 'dc', 'integer', 'half the cycle', 'SYNC0 after the cycle\'s frame '
        '[ns] (0 <= shift < cycle): the outputs arrive this long before the drive takes them'),
    Key('sync1_cycle_ns', 'dc', 'integer', '0', 'SYNC1 after SYNC0 [ns] (0x0700 only)'),
    Key('index', 'sdo', 'integer', 'required', 'object index'),
    Key('subindex', 'sdo', 'integer', 'required', 'subindex (0 or 1 with complete_access)'),
    Key('type', 'sdo', 'string', 'required', 'value type: ' + ', '.join(SDO_TYPES)),
    Key('value', 'sdo', 'number or string', 'required', 'the value'),
    Key('verify', 'sdo', 'bool', 'true', 'read the object back and compare'),
    Key('drive', 'channel', 'string', 'required', 'the cia402_drive slave of the channel'),
    Key('rated_torque', 'channel', 'float [N m]', 'the drive\'s 0x6076', 'rated torque (1000 '
        'units of 0x6071/0x6077); configure reads 0x6076 and fails naming both when they '
        'disagree by more than 0.5 %'),
    Key('position', 'channel', '[{factor, offset}]', 'required', 'encoder counts -> motor '
        'angle X [rad]'),
    Key('velocity', 'channel', '[{factor, offset}]', 'required', '0x606C units -> V [rad/s]'),
    Key('pressure', 'channel', '{source, steps}', 'required', 'raw value -> F_p [N m]: '
        'source {slave, entry}, steps [{factor, offset}]'),
    Key('endpoint_position', 'channel', '{source, steps}', 'null', 'an endpoint encoder -> '
        'X_e [rad]'),
    Key('external_force', 'channel', '{source, steps} or {from_channel, sign}', 'null',
        'F_e [N m] from a sensor, or sign x F_p of another channel (the bonded-finger rig)'),
)

_ALLOWED = {where: {k.name for k in KEYS if k.where == where}
            for where in ('slave', 'dc', 'sdo', 'channel')}


def _check_keys(raw: Dict[str, Any], where: str, what: str) -> None:
    unknown = sorted(set(raw) - _ALLOWED[where])
    if unknown:
        raise BusConfigError(f'{what}: unknown key(s) {", ".join(map(str, unknown))} (known: '
                             f'{", ".join(sorted(_ALLOWED[where]))})')


@dataclass(frozen=True)
class PdoEntry:
    """One process-data object: name used in the YAML, CoE index/subindex, data type."""

    name: str
    index: int
    subindex: int
    dtype: str

    @property
    def size(self) -> int:
        return struct.calcsize('<' + DTYPES[self.dtype])

    @property
    def bits(self) -> int:
        return 8 * self.size

    @property
    def mapping(self) -> int:
        """The entry as a PDO mapping object's value: index << 16 | subindex << 8 | bits."""
        return (self.index << 16) | (self.subindex << 8) | self.bits


@dataclass(frozen=True)
class PdoLayout:
    """Entries packed back to back (the order of the SII/CoE mapping)."""

    entries: Tuple[PdoEntry, ...]

    @property
    def size(self) -> int:
        return sum(e.size for e in self.entries)

    def offsets(self) -> Dict[str, Tuple[int, str]]:
        """name -> (byte offset, struct format)."""
        out, offset = {}, 0
        for e in self.entries:
            out[e.name] = (offset, '<' + DTYPES[e.dtype])
            offset += e.size
        return out

    def names(self) -> Tuple[str, ...]:
        return tuple(e.name for e in self.entries)

    def entry(self, name: str) -> Optional[PdoEntry]:
        for e in self.entries:
            if e.name == name:
                return e
        return None


@dataclass(frozen=True)
class StartupSdo:
    """A start-up SDO: written at PRE-OP in list order, then read back (``verify``)."""

    index: int
    subindex: int
    dtype: str
    value: Any
    verify: bool = True

    def encode(self) -> bytes:
        if self.dtype == 'str':
            return str(self.value).encode('latin-1')
        return struct.pack('<' + SDO_TYPES[self.dtype], self.value)

    def decode(self, data: bytes) -> Any:
        if self.dtype == 'str':
            return data.decode('latin-1').rstrip('\0')
        fmt = '<' + SDO_TYPES[self.dtype]
        if len(data) < struct.calcsize(fmt):
            raise ValueError(f'{len(data)} bytes for a {self.dtype}')
        return struct.unpack_from(fmt, data)[0]

    def describe(self) -> str:
        return f'0x{self.index:04X}:{self.subindex:02X} = {self.value!r} ({self.dtype})'


@dataclass(frozen=True)
class DcConfig:
    """Distributed clocks of one slave: SYNC0 (and SYNC1) at the node's cycle."""

    assign_activate: int
    sync0_shift_ns: Optional[int] = None        # None: half the cycle
    sync1_cycle_ns: int = 0

    def shift_ns(self, cycle_ns: int) -> int:
        return cycle_ns // 2 if self.sync0_shift_ns is None else self.sync0_shift_ns


@dataclass(frozen=True)
class SlaveConfig:
    name: str
    kind: str
    vendor_id: int
    product_code: int
    revision: Optional[int]
    outputs: PdoLayout
    inputs: PdoLayout
    pdo_mapping: str = 'auto'
    rx_pdo: int = 0x1600
    tx_pdo: int = 0x1A00
    complete_access: bool = False
    sdo: Tuple[StartupSdo, ...] = ()
    dc: Optional[DcConfig] = None

    @property
    def passive(self) -> bool:
        """Only checked and kept in its state: nobody reads or writes its process data."""
        return self.kind in ('coupler', 'passive')


@dataclass(frozen=True)
class Affine:
    """y = factor * x + offset (one step of a scaling chain)."""

    factor: float
    offset: float = 0.0


@dataclass(frozen=True)
class Scaling:
    """A chain of affine steps, raw -> SI; also invertible (SI -> raw)."""

    steps: Tuple[Affine, ...]

    def __post_init__(self) -> None:
        if not self.steps:
            raise BusConfigError('a scaling chain needs at least one {factor, offset} step')

    def forward(self, raw: float) -> float:
        y = raw
        for s in self.steps:
            y = s.factor * y + s.offset
        return y

    def inverse(self, value: float) -> float:
        x = value
        for s in reversed(self.steps):
            x = (x - s.offset) / s.factor
        return x

    def compiled(self) -> Tuple[float, float]:
        """The chain as one (gain, offset): forward(x) == gain * x + offset."""
        gain, offset = 1.0, 0.0
        for s in self.steps:
            gain, offset = s.factor * gain, s.factor * offset + s.offset
        return gain, offset


@dataclass(frozen=True)
class Source:
    """A scalar on the bus: slave name and input entry name."""

    slave: str
    entry: str


@dataclass(frozen=True)
class SignalConfig:
    source: Source
    scaling: Scaling


@dataclass(frozen=True)
class ChannelConfig:
    name: str
    drive: str
    rated_torque: Optional[float]            # N m per 1000 units (0x6076); None: the drive's
    position: Scaling                        # counts -> rad
    velocity: Scaling                        # drive units -> rad/s
    pressure: SignalConfig                   # raw -> F_p [N m]
    endpoint_position: Optional[SignalConfig] = None
    external_force: Optional[SignalConfig] = None
    external_from_channel: Optional[str] = None   # F_e = sign * F_p of that channel
    external_sign: float = -1.0


@dataclass(frozen=True)
class BusConfig:
    slaves: Tuple[SlaveConfig, ...]
    channels: Tuple[ChannelConfig, ...]

    def slave_index(self, name: str) -> int:
        for i, s in enumerate(self.slaves):
            if s.name == name:
                return i
        raise BusConfigError(f'no slave named {name!r}; slaves are '
                             + ', '.join(s.name for s in self.slaves))

    def channel(self, name: str) -> ChannelConfig:
        for c in self.channels:
            if c.name == name:
                return c
        raise BusConfigError(f'no channel {name!r} in the bus configuration; it has '
                             + ', '.join(c.name for c in self.channels))

    @property
    def uses_dc(self) -> bool:
        return any(s.dc is not None for s in self.slaves)

    @staticmethod
    def load(path: Any) -> 'BusConfig':
        import yaml
        path = pathlib.Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise BusConfigError(f'cannot read bus configuration {path}: {exc}') from exc
        except yaml.YAMLError as exc:
            raise BusConfigError(f'{path} is not valid YAML: '
                                 + ' '.join(str(exc).split())) from exc
        return BusConfig.from_dict(data, where=str(path))

    @staticmethod
    def from_dict(data: Any, where: str = 'bus configuration') -> 'BusConfig':
        if not isinstance(data, dict) or 'slaves' not in data or 'channels' not in data:
            raise BusConfigError(f'{where}: needs top-level keys `slaves` (list, bus order) '
                                 'and `channels` (mapping)')
        if not isinstance(data['slaves'] or [], list):
            raise BusConfigError(f'{where}: `slaves` must be a list (bus order)')
        slaves = tuple(_slave(s, i, where) for i, s in enumerate(data['slaves'] or []))
        if not slaves:
            raise BusConfigError(f'{where}: `slaves` is empty')
        names = [s.name for s in slaves]
        if len(set(names)) != len(names):
            raise BusConfigError(f'{where}: slave names must be unique: {names}')
        by_name = {s.name: s for s in slaves}
        if not isinstance(data['channels'] or {}, dict):
            raise BusConfigError(f'{where}: `channels` must be a mapping of channel names')
        channels = tuple(_channel(name, c or {}, by_name, where)
                         for name, c in (data['channels'] or {}).items())
        if not channels:
            raise BusConfigError(f'{where}: `channels` is empty')
        known = {c.name for c in channels}
        for c in channels:
            if c.external_from_channel is not None and c.external_from_channel not in known:
                raise BusConfigError(f'{where}: channel {c.name}: external_force.from_channel '
                                     f'{c.external_from_channel!r} is not a channel')
        drives = [c.drive for c in channels]
        if len(set(drives)) != len(drives):
            raise BusConfigError(f'{where}: two channels name the same drive: {drives}')
        return BusConfig(slaves, channels)


def _int(value: Any, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise BusConfigError(f'{what} must be an integer (e.g. 0x00001402), got {value!r}')
    return value


def _entries(raw: Any, what: str) -> PdoLayout:
    if raw is not None and not isinstance(raw, (list, tuple)):
        raise BusConfigError(f'{what}: a list of [name, index, subindex, type], got {raw!r}')
    entries = []
    for item in raw or []:
        if not (isinstance(item, (list, tuple)) and len(item) == 4):
            raise BusConfigError(f'{what}: each entry is [name, index, subindex, type], '
                                 f'got {item!r}')
        name, index, sub, dtype = item
        if dtype not in DTYPES:
            raise BusConfigError(f'{what}: entry {name}: type {dtype!r} is not one of '
                                 + ', '.join(DTYPES))
        entries.append(PdoEntry(str(name), _int(index, f'{what} {name} index'),
                                _int(sub, f'{what} {name} subindex'), dtype))
    names = [e.name for e in entries]
    if len(set(names)) != len(names):
        raise BusConfigError(f'{what}: entry names must be unique: {names}')
    return PdoLayout(tuple(entries))


def _sdo_value(dtype: str, value: Any, what: str) -> Any:
    if dtype == 'str':
        if not isinstance(value, str):
            raise BusConfigError(f'{what}: a str value must be a string, got {value!r}')
        return value
    if dtype == 'f32':
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not math.isfinite(value):
            raise BusConfigError(f'{what}: a f32 value must be a finite number, got {value!r}')
        return float(value)
    value = _int(value, f'{what} value')
    try:
        struct.pack('<' + SDO_TYPES[dtype], value)
    except struct.error:
        raise BusConfigError(f'{what}: {value} does not fit a {dtype}') from None
    return value


def _sdos(raw: Any, what: str) -> Tuple[StartupSdo, ...]:
    if raw is None:
        return ()
    if not isinstance(raw, list):
        raise BusConfigError(f'{what}: sdo is a list of [index, subindex, type, value]')
    out = []
    for k, item in enumerate(raw):
        where = f'{what} sdo[{k}]'
        verify = True
        if isinstance(item, dict):
            _check_keys(item, 'sdo', where)
            missing = [key for key in ('index', 'subindex', 'type', 'value') if key not in item]
            if missing:
                raise BusConfigError(f'{where}: missing {", ".join(missing)}')
            index, sub, dtype, value = (item['index'], item['subindex'], item['type'],
                                        item['value'])
            verify = bool(item.get('verify', True))
        elif isinstance(item, (list, tuple)) and len(item) == 4:
            index, sub, dtype, value = item
        else:
            raise BusConfigError(f'{where}: [index, subindex, type, value] or a mapping with '
                                 f'those keys, got {item!r}')
        if dtype not in SDO_TYPES:
            raise BusConfigError(f'{where}: type {dtype!r} is not one of ' + ', '.join(SDO_TYPES))
        index, sub = _int(index, f'{where} index'), _int(sub, f'{where} subindex')
        if not (0 <= index <= 0xFFFF and 0 <= sub <= 0xFF):
            raise BusConfigError(f'{where}: index 0..0xFFFF, subindex 0..0xFF')
        out.append(StartupSdo(index, sub, dtype, _sdo_value(dtype, value, where), verify))
    return tuple(out)


def _dc(raw: Any, what: str) -> Optional[DcConfig]:
    if raw is None or raw is False:
        return None
    if not isinstance(raw, dict):
        raise BusConfigError(f'{what}: dc is a mapping {{assign_activate: 0x0300, '
                             'sync0_shift_ns: ...}} or null (free run)')
    _check_keys(raw, 'dc', f'{what} dc')
    if 'assign_activate' not in raw:
        raise BusConfigError(f'{what} dc: assign_activate missing (the ESI\'s AssignActivate, '
                             'e.g. 0x0300 for SYNC0)')
    act = _int(raw['assign_activate'], f'{what} dc.assign_activate')
    if act not in DC_ACTIVATIONS:
        raise BusConfigError(f'{what} dc.assign_activate 0x{act:04X} is not one of '
                             + ', '.join(f'0x{a:04X}' for a in DC_ACTIVATIONS)
                             + ' (SYNC0, SYNC0 + SYNC1)')
    shift = raw.get('sync0_shift_ns')
    if shift is not None:
        shift = _int(shift, f'{what} dc.sync0_shift_ns')
        if shift < 0:
            raise BusConfigError(f'{what} dc.sync0_shift_ns must be >= 0 ns')
    sync1 = _int(raw.get('sync1_cycle_ns', 0), f'{what} dc.sync1_cycle_ns')
    if sync1 < 0 or (sync1 and act != 0x0700):
        raise BusConfigError(f'{what} dc.sync1_cycle_ns needs assign_activate 0x0700 and >= 0')
    return DcConfig(act, shift, sync1)


def _slave(raw: Any, i: int, where: str) -> SlaveConfig:
    what = f'{where}: slave {i + 1}'
    if not isinstance(raw, dict) or 'name' not in raw:
        raise BusConfigError(f'{what}: needs name, kind, vendor_id, product_code')
    what = f'{where}: slave {raw["name"]!r}'
    _check_keys(raw, 'slave', what)
    kind = raw.get('kind')
    if kind not in KINDS:
        raise BusConfigError(f'{what}: kind {kind!r} is not one of ' + ', '.join(KINDS))
    for key in ('vendor_id', 'product_code'):
        if key not in raw:
            raise BusConfigError(f'{what}: {key} missing (the identity is checked at start)')
    mapping = raw.get('pdo_mapping', 'auto')
    if mapping not in PDO_MAPPINGS:
        raise BusConfigError(f'{what}: pdo_mapping {mapping!r} is not one of '
                             + ', '.join(PDO_MAPPINGS))
    rx_pdo = _int(raw.get('rx_pdo', 0x1600), f'{what} rx_pdo')
    tx_pdo = _int(raw.get('tx_pdo', 0x1A00), f'{what} tx_pdo')
    if not 0x1600 <= rx_pdo <= 0x17FF or not 0x1A00 <= tx_pdo <= 0x1BFF:
        raise BusConfigError(f'{what}: rx_pdo must be 0x1600..0x17FF and tx_pdo 0x1A00..0x1BFF')
    slave = SlaveConfig(
        name=str(raw['name']), kind=kind,
        vendor_id=_int(raw['vendor_id'], f'{what} vendor_id'),
        product_code=_int(raw['product_code'], f'{what} product_code'),
        revision=None if raw.get('revision') is None else _int(raw['revision'], f'{what} revision'),
        outputs=_entries(raw.get('outputs'), f'{what} outputs'),
        inputs=_entries(raw.get('inputs'), f'{what} inputs'),
        pdo_mapping=mapping, rx_pdo=rx_pdo, tx_pdo=tx_pdo,
        complete_access=bool(raw.get('complete_access', False)),
        sdo=_sdos(raw.get('sdo'), what), dc=_dc(raw.get('dc'), what))
    if kind == 'cia402_drive':
        for needed, layout in ((DRIVE_OUTPUTS, slave.outputs), (DRIVE_INPUTS, slave.inputs)):
            missing = [n for n in needed if n not in layout.names()]
            if missing:
                raise BusConfigError(f'{what}: a cia402_drive needs entries {missing}')
        for name, index in (('controlword', 0x6040), ('target_torque', 0x6071),
                            ('statusword', 0x6041), ('mode_of_operation', 0x6060),
                            ('mode_display', 0x6061), ('error_code', 0x603F)):
            entry = slave.outputs.entry(name) or slave.inputs.entry(name)
            if entry is not None and (entry.index, entry.subindex) != (index, 0):
                raise BusConfigError(f'{what}: entry {name} is object 0x{index:04X}:00, not '
                                     f'0x{entry.index:04X}:{entry.subindex:02X}')
    if kind == 'coupler' and (slave.outputs.entries or slave.inputs.entries):
        raise BusConfigError(f'{what}: a coupler has no process data: remove its entries (or '
                             'make it kind: passive)')
    return slave


def _number(value: Any) -> Any:
    """A YAML number; also a string such as '1.0e5', which YAML 1.1 does not read as a float."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _scaling(raw: Any, what: str) -> Scaling:
    if isinstance(raw, dict) and 'steps' in raw:
        raw = raw['steps']
    if not isinstance(raw, (list, tuple)) or not raw:
        raise BusConfigError(f'{what}: a scaling is a list of {{factor, offset}} steps')
    steps = []
    for step in raw:
        factor = _number(step.get('factor')) if isinstance(step, dict) else None
        offset = _number(step.get('offset', 0.0)) if isinstance(step, dict) else None
        if not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor == 0:
            raise BusConfigError(f'{what}: factor must be a finite non-zero number, got {factor!r}')
        if not isinstance(offset, (int, float)) or not math.isfinite(offset):
            raise BusConfigError(f'{what}: offset must be finite, got {offset!r}')
        steps.append(Affine(float(factor), float(offset)))
    return Scaling(tuple(steps))


def _signal(raw: Any, by_name: Dict[str, SlaveConfig], what: str) -> SignalConfig:
    src = raw.get('source') if isinstance(raw, dict) else None
    if not isinstance(src, dict) or 'slave' not in src or 'entry' not in src:
        raise BusConfigError(f'{what}: needs source: {{slave: NAME, entry: NAME}} and steps')
    slave = by_name.get(src['slave'])
    if slave is None:
        raise BusConfigError(f'{what}: source slave {src["slave"]!r} is not in `slaves`')
    if src['entry'] not in slave.inputs.names():
        raise BusConfigError(f'{what}: slave {slave.name} has no input entry {src["entry"]!r} '
                             f'(it has {", ".join(slave.inputs.names())})')
    if slave.passive:
        raise BusConfigError(f'{what}: slave {slave.name} is {slave.kind}: nothing reads its '
                             'process data (make it analog_input or encoder)')
    return SignalConfig(Source(slave.name, src['entry']), _scaling(raw.get('steps'), what))


def _channel(name: Any, raw: Any, by_name: Dict[str, SlaveConfig], where: str) -> ChannelConfig:
    what = f'{where}: channel {name}'
    if not isinstance(raw, dict):
        raise BusConfigError(f'{what}: a channel is a mapping (drive, position, velocity, '
                             'pressure, ...)')
    _check_keys(raw, 'channel', what)
    drive = by_name.get(str(raw.get('drive')))
    if drive is None or drive.kind != 'cia402_drive':
        raise BusConfigError(f'{what}: drive {raw.get("drive")!r} must name a cia402_drive slave')
    rated = raw.get('rated_torque')
    if rated is not None and (isinstance(rated, bool) or not isinstance(rated, (int, float))
                              or not math.isfinite(rated) or not rated > 0):
        raise BusConfigError(f'{what}: rated_torque [N m] (object 0x6076) must be > 0, or '
                             'omitted to use the drive\'s')
    if 'pressure' not in raw:
        raise BusConfigError(f'{what}: pressure {{source, steps}} is required: it is the '
                             'force feedback')
    ext = raw.get('external_force')
    ext_signal, ext_channel, ext_sign = None, None, -1.0
    if isinstance(ext, dict) and 'from_channel' in ext:
        ext_channel = str(ext['from_channel'])
        ext_sign = float(ext.get('sign', -1.0))
    elif ext is not None:
        ext_signal = _signal(ext, by_name, f'{what} external_force')
    endpoint = raw.get('endpoint_position')
    return ChannelConfig(
        name=str(name), drive=drive.name, rated_torque=None if rated is None else float(rated),
        position=_scaling(raw.get('position'), f'{what} position'),
        velocity=_scaling(raw.get('velocity'), f'{what} velocity'),
        pressure=_signal(raw['pressure'], by_name, f'{what} pressure'),
        endpoint_position=None if endpoint is None else _signal(endpoint, by_name,
                                                                f'{what} endpoint_position'),
        external_force=ext_signal, external_from_channel=ext_channel, external_sign=ext_sign)


def entry_name(index: int, subindex: int) -> str:
    """The name a YAML entry of object ``index:subindex`` gets from ``ethercat_scan``."""
    if subindex == 0 and index in DRIVE_OBJECTS:
        return DRIVE_OBJECTS[index]
    return f'x{index:04x}_{subindex:02x}'


def keys_markdown() -> List[str]:
    """The bus YAML's keys as markdown tables (``docs/parameters.md``)."""
    titles = {'slave': 'Per slave (`slaves:` list, bus order)',
              'dc': 'Distributed clocks (`dc:` of a slave)',
              'sdo': 'Start-up SDO (an entry of `sdo:` written as a mapping)',
              'channel': 'Per channel (`channels:`)'}
    out: List[str] = []
    for where, title in titles.items():
        out += [f'{title}:', '', '| key | type | default | description |', '|---|---|---|---|']
        for k in KEYS:
            if k.where == where:
                text = k.description.replace('|', '\\|')
                out.append(f'| `{k.name}` | {k.type} | {k.default} | {text} |')
        out.append('')
    return out


__all__ = ['KINDS', 'DTYPES', 'SDO_TYPES', 'PDO_MAPPINGS', 'DC_ACTIVATIONS', 'KEYS', 'Key',
           'PdoEntry', 'PdoLayout', 'StartupSdo', 'DcConfig', 'SlaveConfig', 'Affine', 'Scaling',
           'Source', 'SignalConfig', 'ChannelConfig', 'BusConfig', 'entry_name',
           'keys_markdown']
