"""sim_node (node ``sim``): the simulated gripper, a drop-in substitute for hardware_node.

Every cycle it publishes ``actuator_state`` (one synchronous sample of every channel) and
applies the newest ``actuator_command``; ``joint_states`` at ``joint_state_rate`` and
``/diagnostics`` once per ``diagnostics_period``. The physics is
:class:`seaforce_ros.core.simulator.ChannelSimulator` per channel (lumped hydraulic model,
Dahl hysteresis, friction, sensors, endpoint environment).

``clock_mode``:
  * ``realtime`` - an own thread paces the cycle with absolute deadlines at ``rate``; a
    command older than ``command_timeout`` is replaced by zero torque and
    ``STATUS_COMMAND_TIMEOUT`` until commands return.
  * ``lockstep`` - the model advances one sample per command answering the current cycle,
    so a closed loop over ROS reproduces :func:`~seaforce_ros.core.simulator.run_closed_loop`
    sample for sample. Until the first command arrives the current state is re-published
    every 100 ms.

The environment of each channel (``<channel>.environment.*``) can change at run time; it
takes effect at the start of the next cycle.
"""
from __future__ import annotations

import math
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from sensor_msgs.msg import JointState
from seaforce_msgs.msg import ActuatorCommand, ActuatorState

from . import param_specs as ps
from .core.environment import environment_from_dict
from .core.errors import SeaforceError
from .core.params import DahlParams, PlantParams
from .core.sensors import SensorParams
from .core.simulator import ChannelSimulator
from .ros_common import (STATUS_QOS, ParamSpec, StartupError, control_qos, control_qos_spec,
                         declare, diagnostic_status, diagnostics_publisher,
                         publish_diagnostics, run, shutdown_safe, stamp_now)
from .timing import CommandTiming, Deadline, LoopStats

STATUS_OK = ActuatorState.STATUS_OK
STATUS_COMMAND_TIMEOUT = ActuatorState.STATUS_COMMAND_TIMEOUT
STATUS_LIMIT = ActuatorState.STATUS_LIMIT
STATUS_FAULT = ActuatorState.STATUS_FAULT


def node_specs():
    return [
        ps.channels_spec(),
        ParamSpec('clock_mode', 'realtime',
                  'realtime: own cycle at `rate`; lockstep: one sample per received command',
                  choices=('realtime', 'lockstep'), read_only=True),
        ParamSpec('rate', 2000.0, 'cycle rate [Hz]', low=1.0, high=20000.0, read_only=True),
        ParamSpec('command_timeout', 0.01,
                  'zero torque when no command arrived for this long [s] (realtime)',
                  low=1e-4, high=10.0),
        ParamSpec('joint_state_rate', 100.0, 'sensor_msgs/JointState rate [Hz], 0 = off',
                  low=0.0, high=20000.0),
        ParamSpec('diagnostics_period', 1.0, '/diagnostics period [s]', low=0.05, high=60.0,
                  read_only=True),
        ParamSpec('seed', 0, 'seed of the sensor noise generators (channel i uses seed + i)',
                  low=0, high=2**31 - 1, read_only=True),
        ps.executor_spec('events'),
        control_qos_spec(),
    ]


class SimNode(Node):
    """The simulated gripper (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__('sim', **kwargs)
        values = declare(self, node_specs())
        self.channels = ps.channels_from(values)
        self._specs = {}
        for channel in self.channels:
            specs = ps.sim_channel_specs(channel)
            self._specs.update({s.name: s for s in specs})
            values.update(declare(self, specs))
        self.lockstep = values['clock_mode'] == 'lockstep'
        self.dt = 1.0 / values['rate']
        self.command_timeout = values['command_timeout']
        self._js_every = self._decimation(values['joint_state_rate'])

        self.sims = []
        for index, channel in enumerate(self.channels):
            try:
                self.sims.append(self._make_sim(values, channel, values['seed'] + index))
            except (SeaforceError, ValueError) as exc:
                raise StartupError(f'channel {channel}: {exc}') from exc

        n = len(self.channels)
        self.cycle = 0
        self._command = (0.0,) * n       # efforts in channel order
        self._command_time = None        # monotonic time of the newest command
        self._command_fault = False
        self._index_of = None            # cached command name order -> channel index
        self._pending_env = {}           # channel index -> Environment, applied next cycle
        self._timeouts = 0
        self.timing = CommandTiming()    # round trip and commands in time
        self._bad_commands = 0
        self._unknown_names = set()
        self.stats = LoopStats(self.dt)

        self._state_msg = ActuatorState()
        self._state_msg.name = list(self.channels)
        self._js_msg = JointState()
        self._js_msg.name = [f'{c}_{j}' for c in self.channels for j in ('motor', 'endpoint')]

        qos = values['control_qos']
        if self.lockstep and qos != 'reliable':
            raise StartupError('clock_mode lockstep needs control_qos reliable: a lost command '
                               'would stall the simulation')
        self.state_pub = self.create_publisher(ActuatorState, 'actuator_state', control_qos(qos))
        self.js_pub = self.create_publisher(JointState, 'joint_states', STATUS_QOS)
        self.diag_pub = diagnostics_publisher(self)
        self.create_subscription(ActuatorCommand, 'actuator_command', self._on_command,
                                 control_qos(qos, subscriber=True))
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(values['diagnostics_period'], self._publish_diagnostics)

        self._running = True
        self._last_publish = time.monotonic()
        if self.lockstep:
            self._publish_state(0)
            self.create_timer(0.1, self._lockstep_kick)
            self._thread = None
        else:
            self._thread = threading.Thread(target=self._realtime_loop, name='sim_cycle',
                                            daemon=True)
            self._thread.start()
        self.get_logger().info(
            f'simulating channels {self.channels} at {values["rate"]:.0f} Hz, '
            f'clock_mode={values["clock_mode"]}')

    # --- construction --------------------------------------------------------------------
    def _decimation(self, rate_hz):
        if rate_hz <= 0:
            return 0
        return max(1, int(round(1.0 / (self.dt * rate_hz))))

    def _make_sim(self, values, channel, seed):
        plant = PlantParams(**{k.split('.', 1)[1]: values[f'{channel}.{k}']
                               for k in ps.PLANT_KEYS})
        dahl = DahlParams(**{k.split('.', 1)[1]: values[f'{channel}.{k}'] for k in ps.DAHL_KEYS})
        sensors = SensorParams(
            pressure_range=values[f'{channel}.sensors.pressure_range'],
            pressure_noise=values[f'{channel}.sensors.pressure_noise'],
            motor_counts_per_rev=values[f'{channel}.sensors.motor_counts_per_rev'],
            endpoint_counts_per_rev=values[f'{channel}.sensors.endpoint_counts_per_rev'])
        env = environment_from_dict(ps.channel_values(values, channel, 'environment.'))
        return ChannelSimulator(
            plant, dahl=dahl if dahl.sigma > 0 else None, dt=self.dt, seed=seed,
            environment=env, sensors=sensors,
            motor_coulomb=values[f'{channel}.sim.motor_coulomb'],
            endpoint_coulomb=values[f'{channel}.sim.endpoint_coulomb'],
            backlash=values[f'{channel}.sim.backlash'],
            max_torque=values[f'{channel}.sim.max_torque'])

    # --- parameters ----------------------------------------------------------------------
    def _validate_parameters(self, params):
        changed = {p.name: p.value for p in params}
        for name, value in changed.items():
            spec = self._specs.get(name)
            if spec is not None:
                reason = spec.check(value)
                if reason:
                    return SetParametersResult(successful=False, reason=reason)
        for index, channel in enumerate(self.channels):
            env_keys = [k for k in changed if k.startswith(f'{channel}.environment.')]
            if env_keys:
                try:
                    self._environment_with(channel, changed)
                except (SeaforceError, ValueError) as exc:
                    return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _environment_with(self, channel, changed):
        current = {}
        for key, *_ in ps.ENVIRONMENT_SPECS:
            name = f'{channel}.{key}'
            current[key] = changed.get(name, self.get_parameter(name).value)
        return environment_from_dict(current)

    def _apply_parameters(self, params):
        changed = {p.name: p.value for p in params}
        for name, value in changed.items():
            if name == 'command_timeout':
                self.command_timeout = value
            elif name == 'joint_state_rate':
                self._js_every = self._decimation(value)
        for index, channel in enumerate(self.channels):
            if any(k.startswith(f'{channel}.environment.') for k in changed):
                env = self._environment_with(channel, changed)
                self._pending_env[index] = env
                self.get_logger().info(f'{channel}: environment -> {env.mode}')
                if self.lockstep:
                    pass  # applied before the next step

    # --- commands ------------------------------------------------------------------------
    @shutdown_safe
    def _on_command(self, msg):
        efforts = self._command_efforts(msg)
        if efforts is None:
            return
        now = time.monotonic()
        self._command = efforts
        self._command_time = now
        self.timing.on_command(msg.cycle, self.cycle, now)
        if self.lockstep:
            if msg.cycle != self.cycle:
                return  # an answer to an older state (e.g. a re-published one)
            self._step(efforts)

    def _command_efforts(self, msg):
        """Efforts in channel order, NaN/inf replaced by 0 with a fault flag; None if unusable."""
        names = msg.name
        n = len(self.channels)
        if len(msg.effort) != len(names):
            self._reject_command(f'command has {len(names)} names but {len(msg.effort)} efforts')
            return None
        index_of = self._index_of
        if index_of is None or index_of[0] != names:
            mapping = []
            for name in names:
                if name in self.channels:
                    mapping.append(self.channels.index(name))
                else:
                    mapping.append(-1)
                    if name not in self._unknown_names:
                        self._unknown_names.add(name)
                        self.get_logger().warning(f'command for unknown channel {name!r} ignored')
            index_of = self._index_of = (list(names), mapping)
        efforts = [0.0] * n
        fault = False
        for value, index in zip(msg.effort, index_of[1]):
            if index < 0:
                continue
            if math.isfinite(value):
                efforts[index] = value
            else:
                fault = True
        if fault:
            self._bad_commands += 1
            self.get_logger().error('non-finite torque in actuator_command: zero torque applied',
                                    throttle_duration_sec=1.0)
        self._command_fault = fault
        return tuple(efforts)

    def _reject_command(self, reason):
        self._bad_commands += 1
        self.get_logger().error(f'actuator_command rejected: {reason}', throttle_duration_sec=1.0)

    # --- the cycle -----------------------------------------------------------------------
    def _step(self, efforts, timed_out=False):
        """Advance every channel one sample with ``efforts`` and publish the new state."""
        pending = self._pending_env
        if pending:
            for index in list(pending):
                self.sims[index].set_environment(pending.pop(index))
        self.stats.tick()
        for sim, effort in zip(self.sims, efforts):
            sim.step(effort)
        self.cycle += 1
        self._publish_state(self.cycle, timed_out)

    def _publish_state(self, cycle, timed_out=False):
        msg = self._state_msg
        stamp_now(msg.header.stamp)
        msg.cycle = cycle
        ms = [sim.measurement() for sim in self.sims]
        msg.motor_position = [m.x for m in ms]
        msg.motor_velocity = [m.v for m in ms]
        msg.pressure_force = [m.f_p for m in ms]
        msg.motor_effort = [m.f_a for m in ms]
        msg.endpoint_position = [m.x_e for m in ms]
        msg.external_force = [m.f_e for m in ms]
        base = (STATUS_COMMAND_TIMEOUT if timed_out else 0) | (
            STATUS_FAULT if self._command_fault else 0)
        msg.status = [base | (STATUS_LIMIT if sim.limited else 0) for sim in self.sims]
        # the send time is taken before publishing: the answer can arrive before publish returns
        self._last_publish = now = time.monotonic()
        self.timing.on_publish(cycle, now)
        self.state_pub.publish(msg)
        if self._js_every and cycle % self._js_every == 0:
            js = self._js_msg
            js.header.stamp = msg.header.stamp
            js.position = [v for m in ms for v in (m.x, m.x_e)]
            js.velocity = [v for m, sim in zip(ms, self.sims) for v in (m.v, sim.state[3])]
            js.effort = [v for m in ms for v in (m.f_a, m.f_e)]
            self.js_pub.publish(js)

    def _realtime_loop(self):
        deadline = Deadline(self.dt)
        zero = (0.0,) * len(self.channels)
        was_timed_out = False
        try:
            while self._running:
                now = deadline.wait()
                if not self._running:
                    break
                t_cmd = self._command_time
                timed_out = t_cmd is None or (now - t_cmd) > self.command_timeout
                if timed_out and not was_timed_out and t_cmd is not None:
                    self._timeouts += 1
                    self.get_logger().warning(
                        f'no actuator_command for {1e3 * (now - t_cmd):.1f} ms '
                        f'(> command_timeout {1e3 * self.command_timeout:.1f} ms): zero torque')
                elif was_timed_out and not timed_out:
                    self.get_logger().info('actuator_command back: torque re-enabled')
                was_timed_out = timed_out
                self.timing.on_tick(self.cycle)
                self._step(zero if timed_out else self._command, timed_out)
        except Exception as exc:  # never die silently: report and stop publishing
            if self._running and self.context.ok():
                self.get_logger().fatal(f'simulation loop stopped: {exc!r}')
            self._running = False

    @shutdown_safe
    def _lockstep_kick(self):
        if time.monotonic() - self._last_publish > 0.1:
            self._publish_state(self.cycle)

    # --- monitoring ----------------------------------------------------------------------
    @shutdown_safe
    def _publish_diagnostics(self):
        s = self.stats.summary()
        level = DiagnosticStatus.OK
        message = 'running'
        if not self._running:
            level, message = DiagnosticStatus.ERROR, 'simulation loop stopped'
        elif not self.lockstep and self._command_time is None:
            level, message = DiagnosticStatus.WARN, 'waiting for actuator_command'
        elif not self.lockstep and time.monotonic() - self._command_time > self.command_timeout:
            level, message = DiagnosticStatus.WARN, 'command timeout: zero torque'
        rtt50, rtt99 = self.timing.round_trip_ms()
        values = {'cycle': self.cycle, 'rate_hz': s.rate_hz, 'period_p50_ms': s.period_p50_ms,
                  'round_trip_p50_ms': rtt50, 'round_trip_p99_ms': rtt99,
                  'late_commands_total': self.timing.late,
                  'period_p99_ms': s.period_p99_ms, 'jitter_p99_ms': s.jitter_p99_ms,
                  'missed_deadlines': s.missed, 'command_timeouts': self._timeouts,
                  'bad_commands': self._bad_commands,
                  'clock_mode': 'lockstep' if self.lockstep else 'realtime'}
        publish_diagnostics(self, self.diag_pub, [
            diagnostic_status('sim: cycle', 'seaforce_sim', level, message, values)])

    def shutdown(self):
        """Stop the cycle thread (called by :func:`~seaforce_ros.ros_common.run`)."""
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)


def main(args=None):
    sys.setswitchinterval(2e-4)  # the cycle thread must get the GIL promptly
    sys.exit(run(SimNode, args=args, name='sim_node'))


if __name__ == '__main__':
    main()
