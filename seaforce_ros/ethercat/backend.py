"""The gripper over EtherCAT as a :class:`~seaforce_ros.core.backend.PlantBackend` (no ROS).

:class:`EthercatBackend` drives :class:`~.master.EthercatBus` (pysoem, imported only when the
bus is opened) and one :class:`~.cia402.DriveSequencer` per drive through the backend
lifecycle:

* **open** -- the network interface (a raw socket; SOEM sets it promiscuous, close gives the
  flag back as it was);
* **configure** -- every slave found and its vendor / product code / revision checked before
  anything is written to a drive, process data mapped, bus in SAFE-OP, the drives'
  process-data watchdog (``drive_watchdog``) programmed. In SAFE-OP a slave keeps its outputs
  in their safe state: no torque can reach a motor;
* **activate** -- bus in OP (zero outputs, controlword *disable voltage*), every drive told to
  walk to *Operation enabled* for cyclic synchronous torque (mode 10); from here one
  process-data frame per cycle is expected, or the drives' watchdog removes the torque;
* **read / drives / write** -- once per cycle: receive the frame sent at the end of the previous
  cycle (it travelled during the sleep; pysoem releases the GIL), scale the raw inputs to SI
  units (the bus YAML's scaling chains), advance each drive's CiA 402 sequencer on its newest
  statusword, then write controlword and target torque (0x6071, per mille of the rated
  torque, int16) and send;
* **deactivate** -- zero torque and *disable voltage* every cycle until every drive reports
  its power stage off (at least ``MIN_DISABLE_CYCLES``, at most ``DISABLE_TIMEOUT``), then
  SAFE-OP. A drive that stays powered is an error (the bus still goes to SAFE-OP);
* **close** -- from any state: deactivated first if active, bus to INIT, interface closed.
"""
from __future__ import annotations

import time
from typing import List, Optional, Sequence, Tuple

from ..core.backend import (LINK_NOTHING, BackendReport, ChannelReport, LinkStatus,
                            PlantBackend, PlantSample)
from ..core.plant_cycle import PlantOutput
from .bus_config import BusConfig, ChannelConfig
from .cia402 import CW_DISABLE_VOLTAGE, MODE_CST, DriveSequencer, DriveState, state_of
from .errors import BusConfigError, BusError
from .master import EthercatBus

__all__ = ["EthercatBackend", "MIN_DISABLE_CYCLES", "DISABLE_TIMEOUT"]

#: Cycles of zero torque and *disable voltage* a deactivation sends at least (a drive acts on
#: a controlword a few cycles after it arrives).
MIN_DISABLE_CYCLES = 20
#: How long a deactivation waits for every drive to report its power stage off [s].
DISABLE_TIMEOUT = 0.5
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
        self.units_per_nm = 1000.0 / cfg.rated_torque
        drive = bus_config.slaves[self.drive]
        self.has_mode_display = 'mode_display' in drive.inputs.names()
        self.has_mode_output = 'mode_of_operation' in drive.outputs.names()
        self.sequencer = DriveSequencer()
        self.controlword = CW_DISABLE_VOLTAGE


class EthercatBackend(PlantBackend):
    """The EtherCAT gripper (see module docstring).

    Parameters
    ----------
    config : BusConfig
        The bus: slaves with identities and PDO entries, channels with scalings.
    channels : sequence of str
        The node's channels, each one of the configuration's.
    interface : str
        Network interface of the bus (needs CAP_NET_RAW and CAP_NET_ADMIN).
    dt : float > 0
        Cycle period [s] (the pace of a deactivation's zero-torque frames).
    receive_timeout : float > 0
        How long a read waits for the process-data frame [s].
    drive_watchdog : float > 0
        Process-data watchdog programmed into every drive at configure [s].

    Raises
    ------
    BusConfigError
        A channel the configuration does not have, or an ``external_force.from_channel``
        that is not one of ``channels``.
    """

    status_name = 'hardware: bus'
    channel_prefix = 'hardware'

    def __init__(self, config: BusConfig, channels: Sequence[str], interface: str, dt: float,
                 receive_timeout: float = 4e-4, drive_watchdog: float = 0.1) -> None:
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
        self.bus = EthercatBus(config, interface, int(receive_timeout * 1e6))
        self.state = 'closed'
        self.wkc_errors_total = 0
        self._reports: List[Tuple[bool, bool]] = [(False, False)] * len(self.ch)
        self._applied = [0.0] * len(self.ch)     # torque written last cycle [N m]
        self._in_flight = False                  # a frame was sent and not yet received
        self._expected = 0                       # working counter of a complete frame
        self._complete = LINK_NOTHING

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
        bus.configure()
        bus.set_process_data_watchdog(self.drive_watchdog)
        for c in self.ch:
            c.sequencer = DriveSequencer()
            c.controlword = CW_DISABLE_VOLTAGE
        self._zero_outputs()
        self.state = 'configured'
        return (f'bus in SAFE-OP: {len(self.config.slaves)} slaves, identities checked, '
                f'expected working counter {bus.expected_wkc}; drives disabled, no torque')

    def activate(self) -> str:
        bus = self.bus
        expected = bus.expected_wkc
        if expected is None:
            raise BusError('activate needs a configured bus (configure first)')
        for c in self.ch:
            c.sequencer = DriveSequencer()
            c.sequencer.enable = True
        self._reports = [(False, False)] * len(self.ch)
        self._applied = [0.0] * len(self.ch)
        self._zero_outputs()
        self._in_flight = False
        self.wkc_errors_total = 0
        self._expected = expected
        self._complete = LinkStatus(True, expected, expected)
        # OP last, and the cycle right after it: once in OP the slaves' process-data
        # watchdogs expect a frame every cycle
        self.state = 'active'
        bus.request_op()
        return f'bus in OP, expected working counter {bus.expected_wkc}; drives enabling'

    def deactivate(self) -> str:
        bus = self.bus
        for c in self.ch:
            c.sequencer.enable = False
        self._applied = [0.0] * len(self.ch)
        powered = self._disable_drives()
        self.state = 'configured'
        bus.request_safe_op()
        if powered:
            raise BusError('drive(s) still powered after '
                           f'{DISABLE_TIMEOUT:g} s of disable voltage: ' + ', '.join(powered)
                           + '; the bus is in SAFE-OP (outputs safe): check the drives')
        return 'zero torque, drives disabled, bus in SAFE-OP'

    def close(self) -> str:
        bus = self.bus
        if bus.master is None:
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
        while True:
            bus.exchange()
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
            return LinkStatus(True, wkc, self._expected)
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

    def drives(self) -> Sequence[Tuple[bool, bool]]:
        """Advance each drive's CiA 402 sequencer on its newest statusword."""
        bus = self.bus
        reports = self._reports
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            status = bus.get_input(c.drive, 'statusword')
            mode = bus.get_input(c.drive, 'mode_display') if c.has_mode_display else MODE_CST
            c.controlword = seq.controlword(status, mode)
            reports[i] = (seq.torque_allowed, seq.faulted)
        return reports

    def write(self, command: PlantOutput) -> None:
        bus = self.bus
        applied = self._applied
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            seq.enable = command.enable[i]
            if command.fault_reset[i]:
                seq.request_fault_reset()
            bus.set_output(c.drive, 'controlword', c.controlword)
            bus.set_output(c.drive, 'target_torque', command.units[i])
            if c.has_mode_output:
                bus.set_output(c.drive, 'mode_of_operation', MODE_CST)
            applied[i] = command.torque[i]
        bus.send()
        self._in_flight = True

    # --- monitoring -----------------------------------------------------------------------------
    def diagnostics(self) -> BackendReport:
        return BackendReport(
            name=self.status_name, hardware_id=self.interface, running='OP',
            values={'wkc_errors_total': self.wkc_errors_total,
                    'expected_wkc': self.bus.expected_wkc},
            channel_prefix=self.channel_prefix,
            channels=[ChannelReport(c.cfg.drive, {'state': c.sequencer.state.value,
                                                  'drive_state': c.sequencer.state.value})
                      for c in self.ch])
