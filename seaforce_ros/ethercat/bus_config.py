"""The EtherCAT bus description the hardware node works from (no ROS, no pysoem).

A bus YAML (``config/ethercat_bus.yaml`` is the template) lists the slaves in bus order with
the identity each must have, their process-data entries in IOmap order, and per channel where
its signals live and how raw values scale to SI units:

.. code-block:: yaml

    slaves:                          # bus order
      - name: pinch_drive
        kind: cia402_drive           # or analog_input, encoder
        vendor_id: 0x00000A5B
        product_code: 0x00001402
        revision: 0x00000001
        outputs: [[controlword, 0x6040, 0, u16], [target_torque, 0x6071, 0, i16],
                  [mode_of_operation, 0x6060, 0, i8]]
        inputs:  [[statusword, 0x6041, 0, u16], [position, 0x6064, 0, i32],
                  [velocity, 0x606C, 0, i32], [torque, 0x6077, 0, i16]]
    channels:
      pinch:
        drive: pinch_drive
        rated_torque: 1.0            # N m per 1000 units of 0x6071 / 0x6077
        position: [{factor: 5.992e-6}]               # counts -> rad (2 pi / 2^20)
        velocity: [{factor: 5.992e-6}]               # counts/s -> rad/s
        pressure:                                     # ADC counts -> V -> Pa -> N m
          source: {slave: pressure_adc, entry: value1}
          steps: [{factor: 3.0518e-4}, {factor: 1.0e5, offset: 0.0}, {factor: 2.0e-5}]
        endpoint_position: null      # optional {source: {...}, steps: [...]}
        external_force: null         # optional {source: ...} or {from_channel: wrist, sign: -1}

Every mistake (unknown kind, an entry a channel names that no slave has, a bad type, a
missing identity) raises :class:`BusConfigError` naming the item and what to write instead.
"""
from __future__ import annotations

import math
import pathlib
import struct
from dataclasses import dataclass
from typing import Dict, Optional, Tuple

from .errors import BusConfigError

KINDS = ('cia402_drive', 'analog_input', 'encoder')
DTYPES = {'u8': 'B', 'i8': 'b', 'u16': 'H', 'i16': 'h', 'u32': 'I', 'i32': 'i'}
DRIVE_OUTPUTS = ('controlword', 'target_torque')
DRIVE_INPUTS = ('statusword', 'position', 'velocity')


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


@dataclass(frozen=True)
class SlaveConfig:
    name: str
    kind: str
    vendor_id: int
    product_code: int
    revision: Optional[int]
    outputs: PdoLayout
    inputs: PdoLayout


@dataclass(frozen=True)
class Affine:
    """y = factor * x + offset (one step of a scaling chain)."""

    factor: float
    offset: float = 0.0


@dataclass(frozen=True)
class Scaling:
    """A chain of affine steps, raw -> SI; also invertible (SI -> raw)."""

    steps: Tuple[Affine, ...]

    def __post_init__(self):
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
    rated_torque: float                      # N m per 1000 units (0x6076)
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

    @staticmethod
    def load(path) -> 'BusConfig':
        import yaml
        path = pathlib.Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except OSError as exc:
            raise BusConfigError(f'cannot read bus configuration {path}: {exc}') from exc
        except yaml.YAMLError as exc:
            raise BusConfigError(f'{path} is not valid YAML: {exc}') from exc
        return BusConfig.from_dict(data, where=str(path))

    @staticmethod
    def from_dict(data, where: str = 'bus configuration') -> 'BusConfig':
        if not isinstance(data, dict) or 'slaves' not in data or 'channels' not in data:
            raise BusConfigError(f'{where}: needs top-level keys `slaves` (list, bus order) '
                                 'and `channels` (mapping)')
        slaves = tuple(_slave(s, i, where) for i, s in enumerate(data['slaves'] or []))
        if not slaves:
            raise BusConfigError(f'{where}: `slaves` is empty')
        names = [s.name for s in slaves]
        if len(set(names)) != len(names):
            raise BusConfigError(f'{where}: slave names must be unique: {names}')
        by_name = {s.name: s for s in slaves}
        channels = tuple(_channel(name, c or {}, by_name, where)
                         for name, c in (data['channels'] or {}).items())
        if not channels:
            raise BusConfigError(f'{where}: `channels` is empty')
        known = {c.name for c in channels}
        for c in channels:
            if c.external_from_channel is not None and c.external_from_channel not in known:
                raise BusConfigError(f'{where}: channel {c.name}: external_force.from_channel '
                                     f'{c.external_from_channel!r} is not a channel')
        return BusConfig(slaves, channels)


def _int(value, what):
    if isinstance(value, bool) or not isinstance(value, int):
        raise BusConfigError(f'{what} must be an integer (e.g. 0x00001402), got {value!r}')
    return value


def _entries(raw, what) -> PdoLayout:
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


def _slave(raw, i, where) -> SlaveConfig:
    what = f'{where}: slave {i + 1}'
    if not isinstance(raw, dict) or 'name' not in raw:
        raise BusConfigError(f'{what}: needs name, kind, vendor_id, product_code')
    what = f'{where}: slave {raw["name"]!r}'
    kind = raw.get('kind')
    if kind not in KINDS:
        raise BusConfigError(f'{what}: kind {kind!r} is not one of ' + ', '.join(KINDS))
    for key in ('vendor_id', 'product_code'):
        if key not in raw:
            raise BusConfigError(f'{what}: {key} missing (the identity is checked at start)')
    slave = SlaveConfig(
        name=str(raw['name']), kind=kind,
        vendor_id=_int(raw['vendor_id'], f'{what} vendor_id'),
        product_code=_int(raw['product_code'], f'{what} product_code'),
        revision=None if raw.get('revision') is None else _int(raw['revision'], f'{what} revision'),
        outputs=_entries(raw.get('outputs'), f'{what} outputs'),
        inputs=_entries(raw.get('inputs'), f'{what} inputs'))
    if kind == 'cia402_drive':
        for needed, layout in ((DRIVE_OUTPUTS, slave.outputs), (DRIVE_INPUTS, slave.inputs)):
            missing = [n for n in needed if n not in layout.names()]
            if missing:
                raise BusConfigError(f'{what}: a cia402_drive needs entries {missing}')
    return slave


def _number(value):
    """A YAML number; also a string such as '1.0e5', which YAML 1.1 does not read as a float."""
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            return value
    return value


def _scaling(raw, what) -> Scaling:
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


def _signal(raw, by_name, what) -> SignalConfig:
    src = raw.get('source') if isinstance(raw, dict) else None
    if not isinstance(src, dict) or 'slave' not in src or 'entry' not in src:
        raise BusConfigError(f'{what}: needs source: {{slave: NAME, entry: NAME}} and steps')
    slave = by_name.get(src['slave'])
    if slave is None:
        raise BusConfigError(f'{what}: source slave {src["slave"]!r} is not in `slaves`')
    if src['entry'] not in slave.inputs.names():
        raise BusConfigError(f'{what}: slave {slave.name} has no input entry {src["entry"]!r} '
                             f'(it has {", ".join(slave.inputs.names())})')
    return SignalConfig(Source(slave.name, src['entry']), _scaling(raw.get('steps'), what))


def _channel(name, raw, by_name, where) -> ChannelConfig:
    what = f'{where}: channel {name}'
    drive = by_name.get(raw.get('drive'))
    if drive is None or drive.kind != 'cia402_drive':
        raise BusConfigError(f'{what}: drive {raw.get("drive")!r} must name a cia402_drive slave')
    rated = raw.get('rated_torque')
    if not isinstance(rated, (int, float)) or not rated > 0:
        raise BusConfigError(f'{what}: rated_torque [N m] (object 0x6076) must be > 0')
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
        name=str(name), drive=drive.name, rated_torque=float(rated),
        position=_scaling(raw.get('position'), f'{what} position'),
        velocity=_scaling(raw.get('velocity'), f'{what} velocity'),
        pressure=_signal(raw['pressure'], by_name, f'{what} pressure'),
        endpoint_position=None if endpoint is None else _signal(endpoint, by_name,
                                                                f'{what} endpoint_position'),
        external_force=ext_signal, external_from_channel=ext_channel, external_sign=ext_sign)
