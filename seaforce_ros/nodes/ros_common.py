"""ROS 2 plumbing shared by the nodes: parameter declaration, QoS, diagnostics, spinning.

Only conversion and wiring lives here; the algorithms are in :mod:`seaforce_ros.core`.
"""
from __future__ import annotations

import difflib
import functools
import os
import signal
import sys
import threading
import time
from typing import Any, Callable, Dict, Iterable, Optional, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType)
from rclpy.clock import Clock, ClockType
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from ..core.episodes import ERROR, WARNING
from ..core.schema import Spec, rows
from ..core.settings import EXECUTORS

#: Control-rate topics (actuator_state, actuator_command), publisher side: reliable (lockstep
#: simulation advances one sample per command and must never lose a step), and a history of
#: 1000 samples (0.5 s at 2 kHz) so that a recorder stalled by a slow disk still gets every sample.
CONTROL_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.VOLATILE)

#: Control-rate topics, the control loop's subscription: only the newest sample matters to a
#: 2 kHz loop; anything older is worthless.
CONTROL_SUB_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.VOLATILE)

#: Recorders and test observers of the control topics: keep up to 1 s of samples queued.
RECORD_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=2000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)

QOS_RELIABILITY = {'reliable': ReliabilityPolicy.RELIABLE,
                   'best_effort': ReliabilityPolicy.BEST_EFFORT}


def control_qos(reliability: str = 'reliable', subscriber: bool = False) -> QoSProfile:
    """CONTROL_QOS / CONTROL_SUB_QOS with the reliability named by a node's ``control_qos``
    parameter (``reliable`` or ``best_effort``; see bench/control_loop.py for the trade)."""
    base = CONTROL_SUB_QOS if subscriber else CONTROL_QOS
    return QoSProfile(history=base.history, depth=base.depth,
                      reliability=QOS_RELIABILITY[reliability], durability=base.durability)


#: Monitoring topics (controller_status, joint_states): a second of slack at the default
#: 100 Hz (with 10 a recorder held back 150 ms on a busy host lost controller_status samples
#: that a witness got; they are recorded for identification).
STATUS_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)

_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
          list: ParameterType.PARAMETER_STRING_ARRAY}


def descriptor(spec: Spec) -> ParameterDescriptor:
    """The ROS descriptor of a schema row: its description with the unit, type, read-only
    flag, range (rclpy enforces the closed range; a strict bound is the row's own check) and
    allowed strings."""
    d = ParameterDescriptor(name=spec.name, description=spec.text(), read_only=spec.read_only,
                            type=_TYPES[spec.type])
    if spec.choices:
        d.additional_constraints = 'one of: ' + ', '.join(spec.choices)
    if spec.low is not None or spec.high is not None:
        low = -sys.float_info.max if spec.low is None else spec.low
        high = sys.float_info.max if spec.high is None else spec.high
        if spec.type is float:
            d.floating_point_range = [FloatingPointRange(from_value=float(low),
                                                         to_value=float(high), step=0.0)]
        elif spec.type is int:
            d.integer_range = [IntegerRange(from_value=int(max(low, -2**63)),
                                            to_value=int(min(high, 2**63 - 1)), step=1)]
    return d


def declare(node, specs: Iterable[Spec]) -> Dict[str, Any]:
    """Declare every row on ``node`` and return name -> value.

    The value is the one given by ``--params-file`` / ``-p`` (an integer given for a float
    parameter is converted), else the default. Every value is checked by
    :meth:`~seaforce_ros.core.schema.Spec.reason` *before* it is declared; a bad one raises
    :class:`StartupError` naming the parameter (``run`` prints it and exits 2): a node never
    starts on a value it would refuse on a later set.
    """
    # rclpy keeps the command line's and params files' values in Node._parameter_overrides
    # (public only as a constructor argument); reading it is how an int can become a float.
    overrides = getattr(node, '_parameter_overrides', {})
    values = {}
    for spec in specs:
        value = list(spec.default) if spec.type is list else spec.default
        given = overrides.get(spec.name)
        if given is not None:
            if given.type_ == given.Type.NOT_SET:
                raise StartupError(f'{spec.name} has no value (an empty list [] or ~ in the '
                                   f'params file?); it must be {spec.kind()}, like '
                                   f'{value!r}')
            value = spec.coerce(given.value)
        reason = spec.reason(value)
        if reason:
            raise StartupError(reason)
        try:
            node.declare_parameter(spec.name, value, descriptor(spec), ignore_override=True)
        except (ParameterException, ValueError, TypeError) as exc:
            raise StartupError(f'{spec.name}: {exc}') from None
        values[spec.name] = node.get_parameter(spec.name).value
    if not getattr(node, '_seaforce_coerces', False):
        node._seaforce_coerces = True
        node.add_pre_set_parameters_callback(functools.partial(_ints_as_floats, node))
    return values


#: Parameters an rclpy node has without declaring them, or reads as overrides (QoS).
_ROS_NAMES = ('use_sim_time', 'start_type_description_service')
_ROS_PREFIXES = ('qos_overrides.',)


@functools.cache
def _package_names():
    """(the nodes' own parameter names, the per-channel ones without their channel)."""
    own, per = set(), set()
    for spec in rows():
        (per if spec.per_channel else own).add(spec.name)
    return frozenset(own), frozenset(per)


def _package_parameter(name: str, channels: Sequence[str] = ()) -> bool:
    """Whether some node of this package declares ``name`` (``<channel>.<key>`` for a
    channel's, ``<channel>.sim.<key>`` for the sim's true plant) -- for a channel's, under a
    name that is no typo of one of ``channels`` (``pnich.max_torque`` left pinch's torque
    limit as it was, without a word; another node's channel passes)."""
    own, per = _package_names()
    if name in own:
        return True
    channel, _, key = name.partition('.')
    if not (key in per or (key.startswith('sim.') and key[4:] in per)):
        return False
    return channel in channels or not difflib.get_close_matches(channel, channels, n=1,
                                                                cutoff=0.6)


def check_undeclared(node) -> None:
    """The start-up check of the names given (``-p``, params files), once ``node`` has
    declared all of its parameters: a name no node of this package declares that is a typo
    away from one ``node`` declares raises :class:`StartupError` naming both (``-p
    torque_limt:=2.0`` once started the sim with its torque limit at 20 N m, without a
    word); other names no node of this package declares get one warning (a params file
    shared with another package's nodes may hold theirs); a name another node of this
    package declares passes (the shipped file holds every node's). Each node calls it once,
    after its last :func:`declare` and before it touches a plant."""
    overrides = getattr(node, '_parameter_overrides', {})
    channels = list(node.get_parameter('channels').value) \
        if node.has_parameter('channels') else []
    unknown = sorted(n for n in overrides if not node.has_parameter(n)
                     and n not in _ROS_NAMES and not n.startswith(_ROS_PREFIXES)
                     and not _package_parameter(n, channels))
    if not unknown:
        return
    declared = node.list_parameters([], 0).names
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=1, cutoff=0.8)
        if close:
            raise StartupError(
                f'{name}: no such parameter (did you mean {close[0]}? a misspelt name would '
                f'leave {close[0]} at {node.get_parameter(close[0]).value!r})')
    node.get_logger().warning(
        f'ignored: {", ".join(unknown)}: no node of seaforce_ros declares '
        f'{"it" if len(unknown) == 1 else "them"} (docs/parameters.md lists every parameter)')


def steady_timer(node, period: float, callback):
    """A timer of ``node`` on a steady clock of its own (housekeeping: graph watch,
    diagnostics, job feedback), not on the node's ROS clock: rclpy's EventsExecutor prints
    "the number of timers associated with this clock is large" for each timer from the
    eighth on one clock, and the controller's action servers hold seven there (four lines at
    every start)."""
    clock = getattr(node, '_seaforce_steady_clock', None)
    if clock is None:
        clock = node._seaforce_steady_clock = Clock(clock_type=ClockType.STEADY_TIME)
    return node.create_timer(period, callback, clock=clock)


def _ints_as_floats(node, params):
    """Pre-set callback: an integer set on a float parameter (``ros2 param set /controller
    pinch.max_torque 20``) becomes that float instead of a type error."""
    out = []
    for p in params:
        if p.type_ == Parameter.Type.INTEGER and node.has_parameter(p.name) and \
                node.describe_parameter(p.name).type == ParameterType.PARAMETER_DOUBLE:
            p = Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
        out.append(p)
    return out


#: Seconds between two looks at the ROS graph for a second publisher of a control topic.
GRAPH_PERIOD = 0.2


def node_label(info) -> str:
    """'/namespace/node' of a graph endpoint (DDS knows the endpoint before its node's name)."""
    if info.node_name == '_NODE_NAME_UNKNOWN_':
        return '(a node not yet discovered)'
    return f'{info.node_namespace.rstrip("/")}/{info.node_name}'


def log_events(logger, events) -> None:
    """Pass the core's ``(severity, text)`` reports (:mod:`seaforce_ros.core.episodes`) to a
    ROS logger."""
    for severity, text in events:
        if severity == ERROR:
            logger.error(text)
        elif severity == WARNING:
            logger.warning(text)
        else:
            logger.info(text)


def stamp_now(stamp) -> int:
    """Fill a builtin_interfaces/Time in place with the system time; return it in ns.

    The nodes run on the system clock (no use_sim_time): this avoids the two Time objects
    ``get_clock().now().to_msg()`` allocates, which matters at 2 kHz.
    """
    now = time.time_ns()
    stamp.sec, stamp.nanosec = divmod(now, 1_000_000_000)
    return now


def diagnostic_status(name: str, hardware_id: str, level: int, message: str,
                      values: Dict[str, Any]) -> DiagnosticStatus:
    status = DiagnosticStatus(level=level, name=name, message=message, hardware_id=hardware_id)
    status.values = [KeyValue(key=k, value=_fmt(v)) for k, v in values.items()]
    return status


def _fmt(value) -> str:
    if isinstance(value, float):
        return f'{value:.6g}'
    return str(value)


def diagnostics_publisher(node):
    return node.create_publisher(DiagnosticArray, '/diagnostics', 10)


def publish_diagnostics(node, publisher, statuses: Sequence[DiagnosticStatus]) -> None:
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = list(statuses)
    publisher.publish(msg)


def make_executor(kind: str, context=None):
    """The executor named by a node's read-only ``executor`` parameter."""
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single_threaded':
        return SingleThreadedExecutor(context=context)
    raise ValueError(f'executor must be one of {", ".join(EXECUTORS)}; got {kind!r}')


def spin_forever(executor, context=None, chunk_sec: float = 1.0) -> None:
    """Spin until shutdown in a way that works with every executor of the PyPI Jazzy wheels.

    In rclpy 7.1.6 as shipped on PyPI, *every* untimed EventsExecutor call (``spin()``,
    ``spin_once()``, ``spin_until_future_complete(f)``) hangs: its events queue waits on a
    condition variable until ``steady_clock::time_point::max()``, which this manylinux_2_28 build
    converts to a wall-clock deadline that overflows, so ``pthread_cond_timedwait`` fails with
    EINVAL and the queue thread busy-loops holding the mutex every event and ``Stop()`` need.
    No subscription, timer, service (parameters!) or signal is ever handled. Any finite
    timeout works, so we spin in finite chunks with a fresh Future each time. Callback
    exceptions propagate and SIGINT/SIGTERM end the loop within ~0.2 s. The
    SingleThreadedExecutor is spun the same way for uniformity.
    """
    from rclpy.task import Future
    context = context or executor.context
    while context.ok():
        try:
            executor.spin_until_future_complete(Future(), timeout_sec=chunk_sec)
        except Exception:
            if context.ok():
                raise
            return  # a callback raced the shutdown (e.g. publish on a shut-down context)


def _ignore_signal(signum, frame):
    """Python-level SIGINT/SIGTERM handler: rclpy's C handler has already shut down."""


def run(node_factory: Callable[[], Any], args=None, executor_param: str = 'executor',
        name: str = 'seaforce_ros') -> int:
    """``main()`` body of every executable: the Jazzy shutdown idiom.

    ``node_factory()`` returns a node or a list of nodes (composition: one process, one
    executor). The executor is the one the first node's ``executor`` parameter names. Spins
    until SIGINT/SIGTERM; then, in this order: the executor is shut down (it must release the
    nodes' callbacks first: an EventsExecutor destroyed while it still holds them aborts the
    process), each node's ``shutdown()`` runs (safe state), the nodes are destroyed. A
    :class:`StartupError` prints its message (no traceback) and exits 2. A node may end the
    process itself by shutting its context down; its ``exit_code`` attribute (read after its
    ``shutdown()``) is then the exit code.
    """
    # SIGINT/SIGTERM: rclpy's own handler (installed by init, chaining to this one) shuts the
    # context down, which ends spin_forever. The Python-level handler must then do nothing:
    # the default one raises KeyboardInterrupt wherever the main thread happens to be, which at
    # 2 kHz is inside a callback, half-way through a cycle.
    signal.signal(signal.SIGINT, _ignore_signal)
    signal.signal(signal.SIGTERM, _ignore_signal)
    argv = sys.argv if args is None else args
    extra = non_ros_arguments(argv)
    if extra in (['-h'], ['--help']):
        print(f'usage: {name} [--ros-args [--params-file FILE] [-p NAME:=VALUE] ...]; every '
              'parameter with its range: docs/parameters.md')
        return 0
    problem = ros_arguments_problem(argv) or (
        f'unknown argument(s) {" ".join(extra)}: {name} takes ROS arguments only '
        '(--ros-args --params-file FILE -p NAME:=VALUE)' if extra else None)
    if problem is None:
        try:
            rclpy.init(args=args)
        except _rclpy.RCLError as exc:
            # rcl's own parser found what the check above let through; its message names
            # the argument and the file
            problem = str(exc).split(', at /')[0].replace('failed to initialize rcl: ', '')
    if problem is not None:
        print(f'[{name}] cannot start: {problem}', file=sys.stderr)
        return 2
    nodes = []
    executor = None
    kind = 'single_threaded'
    code = 0
    try:
        made = node_factory()
        nodes = list(made) if isinstance(made, (list, tuple)) else [made]
        if nodes[0].has_parameter(executor_param):
            kind = nodes[0].get_parameter(executor_param).value
        executor = make_executor(kind)
        for node in nodes:
            executor.add_node(node)
        nodes[0].get_logger().info(f'spinning with the {kind} executor')
        spin_forever(executor)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except StartupError as exc:
        print(f'[{name}] cannot start: {exc}', file=sys.stderr)
        code = 2
    finally:
        if executor is not None:
            release_executor(executor, nodes)
        for node in reversed(nodes):
            try:
                shutdown = getattr(node, 'shutdown', None)
                if shutdown is not None:
                    shutdown()
            finally:
                node.destroy_node()
            code = code or int(getattr(node, 'exit_code', 0) or 0)
        rclpy.try_shutdown()
    if executor is not None and kind == 'events':
        # The EventsExecutor of the PyPI wheel aborts the process in its destructor ("Destroying
        # callback manager with callbacks remaining") when the interpreter tears it down at exit,
        # even after shutdown() and remove_node(). Everything is cleaned up by now: leave
        # without running finalizers.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def non_ros_arguments(argv: Sequence[str]) -> list[str]:
    """The arguments of ``argv`` (``sys.argv``: the program first) that are no ROS arguments:
    what a node that takes ROS arguments only must refuse. Empty when rcl cannot parse the
    ROS arguments (``rclpy.init`` then says what is wrong)."""
    from rclpy.utilities import remove_ros_args
    try:
        return list(remove_ros_args(list(argv)))[1:]
    except _rclpy.RCLError:
        return []


def ros_arguments_problem(argv: Sequence[str]) -> Optional[str]:
    """What is wrong with the ``--params-file`` files named in ``argv``'s ``--ros-args``
    sections (missing, unreadable, not YAML, empty, not ``node: {ros__parameters: {...}}``),
    or None. rcl would stop at each of these with a traceback, or silently run on defaults
    (an empty file)."""
    files, in_ros, tokens = [], False, iter(argv)
    for token in tokens:
        if token == '--ros-args':
            in_ros = True
        elif token == '--':
            in_ros = False
        elif in_ros and token == '--params-file':
            files.append(next(tokens, None))
    for path in files:
        if path is None:
            return '--params-file needs a file name'
        reason = params_file_problem(path)
        if reason:
            return f'--params-file {path}: {reason}'
    return None


def params_file_problem(path: str) -> Optional[str]:
    """Why ``path`` is not a usable ROS 2 params file, or None."""
    import yaml
    if not os.path.exists(path):
        return 'no such file'
    if os.path.isdir(path):
        return 'is a directory, not a params file'
    try:
        with open(path, encoding='utf-8') as stream:
            data = yaml.safe_load(stream)
    except OSError as exc:
        return f'cannot be read: {exc.strerror}'
    except UnicodeDecodeError:
        return 'is not a text (UTF-8) file'
    except yaml.YAMLError as exc:
        where = getattr(exc, 'problem_mark', None)
        line = f' at line {where.line + 1}' if where is not None else ''
        return f'is not valid YAML{line}: {getattr(exc, "problem", None) or exc}'
    layout = ('the layout is <node name>: {ros__parameters: {<parameter>: <value>}}, '
              'as in config/gripper.yaml')
    if data is None:
        return f'is empty; {layout}'
    if not isinstance(data, dict):
        return f'must be a mapping of node names, got a {type(data).__name__}; {layout}'

    def walk(entry, where):
        if not isinstance(entry, dict):
            return f'{where}: {entry!r} is outside any ros__parameters section; {layout}', 0
        found = 0
        for key, value in entry.items():
            inner = f'{where}.{key}' if where else str(key)
            if key == 'ros__parameters':
                if not isinstance(value, dict):
                    return f'{inner} must be a mapping of parameter: value', 0
                found += 1
            else:
                reason, count = walk(value, inner)
                if reason:
                    return reason, 0
                found += count
        return None, found

    reason, found = walk(data, '')
    if reason:
        return reason
    if not found:
        return f'has no ros__parameters section; {layout}'
    return None


def release_executor(executor, nodes) -> None:
    """Shut ``executor`` down and take ``nodes`` off it, before the nodes are destroyed.

    The order matters with the PyPI wheel's EventsExecutor: destroyed while it still spins or
    still holds a node's callbacks, it aborts the process.
    """
    executor.shutdown(timeout_sec=1.0)
    for node in nodes:
        try:
            executor.remove_node(node)
        except Exception:
            pass  # never added, or already gone with a shut-down context


def request_until_answered(send: Callable[[], Any], timeout: float, resend_after: float = 2.0):
    """``send()`` a service request (returns a Future) and wait for its result, re-sending it
    every ``resend_after`` s while unanswered; :class:`TimeoutError` after ``timeout`` s.

    ``wait_for_service`` only says the server's request reader is matched: until the server
    has also discovered the client's response reader (slow on a loaded host) its answers are
    dropped, a known ROS 2 discovery race. Only for idempotent requests (parameter get/set,
    Trigger-style services). The caller's node must be spun by another thread.
    """
    deadline = time.monotonic() + timeout
    while True:
        future = send()
        resend = min(deadline, time.monotonic() + resend_after)
        while not future.done():
            if time.monotonic() >= resend:
                break
            time.sleep(0.01)
        if future.done():
            return future.result()
        if time.monotonic() >= deadline:
            raise TimeoutError(f'no answer within {timeout:g} s')


def shutdown_safe(callback):
    """Decorate a node callback so that an error raised *because the context is shutting down*
    (SIGINT while a sample was in flight: publish on a shut-down context) ends it quietly;
    any other error propagates."""
    @functools.wraps(callback)
    def guarded(self, *args):
        try:
            return callback(self, *args)
        except KeyboardInterrupt:
            # SIGINT arrives wherever the main thread is -- at 2 kHz usually inside a
            # callback. It means "stop": shut the context down, spin_forever then returns.
            rclpy.try_shutdown(context=self.context)
            return None
        except Exception:
            if self.context.ok():
                raise
            return None  # publish on a context shut down by SIGINT/SIGTERM meanwhile
    return guarded


class StartupError(RuntimeError):
    """A node cannot start with the configuration it was given (message says what to fix)."""


class BackgroundNode:
    """A node on its own Context, spun by an EventsExecutor in a daemon thread.

    For tools, benchmarks and tests that watch the ROS graph while doing other work. The
    executor is spun in finite chunks (see :func:`spin_forever`); :meth:`close` stops the thread
    and shuts the context down.
    """

    def __init__(self, name: str, domain_id: Optional[int] = None):
        """``domain_id``: the DDS domain (default: ``ROS_DOMAIN_ID``'s)."""
        from rclpy.context import Context
        from rclpy.experimental import EventsExecutor

        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain_id)
        self.node = rclpy.create_node(name, context=self.context)
        self.executor = EventsExecutor(context=self.context)
        self.executor.add_node(self.node)
        self._stop = False
        self._closed = False
        self._thread = threading.Thread(target=self._spin, name=f'{name}_spin', daemon=True)
        self._thread.start()

    def _spin(self):
        from rclpy.task import Future
        while not self._stop and self.context.ok():
            try:
                self.executor.spin_until_future_complete(Future(), timeout_sec=0.05)
            except Exception:
                if self._stop or not self.context.ok():
                    return
                raise

    def call(self, fn, timeout: float = 10.0):
        """``fn()`` run on the spin thread; its result (or its exception).

        For rclpy calls that race the executor when made from another thread: Jazzy's
        ``ActionClient.send_goal_async``, ``cancel_goal_async`` and ``get_result_async`` send the
        request first and register the future that waits for its answer after, so an answer
        the spin thread takes in between is dropped ("Ignoring unexpected ... response") and
        the future never completes. On the spin thread nothing runs in between.
        """
        def run():
            # an exception must not reach the wheel's EventsExecutor (it crashes the process)
            try:
                return True, fn()
            except Exception as exc:  # handed to the caller below
                return False, exc
        task = self.executor.create_task(run)
        deadline = time.monotonic() + timeout
        while not task.done():
            if time.monotonic() > deadline:
                raise TimeoutError(f'{self.node.get_name()}: the spin thread did not run a call '
                                   f'within {timeout:g} s')
            time.sleep(0.002)
        ok, value = task.result()
        if not ok:
            raise value
        return value

    def close(self) -> None:
        """Stop spinning, release the executor, destroy the node, shut the context down.

        Idempotent. The spin thread must have stopped before the executor is released (see
        :func:`release_executor`): otherwise the wheel's EventsExecutor aborts the process
        ("terminate called without an active exception").
        """
        if self._closed:
            return
        self._closed = True
        self._stop = True
        self._thread.join(timeout=30.0)
        if self._thread.is_alive():
            raise RuntimeError(f'{self.node.get_name()}: spin thread did not stop within 30 s')
        release_executor(self.executor, [self.node])
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
