"""What sim_node and hardware_node share: the plant side of the loop around PlantCycle.

:class:`PlantNode` owns the parts of a plant node that are not about the plant itself:

* the cycle (:meth:`PlantNode.run_cycle`): the subclass reads the plant (``_read`` /
  ``_sample``), the sample is published (in the direct layout the controller's cycle is called
  right there, on the cycle thread),
  :class:`~seaforce_ros.core.plant_cycle.PlantCycle` decides the torques and the subclass
  writes them (``_write``): ros2_control's read / update / write;
* the ``actuator_command`` subscription (commands are only handed to PlantCycle), the graph
  watch for a second command publisher, ``~/reset``, the run-time parameters;
* publishing ``actuator_state`` / ``joint_states`` (and, in the direct layout, the
  controller's ``actuator_command`` / ``controller_status``) from the cycle;
* the log lines PlantCycle reports (once per episode, throttled) and the common
  ``/diagnostics`` figures.
"""
from __future__ import annotations

import gc
import os
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from sensor_msgs.msg import JointState
from seaforce_msgs.msg import ActuatorCommand, ActuatorState
from std_srvs.srv import Trigger

from . import param_specs as ps
from ..core.plant_cycle import PlantCycle, PlantLimits
from .ros_common import (GRAPH_PERIOD, STATUS_QOS, StartupError, control_qos, declare,
                         diagnostic_status, diagnostics_publisher, log_events, node_label,
                         publish_diagnostics, shutdown_safe)
from .timing import BusyTime, CommandTiming, Deadline, LoopStats

NAN = float('nan')
#: How long another thread may keep the GIL once the cycle thread wants it [s]. Python's
#: default, 5 ms, is ten cycles; a C call that holds the GIL (rclpy's publish) is not cut.
GIL_SWITCH_INTERVAL = 5e-5


def prepare_process():
    """Interpreter settings of a process that runs a plant cycle thread (call in main())."""
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)


def plant_specs(node):
    """Parameters a plant node (``sim`` or ``hardware``) declares: the common ones, its
    :class:`~seaforce_ros.core.plant_cycle.PlantLimits` and its own, with its defaults."""
    return ps.node_specs(node)


#: ROS key -> PlantLimits attribute.
_LIMIT_PARAMS = {spec.name: spec.attribute for spec in PlantLimits.SPECS}


def _raise_thread_priority(logger):
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


class PlantNode(Node):
    """Base class of the plant nodes (see module docstring).

    Subclasses call :meth:`_start_plant` once their plant is ready and implement
    ``_write(out)`` (apply PlantCycle's output), ``_sample(out, sample)`` (fill the sample
    lists of :meth:`_new_sample`; ``out`` is the output being applied) and ``_diagnostics()``,
    optionally ``_read()`` and ``_drives()``.

    Parameters
    ----------
    name : str
        Node name.
    values : dict
        The declared parameter values (:func:`plant_specs` and the subclass's own).
    direct : object, optional
        The controller's direct port (``controller_node.DirectPort``): the direct layout.
    """

    def __init__(self, name, specs, direct=None, **kwargs):
        super().__init__(name, **kwargs)
        values = declare(self, specs)
        self.values = values
        self.channels = ps.channels_from(values)
        self.dt = 1.0 / values['rate']
        self._direct = direct
        self._js_every = self._decimation(values['joint_state_rate'])
        self.stats = LoopStats(self.dt)
        self.busy = BusyTime()
        self.timing = CommandTiming()
        self._running = False
        self._thread = None
        self._velocity = [0.0] * len(self.channels)

    # --- construction (subclasses call these) -------------------------------------------------
    def _make_plant_cycle(self, units_per_nm=None):
        try:
            limits = self._limits_from(self.values)
            self.plant = PlantCycle(self.channels, self.dt, limits, units_per_nm=units_per_nm)
        except ValueError as exc:
            raise StartupError(str(exc)) from exc

    def _limits_from(self, values):
        return PlantLimits(**{field: values[name] for name, field in _LIMIT_PARAMS.items()
                              if name in values})

    def _start_plant(self):
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

    def _start_cycle_thread(self):
        self._running = True
        self._thread = threading.Thread(target=self._cycle_loop, name='plant_cycle',
                                        daemon=True)
        self._thread.start()

    def _decimation(self, rate_hz):
        return 0 if rate_hz <= 0 else max(1, int(round(1.0 / (self.dt * rate_hz))))

    # --- parameters, commands, reset, graph (executor thread) ---------------------------------
    def _apply_parameters(self, params):
        changed = {p.name: p.value for p in params}
        if any(k in changed for k in _LIMIT_PARAMS):
            current = {k: self.get_parameter(k).value for k in _LIMIT_PARAMS
                       if self.has_parameter(k)}
            self.plant.configure(self._limits_from({**current, **changed}))
        if 'joint_state_rate' in changed:
            self._js_every = self._decimation(changed['joint_state_rate'])

    @shutdown_safe
    def _on_command(self, msg):
        now = time.monotonic()
        self.plant.command(msg.name, msg.effort, msg.cycle)
        self.timing.on_command(msg.cycle, self.plant.cycle, now)

    def _on_reset(self, request, response):
        response.message = 'reset requested; ' + self.plant.request_reset()
        response.success = True
        self.get_logger().info(response.message)
        return response

    @shutdown_safe
    def _watch_graph(self):
        infos = self.get_publishers_info_by_topic(self._command_topic)
        self.plant.set_publishers(sorted(node_label(i) for i in infos))

    # --- the cycle ------------------------------------------------------------------------------
    def _cycle_loop(self):
        _raise_thread_priority(self.get_logger())
        # everything built so far (nodes, messages, rclpy) is long-lived: keep it out of the
        # collector's generations, so a full collection during the cycle stays short
        gc.freeze()
        deadline = Deadline(self.dt)
        try:
            while self._running:
                now = deadline.wait()
                if not self._running:
                    break
                self.run_cycle(now)
                self.busy.add(time.monotonic() - now)
        except Exception as exc:  # never die silently: report; the drives' own watchdog acts
            if self._running and self.context.ok():
                self.get_logger().fatal(f'plant cycle stopped: {exc!r}')
            self._running = False

    def run_cycle(self, now):
        """One realtime cycle at monotonic time ``now``: read the plant, then decide the
        torques and write them (ros2_control's read / update / write). Reading first lets a
        bus frame sent at the end of a cycle come back during the sleep instead of being
        waited for. The sample is published at once for a controller in another process; in
        the direct layout the controller runs on it right here, and the state and its
        command are published after the write."""
        self.stats.tick(now)
        sample = self._read_sample(now)
        # the answer that should be in by now: to the previous state from another process, to
        # this cycle's state in the direct layout (none at all when no sample came: late)
        if self._direct is None:
            answered = self.plant.cycle - 1
        else:
            answered = self.plant.cycle if sample is not None else -1
        self._decide_and_write(now, answered=answered)
        if sample is not None and self._direct is not None:
            self._publish(*sample)
        if self.plant.events:
            log_events(self.get_logger(), self.plant.events.drain())

    def _read_sample(self, now):
        """Read the plant into a new sample; topics layout: publish it, direct layout: run the
        controller on it. Returns ``(cycle, stamp_ns, sample, command)`` or None (no
        fresh sample: a lost frame)."""
        plant = self.plant
        if not self._read():
            return None
        cycle = plant.state_published()
        stamp_ns = time.time_ns()
        sample = self._new_sample()
        self._sample(plant.out, sample)
        x, v, fp, fa, xe, fe, status = sample
        self._velocity = v
        if self._direct is None:
            self._publish(cycle, stamp_ns, sample, None)
            return None
        command = self._direct.step(self.channels, cycle, stamp_ns, x, v, fp, fa, status,
                                    stamp_ns, now)
        if command is not None:
            t = time.monotonic()
            self.timing.on_publish(cycle, now)
            plant.command(self.channels, command[0], cycle)
            self.timing.on_command(cycle, cycle, t)
        return cycle, stamp_ns, sample, command

    def _decide_and_write(self, now, answered):
        """PlantCycle decides from the commands received so far; the plant applies it.
        ``answered``: the cycle whose answer should be in by now (timing statistics)."""
        self.timing.on_tick(answered)
        self._write(self.plant.step(now, self._velocity, self._drives()))

    def _read(self):
        """Take a fresh sample of the plant; False when none came (hardware: lost frame)."""
        return True

    def _new_sample(self):
        n = len(self.channels)
        return ([0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n, [NAN] * n, [NAN] * n, [0] * n)

    def _drives(self):
        """Per channel (torque_allowed, faulted) of the drives; None: no drives (simulation)."""
        return None


    # --- publishing -----------------------------------------------------------------------------
    def _publish(self, cycle, stamp_ns, sample, command):
        """Publish one sample (and, direct layout, the controller's command for it); every
        ``joint_state_rate`` also as sensor_msgs/JointState. In the cycle thread: rclpy's
        publish() holds the GIL, so a thread of its own would not keep a publish that blocks
        (a subscriber descheduled mid-receive holds Fast DDS's shared-memory lock) from
        stalling the cycle, and it added a hand-over to every sample."""
        msg = self._state_msg
        x, v, fp, fa, xe, fe, status = sample
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
        msg.cycle = cycle
        msg.motor_position, msg.motor_velocity, msg.pressure_force = x, v, fp
        msg.motor_effort, msg.endpoint_position = fa, xe
        msg.external_force, msg.status = fe, status
        if command is None:
            self.timing.on_publish(cycle, time.monotonic())
        self.state_pub.publish(msg)
        if command is not None:
            self._direct.publish(cycle, msg.header.stamp, command)
        if self._js_every and cycle % self._js_every == 0:
            n = len(self.channels)
            js = self._js_msg
            js.header.stamp = msg.header.stamp
            js.position = [val for i in range(n) for val in (x[i], xe[i])]
            js.velocity = [val for i in range(n) for val in (v[i], self._ve(i))]
            js.effort = [val for i in range(n) for val in (fa[i], fe[i])]
            self.js_pub.publish(js)

    def _ve(self, i):
        """Endpoint velocity of channel ``i`` for joint_states (NaN where not measured)."""
        return NAN

    # --- monitoring -----------------------------------------------------------------------------
    def _common_diagnostics(self, name, hardware_id, running_message, warning=None,
                            extra=None):
        """The node-level status: ERROR on a stopped cycle or a latched fault, WARN with
        ``warning`` if given, else OK with ``running_message``; ``extra`` values appended."""
        plant = self.plant
        s = self.stats.summary()
        rtt50, rtt99 = self.timing.round_trip_ms()
        busy50, busy99, busy_max = self.busy.percentiles_ms()
        latched = plant.latched_faults()
        level = DiagnosticStatus.OK
        message = running_message
        if not self._running and self._thread is not None:
            level, message = DiagnosticStatus.ERROR, 'cycle stopped'
        elif plant.bus_fault or plant.conflict:
            level, message = DiagnosticStatus.ERROR, 'FAULT: ' + (plant.bus_fault
                                                                 or plant.conflict)
        elif latched:
            level, message = DiagnosticStatus.ERROR, 'FAULT: ' + '; '.join(latched)
        elif warning:
            level, message = DiagnosticStatus.WARN, warning
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
                  **(extra or {})}
        return diagnostic_status(name, hardware_id, level, message, values)

    def _channel_diagnostics(self, prefix, hardware_ids, extra=None):
        plant = self.plant
        statuses = []
        for i, channel in enumerate(self.channels):
            fault = plant.channel_fault(i)
            values = {'fault': fault or 'none', 'command_timeouts': plant.timeouts(i),
                      'torque_applied': plant.out.torque[i]}
            if extra is not None:
                values.update(extra(i))
            statuses.append(diagnostic_status(
                f'{prefix}: {channel}', hardware_ids[i],
                DiagnosticStatus.ERROR if fault else DiagnosticStatus.OK,
                f'FAULT: {fault}' if fault else values.get('state', 'ok'), values))
        return statuses

    @shutdown_safe
    def _publish_diagnostics(self):
        publish_diagnostics(self, self.diag_pub, self._diagnostics())

    # --- shut-down ------------------------------------------------------------------------------
    def _stop_threads(self):
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=1.0)
