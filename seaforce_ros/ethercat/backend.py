"""The gripper over EtherCAT as a :class:`~seaforce_ros.core.backend.PlantBackend` (no ROS).

:class:`EthercatBackend` drives :class:`~.master.EthercatBus` (pysoem, imported only when the
bus is opened) and one :class:`~.cia402.DriveSequencer` per drive through the backend
lifecycle:

* **open** -- the network interface (a raw socket; SOEM sets it promiscuous, close gives the
  flag back as it was);
* **configure** -- every slave found and its identity checked before anything is written to
  a drive; at PRE-OP each slave configured from the bus YAML over CoE (start-up SDOs, the
  PDO mapping written and read back entry by entry, 0x6060 = 10) and SYNC0 started on the DC
  slaves; the drives' rated torque 0x6076 and max torque 0x6072 read (a YAML
  ``rated_torque`` that disagrees fails here, naming both; without one the drive's is used);
  bus in SAFE-OP, the drives' process-data watchdog (``drive_watchdog``) programmed. In
  SAFE-OP a slave keeps its outputs in their safe state: no torque can reach a motor;
* **activate** -- each drive's mode read over CoE where 0x6061 is not mapped (a drive not in
  CST fails it); AL errors acknowledged; bus in OP (zero outputs, controlword *disable
  voltage*); every drive told to walk to *Operation enabled* -- which the sequencer reaches
  only while the drive shows mode 10 -- from here one process-data frame per cycle;
* **read / drives / write** -- once per cycle: receive the frame sent at the end of the previous
  cycle (it travelled during the sleep; pysoem releases the GIL), scale the raw inputs to SI
  units, lock the cycle to the reference clock (DC), advance each drive's sequencer on its
  newest statusword and mode, then write controlword and target torque (0x6071, per mille of
  the rated torque, int16) and send. A drive's fault is reported with its 0x603F code (mapped,
  or read over CoE at once) and its emergency message. A reset (``~/reset``) after a bus fault
  first brings the bus back: every AL error acknowledged (SAFE-OP + ERR -> SAFE-OP), OP, the
  modes read again, then the drives' fault reset (bit 7 held ``fault_reset_time``);
* **deactivate** -- zero torque and *disable voltage* every cycle until every drive reports
  its power stage off (at least ``MIN_DISABLE_CYCLES``, at most ``DISABLE_TIMEOUT``), then
  SAFE-OP. A drive that stays powered is an error (the bus still goes to SAFE-OP);
* **close** -- from any state: deactivated first if active, bus to INIT, interface closed.

No torque ever reaches a drive whose newest inputs do not show *Operation enabled* in mode 10:
:meth:`drives` tells PlantCycle so, and PlantCycle zeroes the torque of every other drive.
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any, Dict, List, Optional, Sequence, Tuple

from ..core.backend import (LINK_NOTHING, BackendReport, ChannelReport, LinkStatus,
                            PlantBackend, PlantSample)
from ..core.plant_cycle import PlantOutput
from .bus_config import BusConfig, ChannelConfig
from .cia402 import (CW_DISABLE_VOLTAGE, MODE_CST, DriveSequencer, DriveState,
                     error_text, state_of)
from .coe import CoeError, read_error_code, read_mode, read_sync_counters, set_cst
from .dc import DcLock
from .errors import BusConfigError, BusError
from .master import EthercatBus, al_text

__all__ = ["EthercatBackend", "MIN_DISABLE_CYCLES", "DISABLE_TIMEOUT", "RATED_TORQUE_TOLERANCE"]

#: Cycles of zero torque and *disable voltage* a deactivation sends at least (a drive acts on
#: a controlword a few cycles after it arrives).
MIN_DISABLE_CYCLES = 20
#: How long a deactivation waits for every drive to report its power stage off [s].
DISABLE_TIMEOUT = 0.5
#: Relative difference between the YAML's rated torque and the drive's 0x6076 that fails
#: configure.
RATED_TORQUE_TOLERANCE = 0.005
#: How long a drive may stay held in *Switched on* for want of mode 10 before its channel
#: faults [s].
MODE_TIMEOUT = 0.5
#: How long a reset waits for the bus to come back to OP [s].
RECOVERY_TIMEOUT = 1.0
#: CiA 402 states with the power stage on.
_POWERED = (DriveState.SWITCHED_ON, DriveState.OPERATION_ENABLED,
            DriveState.QUICK_STOP_ACTIVE, DriveState.FAULT_REACTION_ACTIVE)


class _Channel:
    """Per-channel bus addresses, compiled scalings and run-time state."""

    def __init__(self, bus_config: BusConfig, cfg: ChannelConfig) -> None:
        self.cfg = cfg
        self.drive = bus_config.slave_index(cfg.drive)
        self.pos_gain, self.pos_off = cfg.position.compiled()
        self.vel_gain, self.vel_off = cfg.velocity.compiled()
        self.fp_slave = bus_config.slave_index(cfg.pressure.source.slave)
        self.fp_entry = cfg.pressure.source.entry
        self.fp_gain, self.fp_off = cfg.pressure.scaling.compiled()
        self.xe: Optional[Tuple[int, str, float, float]] = None
        if cfg.endpoint_position is not None:
            s = cfg.endpoint_position
            self.xe = (bus_config.slave_index(s.source.slave), s.source.entry,
                       *s.scaling.compiled())
        self.fe: Optional[Tuple[int, str, float, float]] = None
        if cfg.external_force is not None:
            s = cfg.external_force
            self.fe = (bus_config.slave_index(s.source.slave), s.source.entry,
                       *s.scaling.compiled())
        self.rated_torque = cfg.rated_torque          # N m; the drive's after configure
        self.units_per_nm = 1000.0 / (cfg.rated_torque or 1.0)
        self.max_torque: Optional[float] = None       # N m (0x6072), after configure
        drive = bus_config.slaves[self.drive]
        self.has_mode_display = 'mode_display' in drive.inputs.names()
        self.has_mode_output = 'mode_of_operation' in drive.outputs.names()
        self.has_error_code = 'error_code' in drive.inputs.names()
        self.sequencer = DriveSequencer()
        self.controlword = CW_DISABLE_VOLTAGE
        self.mode = 0                 # the mode the drive shows (PDO, or read over CoE)
        self.error_code = 0           # 0x603F (PDO, or read over CoE after a fault)
        self.emergency = ''           # the newest emergency message
        self.fault_seen = False       # a fault being reported now
        self.fault_fetch = False      # its code/emergency being fetched over CoE
        self.held_cycles = 0          # cycles held in Switched on for want of mode 10
        self.reason = ''


class EthercatBackend(PlantBackend):
    """The EtherCAT gripper (see module docstring).

    Parameters
    ----------
    config : BusConfig
        The bus: slaves with identities, PDO entries and their configuration, channels with
        scalings.
    channels : sequence of str
        The node's channels, each one of the configuration's.
    interface : str
        Network interface of the bus (needs CAP_NET_RAW and CAP_NET_ADMIN).
    dt : float > 0
        Cycle period [s] (SYNC0's cycle on DC slaves; the pace of a deactivation's frames).
    receive_timeout : float > 0
        How long a read waits for the process-data frame [s].
    drive_watchdog : float > 0
        Process-data watchdog programmed into every drive at configure [s].
    fault_reset_time : float > 0
        How long each half of a fault-reset pulse is held (bit 7 low, then high) [s].
    bus : EthercatBus, optional
        The master (default: a pysoem one on ``interface``; tests pass another).

    Raises
    ------
    BusConfigError
        A channel the configuration does not have, or an ``external_force.from_channel``
        that is not one of ``channels``.
    """

    status_name = 'hardware: bus'
    channel_prefix = 'hardware'

    def __init__(self, config: BusConfig, channels: Sequence[str], interface: str, dt: float,
                 receive_timeout: float = 4e-4, drive_watchdog: float = 0.1,
                 fault_reset_time: float = 0.01, bus: Optional[EthercatBus] = None) -> None:
        self.channels = tuple(channels)
        self.config = config
        self.ch = [_Channel(config, config.channel(c)) for c in self.channels]
        self._index = {c: i for i, c in enumerate(self.channels)}
        for c in self.ch:
            src = c.cfg.external_from_channel
            if src is not None and src not in self._index:
                raise BusConfigError(f'channel {c.cfg.name}: external_force.from_channel '
                                     f'{src} is not in the node\'s channels')
        self._from = [None if c.cfg.external_from_channel is None
                      else (self._index[c.cfg.external_from_channel], c.cfg.external_sign)
                      for c in self.ch]
        self.units_per_nm = tuple(c.units_per_nm for c in self.ch)
        self.interface = self.hardware_id = interface
        self.dt = float(dt)
        self.drive_watchdog = float(drive_watchdog)
        self.reset_cycles = max(1, int(round(float(fault_reset_time) / self.dt)))
        self.bus = bus if bus is not None else EthercatBus(
            config, interface, int(receive_timeout * 1e6), cycle_ns=int(round(self.dt * 1e9)))
        self.state = 'closed'
        self.wkc_errors_total = 0
        self._reports: List[Tuple[bool, bool, str]] = [(False, False, '')] * len(self.ch)
        self._applied = [0.0] * len(self.ch)     # torque written last cycle [N m]
        self._in_flight = False                  # a frame was sent and not yet received
        self._expected = 0                       # working counter of a complete frame
        self._complete = LINK_NOTHING
        self._bad_frames = 0                     # consecutive incomplete frames
        self._lock = DcLock(int(round(self.dt * 1e9)))
        self._correction = 0.0
        self._mode_timeout = max(1, int(round(MODE_TIMEOUT / self.dt)))
        self._coe_lock = threading.Lock()        # SDO users off the cycle thread, one at a time
        self._seen_complete = True               # a complete frame came while disabling
        self.notes: List[str] = []               # what configure/activate found worth saying
        self.al_status = ''                      # slaves not in OP (diagnostics)
        self.recoveries = 0
        self._sync: Dict[str, Dict[str, int]] = {}

    def describe(self) -> str:
        """One line for the node's start-up log."""
        return (f'EtherCAT on {self.interface} ({len(self.config.slaves)} slaves), channels '
                f'{list(self.channels)}')

    # --- lifecycle ------------------------------------------------------------------------------
    def open(self) -> str:
        self.bus.open()
        self.state = 'opened'
        return f'EtherCAT interface {self.interface} open'

    def configure(self) -> str:
        bus = self.bus
        self.notes = []
        bus.configure()
        self._scaling()
        bus.set_process_data_watchdog(self.drive_watchdog)
        for c in self.ch:
            c.sequencer = DriveSequencer(self.reset_cycles)
            c.controlword = CW_DISABLE_VOLTAGE
        self._zero_outputs()
        self.state = 'configured'
        written = [self.config.slaves[i].name for i, m in enumerate(bus.mapping_mode)
                   if m == 'write']
        dc = [s.name for s in self.config.slaves if s.dc is not None]
        parts = [f'bus in SAFE-OP: {len(self.config.slaves)} slaves, identities checked',
                 f'mapping written and read back on {", ".join(written)}' if written else '',
                 'rated torque ' + ', '.join(f'{c.cfg.name} {c.rated_torque:g} N m'
                                             for c in self.ch),
                 f'SYNC0 on {", ".join(dc)}' if dc else 'free run (no DC)',
                 f'expected working counter {bus.expected_wkc}',
                 f'{1e3 * bus.timings.get("configure", 0.0):.0f} ms',
                 'drives disabled, no torque'] + self.notes
        return '; '.join(p for p in parts if p)

    def _scaling(self) -> None:
        """Each channel's rated torque (the YAML's checked against 0x6076, or the drive's)
        and max torque 0x6072; fails naming both values when they disagree."""
        findings = self.bus.drive_findings
        for c in self.ch:
            found = findings.get(c.drive)
            drive_rated = None if found is None or found.rated_torque_mnm is None else \
                found.rated_torque_mnm * 1e-3
            name = f'channel {c.cfg.name} ({c.cfg.drive})'
            if c.cfg.rated_torque is None:
                if drive_rated is None or drive_rated <= 0:
                    raise BusConfigError(f'{name}: the drive gives no rated torque 0x6076: '
                                         'set rated_torque [N m] for the channel in the bus YAML')
                c.rated_torque = drive_rated
            else:
                c.rated_torque = c.cfg.rated_torque
                if drive_rated is not None and abs(drive_rated - c.cfg.rated_torque) > \
                        RATED_TORQUE_TOLERANCE * drive_rated:
                    raise BusConfigError(
                        f'{name}: rated_torque {c.cfg.rated_torque:g} N m in the bus YAML but '
                        f'the drive\'s 0x6076 is {round(drive_rated * 1e3)} mN m '
                        f'({drive_rated:g} N m): every torque would be scaled wrong; remove '
                        'rated_torque from the YAML to use the drive\'s, or correct it')
            c.units_per_nm = 1000.0 / c.rated_torque
            c.max_torque = None
            if found is not None and found.max_torque_permille is not None:
                c.max_torque = found.max_torque_permille * 1e-3 * c.rated_torque
        self.units_per_nm = tuple(c.units_per_nm for c in self.ch)

    def torque_limit_note(self, torque_limit: float) -> str:
        """What to say about ``torque_limit`` [N m] against the drives' max torque 0x6072
        ('' when it is within every drive's)."""
        above = [f'{c.cfg.name}: {c.max_torque:g} N m' for c in self.ch
                 if c.max_torque is not None and torque_limit > c.max_torque + 1e-9]
        if not above:
            return ''
        return (f'torque_limit {torque_limit:g} N m is above the drives\' max torque 0x6072 ('
                + ', '.join(above) + '): they clamp there')

    def activate(self) -> str:
        bus = self.bus
        expected = bus.expected_wkc
        if expected is None:
            raise BusError('activate needs a configured bus (configure first)')
        modes = self._verify_modes()
        for c in self.ch:
            c.sequencer = DriveSequencer(self.reset_cycles)
            c.sequencer.enable = True
            c.held_cycles = 0
            c.fault_seen = c.fault_fetch = False
            c.reason = ''
        self._reports = [(False, False, '')] * len(self.ch)
        self._applied = [0.0] * len(self.ch)
        self._zero_outputs()
        self._in_flight = False
        self.wkc_errors_total = 0
        self._bad_frames = 0
        self._expected = expected
        self._complete = LinkStatus(True, expected, expected)
        self._lock.reset()
        self._correction = 0.0
        # OP last, and the cycle right after it: once in OP the slaves' process-data
        # watchdogs expect a frame every cycle
        self.state = 'active'
        try:
            acknowledged = bus.request_op()
        except BusError:
            self.state = 'configured'
            raise
        ack = f'; acknowledged AL error(s) {", ".join(acknowledged)}' if acknowledged else ''
        return (f'bus in OP, expected working counter {bus.expected_wkc}; drives enabling '
                f'(mode {modes}){ack}')

    def _verify_modes(self) -> str:
        """Each drive's mode before any enable: read over CoE where 0x6061 is not mapped
        (0x6060 = 10 written again if it is not 10); a drive that will not show 10 fails."""
        shown = []
        for c in self.ch:
            if c.has_mode_display:
                shown.append(f'{c.cfg.name}: 0x6061 mapped')
                continue
            if not self.bus.coe[c.drive]:
                raise BusError(f'channel {c.cfg.name} ({c.cfg.drive}): its mode cannot be read '
                               '(no CoE, 0x6061 not mapped): map mode_display in its inputs')
            port = self.bus.port(c.drive)
            with self._coe_lock:
                mode = read_mode(port)
                if mode != MODE_CST:
                    mode = set_cst(port)
            c.mode = mode
            if mode != MODE_CST:
                raise BusError(f'channel {c.cfg.name} ({c.cfg.drive}): the drive shows mode '
                               f'{mode} (0x6061) after 0x6060 = 10: it does not take cyclic '
                               'synchronous torque; no drive was enabled')
            shown.append(f'{c.cfg.name}: 0x6061 = 10 read over CoE')
        return ', '.join(shown)

    def deactivate(self) -> str:
        bus = self.bus
        if self.state != 'active':           # a failed activate: nothing was enabled
            bus.request_safe_op()
            return 'no drive was enabled; bus in SAFE-OP'
        for c in self.ch:
            c.sequencer.enable = False
        self._applied = [0.0] * len(self.ch)
        powered = self._disable_drives()
        self.state = 'configured'
        states = '' if self._seen_complete else bus.states_text()
        bus.request_safe_op()
        if not self._seen_complete:
            raise BusError('no complete frame while disabling the drives: their states are '
                           f'unknown ({states}); the bus is in SAFE-OP (outputs safe)')
        if powered:
            raise BusError('drive(s) still powered after '
                           f'{DISABLE_TIMEOUT:g} s of disable voltage: ' + ', '.join(powered)
                           + '; the bus is in SAFE-OP (outputs safe): check the drives')
        return 'zero torque, drives disabled, bus in SAFE-OP'

    def close(self) -> str:
        bus = self.bus
        if not bus.is_open:
            self.state = 'closed'
            return ''
        done = ''
        try:
            if self.state == 'active':
                for c in self.ch:
                    c.sequencer.enable = False
                powered = self._disable_drives()
                done = (f'drive(s) still powered ({", ".join(powered)}), ' if powered
                        else 'drives disabled, ')
            ok = bus.to_init()
            return done + ('bus in INIT' if ok else 'bus INIT requested (not all slaves '
                           'reported it)')
        except Exception as exc:   # never raise here: this is the way down from every error
            return f'bus closed after an error on the way to INIT: {exc}'
        finally:
            with self._coe_lock:
                bus.close()
            self.state = 'closed'
            self._in_flight = False

    def _zero_outputs(self) -> None:
        bus = self.bus
        for c in self.ch:
            bus.set_output(c.drive, 'controlword', CW_DISABLE_VOLTAGE)
            bus.set_output(c.drive, 'target_torque', 0)
            if c.has_mode_output:
                bus.set_output(c.drive, 'mode_of_operation', MODE_CST)

    def _disable_drives(self) -> List[str]:
        """Zero torque and *disable voltage* every cycle until no drive is powered; the drives
        still powered after :data:`DISABLE_TIMEOUT` (name: state)."""
        bus = self.bus
        if self._in_flight:      # the cycle's last frame: take it off the wire first
            self._in_flight = False
            bus.receive()
        self._zero_outputs()
        deadline = time.monotonic() + DISABLE_TIMEOUT
        cycles = 0
        self._seen_complete = False
        while True:
            self._seen_complete |= bus.exchange() == bus.expected_wkc
            cycles += 1
            powered = [f'{c.cfg.drive}: {state_of(bus.get_input(c.drive, "statusword")).value}'
                       for c in self.ch
                       if state_of(bus.get_input(c.drive, 'statusword')) in _POWERED]
            if cycles >= MIN_DISABLE_CYCLES and (not powered or time.monotonic() > deadline):
                return powered
            time.sleep(self.dt)

    # --- the cycle ------------------------------------------------------------------------------
    def read(self, sample: PlantSample) -> LinkStatus:
        """Receive the frame sent at the end of the previous cycle and scale its inputs."""
        if not self._in_flight:
            return LINK_NOTHING
        self._in_flight = False
        bus = self.bus
        wkc = bus.receive()
        if wkc != self._expected:
            self.wkc_errors_total += 1
            self._bad_frames += 1
            return LinkStatus(True, wkc, self._expected)
        self._bad_frames = 0
        if bus.dc_active:
            self._correction += self._lock.update(bus.dc_time())
        x, v, fp, fa = sample.position, sample.velocity, sample.pressure_force, sample.effort
        xe, fe = sample.endpoint_position, sample.external_force
        applied = self._applied
        for i, c in enumerate(self.ch):
            x[i] = c.pos_gain * bus.get_input(c.drive, 'position') + c.pos_off
            v[i] = c.vel_gain * bus.get_input(c.drive, 'velocity') + c.vel_off
            fp[i] = c.fp_gain * bus.get_input(c.fp_slave, c.fp_entry) + c.fp_off
            fa[i] = applied[i]
            if c.xe is not None:
                xe[i] = c.xe[2] * bus.get_input(c.xe[0], c.xe[1]) + c.xe[3]
            if c.fe is not None:
                fe[i] = c.fe[2] * bus.get_input(c.fe[0], c.fe[1]) + c.fe[3]
        for i, source in enumerate(self._from):
            if source is not None:
                fe[i] = source[1] * fp[source[0]]
        return self._complete

    def clock_correction(self) -> float:
        """The shift of the cycle's next deadlines the DC lock asks for [s] (0 without DC)."""
        correction, self._correction = self._correction, 0.0
        return correction

    def drives(self) -> Sequence[Tuple[bool, bool, str]]:
        """Advance each drive's CiA 402 sequencer on its newest statusword and mode; report
        ``(torque_allowed, faulted, reason)``."""
        bus = self.bus
        reports = self._reports
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            status = bus.get_input(c.drive, 'statusword')
            if c.has_mode_display:
                c.mode = bus.get_input(c.drive, 'mode_display')
            c.controlword = seq.controlword(status, c.mode)
            faulted = seq.faulted
            if faulted:
                if c.has_error_code:
                    c.error_code = bus.get_input(c.drive, 'error_code')
                if not c.fault_seen:
                    c.fault_seen = True
                    self._fetch_fault(i)
                reason = self._fault_reason(c, status)
            elif seq.held_for_mode and seq.enable:
                c.fault_seen = False
                c.held_cycles += 1
                faulted = c.held_cycles > self._mode_timeout
                reason = (f'drive shows mode {c.mode}, not cyclic synchronous torque (10): '
                          'held in Switched on, no torque' if faulted else '')
            else:
                c.fault_seen = False
                c.held_cycles = 0
                reason = ''
            c.reason = reason
            reports[i] = (seq.torque_allowed, faulted, reason)
        return reports

    def _fault_reason(self, c: _Channel, status: int) -> str:
        text = f'drive fault {error_text(c.error_code)}' if c.error_code else (
            f'drive reports a fault (statusword 0x{status:04X}'
            + ('; reading 0x603F)' if c.fault_fetch else ')'))
        if c.emergency:
            text += f', emergency {c.emergency}'
        return text

    def _fetch_fault(self, i: int) -> None:
        """A drive just faulted: its emergency message (and 0x603F unless mapped) over CoE,
        off the cycle thread."""
        c = self.ch[i]
        if not self.bus.coe[c.drive]:
            return
        c.fault_fetch = True
        threading.Thread(target=self._fetch, args=(c,), name='ethercat_fault', daemon=True).start()

    def _fetch(self, c: _Channel) -> None:
        try:
            with self._coe_lock:
                if not self.bus.is_open:
                    return
                self._poll_emergencies(c)
                if not c.has_error_code:
                    c.error_code = read_error_code(self.bus.port(c.drive))
        except Exception as exc:         # diagnostics only: the fault itself is latched
            c.emergency = c.emergency or f'(not read: {exc})'
        finally:
            c.fault_fetch = False

    def _poll_emergencies(self, c: _Channel) -> None:
        """Read the drive's mailbox once: the newest emergency in it becomes ``c.emergency``
        (an error reset, code 0, clears it)."""
        for code, register in self.bus.poll_emergencies(c.drive):
            c.emergency = f'0x{code:04X} register 0x{register:02X}' if code else ''

    def write(self, command: PlantOutput) -> None:
        bus = self.bus
        if any(command.fault_reset):
            self._reset(command)
        applied = self._applied
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            seq.enable = command.enable[i]
            bus.set_output(c.drive, 'controlword', c.controlword)
            bus.set_output(c.drive, 'target_torque', command.units[i])
            if c.has_mode_output:
                bus.set_output(c.drive, 'mode_of_operation', MODE_CST)
            applied[i] = command.torque[i]
        bus.send()
        self._in_flight = True

    def _reset(self, command: PlantOutput) -> None:
        """``~/reset``: after a bus fault the bus first (AL errors acknowledged, OP, the modes
        read again over CoE where 0x6061 is not mapped), then each drive's fault reset."""
        if self._bad_frames:
            self._recover()
        for i, c in enumerate(self.ch):
            if command.fault_reset[i]:
                c.sequencer.request_fault_reset()
                c.held_cycles = 0
                if not c.has_mode_display and self.bus.coe[c.drive]:
                    try:
                        with self._coe_lock:
                            c.mode = read_mode(self.bus.port(c.drive))
                    except CoeError:
                        c.mode = 0            # unknown: never enabled until read again

    def _recover(self) -> None:
        """Bring every slave back to OP (on the cycle thread: the drives are in SAFE-OP, no
        torque): acknowledge, request OP, exchange zero outputs until OP or
        :data:`RECOVERY_TIMEOUT`."""
        bus = self.bus
        if self._in_flight:
            self._in_flight = False
            bus.receive()
        self._zero_outputs()
        states = bus.slave_states()
        acknowledged = bus.acknowledge(states)
        bus.request_slaves_op([k for k, (status, _) in enumerate(states) if status & 0x0F != 8])
        deadline = time.monotonic() + RECOVERY_TIMEOUT
        while time.monotonic() < deadline:
            if bus.exchange() == self._expected:
                break
            time.sleep(self.dt)
        self.recoveries += 1
        self._bad_frames = 0
        self.al_status = ('acknowledged ' + ', '.join(acknowledged)) if acknowledged else ''

    # --- monitoring -----------------------------------------------------------------------------
    def diagnostics(self) -> BackendReport:
        """The figures for /diagnostics; off the cycle thread it also reads, over CoE, the DC
        slaves' sync counters and the mailboxes (emergencies), and the AL states while
        frames come back incomplete."""
        bus = self.bus
        if self._coe_lock.acquire(blocking=False):
            try:
                if bus.is_open and self.state == 'active':
                    self._refresh_monitoring()
            except Exception:
                pass
            finally:
                self._coe_lock.release()
        values: Dict[str, Any] = {'wkc_errors_total': self.wkc_errors_total,
                                  'expected_wkc': bus.expected_wkc,
                                  'dc': 'locked' if self._lock.locked else (
                                      'locking' if bus.dc_active else 'off'),
                                  'al_status': self.al_status or 'all in OP',
                                  'bus_recoveries': self.recoveries}
        if bus.dc_active:
            values['dc_phase_error_us'] = round(self._lock.mean_ns * 1e-3, 1)
            values['dc_phase_jitter_us'] = round(self._lock.jitter_ns * 1e-3, 1)
        for name, counters in self._sync.items():
            for key, value in counters.items():
                values[f'{name}.{key}'] = value
        warning = ''
        if self._bad_frames and self.al_status:
            warning = self.al_status
        channels = []
        for c in self.ch:
            extra = {'state': c.sequencer.state.value, 'drive_state': c.sequencer.state.value,
                     'mode_display': c.mode,
                     'error_code': error_text(c.error_code) if c.error_code else 'none',
                     'emergency': c.emergency or 'none',
                     'rated_torque': c.rated_torque if c.rated_torque is not None else math.nan,
                     'max_torque': c.max_torque if c.max_torque is not None else math.nan}
            if c.reason:
                extra['drive_fault'] = c.reason
            channels.append(ChannelReport(c.cfg.drive, extra))
        return BackendReport(name=self.status_name, hardware_id=self.interface, running='OP',
                             warning=warning, values=values, channel_prefix=self.channel_prefix,
                             channels=channels)

    def _refresh_monitoring(self) -> None:
        bus = self.bus
        for position, slave in enumerate(self.config.slaves):
            if slave.dc is not None and bus.coe[position]:
                try:
                    self._sync[slave.name] = read_sync_counters(bus.port(position))
                except CoeError:
                    pass
        for c in self.ch:
            if bus.coe[c.drive]:
                self._poll_emergencies(c)
        if self._bad_frames:
            states = bus.slave_states()
            self.al_status = bus.states_text(states) if any(
                s & 0x1F != 8 for s, _ in states) else ''

    def al_codes(self) -> str:
        """(tests, logs) ``name: code`` of every slave in error now."""
        return ', '.join(f'{s.name}: {al_text(code)}' for s, (status, code) in
                         zip(self.config.slaves, self.bus.slave_states()) if status & 0x10)

