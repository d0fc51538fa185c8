"""controller_node (node ``controller``): DOB + endpoint friction feed-forward at 2 kHz.

One instance serves every channel. Each ``actuator_state`` sample is answered by one
``actuator_command`` carrying the state's ``cycle``; the torques come from one
:class:`seaforce_ros.core.controller.ChannelController` per channel. ``controller_status`` is
published at ``status_rate``, ``/diagnostics`` every ``diagnostics_period``.

Parameters per channel (``<channel>.mode``, ``.plant.*``, ``.dahl.*``, ``.dob.*``,
``.target.*``, ``.hold.*``, ...) can change at run time: the on-set callback validates the
whole new channel configuration in the core (passivity, eq. 28, included) and rejects it with
the core's reason, leaving everything as it was; an accepted one takes effect at the start of
the next cycle, bumplessly.

Safety: a state older than ``state_timeout``, a NaN/inf in a state, a channel missing from
the state, or a torque beyond ``<channel>.max_torque`` latches a fault: zero torque on that
channel (every channel for a stale state), reported in ``/diagnostics`` and the log, until
the ``~/reset`` service (std_srvs/Trigger) clears it.
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from seaforce_msgs.msg import ActuatorCommand, ActuatorState, ControllerStatus
from std_srvs.srv import Trigger

from . import param_specs as ps
from .core.controller import ChannelController
from .core.errors import NonFiniteInputError, SeaforceError
from .core.params import ControllerConfig
from .ros_common import (STATUS_QOS, ParamSpec, StartupError, control_qos, control_qos_spec,
                         declare, diagnostic_status, diagnostics_publisher,
                         publish_diagnostics, run, shutdown_safe)
from .timing import LoopStats


def node_specs():
    return [
        ps.channels_spec(),
        ps.executor_spec('events'),
        control_qos_spec(),
        ParamSpec('rate', 2000.0, 'control rate the sample period is derived from [Hz]; '
                  'must equal the rate of the state source', low=1.0, high=20000.0,
                  read_only=True),
        ParamSpec('state_timeout', 0.05,
                  'a state older than this (header stamp vs now) latches a fault [s]',
                  low=1e-4, high=10.0),
        ParamSpec('status_rate', 100.0, 'controller_status rate [Hz], 0 = off', low=0.0,
                  high=20000.0),
        ParamSpec('diagnostics_period', 1.0, '/diagnostics period [s]', low=0.05, high=60.0,
                  read_only=True),
    ]


# the plant side reports it applied zero torque on this channel (watchdog or fault)
_PLANT_STOPPED = ActuatorState.STATUS_COMMAND_TIMEOUT | ActuatorState.STATUS_FAULT


class ControllerNode(Node):
    """DOB + friction feed-forward for every channel (see module docstring)."""

    def __init__(self, **kwargs):
        super().__init__('controller', **kwargs)
        values = declare(self, node_specs())
        self.channels = ps.channels_from(values)
        self._specs = {}
        self.controllers = []
        self.configs = []                # newest accepted config per channel
        self.dt = 1.0 / values['rate']
        for channel in self.channels:
            specs = ps.controller_channel_specs(channel)
            self._specs.update({s.name: s for s in specs})
            channel_values = declare(self, specs)
            try:
                config = ControllerConfig.from_dict(ps.channel_values(channel_values, channel))
            except SeaforceError as exc:
                raise StartupError(f'channel {channel}: {exc}') from exc
            self.configs.append(config)
            self.controllers.append(ChannelController(config, dt=self.dt))
        self.state_timeout_ns = int(values['state_timeout'] * 1e9)
        self._status_every = self._decimation(values['status_rate'])

        n = len(self.channels)
        self.faults = [''] * n           # latched fault reason per channel ('' = none)
        self._fault_count = 0
        self._last_cycle = None
        self._armed = False              # stale-state check armed by the first fresh state
        self._dropped_stale = 0
        self._state_names = None         # cached (names, index of each channel in the state)
        self._states = 0
        self.stats = LoopStats(self.dt)
        self._compute_sum = 0.0          # callback compute time since the last diagnostics [s]
        self._compute_max = 0.0

        self._cmd = ActuatorCommand()
        self._cmd.name = list(self.channels)
        self._effort = [0.0] * n
        self._status = ControllerStatus()
        self._status.name = list(self.channels)

        qos = values['control_qos']
        self.cmd_pub = self.create_publisher(ActuatorCommand, 'actuator_command', control_qos(qos))
        self.status_pub = self.create_publisher(ControllerStatus, 'controller_status', STATUS_QOS)
        self.diag_pub = diagnostics_publisher(self)
        self.create_subscription(ActuatorState, 'actuator_state', self._on_state,
                                 control_qos(qos, subscriber=True))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(values['diagnostics_period'], self._publish_diagnostics)
        modes = ', '.join(f'{c}={ctrl.mode}' for c, ctrl in zip(self.channels, self.controllers))
        self.get_logger().info(f'controlling {self.channels} at {values["rate"]:.0f} Hz ({modes})')

    def _decimation(self, rate_hz):
        if rate_hz <= 0:
            return 0
        return max(1, int(round(1.0 / (self.dt * rate_hz))))

    # --- parameters ----------------------------------------------------------------------
    def _new_configs(self, params):
        """{channel index: validated ControllerConfig} for the channels ``params`` touch."""
        changed = {}
        for p in params:
            spec = self._specs.get(p.name)
            if spec is not None:
                reason = spec.check(p.value)
                if reason:
                    raise SeaforceError(reason)
            changed[p.name] = p.value
        configs = {}
        for index, channel in enumerate(self.channels):
            mine = ps.channel_values(changed, channel)
            if mine:
                configs[index] = ControllerConfig.from_dict(mine, base=self.configs[index])
        return configs

    def _validate_parameters(self, params):
        try:
            self._new_configs(params)
        except SeaforceError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params):
        for p in params:
            if p.name == 'state_timeout':
                self.state_timeout_ns = int(p.value * 1e9)
            elif p.name == 'status_rate':
                self._status_every = self._decimation(p.value)
        for index, config in self._new_configs(params).items():
            old = self.configs[index]
            self.configs[index] = config
            self.controllers[index].configure(config)  # effective at the next cycle's start
            if config.mode != old.mode:
                self.get_logger().info(f'{self.channels[index]}: mode {old.mode} -> {config.mode}')

    # --- the 2 kHz path ------------------------------------------------------------------
    @shutdown_safe
    def _on_state(self, msg):
        t0 = time.perf_counter()
        self.stats.tick()
        self._states += 1
        cmd = self._cmd
        if msg.cycle == self._last_cycle:
            self.cmd_pub.publish(cmd)  # a re-published state: same answer, no new sample
            return
        self._last_cycle = msg.cycle
        names = msg.name
        index = self._state_index(names)
        now_ns = time.time_ns()  # system clock, as the stamps (ros_common.stamp_now)
        stamp = msg.header.stamp
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        if now_ns - stamp_ns > self.state_timeout_ns:
            if not self._armed:
                # before the first fresh sample (start-up, discovery backlog): drop, count
                self._dropped_stale += 1
                return
            age_ms = (now_ns - stamp_ns) * 1e-6
            self._latch_all(f'stale state: {age_ms:.1f} ms old (> state_timeout)')
        self._armed = True
        effort = self._effort
        xs, vs, fps, status = (msg.motor_position, msg.motor_velocity, msg.pressure_force,
                               msg.status)
        n_state = len(names)
        for i, ctrl in enumerate(self.controllers):
            j = index[i]
            if self.faults[i] or j < 0:
                if j < 0 and not self.faults[i]:
                    self._latch(i, 'channel missing from actuator_state')
                effort[i] = 0.0
                continue
            try:
                if len(xs) != n_state or len(vs) != n_state or len(fps) != n_state:
                    raise ValueError('actuator_state arrays differ in length from name')
                if status and status[j] & _PLANT_STOPPED:
                    ctrl.track_applied(0.0)  # the plant side zeroed the torque: no windup
                u = ctrl.update(xs[j], vs[j], fps[j])
            except (NonFiniteInputError, ValueError) as exc:
                self._latch(i, f'bad state: {exc}')
                effort[i] = 0.0
                continue
            if ctrl.limited:
                self._latch(i, f'torque beyond max_torque ({ctrl.config.max_torque:g} N m)')
                u = 0.0
            effort[i] = u
        cmd.header.stamp = msg.header.stamp
        cmd.cycle = msg.cycle
        cmd.effort = effort
        self.cmd_pub.publish(cmd)
        if self._status_every and msg.cycle % self._status_every == 0:
            self._publish_status(msg)
        elapsed = time.perf_counter() - t0
        self._compute_sum += elapsed
        if elapsed > self._compute_max:
            self._compute_max = elapsed

    def _state_index(self, names):
        cached = self._state_names
        if cached is not None and cached[0] == names:
            return cached[1]
        index = [names.index(c) if c in names else -1 for c in self.channels]
        self._state_names = (list(names), index)
        return index

    def _publish_status(self, state):
        s = self._status
        s.header.stamp = state.header.stamp
        s.cycle = state.cycle
        ctrls = self.controllers
        s.mode = [c.mode for c in ctrls]
        s.disturbance = [c.disturbance for c in ctrls]
        s.feedforward = [c.feedforward for c in ctrls]
        s.endpoint_velocity_estimate = [c.endpoint_velocity_estimate for c in ctrls]
        s.dahl_force = [c.dahl_force for c in ctrls]
        self.status_pub.publish(s)

    # --- faults --------------------------------------------------------------------------
    def _latch(self, index, reason):
        if not self.faults[index]:
            self.faults[index] = reason
            self._fault_count += 1
            self.get_logger().error(
                f'{self.channels[index]}: FAULT latched, zero torque: {reason}; '
                f'call ~/reset (std_srvs/Trigger) to clear')

    def _latch_all(self, reason):
        for i in range(len(self.channels)):
            self._latch(i, reason)

    def _on_reset(self, request, response):
        cleared = [c for c, f in zip(self.channels, self.faults) if f]
        for i, ctrl in enumerate(self.controllers):
            if self.faults[i]:
                ctrl.reset()
                self.faults[i] = ''
        response.success = True
        response.message = (f'cleared faults on {", ".join(cleared)}' if cleared
                            else 'no fault was latched')
        self.get_logger().info(f'reset: {response.message}')
        return response

    @shutdown_safe
    def _publish_diagnostics(self):
        s = self.stats.summary()
        statuses = [diagnostic_status(
            'controller: loop', 'seaforce_controller',
            DiagnosticStatus.OK if s.cycles else DiagnosticStatus.WARN,
            'running' if s.cycles else 'no actuator_state received',
            {'state_rate_hz': s.rate_hz, 'period_p50_ms': s.period_p50_ms,
             'period_p99_ms': s.period_p99_ms, 'jitter_p99_ms': s.jitter_p99_ms,
             'missed_deadlines': s.missed, 'states_received': self._states,
             'stale_dropped_before_start': self._dropped_stale,
             'compute_mean_us': 1e6 * self._compute_sum / max(1, s.cycles),
             'compute_max_us': 1e6 * self._compute_max,
             'faults_latched_total': self._fault_count})]
        self._compute_sum = self._compute_max = 0.0
        for channel, ctrl, fault in zip(self.channels, self.controllers, self.faults):
            statuses.append(diagnostic_status(
                f'controller: {channel}', 'seaforce_controller',
                DiagnosticStatus.ERROR if fault else DiagnosticStatus.OK,
                f'FAULT: {fault}' if fault else ctrl.mode,
                {'mode': ctrl.mode, 'fault': fault or 'none', 'torque': ctrl.torque,
                 'disturbance': ctrl.disturbance, 'feedforward': ctrl.feedforward}))
        publish_diagnostics(self, self.diag_pub, statuses)


def main(args=None):
    sys.exit(run(ControllerNode, args=args, name='controller_node'))


if __name__ == '__main__':
    main()
