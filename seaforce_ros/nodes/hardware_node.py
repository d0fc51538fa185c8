"""hardware_node (node ``hardware``): the gripper over EtherCAT, a drop-in for ``sim_node``.

Owns the bus through pysoem (SOEM). Its cycle thread runs at ``rate`` with absolute
deadlines: one process-data frame per cycle, sent at the end of a cycle and received at the
start of the next (it travels during the sleep; pysoem releases the GIL), scaling of
the raw PDO values to SI units (``bus_config`` YAML), an ``actuator_state`` sample with the
same semantics as the sim's, and the torques :class:`~seaforce_ros.core.plant_cycle.PlantCycle`
allows applied as CiA 402 target torque (object 0x6071, per mille of the rated torque, int16)
— only in *Operation enabled*.

Safety: the rules of :mod:`seaforce_ros.core.plant_cycle`, shared with the sim (per-channel
command watchdog, fresh commands only, one command source, ``torque_limit`` clamp, velocity
trip, drive faults, ``wkc_error_limit`` consecutive working-counter errors -> bus fault with
the drives disabled, ``~/reset``), each with a status bit, a ``/diagnostics`` entry and a
log line; plus:

* identity check at start: a missing slave or a wrong vendor/product/revision is a clear
  error and the node exits before any drive is enabled;
* the drives' own process-data watchdog (``drive_watchdog``) drops torque if the master stops;
* SIGINT/SIGTERM -> zero torque, drives disabled, bus back to INIT before exit.
"""
from __future__ import annotations

import dataclasses
import pathlib
import sys
import time

from ..ethercat.bus_config import BusConfig
from ..ethercat.cia402 import CW_DISABLE_VOLTAGE, MODE_CST, DriveSequencer
from ..ethercat.errors import BusConfigError, BusError
from ..ethercat.master import EthercatBus
from .plant_node import PlantNode, plant_specs, prepare_process
from ..core.schema import HARDWARE
from .ros_common import StartupError, run


def _default_bus_config() -> str:
    try:
        from ament_index_python.packages import get_package_share_directory
        return str(pathlib.Path(get_package_share_directory('seaforce_ros')) / 'config'
                   / 'ethercat_bus.yaml')
    except Exception:
        return str(pathlib.Path(__file__).resolve().parents[2] / 'config' / 'ethercat_bus.yaml')


def node_specs():
    """hardware_node's own parameters (the plant's common ones among them); ``bus_config``
    defaults to the installed config/ethercat_bus.yaml."""
    return [dataclasses.replace(spec, default=_default_bus_config())
            if spec.name == 'bus_config' else spec for spec in plant_specs(HARDWARE)]


class _Channel:
    """Per-channel bus addresses, compiled scalings and run-time state."""

    def __init__(self, bus_config: BusConfig, cfg):
        self.cfg = cfg
        self.drive = bus_config.slave_index(cfg.drive)
        self.pos_gain, self.pos_off = cfg.position.compiled()
        self.vel_gain, self.vel_off = cfg.velocity.compiled()
        self.fp_slave = bus_config.slave_index(cfg.pressure.source.slave)
        self.fp_entry = cfg.pressure.source.entry
        self.fp_gain, self.fp_off = cfg.pressure.scaling.compiled()
        self.xe = None
        if cfg.endpoint_position is not None:
            s = cfg.endpoint_position
            self.xe = (bus_config.slave_index(s.source.slave), s.source.entry,
                       *s.scaling.compiled())
        self.fe = None
        if cfg.external_force is not None:
            s = cfg.external_force
            self.fe = (bus_config.slave_index(s.source.slave), s.source.entry,
                       *s.scaling.compiled())
        self.units_per_nm = 1000.0 / cfg.rated_torque
        drive = bus_config.slaves[self.drive]
        self.has_mode_display = 'mode_display' in drive.inputs.names()
        self.has_mode_output = 'mode_of_operation' in drive.outputs.names()
        self.sequencer = DriveSequencer()
        self.controlword = 0


class HardwareNode(PlantNode):
    """The EtherCAT gripper (see module docstring).

    Parameters
    ----------
    direct : controller_node.DirectPort, optional
        The direct layout (``hardware_bringup loop:=direct``): the cycle thread calls the
        controller between two exchanges.
    """

    def __init__(self, direct=None, **kwargs):
        super().__init__('hardware', node_specs(), direct=direct, **kwargs)
        values = self.values
        if not values['interface']:
            raise StartupError('interface is not set: pass the EtherCAT network interface, '
                               'e.g. --ros-args -p interface:=enp3s0 (ip link lists them)')
        try:
            self.bus_config = BusConfig.load(values['bus_config'])
            channel_cfgs = [self.bus_config.channel(c) for c in self.channels]
        except (ValueError, BusConfigError) as exc:
            raise StartupError(str(exc)) from exc
        self.ch = [_Channel(self.bus_config, c) for c in channel_cfgs]
        self._index = {c: i for i, c in enumerate(self.channels)}
        for c in self.ch:
            src = c.cfg.external_from_channel
            if src is not None and src not in self._index:
                raise StartupError(f'channel {c.cfg.name}: external_force.from_channel '
                                   f'{src} is not in the node\'s channels')
        self._make_plant_cycle(units_per_nm=[c.units_per_nm for c in self.ch])
        self._drive_reports = [(False, False)] * len(self.ch)
        self._in_flight = False          # a process-data frame was sent and not yet received

        self.bus = EthercatBus(self.bus_config, values['interface'],
                               int(values['receive_timeout'] * 1e6))
        self.get_logger().info(f'bringing up EtherCAT on {values["interface"]} '
                               f'({len(self.bus_config.slaves)} slaves)')
        try:
            self._bring_up(values)
        except BusError as exc:
            self.bus.to_init()
            self.bus.close()
            raise StartupError(str(exc)) from None
        except BaseException:
            self.bus.to_init()
            self.bus.close()     # never leave the interface promiscuous or a slave in OP
            raise
        self._start_cycle_thread()
        self.get_logger().info(f'bus in OP, expected working counter {self.bus.expected_wkc}, '
                               f'loop={"direct" if direct else "topics"}')

    def _bring_up(self, values):
        self.bus.open()      # identities checked, process data mapped, SAFE-OP
        self.bus.set_process_data_watchdog(values['drive_watchdog'])
        self._start_plant()
        for c in self.ch:
            c.sequencer.enable = True
        # OP last, and the cycle right after it: once in OP the slaves' process-data
        # watchdogs (typically 100 ms) expect a frame every cycle
        self.bus.request_op()

    # --- the cycle (PlantNode hooks) -----------------------------------------------------
    def _drives(self):
        """Advance each drive's CiA 402 sequencer on its newest statusword."""
        bus = self.bus
        reports = self._drive_reports
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            status = bus.get_input(c.drive, 'statusword')
            mode = bus.get_input(c.drive, 'mode_display') if c.has_mode_display else MODE_CST
            c.controlword = seq.controlword(status, mode)
            reports[i] = (seq.torque_allowed, seq.faulted)
        return reports

    def _read(self):
        """Receive the frame sent at the end of the previous cycle (it came back meanwhile)."""
        if not self._in_flight:
            return False
        self._in_flight = False
        bus = self.bus
        return self.plant.exchange(bus.receive(), bus.expected_wkc)

    def _write(self, out):
        bus = self.bus
        for i, c in enumerate(self.ch):
            seq = c.sequencer
            seq.enable = out.enable[i]
            if out.fault_reset[i]:
                seq.request_fault_reset()
            bus.set_output(c.drive, 'controlword', c.controlword)
            bus.set_output(c.drive, 'target_torque', out.units[i])
            if c.has_mode_output:
                bus.set_output(c.drive, 'mode_of_operation', MODE_CST)
        bus.send()
        self._in_flight = True

    def _sample(self, out, sample):
        """Scale this cycle's inputs to SI units."""
        bus = self.bus
        x, v, fp, fa, xe, fe, st = sample
        for i, c in enumerate(self.ch):
            x[i] = c.pos_gain * bus.get_input(c.drive, 'position') + c.pos_off
            v[i] = c.vel_gain * bus.get_input(c.drive, 'velocity') + c.vel_off
            fp[i] = c.fp_gain * bus.get_input(c.fp_slave, c.fp_entry) + c.fp_off
            fa[i] = out.torque[i]
            if c.xe is not None:
                xe[i] = c.xe[2] * bus.get_input(c.xe[0], c.xe[1]) + c.xe[3]
            if c.fe is not None:
                fe[i] = c.fe[2] * bus.get_input(c.fe[0], c.fe[1]) + c.fe[3]
            st[i] = out.status[i]
        for i, c in enumerate(self.ch):
            if c.cfg.external_from_channel is not None:
                fe[i] = c.cfg.external_sign * fp[self._index[c.cfg.external_from_channel]]

    # --- monitoring / shut-down ----------------------------------------------------------
    def _diagnostics(self):
        bus = self.bus
        status = self._common_diagnostics(
            'hardware: bus', bus.interface, 'OP',
            extra={'wkc_errors_total': self.plant.wkc_errors_total,
                   'expected_wkc': bus.expected_wkc})
        return [status] + self._channel_diagnostics(
            'hardware', [c.cfg.drive for c in self.ch],
            lambda i: {'state': self.ch[i].sequencer.state.value,
                       'drive_state': self.ch[i].sequencer.state.value})

    def shutdown(self):
        """Zero torque, drives disabled, bus to INIT (called on SIGINT/SIGTERM and on exit)."""
        self._stop_threads()
        bus = self.bus
        if bus.master is None:
            return
        try:
            for c in self.ch:
                c.sequencer.enable = False
            for _ in range(20):   # a few cycles of zero torque + disable voltage
                for c in self.ch:
                    bus.set_output(c.drive, 'controlword', CW_DISABLE_VOLTAGE)
                    bus.set_output(c.drive, 'target_torque', 0)
                bus.exchange()
                time.sleep(self.dt)
            ok = bus.to_init()
            print(f'[hardware] drives disabled, bus {"in INIT" if ok else "INIT requested"}',
                  file=sys.stderr)
        finally:
            bus.close()


def main(args=None):
    prepare_process()
    sys.exit(run(HardwareNode, args=args, name='hardware_node'))


if __name__ == '__main__':
    main()
