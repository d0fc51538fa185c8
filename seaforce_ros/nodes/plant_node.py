"""One plant node for every plant: the ROS side of the loop, composing a plant backend.

:class:`PlantNode` owns everything of a plant node that is not the plant itself, once for
sim_node and hardware_node alike; the plant is a
:class:`~seaforce_ros.core.backend.PlantBackend` (the simulator or the EtherCAT bus) that
the thin node modules build from their parameters and hand to :meth:`PlantNode.attach`:

* the cycle (:meth:`PlantNode.run_cycle`): the backend reads the plant, the sample is
  published (in the direct layout the controller's cycle is called right there, on the
  cycle thread), :class:`~seaforce_ros.core.plant_cycle.PlantCycle` decides the torques and
  the backend writes them: ros2_control's read / update / write;
* the ``actuator_command`` subscription (commands are only handed to PlantCycle), the graph
  watch for a second command publisher, ``~/reset``, the run-time parameters;
* publishing ``actuator_state`` / ``joint_states`` (and, in the direct layout, the
  controller's ``actuator_command`` / ``controller_status``) from the cycle;
* the log lines PlantCycle reports (once per episode, throttled) and ``/diagnostics``.

It is a managed (lifecycle) node, as ros2_control's hardware components are: the standard
``lifecycle_msgs`` services (``~/change_state``, ``~/get_state``, ``~/get_available_states``,
``~/get_available_transitions``, ``~/get_transition_graph``; what ``ros2 lifecycle set
/hardware activate`` calls) move it, each transition calling the backend's step of the same
meaning:

==============  ===========================================================================
configure       backend open + configure: the plant checked (EtherCAT: every identity, bus
                in SAFE-OP); no torque -> *inactive*
activate        a fresh PlantCycle (cycle numbers from 1, no latched fault, no command: as at
                a node start; limits from the parameters now), backend activate, then the
                cycle -> *active*: torque follows ``actuator_command``
deactivate      the cycle stops, backend deactivate: zero torque, drives disabled -> *inactive*
cleanup         backend close (EtherCAT: bus in INIT) -> *unconfigured*
shutdown        the cycle stops, backend close -> *finalized*
==============  ===========================================================================

``actuator_state`` is published only while active. A transition the backend cannot do (its
:class:`~seaforce_ros.core.backend.BackendError` gives the reason, logged as an error) takes
the plant back to the safe side of it -- a failed configure closes the backend, a failed
activate deactivates it -- and returns FAILURE: the node stays in the state it was in. An
unexpected error, or a deactivation the plant did not follow, returns ERROR: the node's
``on_error`` (ErrorProcessing) stops the cycle and closes the backend, and the node is
*unconfigured*. The ``autostart`` parameter says which state the node goes to by itself at
start (a transition failing then ends the process with the reason, as a start-up error).
"""
from __future__ import annotations

import gc
import os
import sys
import threading
import time
from typing import Any, Callable, Dict, List, Optional, Sequence

from diagnostic_msgs.msg import DiagnosticStatus
from lifecycle_msgs.srv import ChangeState
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import JointState
from seaforce_msgs.msg import ActuatorCommand, ActuatorState
from std_srvs.srv import Trigger

from . import param_specs as ps
from ..core.backend import BackendReport, PlantBackend, PlantSample
from ..core.errors import SeaforceError
from ..core.plant_cycle import STATUS_COMMAND_TIMEOUT, PlantCycle, PlantLimits
from ..core.schema import Spec
from .ros_common import (GRAPH_PERIOD, STATUS_QOS, StartupError, control_qos, declare,
                         diagnostic_status, diagnostics_publisher, log_events, node_label,
                         publish_diagnostics, shutdown_safe)
from .timing import BusyTime, CommandTiming, Deadline, LoopStats

NAN = float('nan')
#: How long another thread may keep the GIL once the cycle thread wants it [s]. Python's
#: default, 5 ms, is ten cycles; a C call that holds the GIL (rclpy's publish) is not cut.
GIL_SWITCH_INTERVAL = 5e-5
#: s without progress after which a lockstep plant re-publishes its state.
LOCKSTEP_REPUBLISH = 0.1

SUCCESS = TransitionCallbackReturn.SUCCESS
FAILURE = TransitionCallbackReturn.FAILURE
ERROR = TransitionCallbackReturn.ERROR

#: What the plant is while the node is not active, for ``/diagnostics``.
_IDLE_MESSAGES = {
    'unconfigured': 'unconfigured: plant closed, no torque (configure, then activate)',
    'inactive': 'inactive: plant configured and checked, no torque (activate to close the '
                'loop)',
    'finalized': 'finalized: plant closed, no torque',
}


def prepare_process() -> None:
    """Interpreter settings of a process that runs a plant cycle thread (call in main())."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)


def plant_specs(node: str) -> List[Spec]:
    """Parameters a plant node (``sim`` or ``hardware``) declares: the common ones, its
    :class:`~seaforce_ros.core.plant_cycle.PlantLimits` and its own, with its defaults."""
    return ps.node_specs(node)


#: ROS key -> PlantLimits attribute.
_LIMIT_PARAMS = {spec.name: spec.attribute for spec in PlantLimits.SPECS}


def _raise_thread_priority(logger) -> None:
    """Under SCHED_FIFO (``chrt -f P``, as on a rig), run the calling thread one priority above
    the process's other threads (DDS, executor, publisher), so that they never delay a cycle
    by holding the core it wakes up on. Without real-time scheduling: nothing."""
    try:
        if os.sched_getscheduler(0) != os.SCHED_FIFO:
            return
        priority = min(os.sched_get_priority_max(os.SCHED_FIFO),
                       os.sched_getparam(0).sched_priority + 1)
        os.sched_setscheduler(threading.get_native_id(), os.SCHED_FIFO,
                              os.sched_param(priority))
    except OSError as exc:
        logger.warning(f'cycle thread stays at the process priority: {exc}')


class PlantNode(LifecycleNode):
    """A plant node: ROS I/O and lifecycle around a backend (see module docstring).

    Construct it (it declares ``specs``), declare the plant's own parameters, build the
    backend, then call :meth:`attach` once.

    Parameters
    ----------
    name : str
        Node name.
    specs : sequence of Spec
        The node's own parameters (:func:`plant_specs`).
    direct : object, optional
        The controller's direct port (``controller_node.DirectPort``): the direct layout.
    """

    def __init__(self, name: str, specs: Sequence[Spec], direct: Any = None,
                 **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self._name = name
        # rclpy answers a transition that does not exist from the current state (``activate``
        # while unconfigured, by id) with an exception out of the service callback, which ends
        # the process: refuse it here instead, as rclcpp does
        service = self._service_change_state
        self._rclpy_change_state = service.callback
        service.callback = self._on_change_state
        values = declare(self, specs)
        self.values: Dict[str, Any] = values
        self.channels = ps.channels_from(values)
        self.dt = 1.0 / values['rate']
        self._direct = direct
        self._js_every = self._decimation(values['joint_state_rate'])
        self.backend: Optional[PlantBackend] = None
        self.plant: Optional[PlantCycle] = None
        self.lockstep = False
        self._active = False
        self._running = False
        self._thread: Optional[threading.Thread] = None
        self._failure = ''
        self._velocity = [0.0] * len(self.channels)
        self._last_progress = time.monotonic()
        self._new_statistics()

    # --- construction -------------------------------------------------------------------------
    def attach(self, backend: PlantBackend, lockstep: bool = False, description: str = '') -> None:
        """Compose ``backend``: create the ROS I/O, then go to the ``autostart`` state.

        ``lockstep``: the plant advances one sample per command answering its newest state
        instead of on its own cycle thread. Raises :class:`StartupError` with the reason if
        an autostart transition fails (the plant is closed again first).
        """
        self.backend = backend
        self.lockstep = lockstep
        self._start_io()
        target = self.values['autostart']
        self.get_logger().info(
            f'{description or "channels " + str(self.channels)}, '
            f'loop={"direct" if self._direct is not None else "topics"}, autostart={target}')
        if target == 'unconfigured':
            return
        if self.trigger_configure() != SUCCESS:
            raise StartupError(self._failure or 'configure failed')
        if target == 'active' and self.trigger_activate() != SUCCESS:
            reason = self._failure or 'activate failed'
            self.shutdown()
            raise StartupError(reason)

    def _start_io(self) -> None:
        """Publishers, subscription, services and timers."""
        qos = self.values['control_qos']
        self._state_msg = ActuatorState()
        self._state_msg.name = list(self.channels)
        self._js_msg = JointState()
        self._js_msg.name = [f'{c}_{j}' for c in self.channels for j in ('motor', 'endpoint')]
        self.state_pub = self.create_publisher(ActuatorState, 'actuator_state', control_qos(qos))
        self.js_pub = self.create_publisher(JointState, 'joint_states', STATUS_QOS)
        self.diag_pub = diagnostics_publisher(self)
        if self._direct is None:
            sub = self.create_subscription(ActuatorCommand, 'actuator_command',
                                           self._on_command, control_qos(qos, subscriber=True))
            self._command_topic = sub.topic_name
        else:
            self._command_topic = self.resolve_topic_name('actuator_command')
        self.create_service(Trigger, '~/reset', self._on_reset)
        self.add_post_set_parameters_callback(self._apply_parameters)
        self.create_timer(self.values['diagnostics_period'], self._publish_diagnostics)
        self.create_timer(GRAPH_PERIOD, self._watch_graph)
        if self.lockstep:
            self.create_timer(LOCKSTEP_REPUBLISH, self._lockstep_kick)

    def _decimation(self, rate_hz: float) -> int:
        return 0 if rate_hz <= 0 else max(1, int(round(1.0 / (self.dt * rate_hz))))

    def _new_statistics(self) -> None:
        self.stats = LoopStats(self.dt)
        self.busy = BusyTime()
        self.timing = CommandTiming()

    def _limits(self, changed: Optional[Dict[str, Any]] = None) -> PlantLimits:
        """PlantCycle's limits from the parameters now (and ``changed``, being set)."""
        current = {k: self.get_parameter(k).value for k in _LIMIT_PARAMS
                   if self.has_parameter(k)}
        current.update({k: v for k, v in (changed or {}).items() if k in _LIMIT_PARAMS})
        return PlantLimits(**{_LIMIT_PARAMS[k]: v for k, v in current.items()})

    # --- lifecycle ------------------------------------------------------------------------------
    def lifecycle_state(self) -> str:
        """The managed node's state label (``unconfigured``, ``inactive``, ``active``, ...)."""
        # rclpy's LifecycleNodeMixin has no public getter; its state machine is the truth
        return self._state_machine.current_state[1]

    def _on_change_state(self, request: ChangeState.Request,
                         response: ChangeState.Response) -> ChangeState.Response:
        """``~/change_state``: a transition not available from the current state gets
        ``success: false`` and a warning naming the available ones; the others run."""
        wanted = request.transition
        available = {t[0]: t[1] for t in self._state_machine.available_transitions}
        if (wanted.label not in available.values()) if wanted.label else \
                (wanted.id not in available):
            self.get_logger().warning(
                f'transition {wanted.label or wanted.id} refused: not available from '
                f'{self.lifecycle_state()} (available: {", ".join(available.values())})')
            response.success = False
            return response
        return self._rclpy_change_state(request, response)

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('configure', self._configure, self._close_backend)

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('activate', self._activate, self._deactivate_backend)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('deactivate', self._deactivate_backend, None)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('cleanup', self._close_backend, None)

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        return self._transition('shutdown', self._close_backend, None)

    def on_error(self, state: LifecycleState) -> TransitionCallbackReturn:
        """ErrorProcessing: stop the cycle, close the backend (the plant's safe state); the
        node is then unconfigured."""
        done = self._close_backend()
        self.get_logger().error(f'error processing (from {state.label}): cycle stopped, '
                                f'{done}; unconfigured: configure to start again')
        return SUCCESS

    def _transition(self, name: str, action: Callable[[], str],
                    undo: Optional[Callable[[], str]]) -> TransitionCallbackReturn:
        """Run a transition's ``action``; on a backend's error take the plant back with
        ``undo`` and fail (None: ERROR, for ErrorProcessing to close the plant)."""
        try:
            done = action()
        except SeaforceError as exc:
            self._failure = f'{name} failed: {exc}'
            if undo is None:
                self.get_logger().error(f'{self._failure}; error processing follows')
                return ERROR
            try:
                back = undo()
            except Exception as undo_exc:   # the way back failed too: ErrorProcessing
                self.get_logger().error(f'{self._failure}; then {undo_exc}; error processing '
                                        'follows')
                return ERROR
            self.get_logger().error(f'{self._failure}; {back or "plant closed"}')
            return FAILURE
        except Exception as exc:   # a defect: never leave it to rclpy, which says nothing
            self._failure = f'{name} failed: {exc!r}'
            self.get_logger().error(f'{self._failure}; error processing follows')
            return ERROR
        self._failure = ''
        self.get_logger().info(f'{name}: {done}')
        return SUCCESS

    def _configure(self) -> str:
        opened = self.backend.open()
        return f'{opened}; {self.backend.configure()}'

    def _activate(self) -> str:
        # the state numbers go on from the previous activation: a controller must not take
        # this run's states for the last run's (it would answer them from its cache, or drop
        # them as out of order) nor a late command of the last run for an answer to this one;
        # the first states carry STATUS_COMMAND_TIMEOUT (no command yet), from which the
        # controller re-enters bumplessly at the torque applied, zero
        start = 0 if self.plant is None else self.plant.cycle + 1
        self.plant = PlantCycle(self.channels, self.dt, self._limits(),
                                units_per_nm=self.backend.units_per_nm, start_cycle=start)
        self._new_statistics()
        self._velocity = [0.0] * len(self.channels)
        self._watch_graph()
        done = self.backend.activate()
        self._active = True
        if self.lockstep:
            self._last_progress = time.monotonic()
            self._republish()
        else:
            self._start_cycle_thread()
        return done

    def _deactivate_backend(self) -> str:
        self._stop_cycle()
        return self.backend.deactivate()

    def _close_backend(self) -> str:
        self._stop_cycle()
        return self.backend.close() or 'plant closed'

    def _start_cycle_thread(self) -> None:
        self._running = True
        self._thread = threading.Thread(target=self._cycle_loop, name='plant_cycle',
                                        daemon=True)
        self._thread.start()

    def _stop_cycle(self) -> None:
        self._active = False
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
            self._thread = None

    # --- parameters, commands, reset, graph (executor thread) ---------------------------------
    def _apply_parameters(self, params) -> None:
        changed = {p.name: p.value for p in params}
        plant = self.plant
        if plant is not None and any(k in changed for k in _LIMIT_PARAMS):
            plant.configure(self._limits(changed))
        if 'joint_state_rate' in changed:
            self._js_every = self._decimation(changed['joint_state_rate'])

    @shutdown_safe
    def _on_command(self, msg: ActuatorCommand) -> None:
        plant = self.plant
        if not self._active or plant is None:
            return
        now = time.monotonic()
        plant.command(msg.name, msg.effort, msg.cycle)
        self.timing.on_command(msg.cycle, plant.cycle, now)
        if self.lockstep and msg.cycle == plant.cycle:
            # one sample per answer: apply it, then publish the state it leads to
            now = self._last_progress = time.monotonic()
            self.stats.tick(now)
            self._decide_and_write(now, answered=plant.cycle)
            self._read_sample(now)
            if plant.events:
                log_events(self.get_logger(), plant.events.drain())

    def _on_reset(self, request, response):
        plant = self.plant
        if not self._active or plant is None:
            response.success = False
            response.message = (f'{self.lifecycle_state()}: nothing to reset (activate starts '
                                "without the plant's latched faults; a drive that still "
                                'reports a fault latches it again: ~/reset once active clears '
                                'it)')
        else:
            response.message = 'reset requested; ' + plant.request_reset()
            response.success = True
        self.get_logger().info(response.message)
        return response

    @shutdown_safe
    def _watch_graph(self) -> None:
        plant = self.plant
        if plant is None:
            return
        infos = self.get_publishers_info_by_topic(self._command_topic)
        plant.set_publishers(sorted(node_label(i) for i in infos))

    @shutdown_safe
    def _lockstep_kick(self) -> None:
        if self._active and time.monotonic() - self._last_progress > LOCKSTEP_REPUBLISH:
            self._republish()

    # --- the cycle ------------------------------------------------------------------------------
    def _cycle_loop(self) -> None:
        _raise_thread_priority(self.get_logger())
        # everything built so far (nodes, messages, rclpy) is long-lived: keep it out of the
        # collector's generations, so a full collection during the cycle stays short
        gc.freeze()
        deadline = Deadline(self.dt)
        backend = self.backend
        try:
            while self._running:
                now = deadline.wait()
                if not self._running:
                    break
                self.run_cycle(now)
                self.busy.add(time.monotonic() - now)
                # the plant's clock (EtherCAT DC) moves the next deadlines, if it has one
                deadline.start += backend.clock_correction()
        except Exception as exc:  # never die silently: report; the drives' own watchdog acts
            if self._running and self.context.ok():
                self.get_logger().fatal(f'plant cycle stopped: {exc!r}')
            self._running = False

    def run_cycle(self, now: float) -> None:
        """One realtime cycle at monotonic time ``now``: read the plant, then decide the
        torques and write them (ros2_control's read / update / write). Reading first lets a
        bus frame sent at the end of a cycle come back during the sleep instead of being
        waited for. The sample is published at once for a controller in another process; in
        the direct layout the controller runs on it right here, and the state and its
        command are published after the write."""
        plant = self.plant
        self.stats.tick(now)
        sample = self._read_sample(now)
        # the answer that should be in by now: to the previous state from another process, to
        # this cycle's state in the direct layout (none at all when no sample came: late)
        if self._direct is None:
            answered = plant.cycle - 1
        else:
            answered = plant.cycle if sample is not None else -1
        self._decide_and_write(now, answered=answered)
        if sample is not None and self._direct is not None:
            self._publish(*sample)
        if plant.events:
            log_events(self.get_logger(), plant.events.drain())

    def _read_sample(self, now: float):
        """Read the plant into a new sample; topics layout: publish it, direct layout: run the
        controller on it. Returns ``(cycle, stamp_ns, sample, command)`` or None (no
        fresh sample: a lost frame)."""
        plant = self.plant
        sample = PlantSample(len(self.channels))
        link = self.backend.read(sample)
        if not link.received or not plant.exchange(link.counter, link.expected):
            return None
        cycle = plant.state_published()
        stamp_ns = time.time_ns()
        status = sample.flags
        for i, bits in enumerate(plant.out.status):
            status[i] |= bits
        self._velocity = sample.velocity
        if self._direct is None:
            self._publish(cycle, stamp_ns, sample, None)
            return None
        command = self._direct.step(self.channels, cycle, stamp_ns, sample.position,
                                    sample.velocity, sample.pressure_force, sample.effort,
                                    status, stamp_ns, now)
        if command is not None:
            t = time.monotonic()
            self.timing.on_publish(cycle, now)
            plant.command(self.channels, command[0], cycle)
            self.timing.on_command(cycle, cycle, t)
        return cycle, stamp_ns, sample, command

    def _decide_and_write(self, now: float, answered: int) -> None:
        """PlantCycle decides from the commands received so far; the backend applies it.
        ``answered``: the cycle whose answer should be in by now (timing statistics)."""
        self.timing.on_tick(answered)
        backend = self.backend
        drives = backend.drives()
        backend.write(self.plant.step(now, self._velocity, drives))

    def _republish(self) -> None:
        """(lockstep) Publish the current state again, e.g. state 0 before the first command."""
        plant = self.plant
        sample = PlantSample(len(self.channels))
        self.backend.read(sample)
        status = sample.flags
        if plant.cycle == 0:
            status[:] = [STATUS_COMMAND_TIMEOUT] * len(self.channels)
        else:
            for i, bits in enumerate(plant.out.status):
                status[i] |= bits
        self._publish(plant.cycle, time.time_ns(), sample, None)

    # --- publishing -----------------------------------------------------------------------------
    def _publish(self, cycle: int, stamp_ns: int, sample: PlantSample, command) -> None:
        """Publish one sample (and, direct layout, the controller's command for it); every
        ``joint_state_rate`` also as sensor_msgs/JointState. In the cycle thread: rclpy's
        publish() holds the GIL, so a thread of its own would not keep a publish that blocks
        (a subscriber descheduled mid-receive holds Fast DDS's shared-memory lock) from
        stalling the cycle, and it added a hand-over to every sample."""
        msg = self._state_msg
        x, v, fa, xe, fe = (sample.position, sample.velocity, sample.effort,
                            sample.endpoint_position, sample.external_force)
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
        msg.cycle = cycle
        msg.motor_position, msg.motor_velocity, msg.pressure_force = x, v, sample.pressure_force
        msg.motor_effort, msg.endpoint_position = fa, xe
        msg.external_force, msg.status = fe, sample.flags
        if command is None:
            self.timing.on_publish(cycle, time.monotonic())
        self.state_pub.publish(msg)
        if command is not None:
            self._direct.publish(cycle, msg.header.stamp, command)
        if self._js_every and cycle % self._js_every == 0:
            n = len(self.channels)
            ve = sample.endpoint_velocity
            js = self._js_msg
            js.header.stamp = msg.header.stamp
            js.position = [val for i in range(n) for val in (x[i], xe[i])]
            js.velocity = [val for i in range(n) for val in (v[i], ve[i])]
            js.effort = [val for i in range(n) for val in (fa[i], fe[i])]
            self.js_pub.publish(js)

    # --- monitoring -----------------------------------------------------------------------------
    @shutdown_safe
    def _publish_diagnostics(self) -> None:
        publish_diagnostics(self, self.diag_pub, self._diagnostics())

    def _diagnostics(self) -> List[DiagnosticStatus]:
        backend = self.backend
        plant = self.plant
        if not self._active or plant is None:
            state = self.lifecycle_state()
            message = _IDLE_MESSAGES.get(state, f'{state}: no torque')
            if self._failure:
                message += f'; last transition: {self._failure}'
            return [diagnostic_status(backend.status_name, backend.hardware_id,
                                      DiagnosticStatus.OK, message,
                                      {'lifecycle_state': state})]
        report = backend.diagnostics()
        return [self._node_status(plant, report)] + self._channel_statuses(plant, report)

    def _node_status(self, plant: PlantCycle, report: BackendReport) -> DiagnosticStatus:
        """The node-level status: ERROR on a stopped cycle or a latched fault, WARN with the
        backend's warning if any, else OK with its running message."""
        s = self.stats.summary()
        rtt50, rtt99 = self.timing.round_trip_ms()
        busy50, busy99, busy_max = self.busy.percentiles_ms()
        latched = plant.latched_faults()
        level = DiagnosticStatus.OK
        message = report.running
        if not self._running and not self.lockstep:
            level, message = DiagnosticStatus.ERROR, 'cycle stopped'
        elif plant.bus_fault or plant.conflict:
            level, message = DiagnosticStatus.ERROR, 'FAULT: ' + (plant.bus_fault
                                                                 or plant.conflict)
        elif latched:
            level, message = DiagnosticStatus.ERROR, 'FAULT: ' + '; '.join(latched)
        elif report.warning:
            level, message = DiagnosticStatus.WARN, report.warning
        values = {'cycle': plant.cycle, 'rate_hz': s.rate_hz, 'period_p50_ms': s.period_p50_ms,
                  'period_p99_ms': s.period_p99_ms, 'period_max_ms': s.period_max_ms,
                  'jitter_p99_ms': s.jitter_p99_ms, 'missed_deadlines': s.missed,
                  'busy_p50_ms': busy50, 'busy_p99_ms': busy99, 'busy_max_ms': busy_max,
                  'round_trip_p50_ms': rtt50, 'round_trip_p99_ms': rtt99,
                  'late_commands_total': self.timing.late,
                  'command_timeouts': sum(plant.timeouts(i) for i in range(len(self.channels))),
                  'commands_rejected': sum(plant.rejected.values()),
                  'command_publishers': ', '.join(plant._publishers) or 'none',
                  'faults_latched_total': plant.faults_latched,
                  'layout': 'direct' if self._direct is not None else 'topics',
                  'lifecycle_state': 'active', **report.values}
        return diagnostic_status(report.name, report.hardware_id, level, message, values)

    def _channel_statuses(self, plant: PlantCycle,
                          report: BackendReport) -> List[DiagnosticStatus]:
        statuses = []
        for i, (channel, extra) in enumerate(zip(self.channels, report.channels)):
            fault = plant.channel_fault(i)
            values = {'fault': fault or 'none', 'command_timeouts': plant.timeouts(i),
                      'torque_applied': plant.out.torque[i], **extra.values}
            statuses.append(diagnostic_status(
                f'{report.channel_prefix}: {channel}', extra.hardware_id,
                DiagnosticStatus.ERROR if fault else DiagnosticStatus.OK,
                f'FAULT: {fault}' if fault else values.get('state', 'ok'), values))
        return statuses

    # --- shut-down ------------------------------------------------------------------------------
    def shutdown(self) -> None:
        """The process ends (SIGINT/SIGTERM, or a failed start): stop the cycle, close the
        backend (EtherCAT: zero torque, drives disabled, bus to INIT) whatever the lifecycle
        state. Called by :func:`~seaforce_ros.nodes.ros_common.run`."""
        self._stop_cycle()
        if self.backend is not None:
            done = self.backend.close()
            if done:
                print(f'[{self._name}] {done}', file=sys.stderr)
