"""The EtherCAT master of the hardware node: pysoem (SOEM) driven from a :class:`BusConfig`.

No ROS here. :class:`EthercatBus` opens the interface (:meth:`~EthercatBus.open`), brings
the bus to SAFE-OP with every slave configured from the bus YAML before anything is written
to a drive (:meth:`~EthercatBus.configure`):

1. ``config_init``: every slave found, its identity checked (vendor, product, revision);
2. each slave's SII read where the YAML needs it (its mailbox: CoE or not; for a slave mapped
   from its SII, the PDOs listed there);
3. distributed clocks (``config_dc``) if a slave has ``dc:``: the propagation delays measured,
   the system times aligned;
4. ``config_map``, whose PRE-OP -> SAFE-OP hook (pysoem's ``config_func``) runs, per slave,
   :func:`~.coe.configure_slave` -- start-up SDOs, the PDO mapping written and read back entry
   by entry, 0x6060 = 10 and the drive's scaling read -- and starts SYNC0 on a DC slave,
   before SOEM reads the mapping over CoE and programs the SyncManagers;
5. the process-data sizes compared with the YAML's, every slave in SAFE-OP.

:meth:`~EthercatBus.request_op` acknowledges AL errors (SAFE-OP + ERR -> SAFE-OP) before it
asks for OP, and names each refusing slave's AL status code with its fix
(:data:`AL_HINTS`). :meth:`~EthercatBus.acknowledge` and :meth:`~EthercatBus.slave_states`
serve the backend's recovery while the cycle runs. The per-cycle path (``set_output``,
``get_input``, ``send``, ``receive``) does no allocation beyond the bytes objects pysoem
itself returns.
"""
from __future__ import annotations

import fcntl
import socket
import struct
import time
from collections import deque
from typing import Any, Callable, Deque, Dict, List, Optional, Tuple

from .bus_config import BusConfig, SlaveConfig
from .coe import CoeError, DriveFindings, SdoAbortError, abort_text, configure_slave
from .errors import BusConfigError, BusError, IdentityError
from .sii import Sii, describe, read_sii

_SIOCGIFFLAGS, _SIOCSIFFLAGS, IFF_PROMISC = 0x8913, 0x8914, 0x100
INIT, PREOP, SAFEOP, OP, ACK = 1, 2, 4, 8, 0x10
STATE_NAMES = {1: 'INIT', 2: 'PRE-OP', 3: 'BOOT', 4: 'SAFE-OP', 8: 'OP'}
#: ESC feature register bit: distributed clocks
ESC_FEATURES, ESC_DC = 0x0008, 0x0004
REG_AL_STATUS = 0x0130
#: Tries of an SDO transfer that got no answer (a lost mailbox frame on a loaded host: SOEM
#: gives a mailbox write 6 ms); an abort is never retried
SDO_ATTEMPTS = 3
#: Emergency messages a slave's port keeps until they are read (the oldest are dropped)
EMERGENCIES_KEPT = 16
#: How long a single register read may take, resent every 2 ms meanwhile [us] (SOEM's own
#: single try, 2 ms, fails now and then on a loaded host)
REGISTER_TIMEOUT_US = 10000

#: AL status codes (ETG.1000.6 table 11) and what to do about them.
AL_CODES = {
    0x0000: 'no error',
    0x0001: 'unspecified error',
    0x0011: 'invalid requested state change',
    0x0012: 'unknown requested state',
    0x0016: 'invalid mailbox configuration',
    0x0017: 'invalid sync manager configuration',
    0x001A: 'synchronization error',
    0x001B: 'sync manager watchdog',
    0x001D: 'invalid output configuration',
    0x001E: 'invalid input configuration',
    0x0020: 'slave needs cold start',
    0x0024: 'invalid input mapping',
    0x0025: 'invalid output mapping',
    0x0027: 'freerun not supported',
    0x0028: 'synchronization not supported',
    0x002C: 'fatal sync error',
    0x002D: 'no sync error',
    0x0030: 'invalid DC SYNC configuration',
    0x0032: 'PLL error',
    0x0033: 'DC sync IO error',
    0x0034: 'DC sync timeout error',
    0x0035: 'invalid DC sync cycle time',
    0x0036: 'invalid DC sync0 cycle time',
    0x0037: 'invalid DC sync1 cycle time',
}
AL_HINTS = {
    0x001A: 'SYNC0 came without outputs too often: the cycle is late (real-time priority, '
            'an isolated core) or the drive\'s sync error limit 0x10F1:02 is too tight',
    0x001B: 'the process data stopped for longer than the drive\'s watchdog: ~/reset or '
            'deactivate/activate acknowledges it',
    0x001D: 'the outputs disagree with the drive\'s mapping: check outputs and pdo_mapping',
    0x001E: 'the inputs disagree with the drive\'s mapping: check inputs and pdo_mapping',
    0x0027: 'the drive needs distributed clocks: add dc: {assign_activate: 0x0300} to it',
    0x0028: 'the drive does not support this synchronisation: check its dc: entry',
    0x002C: 'SYNC0 stopped or came without outputs: see 0x001A',
    0x0030: 'the drive needs SYNC0: add dc: {assign_activate: 0x0300} to this slave in the '
            'bus YAML (its ESI\'s AssignActivate)',
    0x0035: 'the drive\'s sync cycle objects disagree with the cycle: set them in its sdo: '
            'list (e.g. 0x60C2 interpolation time period = the cycle)',
    0x0036: 'SYNC0\'s cycle is not one the drive takes: check the node\'s rate',
}


def al_text(code: int) -> str:
    """``0x0030 (invalid DC SYNC configuration)``."""
    return f'0x{code:04X} ({AL_CODES.get(code, "vendor specific")})'


def interface_flags(interface: str) -> int:
    """The interface's flags (``IFF_*``, as ``ip link`` shows them); OSError if there is no
    such interface."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        request = struct.pack('16sH14x', interface.encode()[:15], 0)
        return int(struct.unpack('16sH14x', fcntl.ioctl(sock, _SIOCGIFFLAGS, request))[1])


def set_promiscuous(interface: str, on: bool) -> None:
    """Set or clear the interface's promiscuous flag, leaving the others as they are now."""
    flags = interface_flags(interface)
    flags = (flags | IFF_PROMISC) if on else (flags & ~IFF_PROMISC)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        fcntl.ioctl(sock, _SIOCSIFFLAGS, struct.pack('16sH14x', interface.encode()[:15], flags))


def _hex(value: Optional[int]) -> str:
    return 'none' if value is None else f'0x{value:08X}'


class PysoemSdoPort:
    """:class:`~.coe.SdoPort` over one pysoem slave (SDO errors -> :class:`CoeError`).

    It listens to the slave's emergency messages from the start: SOEM empties the slave's
    mailbox before a transfer, and pysoem raises an emergency it found there out of the
    transfer (its answer lost) unless a callback takes it. They are kept in
    :attr:`emergencies` ((error code, error register), oldest first, the newest
    :data:`EMERGENCIES_KEPT`) for whoever reads them.
    """

    def __init__(self, slave: Any, name: str, pysoem: Any) -> None:
        self.slave, self.name, self._pysoem = slave, name, pysoem
        self.emergencies: Deque[Tuple[int, int]] = deque(maxlen=EMERGENCIES_KEPT)
        slave.add_emergency_callback(self._emergency)

    def _emergency(self, message: Any) -> None:
        self.emergencies.append((int(message.error_code), int(message.error_reg)))

    def _failed(self, exc: Exception, index: int, subindex: int, what: str) -> CoeError:
        p = self._pysoem
        if isinstance(exc, p.SdoError):
            return SdoAbortError(f'{self.name}: SDO {what} 0x{index:04X}:{subindex:02X} aborted: '
                                 f'{abort_text(exc.abort_code)}', exc.abort_code, index,
                                 subindex)
        if isinstance(exc, p.WkcError):
            return CoeError(f'{self.name}: no answer to the SDO {what} of '
                            f'0x{index:04X}:{subindex:02X} (mailbox timeout): is it powered, in '
                            'PRE-OP or above, with a CoE mailbox?')
        return CoeError(f'{self.name}: SDO {what} of 0x{index:04X}:{subindex:02X} failed: '
                        f'{type(exc).__name__} {getattr(exc, "desc", exc)}')

    def read(self, index: int, subindex: int, size: int = 0, ca: bool = False) -> bytes:
        p = self._pysoem
        for attempt in range(SDO_ATTEMPTS):
            try:
                return bytes(self.slave.sdo_read(index, subindex, size, ca=ca))
            except p.WkcError as exc:             # no answer: the mailbox frames were lost
                if attempt + 1 == SDO_ATTEMPTS:
                    raise self._failed(exc, index, subindex, 'upload') from None
            except (p.SdoError, p.MailboxError, p.PacketError) as exc:
                raise self._failed(exc, index, subindex, 'upload') from None
        raise AssertionError('unreachable')

    def write(self, index: int, subindex: int, data: bytes, ca: bool = False) -> None:
        p = self._pysoem
        for attempt in range(SDO_ATTEMPTS):
            try:
                self.slave.sdo_write(index, subindex, bytes(data), ca=ca)
                return
            except p.WkcError as exc:             # no answer (a write is sent whole again)
                if attempt + 1 == SDO_ATTEMPTS:
                    raise self._failed(exc, index, subindex, 'download') from None
            except (p.SdoError, p.MailboxError, p.PacketError) as exc:
                raise self._failed(exc, index, subindex, 'download') from None


class EthercatBus:
    """pysoem master for one bus configuration.

    Parameters
    ----------
    config : BusConfig
    interface : str
        Network interface the bus is on (needs CAP_NET_RAW and CAP_NET_ADMIN).
    receive_timeout_us : int
        How long ``exchange`` waits for the frame to come back [us].
    cycle_ns : int
        The node's cycle [ns]: SYNC0's cycle on the DC slaves.
    pysoem : module, optional
        The pysoem module (default: imported by :meth:`open`); tests pass a stand-in, and
        the interface is then not touched.

    Attributes
    ----------
    drive_findings : dict
        Slave position -> :class:`~.coe.DriveFindings` of each CoE drive (configure).
    coe : list of bool
        Per slave: it has a CoE mailbox (configure).
    mapping_mode : list of str
        Per slave: the ``pdo_mapping`` in effect (``write``, ``check``, ``sii``).
    """

    def __init__(self, config: BusConfig, interface: str, receive_timeout_us: int = 400,
                 cycle_ns: int = 500000, pysoem: Any = None) -> None:
        self.config = config
        self.interface = interface
        self.receive_timeout_us = int(receive_timeout_us)
        self.cycle_ns = int(cycle_ns)
        self.master: Any = None
        self._pysoem: Any = pysoem
        self._injected = pysoem is not None
        self._was_promiscuous: Optional[bool] = None  # the flag before open(); None: not open
        self.expected_wkc: Optional[int] = None
        self._outputs: List[bytearray] = [bytearray(s.outputs.size) for s in config.slaves]
        self._out_offsets = [s.outputs.offsets() for s in config.slaves]
        self._in_offsets = [s.inputs.offsets() for s in config.slaves]
        self._inputs: List[bytes] = [bytes(s.inputs.size) for s in config.slaves]
        self.drive_findings: Dict[int, DriveFindings] = {}
        self.coe: List[bool] = [False] * len(config.slaves)
        self.mapping_mode: List[str] = ['sii'] * len(config.slaves)
        self.dc_active = False
        self.timings: Dict[str, float] = {}
        self._ports: Dict[int, PysoemSdoPort] = {}

    # --- bring-up ------------------------------------------------------------------------
    def open(self) -> None:
        """Open the interface (a raw socket; nothing is sent yet). Raises :class:`BusError`
        naming what to check; then nothing is left open."""
        if self._injected:
            master = self._pysoem.Master()
            master.open(self.interface)
            self.master = master
            return
        try:
            import pysoem
        except ImportError as exc:
            raise BusError('pysoem is not installed (it has no rosdep key): '
                           '`pip install pysoem` into the Python that runs hardware_node') from exc
        self._pysoem = pysoem
        try:
            # SOEM switches the interface to promiscuous mode and never switches it back:
            # close() restores what it was
            was_promiscuous = bool(interface_flags(self.interface) & IFF_PROMISC)
        except OSError as exc:
            raise BusError(f'no network interface {self.interface!r} ({exc.strerror}); '
                           '`ip link` lists them') from None
        master = pysoem.Master()
        self._was_promiscuous = was_promiscuous
        try:
            master.open(self.interface)
        except Exception as exc:
            self.close()
            raise BusError(
                f'cannot open EtherCAT interface {self.interface!r}: {exc}. Check the name '
                '(ip link) and the capabilities: sudo setcap cap_net_raw,cap_net_admin+ep '
                '$(readlink -f $(which python3))') from exc
        self.master = master

    def slave_name(self, position: int) -> str:
        return f'slave {position + 1} ({self.config.slaves[position].name})'

    def port(self, position: int) -> PysoemSdoPort:
        """SDO access to the slave at ``position`` (0-based)."""
        port = self._ports.get(position)
        if port is None:
            port = self._ports[position] = PysoemSdoPort(
                self.master.slaves[position], self.slave_name(position), self._pysoem)
        return port

    def configure(self) -> None:
        """Find, check and configure every slave, map the process data, bring the bus to
        SAFE-OP (module docstring). Nothing is written to a drive before every identity has
        been checked. Raises :class:`BusError` (:class:`IdentityError` for a wrong device,
        :class:`~.coe.CoeError` for a refused configuration) naming what to fix; the bus is
        then left as it is for :meth:`to_init` and :meth:`close`."""
        pysoem, master = self._pysoem, self.master
        if master is None:
            raise BusError('the EtherCAT interface is not open')
        t0 = time.monotonic()
        self.expected_wkc = None
        self.drive_findings = {}
        self._ports = {}                    # config_init makes new slave objects
        self.dc_active = False
        self._inputs = [bytes(s.inputs.size) for s in self.config.slaves]
        for out in self._outputs:
            out[:] = bytes(len(out))
        try:
            master.always_release_gil = False     # config_map's hooks hold it anyway
        except AttributeError:
            pass
        found = master.config_init()
        if found <= 0:
            raise BusError(f'no EtherCAT slave answered on {self.interface} (config_init '
                           f'returned {found}); check cabling and power')
        expected = self.config.slaves
        if found != len(expected):
            names = [master.slaves[i].name for i in range(found)]
            raise BusError(f'{found} slave(s) on the bus ({", ".join(names)}) but the '
                           f'configuration lists {len(expected)} '
                           f'({", ".join(s.name for s in expected)}); `ethercat_scan '
                           f'--interface {self.interface}` lists them')
        for position, want in enumerate(expected):
            self._check_identity(position, want, master.slaves[position])
        self.timings['init'] = time.monotonic() - t0
        siis = self._read_siis()
        if self.config.uses_dc:
            self._configure_dc()
        errors: List[BaseException] = []
        for position, want in enumerate(expected):
            master.slaves[position].config_func = self._hook(position, want, errors)
        t1 = time.monotonic()
        try:
            master.config_map()
        except CoeError:
            raise
        except BusError:
            raise
        except pysoem.ConfigMapError as exc:
            raise BusError(self._config_map_errors(exc)) from None
        except Exception as exc:
            raise BusError(f'process data mapping failed: {exc}') from exc
        finally:
            for slave in master.slaves:
                slave.config_func = None
        if errors:
            raise errors[0]
        self.timings['map'] = time.monotonic() - t1
        self._check_sizes(siis)
        if master.state_check(pysoem.SAFEOP_STATE, 50000) != pysoem.SAFEOP_STATE:
            raise BusError(f'slaves did not reach SAFE-OP: {self.states_text()}')
        self.expected_wkc = master.expected_wkc
        try:
            master.always_release_gil = True
        except AttributeError:
            pass
        self.timings['configure'] = time.monotonic() - t0

    def _read_siis(self) -> Dict[int, Sii]:
        """The SII of every slave whose configuration needs it: the mailbox of those that
        could use CoE, the PDOs of those mapped from their SII."""
        out: Dict[int, Sii] = {}
        for position, want in enumerate(self.config.slaves):
            if want.kind == 'coupler':
                self.mapping_mode[position] = 'sii'
                continue
            sii = self._sii(position, categories=False)
            self.coe[position] = sii.has_coe
            mode = want.pdo_mapping
            if mode == 'auto':
                mode = 'write' if sii.has_coe and want.kind != 'passive' else 'sii'
            if mode == 'sii' or want.complete_access:
                sii = self._sii(position, categories=True)
            out[position] = sii
            if mode in ('write', 'check') and not sii.has_coe:
                raise BusConfigError(f'{self.slave_name(position)} has no CoE mailbox: its '
                                     f'mapping cannot be {mode}-ed over CoE; set pdo_mapping: '
                                     'sii (the SII\'s) for it')
            if want.sdo and not sii.has_coe:
                raise BusConfigError(f'{self.slave_name(position)} has no CoE mailbox: remove '
                                     'its sdo: list')
            if want.complete_access and not sii.complete_access:
                raise BusConfigError(f'{self.slave_name(position)}: its SII does not announce '
                                     'SDO complete access: set complete_access: false')
            self.mapping_mode[position] = mode
        return out

    def _sii(self, position: int, categories: bool) -> Sii:
        slave = self.master.slaves[position]
        try:
            return read_sii(lambda word: bytes(slave.eeprom_read(word)), categories=categories)
        except Exception as exc:
            raise BusError(f'{self.slave_name(position)}: its SII could not be read ({exc}); '
                           'check the slave') from None

    def _configure_dc(self) -> None:
        master = self.master
        for position, want in enumerate(self.config.slaves):
            if want.dc is None:
                continue
            try:
                features = struct.unpack('<H', master.slaves[position]._fprd(
                    ESC_FEATURES, 2, REGISTER_TIMEOUT_US))[0]
            except self._pysoem.WkcError:
                raise BusError(f'{self.slave_name(position)} did not answer a read of its ESC '
                               'features: check the slave') from None
            if not features & ESC_DC:
                raise BusConfigError(f'{self.slave_name(position)} has no distributed clocks '
                                     '(ESC feature register): remove its dc: entry')
            shift = want.dc.shift_ns(self.cycle_ns)
            if not 0 <= shift < self.cycle_ns:
                raise BusConfigError(f'{self.slave_name(position)}: dc.sync0_shift_ns {shift} '
                                     f'must be below the cycle, {self.cycle_ns} ns')
        if not master.config_dc():
            raise BusError('config_dc found no slave with distributed clocks, but the bus YAML '
                           'asks for them')
        self.dc_active = True

    def _hook(self, position: int, want: SlaveConfig,
              errors: List[BaseException]) -> Callable[[int], None]:
        """pysoem's PRE-OP -> SAFE-OP hook of one slave: its CoE configuration, SYNC0."""
        def hook(slave_pos: int) -> None:
            if errors:
                return
            try:
                mode = self.mapping_mode[position]
                if self.coe[position]:
                    findings = configure_slave(self.port(position), want, mode,
                                               want.complete_access)
                    if findings is not None:
                        self.drive_findings[position] = findings
                if want.dc is not None:
                    dc = want.dc
                    slave = self.master.slaves[position]
                    if dc.assign_activate == 0x0700:
                        slave.dc_sync(True, self.cycle_ns, dc.shift_ns(self.cycle_ns),
                                      dc.sync1_cycle_ns)
                    else:
                        slave.dc_sync(True, self.cycle_ns, dc.shift_ns(self.cycle_ns))
            except BaseException as exc:      # kept for configure: never into SOEM's C code
                errors.append(exc)
        return hook

    def _config_map_errors(self, exc: Any) -> str:
        """One line for pysoem's ConfigMapError (SOEM's own reading of a CoE mapping)."""
        parts = []
        for err in getattr(exc, 'error_list', []):
            position = getattr(err, 'slave_pos', 0) - 1
            who = self.slave_name(position) if 0 <= position < len(self.config.slaves) else \
                'a slave'
            if hasattr(err, 'abort_code'):
                parts.append(f'{who}: SDO 0x{err.index:04X}:{err.subindex:02X} aborted: '
                             f'{abort_text(err.abort_code)}')
            else:
                parts.append(f'{who}: {type(err).__name__} {getattr(err, "desc", "")}')
        return ('reading the PDO mapping over CoE failed: ' + '; '.join(parts or [str(exc)])
                + '; the slave\'s mapping objects (0x1C12/0x1C13) must be readable')

    def _check_sizes(self, siis: Dict[int, Sii]) -> None:
        """The process data SOEM mapped against the YAML: byte counts for every slave, and
        entry by entry for a slave mapped from its SII (a CoE mapping was read back in the
        hook)."""
        from .coe import match_entries
        master = self.master
        for position, want in enumerate(self.config.slaves):
            slave = master.slaves[position]
            n_out, n_in = len(slave.output), len(slave.input)
            if n_out != want.outputs.size or n_in != want.inputs.size:
                raise BusError(
                    f'{self.slave_name(position)} maps {n_out} output / {n_in} input bytes but '
                    f'the configuration describes {want.outputs.size} / {want.inputs.size}: fix '
                    'its outputs/inputs entries (ethercat_scan shows what it maps)')
            sii = siis.get(position)
            if self.mapping_mode[position] != 'sii' or sii is None or want.kind == 'coupler':
                continue
            if self.coe[position]:
                continue        # SOEM mapped it from CoE: compared there when written/checked
            for direction, layout in (('rx', want.outputs), ('tx', want.inputs)):
                found = sii.mapping(direction)
                problem = match_entries(found, layout)
                if problem is not None:
                    name = 'outputs' if direction == 'rx' else 'inputs'
                    raise BusError(f'{self.slave_name(position)}: the {name} its SII maps '
                                   f'({describe(found)}) disagree with the YAML: {problem}; '
                                   f'fix the {name} list')

    def set_process_data_watchdog(self, seconds: float) -> None:
        """Program every drive's SyncManager (process-data) watchdog: a drive whose outputs stop
        for this long drops its torque and faults on its own."""
        for position, want in enumerate(self.config.slaves):
            if want.kind == 'cia402_drive':
                self.master.slaves[position].set_watchdog('processdata', 1e3 * seconds)

    def _check_identity(self, position: int, want: SlaveConfig, slave: Any) -> None:
        got = (slave.man, slave.id, slave.rev)
        mismatch = got[0] != want.vendor_id or got[1] != want.product_code or (
            want.revision is not None and got[2] != want.revision)
        if mismatch:
            raise IdentityError(
                f'slave {position + 1} ({want.name}, "{slave.name}") is not the configured '
                f'device: vendor {_hex(got[0])} product code {_hex(got[1])} revision '
                f'{_hex(got[2])}, expected vendor {_hex(want.vendor_id)} product code '
                f'{_hex(want.product_code)} revision {_hex(want.revision)}. No torque was '
                'commanded; fix the bus YAML or the cabling order.')

    # --- AL states -------------------------------------------------------------------------
    def slave_states(self) -> List[Tuple[int, int]]:
        """Every slave's (AL status, AL status code), read one by one (a few frames; the
        GIL is held only per frame)."""
        out = []
        for slave in self.master.slaves:
            try:
                status, _, code = struct.unpack('<HHH', slave._fprd(REG_AL_STATUS, 6,
                                                                    REGISTER_TIMEOUT_US))
            except Exception:
                status, code = 0, 0          # no answer: shown as state 0
            out.append((status, code))
        return out

    def states_text(self, states: Optional[List[Tuple[int, int]]] = None) -> str:
        """``wrist_drive: OP, pinch_drive: SAFE-OP+ERR 0x001B (sync manager watchdog)``."""
        states = self.slave_states() if states is None else states
        parts = []
        for want, (status, code) in zip(self.config.slaves, states):
            name = STATE_NAMES.get(status & 0x0F, 'no answer' if not status else
                                   f'0x{status & 0x0F:X}')
            text = f'{want.name}: {name}'
            if status & ACK:
                text += f'+ERR {al_text(code)}'
            parts.append(text)
        return ', '.join(parts)

    def acknowledge(self, states: Optional[List[Tuple[int, int]]] = None) -> List[str]:
        """Acknowledge every slave's AL error (request its state with the ack bit: SAFE-OP
        + ERR -> SAFE-OP); returns ``name: code`` of those acknowledged."""
        states = self.slave_states() if states is None else states
        done = []
        for position, (status, code) in enumerate(states):
            if status & ACK:
                slave = self.master.slaves[position]
                slave.state = (status & 0x0F) | ACK
                slave.write_state()
                done.append(f'{self.config.slaves[position].name}: {al_text(code)}')
        return done

    def request_op(self, timeout_s: float = 2.0) -> List[str]:
        """Acknowledge AL errors, then request OP while exchanging process data (the outputs
        as they are set now), as SOEM needs. Returns the errors acknowledged;
        :class:`BusError` naming each slave's AL code and its fix if they do not all get
        there in time."""
        pysoem = self._pysoem
        master = self.master
        acknowledged = self.acknowledge()
        master.state = pysoem.OP_STATE
        master.write_state()
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self.exchange()
            if master.state_check(pysoem.OP_STATE, 1000) == pysoem.OP_STATE:
                return acknowledged
            states = self.slave_states()
            if any(status & ACK for status, _ in states):
                break          # refused with an error: no point waiting
            time.sleep(0.0005)
        raise BusError(self.refusal('did not reach OP', timeout_s))

    def refusal(self, what: str, timeout_s: float) -> str:
        """``slaves did not reach OP: pinch_drive: SAFE-OP+ERR 0x0030 (...): <fix>``."""
        states = self.slave_states()
        hints = [f'{want.name}: {AL_HINTS[code]}'
                 for want, (status, code) in zip(self.config.slaves, states)
                 if status & ACK and code in AL_HINTS]
        return (f'slaves {what} within {timeout_s:g} s: {self.states_text(states)}'
                + ('; ' + '; '.join(hints) if hints else ''))

    def request_safe_op(self) -> None:
        """Bring every slave back to SAFE-OP (their outputs go to their safe state; inputs
        stay readable); :class:`BusError` if they do not all report it."""
        pysoem = self._pysoem
        master = self.master
        master.state = pysoem.SAFEOP_STATE
        master.write_state()
        if master.state_check(pysoem.SAFEOP_STATE, 50000) != pysoem.SAFEOP_STATE:
            raise BusError(f'slaves did not go back to SAFE-OP: {self.states_text()}')

    def request_slaves_op(self, positions: List[int]) -> None:
        """Ask the slaves at ``positions`` for OP (one frame each; no wait)."""
        for position in positions:
            slave = self.master.slaves[position]
            slave.state = OP
            slave.write_state()

    # --- cycle ---------------------------------------------------------------------------
    def set_output(self, slave: int, entry: str, value: int) -> None:
        offset, fmt = self._out_offsets[slave][entry]
        struct.pack_into(fmt, self._outputs[slave], offset, value)

    def get_input(self, slave: int, entry: str) -> Any:
        offset, fmt = self._in_offsets[slave][entry]
        return struct.unpack_from(fmt, self._inputs[slave], offset)[0]

    def send(self) -> None:
        """Write the outputs and send one process-data frame (it comes back with the inputs,
        which :meth:`receive` reads)."""
        master = self.master
        slaves = master.slaves
        for i, data in enumerate(self._outputs):
            if data:
                slaves[i].output = bytes(data)
        master.send_processdata()

    def receive(self) -> int:
        """Receive the frame :meth:`send` sent and read its inputs; return the working
        counter (inputs are only taken from a complete frame)."""
        master = self.master
        wkc = master.receive_processdata(self.receive_timeout_us)
        if wkc == self.expected_wkc:
            slaves = master.slaves
            for i in range(len(self._inputs)):
                self._inputs[i] = slaves[i].input
        return int(wkc)

    def exchange(self) -> int:
        """:meth:`send` then :meth:`receive` (bring-up and shut-down); returns the WKC."""
        self.send()
        return self.receive()

    @property
    def is_open(self) -> bool:
        return self.master is not None

    def poll_emergencies(self, position: int) -> List[Tuple[int, int]]:
        """Read the slave's mailbox once; the emergency messages that were in it, or that
        came during its SDO transfers since the last call (error code, error register),
        oldest first."""
        port = self.port(position)
        p = self._pysoem
        try:
            port.slave.mbx_receive()
        except (p.Emergency, p.MailboxError, p.PacketError, p.WkcError):
            pass
        received = port.emergencies
        out = list(received)
        received.clear()
        return out

    def dc_time(self) -> int:
        """The reference clock's system time [ns] the last frame read (0 without DC)."""
        return int(self.master.dc_time) if self.dc_active else 0

    # --- shut-down -----------------------------------------------------------------------
    def to_init(self) -> bool:
        """Request INIT on every slave; True when they report it."""
        if self.master is None:
            return False
        pysoem = self._pysoem
        try:
            self.master.state = pysoem.INIT_STATE
            self.master.write_state()
            return bool(self.master.state_check(pysoem.INIT_STATE, 50000) == pysoem.INIT_STATE)
        except Exception:
            return False

    def close(self) -> None:
        """Close the master (if open) and give the interface back its promiscuous flag as it
        was before :meth:`open`. Idempotent; safe on every exit path."""
        try:
            if self.master is not None:
                try:
                    self.master.close()
                finally:
                    self.master = None
        finally:
            was = self._was_promiscuous
            self._was_promiscuous = None
            if was is not None:
                try:
                    set_promiscuous(self.interface, was)
                except OSError:
                    pass  # the interface went away meanwhile: nothing to restore
