"""controller_node (node ``controller``): DOB + endpoint friction feed-forward at 2 kHz.

One instance serves every channel. Each ``actuator_state`` sample is answered by one
``actuator_command`` carrying the state's ``cycle``; what the command says comes from
:class:`~seaforce_ros.core.control_cycle.ControlCycle`: the state is checked (shapes, names,
finite and plausible values, stamp neither stale nor in the future, cycle continuity), one
:class:`~seaforce_ros.core.controller.ChannelController` per channel computes, the torque is
checked against ``<channel>.max_torque``. ``controller_status`` is published at
``status_rate`` (with each channel's fault, live during a fault), ``/diagnostics`` every
``diagnostics_period``.

Parameters per channel (``<channel>.mode``, ``.plant.*``, ``.dahl.*``, ``.dob.*``,
``.target.*``, ``.hold.*``, ...) can change at run time: the on-set callback validates the
whole new channel configuration in the core (passivity, eq. 28, included) and rejects it with
the core's reason, leaving everything as it was; an accepted one takes effect at the start of
the next cycle, bumplessly. Whether ``feedforward.damping_reserve`` holds a free finger over
the model's band is checked at start-up, and after an accepted change of the model, the
feed-forward or the DOB in a child process (:mod:`.free_finger_watch`); both warn, neither
refuses.

Faults: faults of the data (``latched_faults``) give the channel zero torque until the
``~/reset`` service (std_srvs/Trigger); a stall of the state stream or a plant restart only
zeroes it until states flow again, then the channel re-arms from the plant's present state
(its first torque is the torque the plant applies: no step).

Jobs: three actions hand a job (:mod:`seaforce_ros.core.jobs`) to a channel's controller, through
one adapter (:mod:`.jobs`: one goal per channel, whatever its action; a goal that cannot be
executed -- unknown channel, NaN or out-of-range fields, a faulted channel, a channel another
goal holds, no states arriving -- ends at once ABORTED with ``rejected: <reason>`` in
``result.message``; feedback at ``JOB_FEEDBACK_RATE``):

* Grasping: the action ``~/grasp`` (``seaforce_msgs/action/Grasp``) runs a
  :class:`~seaforce_ros.core.grasp.Grasp`; the goal holds the object until it is canceled,
  which releases it (the channel returns to its mode). Each channel's contact and object
  estimates are in ``controller_status`` whatever the mode.
* Friction calibration: the action ``~/calibrate_friction``
  (``seaforce_msgs/action/CalibrateFriction``) runs a
  :class:`~seaforce_ros.core.friction_calibration.FrictionCalibration`; when it applies the new
  values the node sets the channel's ``plant.endpoint_damping``,
  ``plant.endpoint_stiffness``, ``dahl.coulomb_force``, ``dahl.sigma`` and, where it found
  it, ``pressure_offset`` to them.
  ``<channel>.friction.adaptation`` turns the online adaptation on; its state is in
  ``/diagnostics``.
* The pressure sensor's offset: the service ``~/tare`` (std_srvs/Trigger, :mod:`.tare_service`)
  tares every free finger (:class:`~seaforce_ros.core.tare.PressureTare`) and sets
  ``<channel>.pressure_offset``.
* Commissioning: the action ``~/commission`` (``seaforce_msgs/action/Commission``,
  :mod:`.commissioning`) excites the free finger, identifies the plant, predicts the Z-width,
  tunes, reports, and applies when asked.
* Gripper commands: per channel, ``<ns>/gripper_cmd`` (``control_msgs/action/GripperCommand``)
  and ``<ns>/parallel_gripper_cmd`` (``ParallelGripperCommand``), ``<ns>`` =
  ``grasp.gripper_namespace`` or ``<channel>_gripper``, run a
  :class:`~seaforce_ros.core.gripper.GripperMove` (:mod:`.gripper_actions`; bad goals are
  rejected by the goal callback, the reason logged).

Layouts: separate processes (this executable) or composed with the plant in ``bringup`` /
``hardware_bringup``; with ``loop:=direct`` there the plant's cycle thread calls
:meth:`DirectPort.step` instead of going through DDS, and parameters and ``~/reset`` still
work from this node's executor (they hand over to the cycle at its next start).
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from seaforce_msgs.action import CalibrateFriction as CalibrateFrictionAction
from seaforce_msgs.action import Grasp as GraspAction
from seaforce_msgs.msg import ActuatorCommand, ActuatorState, ControllerStatus
from std_srvs.srv import Trigger

from . import param_specs as ps
from ..core.control_cycle import ControlCycle, StateChecks
from ..core.controller import ChannelController
from ..core.errors import SeaforceError
from ..core.friction_calibration import (CalibrationGoal, FrictionCalibration,
                                       check_calibration_goal)
from ..core.grasp import Grasp, GraspGoal, check_goal
from ..core.params import DOB_MODES, ControllerConfig, guard_carries
from ..core.schema import BRINGUP, CONTROLLER
from ..commissioning.free_finger import reserve_verdict
from .commissioning import CommissionAction
from .free_finger_watch import UNCHECKED, FreeFingerWatch
from .gripper_actions import gripper_job_actions
from .jobs import JobAction, JobActions
from .tare_service import TareService
from .ros_common import (GRAPH_PERIOD, STATUS_QOS, StartupError, check_undeclared, control_qos,
                         declare, diagnostic_status, diagnostics_publisher, log_events,
                         node_label, publish_diagnostics, run, shutdown_safe,
                         steady_timer)
from .timing import LoopStats

#: s without a state the cycle ran on after which the node (not the cycle, which does not
#: run) ends a goal and refuses new ones -- at least state_timeout. Shorter stalls the cycle
#: sees itself when states return (it re-arms and ends the goal); a starved node process
#: would otherwise take its own scheduling hiccup (70 ms beside a CPU hog) for a dead plant.
STALL_TIME = 0.5

#: s between looks at a free-finger check's child (:class:`.free_finger_watch.FreeFingerWatch`)
FREE_FINGER_POLL = 0.5

#: The parameters a friction calibration sets, in the order of its result's arrays.
_FRICTION_KEYS = ('plant.endpoint_damping', 'plant.endpoint_stiffness', 'dahl.coulomb_force',
                  'dahl.sigma', 'pressure_offset')

#: ROS key -> StateChecks attribute.
_CHECK_PARAMS = {spec.name: spec.attribute for spec in StateChecks.SPECS}


def node_specs():
    """controller_node's own parameters (its state checks among them)."""
    return ps.node_specs(CONTROLLER)


def _checks_from(values):
    return StateChecks(**{field: (tuple(values[name]) if name == 'latched_faults'
                                  else values[name])
                          for name, field in _CHECK_PARAMS.items()})


class ControllerNode(Node):
    """DOB + friction feed-forward for every channel (see module docstring).

    Parameters
    ----------
    composed : bool
        Declare the read-only ``loop`` parameter (``topics`` or ``direct``) of a bringup;
        with ``direct`` no ``actuator_state`` subscription is made: the plant calls
        :meth:`direct_port`'s ``step`` from its cycle thread.
    """

    def __init__(self, composed=False, **kwargs):
        super().__init__('controller', **kwargs)
        specs = node_specs()
        if composed:
            specs += ps.node_specs(BRINGUP)
        values = declare(self, specs)
        self._specs = {s.name: s for s in specs}
        self.channels = ps.channels_from(values)
        self.loop = values.get('loop', 'topics')
        self.configs = []                # newest accepted config per channel
        controllers = []
        self.dt = 1.0 / values['rate']
        for channel in self.channels:
            specs = ps.controller_channel_specs(channel)
            self._specs.update({s.name: s for s in specs})
            # dob.nominal_inertia's default is the given plant's motor inertia (its documented
            # default), so it is declared after the plant
            nominal = f'{channel}.dob.nominal_inertia'
            channel_values = declare(self, [s for s in specs if s.name != nominal])
            m = channel_values[f'{channel}.plant.motor_inertia']
            channel_values.update(declare(self, [dataclasses.replace(s, default=m)
                                                 for s in specs if s.name == nominal]))
            try:
                config = ControllerConfig.from_dict(ps.channel_values(channel_values, channel))
            except SeaforceError as exc:
                raise StartupError(ps.channel_error(exc, channel)) from None
            self.configs.append(config)
            controllers.append(ChannelController(config, dt=self.dt))
        check_undeclared(self)
        try:
            self.cycle = ControlCycle(self.channels, controllers, _checks_from(values))
        except ValueError as exc:
            raise StartupError(str(exc)) from exc
        self.controllers = controllers
        self._status_every = self._decimation(values['status_rate'])
        self.stats = LoopStats(self.dt)
        self._states = 0
        self._compute_sum = 0.0          # compute time since the last diagnostics [s]
        self._compute_max = 0.0

        self._cmd = ActuatorCommand()
        self._cmd.name = list(self.channels)
        self._status = ControllerStatus()
        self._status.name = list(self.channels)

        qos = values['control_qos']
        self.cmd_pub = self.create_publisher(ActuatorCommand, 'actuator_command', control_qos(qos))
        self.status_pub = self.create_publisher(ControllerStatus, 'controller_status', STATUS_QOS)
        self.diag_pub = diagnostics_publisher(self)
        if self.loop == 'topics':
            self.create_subscription(ActuatorState, 'actuator_state', self._on_state,
                                     control_qos(qos, subscriber=True))
        self.create_service(Trigger, '~/reset', self._on_reset)
        self._last_state = None          # monotonic time of the latest state run on [s]
        self.jobs = JobActions(self, self.channels, controllers, self.cycle, self._stalled)
        self.jobs.add(self._grasp_action())
        self.jobs.add(self._calibration_action())
        for action in gripper_job_actions(self):     # control_msgs, per channel
            self.jobs.add(action)
        self.commissioning = CommissionAction(self)
        self.jobs.add(self.commissioning.action())
        self.tare = TareService(self, self.channels, controllers, self.jobs, self._stalled)
        self._state_topic = self.resolve_topic_name('actuator_state')
        steady_timer(self, GRAPH_PERIOD, self._watch_graph)
        self.add_on_set_parameters_callback(self._validate_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        steady_timer(self, values['diagnostics_period'], self._publish_diagnostics)
        logger = self.get_logger()
        self.free_finger = FreeFingerWatch(self._ff_delay(), self.dt, logger.warning,
                                           logger.info)
        for channel, config in zip(self.channels, self.configs):
            self._warn_guarded(channel, None, config)
            self._warn_free_finger(channel, config)
        steady_timer(self, FREE_FINGER_POLL, self.free_finger.poll)
        modes = ', '.join(f'{c}={ctrl.mode}' for c, ctrl in zip(self.channels, controllers))
        self.get_logger().info(f'controlling {self.channels} at {values["rate"]:.0f} Hz '
                               f'({modes}), loop={self.loop}')

    def _decimation(self, rate_hz):
        if rate_hz <= 0:
            return 0
        return max(1, int(round(1.0 / (self.dt * rate_hz))))

    # --- parameters ----------------------------------------------------------------------
    def _new_configs(self, params):
        """({channel index: validated ControllerConfig}, StateChecks or None) for ``params``."""
        changed = {}
        for p in params:
            spec = self._specs.get(p.name)
            if spec is not None:
                reason = spec.reason(p.value)
                if reason:
                    raise SeaforceError(reason)
            changed[p.name] = p.value
        configs = {}
        for index, channel in enumerate(self.channels):
            mine = ps.channel_values(changed, channel)
            if mine:
                try:
                    configs[index] = ControllerConfig.from_dict(mine, base=self.configs[index])
                except SeaforceError as exc:
                    raise SeaforceError(ps.channel_error(exc, channel)) from None
        checks = None
        if any(name in changed for name in _CHECK_PARAMS):
            current = {name: self.get_parameter(name).value for name in _CHECK_PARAMS}
            checks = _checks_from({**current, **changed})
        return configs, checks

    def _validate_parameters(self, params):
        try:
            self._new_configs(params)
        except SeaforceError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params):
        for p in params:
            if p.name == 'status_rate':
                self._status_every = self._decimation(p.value)
        configs, checks = self._new_configs(params)
        if checks is not None:
            self.cycle.configure(checks)
        if configs:     # all of them at the next cycle's start; a set mode ends a job
            names = {p.name for p in params}
            self.cycle.configure_channels(configs, (i for i, c in enumerate(self.channels)
                                                    if f'{c}.mode' in names))
        for index, config in configs.items():
            old = self.configs[index]
            self.configs[index] = config
            if config.mode != old.mode:
                self.get_logger().info(f'{self.channels[index]}: mode {old.mode} -> {config.mode}')
            self._warn_guarded(self.channels[index], old, config)
            self.free_finger.changed(self.channels[index], old, config)

    def _warn_guarded(self, channel, old, config):
        """Warn once when an active passivity guard carries a DOB setting outside eq. 28."""
        text = guard_carries(config)
        if text and (old is None or text != guard_carries(old)):
            self.get_logger().warning(f'{channel}: {text}')

    def _ff_delay(self):
        """Samples from a state to its command's first sample in this layout."""
        return 1 if self.loop == 'direct' else 2

    def _warn_free_finger(self, channel, config):
        """At start-up: warn when the damping reserve does not hold a free finger over the
        model's band (commissioning.free_finger). After a parameter set the check runs in a
        child process (:class:`.free_finger_watch.FreeFingerWatch`: 0.1-2 s of CPU, which
        the 2 kHz loop cannot wait)."""
        try:
            text = reserve_verdict(config, delay=self._ff_delay(), dt=self.dt)
        except Exception as exc:      # noqa: BLE001 -- the check must not keep the node down
            text = UNCHECKED
            self.get_logger().warning(f'{channel}: the free-finger check did not run ({exc}); '
                                      'the damping reserve is unchecked')
        else:
            if text:
                self.get_logger().warning(f'{channel}: {text}')
        self.free_finger.started(channel, text)

    # --- the 2 kHz path ------------------------------------------------------------------
    @shutdown_safe
    def _on_state(self, msg):
        """(topics layout) One state in, one command out."""
        stamp = msg.header.stamp
        out = self._run_cycle(msg.name, msg.cycle, stamp.sec * 1_000_000_000 + stamp.nanosec,
                              msg.motor_position, msg.motor_velocity, msg.pressure_force,
                              msg.motor_effort, msg.status, time.time_ns(), time.monotonic())
        if out.answered:
            cmd = self._cmd
            cmd.header.stamp = stamp
            cmd.cycle = msg.cycle
            cmd.effort = out.effort
            self.cmd_pub.publish(cmd)
            if self._status_every and msg.cycle % self._status_every == 0:
                self._publish_status(self._status_values(), msg.cycle, stamp)

    def direct_port(self):
        """The controller's cycle for a plant's cycle thread (direct layout)."""
        return DirectPort(self)

    def _status_values(self):
        """Per-channel status fields now (lists: safe to publish later from another thread);
        the object estimates are added when the message is published (:meth:`_publish_status`:
        solving them is no work for the control path)."""
        ctrls, cycle = self.controllers, self.cycle
        return ([c.mode for c in ctrls], [c.disturbance for c in ctrls],
                [c.feedforward for c in ctrls], [c.endpoint_velocity_estimate for c in ctrls],
                [c.dahl_force for c in ctrls], [cycle.fault(i) for i in range(len(ctrls))],
                [c.estimator.contact for c in ctrls], [c.estimator.force for c in ctrls],
                [c.grasp_phase for c in ctrls], *_guard_status(ctrls))

    def _publish_status(self, values, cycle, stamp):
        s = self._status
        s.header.stamp = stamp
        s.cycle = cycle
        (s.mode, s.disturbance, s.feedforward, s.endpoint_velocity_estimate, s.dahl_force,
         s.fault, s.contact, s.contact_force, s.grasp_phase, s.passivity_energy,
         s.passivity_dissipated, s.passivity_damping) = values
        estimates = [c.estimator.estimate() for c in self.controllers]
        self.commissioning.observe(cycle, [c.estimator.velocity for c in self.controllers],
                                   [c.estimator.contact for c in self.controllers])
        s.contact_position = [e.contact_position for e in estimates]
        s.object_stiffness = [e.stiffness for e in estimates]
        s.object_stiffness_sigma = [e.stiffness_sigma for e in estimates]
        s.object_damping = [e.damping for e in estimates]
        s.object_damping_sigma = [e.damping_sigma for e in estimates]
        self.status_pub.publish(s)

    def _run_cycle(self, names, cycle, stamp_ns, x, v, f_p, f_a, status, now_ns, now):
        """ControlCycle.step, timed, its reports logged (both layouts)."""
        t0 = time.perf_counter()
        self.stats.tick(now)
        self._states += 1
        out = self.cycle.step(names, cycle, stamp_ns, x, v, f_p, f_a, status, now_ns, now)
        if out.answered:        # a state the cycle ran on (not one it dropped)
            self._last_state = now
        if self.cycle.events:
            log_events(self.get_logger(), self.cycle.events.drain())
        elapsed = time.perf_counter() - t0
        self._compute_sum += elapsed
        if elapsed > self._compute_max:
            self._compute_max = elapsed
        return out

    @shutdown_safe
    def _watch_graph(self):
        self.cycle.set_state_publishers(sorted(
            node_label(i) for i in self.get_publishers_info_by_topic(self._state_topic)))

    def _stalled(self):
        """'no actuator_state for ...' when the cycle has run on none for longer than
        max(STALL_TIME, state_timeout) (then the cycle, when states return, sees the stall
        first and re-arms), else ''."""
        limit = max(STALL_TIME, self.cycle.checks.state_timeout)
        if self._last_state is None:
            return 'no actuator_state is arriving'
        age = time.monotonic() - self._last_state
        if age > limit:
            return f'no actuator_state for {age:.2f} s (> {limit:g} s)'
        return ''

    # --- grasps --------------------------------------------------------------------------
    def _grasp_action(self) -> JobAction:
        """``~/grasp``: a Grasp per goal."""
        def make(index, goal):
            config = self.configs[index]
            request = GraspGoal(goal.channel, goal.closing_velocity, goal.grip_force,
                                goal.max_force, goal.probe)
            check_goal(request, config.grasp, config.estimator, config.max_torque)
            return Grasp(request, config, self.dt)

        def describe(goal):
            return (f'grasp at {goal.closing_velocity:g} rad/s, grip {goal.grip_force:g} N m, '
                    f'max {goal.max_force:g} N m' + (', probing' if goal.probe else ''))

        return JobAction('~/grasp', GraspAction, Grasp.kind, make, self._grasp_result, describe,
                         busy=lambda grasp: f'is held by a grasp goal ({grasp.phase})',
                         cancel_reason='released (goal canceled)')

    def _grasp_result(self, index, grasp, message):
        """The action's result: the object as the grasp let go of it, or as the estimator has
        it for a goal ended while its grasp runs (a stall); none without a contact."""
        result = GraspAction.Result()
        result.message = message
        result.contact = bool(grasp is not None and grasp.contact)
        estimate = None
        if result.contact:
            estimate = (self.controllers[index].estimator.estimate() if grasp.active
                        else grasp.estimate)
        nan = math.nan
        result.contact_position = estimate.contact_position if estimate else nan
        result.object_stiffness = estimate.stiffness if estimate else nan
        result.object_stiffness_sigma = estimate.stiffness_sigma if estimate else nan
        result.object_damping = estimate.damping if estimate else nan
        result.object_damping_sigma = estimate.damping_sigma if estimate else nan
        result.grip_force = grasp.grip_force if grasp is not None else nan
        return result

    # --- friction calibration ------------------------------------------------------------
    def _calibration_action(self) -> JobAction:
        """``~/calibrate_friction``: a FrictionCalibration per goal; the values it applies
        become the channel's parameters."""
        def make(index, goal):
            config = self.configs[index]
            request = CalibrationGoal(goal.channel, goal.amplitude, goal.speed, goal.apply)
            check_calibration_goal(request, config.friction,
                                   self.controllers[index].endpoint_position_estimate)
            return FrictionCalibration(request, config, self.dt)

        def describe(goal):
            return (f'friction calibration, {goal.amplitude:g} rad at up to {goal.speed:g} '
                    'rad/s' + (', applying' if goal.apply else ''))

        def finish(index, calibration):
            if calibration.applied:
                return self._store_friction(index, calibration.new, calibration.message)
            return calibration.message

        return JobAction('~/calibrate_friction', CalibrateFrictionAction,
                         FrictionCalibration.kind, make, _calibration_result, describe,
                         busy=lambda calibration: 'is calibrating its friction',
                         cancel_reason='canceled', finish=finish)

    def _store_friction(self, index, new, message):
        """Set the channel's friction parameters to the applied values (the controller already
        runs on them: the same config comes back, bumplessly)."""
        channel = self.channels[index]
        values = dict(zip(_FRICTION_KEYS, (new.endpoint_damping, new.endpoint_stiffness,
                                           new.coulomb_force, new.sigma, new.pressure_offset)))
        if not math.isfinite(values['pressure_offset']):
            del values['pressure_offset']           # (not identified: not applied either)
        results = self.set_parameters([Parameter(f'{channel}.{key}', value=float(value))
                                       for key, value in values.items()])
        failed = [r.reason for r in results if not r.successful]
        if failed:
            return f'{message}; parameters not updated: {failed[0]}'
        return message

    @staticmethod
    def _friction_diagnostics(ctrl):
        adaptation = ctrl.adaptation
        if not ctrl.config.friction.adaptation:
            return {'friction_adaptation': 'off'}
        be, ke, fc, sigma = adaptation.values
        return {'friction_adaptation': 'adapting' if adaptation.adapting else
                adaptation.reason, 'adapted_endpoint_damping': be,
                'adapted_endpoint_stiffness': ke, 'adapted_coulomb_force': fc,
                'adapted_sigma': sigma, 'friction_adaptation_updates': adaptation.updates}

    def shutdown(self):
        """(the node is going down) End every commissioning analysis and free-finger check
        still running."""
        self.commissioning.close()
        self.free_finger.close()

    # --- faults --------------------------------------------------------------------------
    def _on_reset(self, request, response):
        response.success = True
        response.message = self.cycle.request_reset()
        self.get_logger().info(f'reset: {response.message}')
        return response

    @shutdown_safe
    def _publish_diagnostics(self):
        s = self.stats.summary()
        cycle = self.cycle
        n_faults = sum(1 for i, c in enumerate(self.controllers)
                       if cycle.latched(i) or c.fallback)
        level = DiagnosticStatus.OK if s.cycles else DiagnosticStatus.WARN
        message = 'running' if s.cycles else 'no actuator_state received'
        if n_faults:
            level, message = DiagnosticStatus.ERROR, f'{n_faults} channel(s) faulted'
        statuses = [diagnostic_status(
            'controller: loop', 'seaforce_controller', level, message,
            {'state_rate_hz': s.rate_hz, 'period_p50_ms': s.period_p50_ms,
             'period_p99_ms': s.period_p99_ms, 'jitter_p99_ms': s.jitter_p99_ms,
             'missed_deadlines': s.missed, 'states_received': self._states,
             'states_dropped': cycle.dropped, 'loop': self.loop,
             'compute_mean_us': 1e6 * self._compute_sum / max(1, s.cycles),
             'compute_max_us': 1e6 * self._compute_max,
             'faults_latched_total': cycle.faults_latched,
             **{f'{kind}_total': count for kind, count in cycle.counts.items()}})]
        self._compute_sum = self._compute_max = 0.0
        for i, (channel, ctrl) in enumerate(zip(self.channels, self.controllers)):
            fault = cycle.fault(i)
            # a latched fault, or the runaway monitor's fall-back (latched until ~/reset too)
            stopped = bool(cycle.latched(i) or ctrl.fallback)
            creep = self._creep_line(channel, ctrl)
            statuses.append(diagnostic_status(
                f'controller: {channel}', 'seaforce_controller',
                DiagnosticStatus.ERROR if stopped else (
                    DiagnosticStatus.WARN if fault or creep else DiagnosticStatus.OK),
                f'FAULT: {fault}' if stopped else (fault or creep or ctrl.mode),
                {'mode': ctrl.mode, 'fault': fault or 'none', 'torque': ctrl.torque,
                 'fallback': ctrl.fallback or 'none', 'wall_force': ctrl.walls.force,
                 'disturbance': ctrl.disturbance, 'feedforward': ctrl.feedforward,
                 'grasp': ctrl.grasp_phase or 'none', 'contact': ctrl.estimator.contact,
                 'passivity_guard': ctrl.config.passivity.mode,
                 'pressure_offset': ctrl.pressure_offset, **self.tare.diagnostics(i),
                 'creeping_speed': ctrl.settling.creeping,
                 'unexplained_force': ctrl.estimator.bias + ctrl.estimator.force,
                 **dict(zip(_GUARD_FIELDS, _guard_values(ctrl))),
                 **self._friction_diagnostics(ctrl)}))
            statuses += [_passivity_status(channel, ctrl), _grasp_status(channel, ctrl)]
        publish_diagnostics(self, self.diag_pub, statuses)


    def _creep_line(self, channel, ctrl):
        """A finger that creeps steadily one way, or keeps moving, in a mode that runs the
        DOB, in words (and a warning, at most every 10 s per channel), or ''."""
        watch = ctrl.settling
        if not (watch.creeping or watch.restless) or ctrl.mode not in DOB_MODES or \
                ctrl.fallback or ctrl.job is not None:
            return ''
        force = ctrl.estimator.bias + ctrl.estimator.force
        if watch.creeping:
            line = (f'the finger creeps at {watch.creeping:+.3g} rad/s with a steady '
                    f'unexplained force of {1e3 * force:+.3g} mN m on it: if nothing pushes '
                    'it, a pressure offset (call ~/tare) or over-compensated friction '
                    '(commission the gripper)')
        else:
            line = (f'the finger has kept moving for {watch.moving:.3g} s: if nothing moves '
                    'it, the feed-forward over-compensates its friction (commission the '
                    'gripper)')
        self.get_logger().warning(f'{channel}: {line}', throttle_duration_sec=10.0)
        return line


def _calibration_result(index, calibration, message):
    """``~/calibrate_friction``'s result: the values before and after with the new ones'
    1-sigma; a goal ended while its calibration runs (a stall) applied nothing."""
    result = CalibrateFrictionAction.Result()
    result.names = list(_FRICTION_KEYS)
    if calibration is not None and calibration.active:
        message += ', nothing applied'
    result.message = message
    nan = math.nan
    old = new = None
    if calibration is not None:
        old, new = calibration.old, calibration.new
    n = len(_FRICTION_KEYS)
    olds = ([old.endpoint_damping, old.endpoint_stiffness, old.coulomb_force, old.sigma,
             old.pressure_offset] if old else [nan] * n)
    news = ([new.endpoint_damping, new.endpoint_stiffness, new.coulomb_force, new.sigma,
             new.pressure_offset] if new else [nan] * n)
    result.old_values = [float(v) for v in olds]
    result.new_values = [float(v) for v in news]
    result.new_values_sigma = ([float(v) for v in (
        new.endpoint_damping_sigma, new.endpoint_stiffness_sigma, new.coulomb_force_sigma,
        new.sigma_sigma, new.pressure_offset_sigma)] if new else [nan] * n)
    result.change = [n - o for n, o in zip(result.new_values, result.old_values)]
    result.applied = bool(calibration is not None and calibration.applied)
    return result


_GUARD_FIELDS = ('passivity_energy', 'passivity_dissipated', 'passivity_damping')


def _guard_values(ctrl):
    """The passivity guard's observed energy [J], the energy its damping took out [J] and the
    damping it adds (``monitor``: would add) [N m s/rad]; NaN when it is disabled."""
    g = ctrl.passivity_guard
    return (math.nan,) * 3 if g is None else (g.energy, g.dissipated, g.damping)


#: Prefixes of the controller's ``/diagnostics`` status names: ``<prefix>: <channel>`` (the
#: loop's own status is ``controller: loop``); config/diagnostics_analyzers.yaml groups by them.
STATUS_PREFIXES = ('controller', 'passivity', 'grasp')


def _passivity_status(channel, ctrl):
    """``passivity: <channel>``: the guard's mode and figures; WARN while it adds damping."""
    mode = ctrl.config.passivity.mode
    energy, dissipated, damping = _guard_values(ctrl)
    acting = mode != 'disabled' and damping > 0.0
    return diagnostic_status(
        f'passivity: {channel}', 'seaforce_controller',
        DiagnosticStatus.WARN if acting else DiagnosticStatus.OK,
        f'{mode}: adding {damping:.3g} N m s/rad' if acting else mode,
        {'passivity_guard': mode, **dict(zip(_GUARD_FIELDS, (energy, dissipated, damping)))})


def _grasp_status(channel, ctrl):
    """``grasp: <channel>``: the running grasp's phase, the contact and the latest object
    estimate (stiffness k_o, damping b_o with their 1-sigma)."""
    estimator = ctrl.estimator
    estimate = estimator.estimate()
    phase = ctrl.grasp_phase or 'none'
    return diagnostic_status(
        f'grasp: {channel}', 'seaforce_controller', DiagnosticStatus.OK,
        f'{phase}, contact' if estimator.contact else phase,
        {'grasp': phase, 'contact': estimator.contact, 'contact_force': estimator.force,
         'contact_position': estimate.contact_position,
         'object_stiffness': estimate.stiffness, 'object_stiffness_sigma': estimate.stiffness_sigma,
         'object_damping': estimate.damping, 'object_damping_sigma': estimate.damping_sigma})


def _guard_status(ctrls):
    """The :data:`_GUARD_FIELDS` of ``controller_status``: one list per field."""
    return tuple(list(column) for column in zip(*(_guard_values(c) for c in ctrls)))


class DirectPort:
    """The controller's cycle called by a plant's cycle thread (the direct layout).

    :meth:`step` runs :class:`ControlCycle` on the plant's fresh sample and returns
    ``(efforts, status)`` (new lists the plant keeps; ``status`` only every ``status_rate``)
    or None when the state was dropped; :meth:`publish`, on the plant's cycle thread after it
    wrote the torque, publishes the ``actuator_command`` (and ``controller_status``) of that
    cycle, so recorders and observers see the same topics as with separate processes.
    """

    def __init__(self, node: ControllerNode):
        self._node = node
        self._cmd = ActuatorCommand()
        self._cmd.name = list(node.channels)

    def step(self, names, cycle, stamp_ns, x, v, f_p, f_a, status, now_ns, now):
        node = self._node
        out = node._run_cycle(names, cycle, stamp_ns, x, v, f_p, f_a, status, now_ns, now)
        if not out.answered:
            return None
        every = node._status_every
        status_values = node._status_values() if every and cycle % every == 0 else None
        return list(out.effort), status_values

    def publish(self, cycle, stamp, command):
        efforts, status_values = command
        cmd = self._cmd
        cmd.header.stamp = stamp
        cmd.cycle = cycle
        cmd.effort = efforts
        self._node.cmd_pub.publish(cmd)
        if status_values is not None:
            self._node._publish_status(status_values, cycle, stamp)


def main(args=None):
    sys.exit(run(ControllerNode, args=args, name='controller_node'))


if __name__ == '__main__':
    main()
