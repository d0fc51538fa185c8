"""``ethercat_scan``: what is on an EtherCAT bus, and a bus YAML for it.

    ros2 run seaforce_ros ethercat_scan --interface enp3s0 [--output bus.yaml]
        [--channels wrist,pinch]

Finds every slave (SOEM's ``config_init``: the bus then stays in PRE-OP and is left in INIT),
reads its SII (identity, name, mailbox, the PDOs it lists) and, over CoE where it has it, its
device type (0x1000), name (0x1008), the PDO mapping it holds now (0x1C12/0x1C13 and the
mapping objects) and, for a drive, the objects CST needs (0x6071, 0x6077, 0x6061, 0x603F) and
its scaling (0x6076, 0x6072). It prints one line per slave and writes a bus YAML that
:meth:`~.bus_config.BusConfig.load` accepts and that configures as written: each drive with
the CST mapping the master writes at PRE-OP (the drive's own mapping in a comment), each
terminal with the entries its SII maps, couplers and slaves nobody reads as such, one channel
per drive with placeholder scalings marked ``CHECK``. Nothing is written to a slave.

The functions take a pysoem-shaped master (:func:`scan` on an opened one), so that the tests
run them on the emulator.
"""
from __future__ import annotations

import argparse
import datetime
import math
import struct
import sys
from dataclasses import dataclass, field
from typing import Any, List, Optional, Sequence, Tuple

from .bus_config import DRIVE_OBJECTS, BusConfig, entry_name
from .coe import (NO_OBJECT, NO_SUBINDEX, CoeError, SdoAbortError, read_drive, read_mapping)
from .errors import EthercatError
from .master import ESC_DC, ESC_FEATURES, REGISTER_TIMEOUT_US, PysoemSdoPort
from .sii import describe, read_sii

#: CiA 402 device profile number in 0x1000's low word
PROFILE_402 = 402
#: the CST mapping a drive gets (name, index, type); mode/error entries only where it has them
CST_OUTPUTS = (('controlword', 0x6040, 'u16'), ('target_torque', 0x6071, 'i16'),
               ('mode_of_operation', 0x6060, 'i8'))
CST_INPUTS = (('statusword', 0x6041, 'u16'), ('position', 0x6064, 'i32'),
              ('velocity', 0x606C, 'i32'), ('torque', 0x6077, 'i16'),
              ('mode_display', 0x6061, 'i8'), ('error_code', 0x603F, 'u16'))
_OPTIONAL = {0x6060, 0x6061, 0x603F, 0x6077}
#: CoE data types (SII PDO entries) that are signed
_SIGNED = {0x02: 8, 0x03: 16, 0x04: 32}
COUNTS_PER_REV = 2 ** 20
ADC_VOLTS_PER_COUNT = 10.0 / 32767


@dataclass
class Found:
    """One slave as the scan saw it."""

    position: int
    name: str
    vendor_id: int
    product_code: int
    revision: int
    serial: int
    kind: str = 'passive'
    coe: bool = False
    dc: bool = False
    device_type: Optional[int] = None
    device_name: str = ''
    held: List[Tuple[int, List[Tuple[int, int, int]]]] = field(default_factory=list)  # rx+tx
    outputs: List[Tuple[str, int, int, str]] = field(default_factory=list)
    inputs: List[Tuple[str, int, int, str]] = field(default_factory=list)
    rx_pdo: int = 0x1600
    tx_pdo: int = 0x1A00
    rated_torque_mnm: Optional[int] = None
    max_torque_permille: Optional[int] = None
    notes: List[str] = field(default_factory=list)
    yaml_name: str = ''

    def summary(self) -> str:
        what = [self.kind, 'CoE' if self.coe else 'no mailbox']
        if self.dc:
            what.append('DC')
        if self.rated_torque_mnm is not None:
            what.append(f'rated torque {self.rated_torque_mnm} mN m')
        return (f'{self.position + 1:2d}  {self.yaml_name:14s} 0x{self.vendor_id:08X} '
                f'0x{self.product_code:08X} 0x{self.revision:08X}  "{self.name}"  '
                + ', '.join(what))


def _dtype(bits: int, data_type: int = 0, signed: Optional[bool] = None) -> str:
    if signed is None:
        signed = data_type in _SIGNED
    return ('i' if signed else 'u') + str(bits)


def sii_entries(pdos: Sequence[Any]) -> List[Tuple[str, int, int, str]]:
    """YAML entries for the PDOs an SII lists: byte-aligned 8/16/32-bit entries as they are,
    runs of bit entries (and gaps) grouped into one unsigned entry named after its first."""
    out: List[Tuple[str, int, int, str]] = []
    names: set = set()
    run: List[Tuple[int, int, int]] = []

    def add(name: str, index: int, sub: int, dtype: str) -> None:
        base, k = name, 2
        while name in names:
            name, k = f'{base}_{k}', k + 1
        names.add(name)
        out.append((name, index, sub, dtype))

    for pdo in pdos:
        if not pdo.assigned:
            continue
        types = pdo.types or (0,) * len(pdo.entries)
        for (index, sub, bits), data_type in zip(pdo.entries, types):
            if not run and bits in (8, 16, 32) and index:
                add(_entry_name(index, sub, bits), index, sub, _dtype(bits, data_type))
                continue
            run.append((index, sub, bits))
            total = sum(b for _, _, b in run)
            if total in (8, 16, 32):
                first = next(((i, s) for i, s, _ in run if i), (0, 0))
                add(_entry_name(first[0], first[1], total, status=True), first[0], first[1],
                    _dtype(total, signed=False))
                run = []
    return out


def _entry_name(index: int, sub: int, bits: int, status: bool = False) -> str:
    """``status1`` / ``value1`` for a CiA 401-like analog channel (0x60n0), the drive names,
    else ``x6000_11``."""
    if 0x6000 <= index <= 0x60F0 and index & 0x0F == 0 and index not in DRIVE_OBJECTS:
        n = (index - 0x6000) // 0x10 + 1
        if status or sub == 1:
            return f'status{n}'
        if sub == 0x11:
            return f'value{n}'
    return entry_name(index, sub)


def _has(port: PysoemSdoPort, index: int) -> bool:
    try:
        port.read(index, 0)
        return True
    except SdoAbortError as exc:
        if exc.code in (NO_OBJECT, NO_SUBINDEX):
            return False
        raise


def scan_slave(master: Any, position: int, pysoem: Any) -> Found:
    """Everything the scan reads from one slave (module docstring)."""
    slave = master.slaves[position]
    sii = read_sii(lambda word: bytes(slave.eeprom_read(word)))
    found = Found(position, sii.name or slave.name, slave.man, slave.id, slave.rev, sii.serial,
                  coe=sii.has_coe)
    try:
        features = struct.unpack('<H', slave._fprd(ESC_FEATURES, 2, REGISTER_TIMEOUT_US))[0]
        found.dc = bool(features & ESC_DC)
    except Exception:
        found.notes.append('ESC features not readable')
    port = PysoemSdoPort(slave, f'slave {position + 1}', pysoem)
    tx_sii = [e for p in sii.tx_pdos if p.assigned for e in p.entries]
    rx_sii = [e for p in sii.rx_pdos if p.assigned for e in p.entries]
    if found.coe:
        try:
            found.device_type = struct.unpack('<I', port.read(0x1000, 0)[:4])[0]
        except CoeError:
            pass
        try:
            found.device_name = port.read(0x1008, 0, 512).decode('latin-1').rstrip('\0')
        except CoeError:
            pass
        try:
            found.held = read_mapping(port, 0x1C12) + read_mapping(port, 0x1C13)
        except CoeError as exc:
            found.notes.append(f'mapping not readable over CoE ({exc})')
    is_drive = (found.device_type is not None and found.device_type & 0xFFFF == PROFILE_402) \
        or any(i == 0x6041 for _, entries in found.held for i, _, _ in entries) \
        or any(i == 0x6041 for i, _, _ in tx_sii)
    if is_drive and found.coe:
        found.kind = 'cia402_drive'
        _drive(found, port)
    elif is_drive:
        found.kind = 'cia402_drive'
        found.notes.append('a drive without CoE: its SII mapping is taken (pdo_mapping: sii)')
        found.outputs = sii_entries(sii.rx_pdos)
        found.inputs = sii_entries(sii.tx_pdos)
    elif not tx_sii and not rx_sii and not found.held:
        found.kind = 'coupler'
    else:
        analog = any(0x6000 <= i <= 0x60F0 and s == 0x11 for i, s, _ in tx_sii)
        found.kind = 'analog_input' if analog else 'passive'
        found.outputs = sii_entries(sii.rx_pdos)
        found.inputs = sii_entries(sii.tx_pdos)
    return found


def _drive(found: Found, port: PysoemSdoPort) -> None:
    """A CoE drive: the CST mapping made of the objects it has, its mapping objects, its
    scaling."""
    missing = [name for name, index, _ in CST_OUTPUTS + CST_INPUTS
               if index not in _OPTIONAL and not _has(port, index)]
    if missing:
        found.notes.append('it lacks ' + ', '.join(missing) + ': no CST with this drive?')
    found.outputs = [(n, i, 0, t) for n, i, t in CST_OUTPUTS
                     if i not in _OPTIONAL or _has(port, i)]
    found.inputs = [(n, i, 0, t) for n, i, t in CST_INPUTS
                    if i not in _OPTIONAL or _has(port, i)]
    for attr, candidates in (('rx_pdo', range(0x1600, 0x1604)), ('tx_pdo', range(0x1A00, 0x1A04))):
        for index in candidates:
            if _has(port, index):
                setattr(found, attr, index)
                break
    drive = read_drive(port)
    found.rated_torque_mnm = drive.rated_torque_mnm
    found.max_torque_permille = drive.max_torque_permille


def scan(master: Any, pysoem: Any) -> List[Found]:
    """Find and read every slave on an opened master (left in PRE-OP)."""
    count = master.config_init()
    if count <= 0:
        raise EthercatError(f'no EtherCAT slave answered (config_init returned {count}): check '
                            'cabling and power')
    found = [scan_slave(master, k, pysoem) for k in range(count)]
    counters: dict = {}
    for f in found:
        base = {'cia402_drive': 'drive', 'analog_input': 'analog', 'encoder': 'encoder',
                'coupler': 'coupler'}.get(f.kind, 'slave')
        counters[base] = counters.get(base, 0) + 1
        f.yaml_name = f'{base}{counters[base]}'
    return found


# --- the YAML -------------------------------------------------------------------------------
def _entries_text(entries: Sequence[Tuple[str, int, int, str]], indent: int) -> str:
    if not entries:
        return '[]'
    items = [f'[{n}, 0x{i:04X}, 0x{s:02X}, {t}]' for n, i, s, t in entries]
    pad = ' ' * indent
    return '[' + (',\n' + pad + ' ').join(items) + ']'


def bus_yaml(found: Sequence[Found], interface: str, channels: Sequence[str] = (),
             when: Optional[str] = None) -> Tuple[str, List[str]]:
    """The bus YAML text for ``found``, and the problems that keep it from configuring."""
    problems: List[str] = []
    when = when or datetime.datetime.now().strftime('%Y-%m-%d %H:%M')
    lines = [f'# Bus YAML written by ethercat_scan on {interface}, {when}: {len(found)} slaves '
             'in bus order.',
             '# Before the first power-on check every line marked CHECK '
             '(docs/ethercat-hardware.md).',
             'slaves:']
    for f in found:
        lines += [f'  - name: {f.yaml_name:<20s} # "{f.name}", serial {f.serial}'
                  + (f', 0x1008 "{f.device_name}"' if f.device_name and f.device_name != f.name
                     else ''),
                  f'    kind: {f.kind}',
                  f'    vendor_id: 0x{f.vendor_id:08X}',
                  f'    product_code: 0x{f.product_code:08X}',
                  f'    revision: 0x{f.revision:08X}']
        for note in f.notes:
            lines.append(f'    # {note}')
        if f.kind == 'coupler':
            continue
        if f.kind == 'cia402_drive' and f.coe:
            for pdo, entries in f.held:
                lines.append(f'    # at power-up 0x{pdo:04X} maps {describe(entries)}')
            lines.append('    # the master writes this CST mapping at PRE-OP and reads it back:')
            if (f.rx_pdo, f.tx_pdo) != (0x1600, 0x1A00):
                lines += [f'    rx_pdo: 0x{f.rx_pdo:04X}', f'    tx_pdo: 0x{f.tx_pdo:04X}']
        elif f.coe:
            lines.append('    pdo_mapping: check          # its mapping as the SII lists it')
        else:
            lines.append('    pdo_mapping: sii            # no mailbox: the SII\'s mapping')
        lines.append(f'    outputs: {_entries_text(f.outputs, 13)}')
        lines.append(f'    inputs: {_entries_text(f.inputs, 12)}')
        if f.kind == 'cia402_drive':
            if f.rated_torque_mnm is not None:
                limit = ('' if f.max_torque_permille is None else
                         f', max torque 0x6072 = {f.max_torque_permille} per mille '
                         f'({f.max_torque_permille * f.rated_torque_mnm * 1e-6:g} N m)')
                lines.append(f'    # rated torque 0x6076 = {f.rated_torque_mnm} mN m{limit}')
            if f.dc:
                lines.append('    # it has distributed clocks; if it needs SYNC0 (AL 0x0030 at '
                             'activate), its ESI\'s AssignActivate:')
                lines.append('    # dc: {assign_activate: 0x0300, sync0_shift_ns: 250000}')
    drives = [f for f in found if f.kind == 'cia402_drive']
    analog = [(f, n) for f in found if f.kind == 'analog_input'
              for n, *_ in f.inputs if n.startswith('value')]
    names = list(channels) or [f'channel{k + 1}' for k in range(len(drives))]
    if len(names) != len(drives):
        problems.append(f'{len(drives)} drive(s) found but --channels names {len(names)}')
    lines.append('channels:')
    factor = 2 * math.pi / COUNTS_PER_REV
    for k, f in enumerate(drives):
        name = names[k] if k < len(names) else f'channel{k + 1}'
        lines += [f'  {name}:', f'    drive: {f.yaml_name}']
        if f.rated_torque_mnm:
            lines.append(f'    # rated_torque: omitted: the drive\'s 0x6076 '
                         f'({f.rated_torque_mnm * 1e-3:g} N m) is used')
        else:
            lines.append('    rated_torque: 1.0             # CHECK: the drive gives no 0x6076')
        lines += [f'    position: [{{factor: {factor!r}}}]   # CHECK: counts -> rad '
                  f'(2 pi / {COUNTS_PER_REV} counts per turn, direct drive)',
                  f'    velocity: [{{factor: {factor!r}}}]   # CHECK: counts/s -> rad/s']
        if k < len(analog):
            slave, entry = analog[k]
            lines += ['    pressure:                          # CHECK: which input, and its '
                      'chain to F_p',
                      f'      source: {{slave: {slave.yaml_name}, entry: {entry}}}',
                      f'      steps: [{{factor: {ADC_VOLTS_PER_COUNT!r}}}, {{factor: 1.0}}]  '
                      '# counts -> V -> (CHECK: V -> N m)']
        else:
            problems.append(f'no analog input left for channel {name}\'s pressure: add one (or '
                            'write its pressure source by hand)')
    return '\n'.join(lines) + '\n', problems


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog='ethercat_scan', description='List the slaves of an EtherCAT bus and write a bus '
        'YAML for them (docs/ethercat-hardware.md). Nothing is written to a slave.')
    parser.add_argument('--interface', required=True, help='network interface of the bus')
    parser.add_argument('--output', help='write the bus YAML here (default: print it)')
    parser.add_argument('--channels', default='', help='channel names, one per drive in bus '
                        'order, comma-separated (default channel1, channel2, ...)')
    args = parser.parse_args(argv)
    from .master import EthercatBus
    bus = EthercatBus(BusConfig((), ()), args.interface)
    try:
        bus.open()
        found = scan(bus.master, bus._pysoem)
        text, problems = bus_yaml(found, args.interface,
                                  [c for c in args.channels.split(',') if c])
        bus.to_init()
    except EthercatError as exc:
        print(f'ethercat_scan: {exc}', file=sys.stderr)
        return 2
    finally:
        bus.close()
    print(f'{len(found)} slave(s) on {args.interface}:')
    for f in found:
        print(f.summary())
    if args.output:
        with open(args.output, 'w') as out:
            out.write(text)
        print(f'bus YAML written to {args.output}')
    else:
        print(text)
    for problem in problems:
        print(f'ethercat_scan: {problem}', file=sys.stderr)
    return 1 if problems else 0


if __name__ == '__main__':
    sys.exit(main())
