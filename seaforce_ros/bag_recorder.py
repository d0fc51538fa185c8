"""bag_recorder (node ``bag_recorder``): record topics into rosbag2 bags with ``rosbags``.

What it does
    Subscribes to ``topics`` (default ``actuator_state``, ``actuator_command``,
    ``controller_status``) with raw (still serialised) messages, so the subscription callback
    only stamps the receive time and appends ``(topic, time, bytes)`` to a queue. A writer
    thread drains the queue into :class:`~seaforce_ros.identification.bagio.SplitBagWriter`:
    ``<output>/split_0000/``, ``split_0001/``, ... each a complete rosbag2 bag (``storage`` mcap
    or sqlite3, ``metadata.yaml``, the message definitions of ``seaforce_msgs`` and of the
    standard types in the bag, so ``ros2 bag info`` / ``ros2 bag play`` read it), a new one every
    ``split_duration`` seconds of receive time. The bag timestamp of a message is its receive
    time (as ``ros2 bag record`` does).

What survives a crash
    SIGINT/SIGTERM: everything received is written and the open split is closed. SIGKILL (or
    power loss): every split closed before the kill is complete and readable; the split being
    written is lost (its mcap file lacks the summary, a sqlite3 split its commit; an mcap
    split may still be partly readable from its storage file). So at most ``split_duration``
    seconds (plus the queue) are lost.

Counts
    Per topic ``received`` (callbacks) and ``written`` (in closed or open splits) are logged
    every ``report_period`` and at shutdown (``received == written`` after a clean stop), and
    published on ``/diagnostics``.

Topics whose type is not known up front (anything but the three seaforce_msgs topics) are
subscribed as soon as a publisher appears in the graph.
"""
from __future__ import annotations

import datetime
import importlib
import pathlib
import queue
import sys
import threading
import time

from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from .identification.bagio import SplitBagWriter
from .identification.errors import IdentificationError
from .ros_common import (RECORD_QOS, ParamSpec, StartupError, declare, diagnostic_status,
                         diagnostics_publisher, publish_diagnostics, run)
from . import param_specs as ps

#: relative topic -> message type of the package's own topics
KNOWN_TYPES = {
    'actuator_state': 'seaforce_msgs/msg/ActuatorState',
    'actuator_command': 'seaforce_msgs/msg/ActuatorCommand',
    'controller_status': 'seaforce_msgs/msg/ControllerStatus',
}
DEFAULT_TOPICS = ('actuator_state', 'actuator_command', 'controller_status')
#: the writer thread wakes up this often [s] when the queue is empty
WRITE_PERIOD = 0.01


def node_specs():
    return [
        ParamSpec('topics', list(DEFAULT_TOPICS), 'topics to record (relative names resolve in '
                  'the node namespace)', read_only=True),
        ParamSpec('output', '', 'output directory (created; must be new or empty); default '
                  'bag_recorder_<date>_<time> in the working directory', read_only=True),
        ParamSpec('storage', 'mcap', 'rosbag2 storage plugin', choices=('mcap', 'sqlite3'),
                  read_only=True),
        ParamSpec('split_duration', 10.0, 'seconds of receive time per split bag; a SIGKILL '
                  'loses at most the open split', low=0.1, high=86400.0, read_only=True),
        ParamSpec('reliability', 'reliable', 'QoS reliability of the subscriptions (must be '
                  'compatible with the publishers: best_effort also matches reliable ones)',
                  choices=('reliable', 'best_effort'), read_only=True),
        ParamSpec('report_period', 5.0, 'period of the count log line and /diagnostics [s]',
                  low=0.1, high=3600.0, read_only=True),
        ps.executor_spec('events'),
    ]


def check_output(path: pathlib.Path) -> None:
    """The ``output`` directory must be new or empty and creatable: StartupError naming the
    parameter otherwise (before anything is created or subscribed)."""
    if path.exists() and not path.is_dir():
        raise StartupError(f'output: {path} exists and is not a directory; give a new '
                           'directory for the bag splits')
    if path.is_dir() and any(path.iterdir()):
        raise StartupError(f'output: {path} exists and is not empty; give a new or empty '
                           'directory')
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise StartupError(f'output: cannot create {path}: {parent} is not a directory')


def message_class(msgtype: str):
    """The Python message class of ``pkg/msg/Type``."""
    pkg, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


class BagRecorderNode(Node):
    """Records topics into split rosbag2 bags off the subscription callbacks."""

    def __init__(self, **kwargs):
        super().__init__('bag_recorder', **kwargs)
        values = declare(self, node_specs())
        topics = [t for t in values['topics'] if t]
        if not topics:
            raise StartupError('topics is empty: nothing to record')
        output = values['output'] or f'bag_recorder_{datetime.datetime.now():%Y%m%d_%H%M%S}'
        self.output = pathlib.Path(output).resolve()
        check_output(self.output)
        qos = QoSProfile(history=RECORD_QOS.history, depth=RECORD_QOS.depth,
                         durability=RECORD_QOS.durability,
                         reliability=(ReliabilityPolicy.RELIABLE
                                      if values['reliability'] == 'reliable'
                                      else ReliabilityPolicy.BEST_EFFORT))
        self._qos = qos
        try:
            self.writer = SplitBagWriter(self.output, {}, storage=values['storage'],
                                         split_duration=values['split_duration'])
        except IdentificationError as exc:
            raise StartupError(f'output: {exc}') from None
        self.received = {}
        self._queue = queue.SimpleQueue()
        self._pending = []            # (resolved topic, requested name) awaiting a publisher
        self._subs = []
        for topic in topics:
            resolved = self.resolve_topic_name(topic)
            self.received[resolved] = 0
            msgtype = KNOWN_TYPES.get(resolved.rsplit('/', 1)[-1])
            if msgtype is None:
                self._pending.append(resolved)
            else:
                self._subscribe(resolved, msgtype)
        if self._pending:
            self.create_timer(0.5, self._discover)
        self._write_error = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._write_loop, name='bag_writer', daemon=True)
        self._thread.start()
        self.diag_pub = diagnostics_publisher(self)
        self.create_timer(values['report_period'], self._report)
        self.get_logger().info(
            f'recording {", ".join(self.received)} into {self.output} '
            f'({values["storage"]}, split every {values["split_duration"]:g} s)')

    # --- subscriptions ---------------------------------------------------------------------
    def _subscribe(self, topic, msgtype):
        try:
            cls = message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            self.get_logger().error(f'cannot record {topic}: no Python type {msgtype} ({exc})')
            return
        # the bag connection is created in the writer thread, in queue order
        self._queue.put(('__topic__', msgtype, topic))
        counter = self.received
        put = self._queue.put
        now = time.time_ns

        def callback(data, topic=topic):
            counter[topic] += 1
            put((topic, now(), data))

        self._subs.append(self.create_subscription(cls, topic, callback, self._qos, raw=True))

    def _discover(self):
        if not self._pending:
            return
        types = dict(self.get_topic_names_and_types())
        for topic in list(self._pending):
            if topic in types and types[topic]:
                self._pending.remove(topic)
                self.get_logger().info(f'{topic} appeared as {types[topic][0]}: recording it')
                self._subscribe(topic, types[topic][0])

    # --- writer thread -----------------------------------------------------------------------
    def _write_loop(self):
        """Drain the queue in batches every few milliseconds (few wake-ups and GIL hand-overs
        per message: the executor thread that takes messages from DDS stays responsive)."""
        q = self._queue
        writer = self.writer
        get = q.get_nowait
        try:
            while True:
                batch = []
                try:
                    while len(batch) < 20000:
                        batch.append(get())
                except queue.Empty:
                    pass
                for topic, stamp, data in batch:
                    if topic == '__topic__':
                        writer.add_topic(data, stamp)
                    else:
                        writer.write(topic, stamp, data)
                if not batch:
                    if self._stop.is_set():
                        break
                    time.sleep(WRITE_PERIOD)
        except Exception as exc:  # disk full, permissions: report, keep counting
            self._write_error = repr(exc)
            self.get_logger().error(f'writing the bag failed: {exc!r}; recording stopped')
        finally:
            try:
                writer.close()
            except Exception as exc:
                self._write_error = self._write_error or repr(exc)

    def counts(self):
        """``{topic: (received, written)}``."""
        written = self.writer.written
        return {t: (n, written.get(t, 0)) for t, n in self.received.items()}

    def _summary(self):
        return '; '.join(f'{t}: received {r}, written {w}' for t, (r, w) in
                         self.counts().items())

    def _report(self):
        counts = self.counts()
        backlog = sum(r - w for r, w in counts.values())
        self.get_logger().info(f'{self._summary()}; queued {backlog}; '
                               f'{len(self.writer.splits)} splits closed')
        values = {f'{t} received': r for t, (r, _w) in counts.items()}
        values.update({f'{t} written': w for t, (_r, w) in counts.items()})
        values.update({'queued': backlog, 'splits_closed': len(self.writer.splits),
                       'output': str(self.output)})
        level = DiagnosticStatus.ERROR if self._write_error else DiagnosticStatus.OK
        publish_diagnostics(self, self.diag_pub, [diagnostic_status(
            'bag_recorder', 'seaforce_bag_recorder', level,
            self._write_error or 'recording', values)])

    def shutdown(self):
        """Stop receiving, write everything queued, close the open split, print the counts."""
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        self._stop.set()
        self._thread.join(timeout=60.0)
        line = f'[bag_recorder] final counts: {self._summary()}; splits {len(self.writer.splits)}'
        if self._write_error:
            line += f'; WRITE ERROR {self._write_error}'
        print(line, flush=True)


def main(args=None):
    sys.exit(run(BagRecorderNode, args=args, name='bag_recorder'))


if __name__ == '__main__':
    main()
