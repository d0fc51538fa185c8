"""hardware_node (node ``hardware``): the gripper over EtherCAT, a drop-in for ``sim_node``.

Owns the bus through pysoem (SOEM). Its cycle thread runs at ``rate`` with absolute
deadlines: one process-data exchange per cycle (pysoem releases the GIL for it), scaling of
the raw PDO values to SI units (``bus_config`` YAML), an ``actuator_state`` sample with the
same semantics as the sim's, and the newest ``actuator_command`` applied as CiA 402 target
torque (object 0x6071, per mille of the rated torque) — only in *Operation enabled*.

Safety (each with a status bit, a ``/diagnostics`` entry and a log line):

* identity check at start: a missing slave or a wrong vendor/product/revision is a clear
  error and the node exits before any drive is enabled;
* command watchdog: no command for ``command_timeout`` -> zero torque, STATUS_COMMAND_TIMEOUT;
* ``wkc_error_limit`` consecutive working-counter errors -> bus fault latched: zero torque,
  drives disabled, STATUS_FAULT;
* ``|V| > max_velocity`` on a channel -> torque off on that channel, fault latched
  (active safety, as the paper's Safety paragraph asks);
* drive fault bit -> zero torque, STATUS_FAULT; ``~/reset`` sends the CiA 402 fault reset and
  clears latched faults;
* torque clamp to ``max_torque`` (STATUS_LIMIT);
* SIGINT/SIGTERM -> zero torque, drives disabled, bus back to INIT before exit.
"""
from __future__ import annotations

import collections
import math
import pathlib
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState
from seaforce_msgs.msg import ActuatorCommand, ActuatorState
from std_srvs.srv import Trigger

from . import param_specs as ps
from .ethercat.bus_config import BusConfig, BusConfigError
from .ethercat.cia402 import CW_DISABLE_VOLTAGE, MODE_CST, DriveSequencer
from .ethercat.master import BusError, EthercatBus
from .ros_common import (STATUS_QOS, ParamSpec, StartupError, control_qos, control_qos_spec,
                         declare, diagnostic_status, diagnostics_publisher,
                         publish_diagnostics, run, shutdown_safe)
from .timing import CommandTiming, Deadline, LoopStats

STATUS_COMMAND_TIMEOUT = ActuatorState.STATUS_COMMAND_TIMEOUT
STATUS_LIMIT = ActuatorState.STATUS_LIMIT
STATUS_FAULT = ActuatorState.STATUS_FAULT
NAN = float('nan')
RESET_GRACE_CYCLES = 200  # 0.1 s at 2 kHz for a drive to leave Fault after a fault reset


def _default_bus_config() -> str:
    try:
        from ament_index_python.packages import get_package_share_directory
        return str(pathlib.Path(get_package_share_directory('seaforce_ros')) / 'config'
                   / 'ethercat_bus.yaml')
    except Exception:
        return str(pathlib.Path(__file__).resolve().parent.parent / 'config' / 'ethercat_bus.yaml')


def node_specs():
    return [
        ps.channels_spec(),
        ParamSpec('interface', 'eth0', 'network interface of the EtherCAT bus',
                  read_only=True),
        ParamSpec('bus_config', _default_bus_config(),
                  'bus YAML: slaves in bus order with identities, PDO entries, scaling',
                  read_only=True),
        ParamSpec('rate', 2000.0, 'cycle rate [Hz]', low=1.0, high=20000.0, read_only=True),
        ParamSpec('command_timeout', 0.01, 'zero torque when no command arrived for this '
                  'long [s]', low=1e-4, high=10.0),
        ParamSpec('wkc_error_limit', 10, 'consecutive working-counter errors that latch a '
                  'bus fault (safe state)', low=1, high=100000),
        ParamSpec('max_velocity', 30.0, 'motor speed beyond which torque is removed and a '
                  'fault latched [rad/s]', low=0.0, high=1e4),
        ParamSpec('max_torque', 5.0, 'torque commands are clamped to +-max_torque [N m]',
                  low=0.0, high=1e3),
        ParamSpec('drive_watchdog', 0.1, 'process-data watchdog programmed into every drive: '
                  'it drops torque on its own when the master stops for this long [s]',
                  low=0.001, high=6.0, read_only=True),
        ParamSpec('receive_timeout', 4e-4, 'wait for the process-data frame [s]',
                  low=1e-5, high=0.1, read_only=True),
        ParamSpec('joint_state_rate', 100.0, 'sensor_msgs/JointState rate [Hz], 0 = off',
                  low=0.0, high=20000.0),
        ParamSpec('diagnostics_period', 1.0, '/diagnostics period [s]', low=0.05, high=60.0,
                  read_only=True),
        ps.executor_spec('events'),
        control_qos_spec(),
    ]


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
        self.fault = ''              # latched fault reason
        self.reset_grace = 0         # cycles a drive may still report Fault after ~/reset
        self.applied = 0.0
        self.limited = False


class HardwareNode(Node):
    """The EtherCAT gripper (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__('hardware', **kwargs)
        values = declare(self, node_specs())
        self.channels = ps.channels_from(values)
        try:
            self.bus_config = BusConfig.load(values['bus_config'])
            channel_cfgs = [self.bus_config.channel(c) for c in self.channels]
        except (ValueError, BusConfigError) as exc:
            raise StartupError(str(exc)) from exc
        self.dt = 1.0 / values['rate']
        self.command_timeout = values['command_timeout']
        self.wkc_error_limit = values['wkc_error_limit']
        self.max_velocity = values['max_velocity']
        self.max_torque = values['max_torque']
        self._js_every = self._decimation(values['joint_state_rate'])
        self.ch = [_Channel(self.bus_config, c) for c in channel_cfgs]
        self._index = {c: i for i, c in enumerate(self.channels)}
        for i, c in enumerate(self.ch):
            if c.cfg.external_from_channel is not None:
                src = c.cfg.external_from_channel
                if src not in self._index:
                    raise StartupError(f'channel {c.cfg.name}: external_force.from_channel '
                                       f'{src} is not in the node\'s channels')

        self.bus = EthercatBus(self.bus_config, values['interface'],
                               int(values['receive_timeout'] * 1e6))
        self.get_logger().info(f'bringing up EtherCAT on {values["interface"]} '
                               f'({len(self.bus_config.slaves)} slaves)')
        try:
            self.bus.open()      # identities checked, process data mapped, SAFE-OP
            self.bus.set_process_data_watchdog(values['drive_watchdog'])
        except BusError as exc:
            self.bus.close()
            raise StartupError(str(exc)) from exc

        self._thread = None
        self._publisher = None
        self.cycle = 0
        self._command = [0.0] * len(self.channels)
        self._command_time = None
        self._index_of = None
        self._bus_fault = ''
        self._wkc_errors = 0            # consecutive
        self._wkc_errors_total = 0
        self._timeouts = 0
        self._faults_total = 0
        self._reset_requested = False
        self.stats = LoopStats(self.dt)
        self.timing = CommandTiming()

        qos = values['control_qos']
        self._state_msg = ActuatorState()
        self._state_msg.name = list(self.channels)
        self._js_msg = JointState()
        self._js_msg.name = [f'{c}_{j}' for c in self.channels for j in ('motor', 'endpoint')]
        self.state_pub = self.create_publisher(ActuatorState, 'actuator_state', control_qos(qos))
        self.js_pub = self.create_publisher(JointState, 'joint_states', STATUS_QOS)
        self.diag_pub = diagnostics_publisher(self)
        self.create_subscription(ActuatorCommand, 'actuator_command', self._on_command,
                                 control_qos(qos, subscriber=True))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(values['diagnostics_period'], self._publish_diagnostics)
        for c in self.ch:
            c.sequencer.enable = True
        # OP last, and the cycle right after it: once in OP the slaves' process-data
        # watchdogs (typically 100 ms) expect a frame every cycle
        try:
            self.bus.request_op()
        except BusError as exc:
            self.bus.to_init()
            self.bus.close()
            raise StartupError(str(exc)) from exc
        self._outbox = collections.deque(maxlen=4096)   # cycle -> publisher thread
        self._outbox_ready = threading.Event()
        self._publishing = True
        self._publisher = threading.Thread(target=self._publisher_loop, name='state_publisher',
                                           daemon=True)
        self._publisher.start()
        self._running = True
        self._thread = threading.Thread(target=self._loop, name='ethercat_cycle', daemon=True)
        self._thread.start()
        self.get_logger().info(f'bus in OP, expected working counter {self.bus.expected_wkc}')

    def _decimation(self, rate_hz):
        return 0 if rate_hz <= 0 else max(1, int(round(1.0 / (self.dt * rate_hz))))

    def _apply_parameters(self, params):
        for p in params:
            if p.name == 'command_timeout':
                self.command_timeout = p.value
            elif p.name == 'wkc_error_limit':
                self.wkc_error_limit = p.value
            elif p.name == 'max_velocity':
                self.max_velocity = p.value
            elif p.name == 'max_torque':
                self.max_torque = p.value
            elif p.name == 'joint_state_rate':
                self._js_every = self._decimation(p.value)

    # --- commands ------------------------------------------------------------------------
    @shutdown_safe
    def _on_command(self, msg):
        names = msg.name
        if len(msg.effort) != len(names):
            self.get_logger().error('actuator_command rejected: names and efforts differ in '
                                    'length', throttle_duration_sec=1.0)
            return
        if self._index_of is None or self._index_of[0] != names:
            self._index_of = (list(names), [self._index.get(n, -1) for n in names])
        command = list(self._command)
        for value, i in zip(msg.effort, self._index_of[1]):
            if i >= 0:
                command[i] = value if math.isfinite(value) else NAN
        self._command = command
        self._command_time = now = time.monotonic()
        self.timing.on_command(msg.cycle, self.cycle, now)

    def _on_reset(self, request, response):
        faults = [f'{c.cfg.name}: {c.fault}' for c in self.ch if c.fault]
        if self._bus_fault:
            faults.append(f'bus: {self._bus_fault}')
        self._reset_requested = True    # handled by the cycle thread at its next cycle
        response.success = True
        response.message = ('reset requested; cleared: ' + '; '.join(faults)) if faults else \
            'reset requested; no fault was latched'
        self.get_logger().info(response.message)
        return response

    # --- the cycle -----------------------------------------------------------------------
    def _latch(self, c, reason):
        if not c.fault:
            c.fault = reason
            self._faults_total += 1
            self.get_logger().error(f'{c.cfg.name}: FAULT latched, zero torque: {reason}; '
                                    'call ~/reset (std_srvs/Trigger) to clear')

    def _loop(self):
        deadline = Deadline(self.dt)
        bus = self.bus
        was_timed_out = False
        try:
            while self._running:
                now = deadline.wait()
                if not self._running:
                    break
                self.stats.tick(now)
                self.timing.on_tick(self.cycle)
                if self._reset_requested:
                    self._reset_requested = False
                    self._bus_fault = ''
                    self._wkc_errors = 0
                    for c in self.ch:
                        c.fault = ''
                        c.sequencer.request_fault_reset()
                        c.sequencer.enable = True
                        # the drive needs a few cycles to leave Fault: don't re-latch meanwhile
                        c.reset_grace = RESET_GRACE_CYCLES
                t_cmd = self._command_time
                timed_out = t_cmd is None or (now - t_cmd) > self.command_timeout
                if timed_out and not was_timed_out and t_cmd is not None:
                    self._timeouts += 1
                    self.get_logger().warning('no actuator_command for '
                                              f'{1e3 * (now - t_cmd):.1f} ms: zero torque')
                was_timed_out = timed_out
                command = self._command
                # outputs from the newest inputs
                for i, c in enumerate(self.ch):
                    seq = c.sequencer
                    status = bus.get_input(c.drive, 'statusword')
                    mode = bus.get_input(c.drive, 'mode_display') if c.has_mode_display else MODE_CST
                    cw = seq.controlword(status, mode)
                    if seq.faulted:
                        if c.reset_grace > 0:
                            c.reset_grace -= 1    # torque stays off: not in Operation enabled
                        else:
                            self._latch(c, 'drive reports a fault (statusword bit 3)')
                    else:
                        c.reset_grace = 0
                    u = command[i]
                    c.limited = False
                    if not math.isfinite(u):
                        self._latch(c, 'non-finite torque command')
                        u = 0.0
                    if timed_out or c.fault or self._bus_fault or not seq.torque_allowed:
                        u = 0.0
                    elif u > self.max_torque or u < -self.max_torque:
                        u = math.copysign(self.max_torque, u)
                        c.limited = True
                    units = int(round(u * c.units_per_nm))
                    units = max(-32768, min(32767, units))
                    c.applied = units / c.units_per_nm
                    bus.set_output(c.drive, 'controlword', cw)
                    bus.set_output(c.drive, 'target_torque', units)
                    if c.has_mode_output:
                        bus.set_output(c.drive, 'mode_of_operation', MODE_CST)
                wkc = bus.exchange()
                if wkc != bus.expected_wkc:
                    self._wkc_errors += 1
                    self._wkc_errors_total += 1
                    if self._wkc_errors >= self.wkc_error_limit and not self._bus_fault:
                        self._bus_fault = (f'{self._wkc_errors} consecutive working-counter '
                                           f'errors (got {wkc}, expected {bus.expected_wkc})')
                        self._faults_total += 1
                        self.get_logger().error(f'bus FAULT latched: {self._bus_fault}; zero '
                                                'torque, drives disabled; ~/reset to retry')
                        for c in self.ch:
                            c.sequencer.enable = False
                    continue  # no fresh inputs this cycle: publish nothing new
                self._wkc_errors = 0
                self.cycle += 1
                self._publish(timed_out)
        except Exception as exc:
            if self._running and self.context.ok():
                self.get_logger().fatal(f'EtherCAT cycle stopped: {exc!r}')
            self._running = False

    def _publish(self, timed_out):
        """Scale this cycle's inputs and hand them to the publisher thread (never blocks)."""
        bus = self.bus
        n = len(self.ch)
        x, v, fp, fa, xe, fe, st = ([0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n, [NAN] * n,
                                    [NAN] * n, [0] * n)
        for i, c in enumerate(self.ch):
            x[i] = c.pos_gain * bus.get_input(c.drive, 'position') + c.pos_off
            v[i] = c.vel_gain * bus.get_input(c.drive, 'velocity') + c.vel_off
            fp[i] = c.fp_gain * bus.get_input(c.fp_slave, c.fp_entry) + c.fp_off
            fa[i] = c.applied
            if c.xe is not None:
                xe[i] = c.xe[2] * bus.get_input(c.xe[0], c.xe[1]) + c.xe[3]
            if c.fe is not None:
                fe[i] = c.fe[2] * bus.get_input(c.fe[0], c.fe[1]) + c.fe[3]
            if abs(v[i]) > self.max_velocity and self.max_velocity > 0:
                self._latch(c, f'motor speed {v[i]:.2f} rad/s beyond max_velocity '
                               f'{self.max_velocity:g}')
            st[i] = ((STATUS_COMMAND_TIMEOUT if timed_out else 0)
                     | (STATUS_LIMIT if c.limited else 0)
                     | (STATUS_FAULT if (c.fault or self._bus_fault) else 0))
        for i, c in enumerate(self.ch):
            if c.cfg.external_from_channel is not None:
                fe[i] = c.cfg.external_sign * fp[self._index[c.cfg.external_from_channel]]
        self._outbox.append((self.cycle, time.time_ns(), x, v, fp, fa, xe, fe, st))
        self._outbox_ready.set()

    def _publisher_loop(self):
        """Publishes the samples the cycle queued. A reliable DDS writer can block for up to
        100 ms (its max_blocking_time) when a subscriber lags; that must never hold up the
        EtherCAT cycle, whose slaves' watchdogs expire after 100 ms without process data."""
        outbox, ready = self._outbox, self._outbox_ready
        msg, js = self._state_msg, self._js_msg
        n = len(self.ch)
        try:
            while self._publishing:
                ready.wait(0.1)
                ready.clear()
                while outbox:
                    cycle, now_ns, x, v, fp, fa, xe, fe, st = outbox.popleft()
                    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(now_ns, 10**9)
                    msg.cycle = cycle
                    msg.motor_position, msg.motor_velocity, msg.pressure_force = x, v, fp
                    msg.motor_effort, msg.endpoint_position = fa, xe
                    msg.external_force, msg.status = fe, st
                    self.timing.on_publish(cycle, time.monotonic())
                    self.state_pub.publish(msg)
                    if self._js_every and cycle % self._js_every == 0:
                        js.header.stamp = msg.header.stamp
                        js.position = [val for i in range(n) for val in (x[i], xe[i])]
                        js.velocity = [val for i in range(n) for val in (v[i], NAN)]
                        js.effort = [val for i in range(n) for val in (fa[i], fe[i])]
                        self.js_pub.publish(js)
        except Exception as exc:
            if self._publishing and self.context.ok():
                self.get_logger().fatal(f'state publisher stopped: {exc!r}')

    # --- monitoring / shut-down ----------------------------------------------------------
    @shutdown_safe
    def _publish_diagnostics(self):
        s = self.stats.summary()
        rtt50, rtt99 = self.timing.round_trip_ms()
        statuses = [diagnostic_status(
            'hardware: bus', self.bus.interface,
            DiagnosticStatus.ERROR if (self._bus_fault or not self._running) else DiagnosticStatus.OK,
            f'FAULT: {self._bus_fault}' if self._bus_fault else
            ('cycle stopped' if not self._running else 'OP'),
            {'cycle': self.cycle, 'rate_hz': s.rate_hz, 'period_p50_ms': s.period_p50_ms,
             'period_p99_ms': s.period_p99_ms, 'jitter_p99_ms': s.jitter_p99_ms,
             'period_max_ms': s.period_max_ms,
             'missed_deadlines': s.missed, 'wkc_errors_total': self._wkc_errors_total,
             'round_trip_p50_ms': rtt50, 'round_trip_p99_ms': rtt99,
             'late_commands_total': self.timing.late,
             'expected_wkc': self.bus.expected_wkc, 'command_timeouts': self._timeouts,
             'faults_latched_total': self._faults_total})]
        for c in self.ch:
            statuses.append(diagnostic_status(
                f'hardware: {c.cfg.name}', c.cfg.drive,
                DiagnosticStatus.ERROR if c.fault else DiagnosticStatus.OK,
                f'FAULT: {c.fault}' if c.fault else c.sequencer.state.value,
                {'drive_state': c.sequencer.state.value, 'fault': c.fault or 'none',
                 'torque_applied': c.applied}))
        publish_diagnostics(self, self.diag_pub, statuses)

    def shutdown(self):
        """Zero torque, drives disabled, bus to INIT (called on SIGINT/SIGTERM and on exit)."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        self._publishing = False
        if self._publisher is not None:
            self._outbox_ready.set()
            self._publisher.join(timeout=1.0)
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
    sys.setswitchinterval(2e-4)  # the cycle thread must get the GIL promptly
    sys.exit(run(HardwareNode, args=args, name='hardware_node'))


if __name__ == '__main__':
    main()
