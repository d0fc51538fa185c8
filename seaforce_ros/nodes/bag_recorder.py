"""bag_recorder (node ``bag_recorder``): record topics into one rosbag2 bag, as ``ros2 bag
record`` does, with :mod:`seaforce_ros.bags`.

What it does
    Subscribes to ``topics`` (default ``actuator_state``, ``actuator_command``,
    ``controller_status``) with raw (still serialised) messages, so the subscription callback
    only stamps the receive time and appends ``(topic, time, bytes)`` to a queue. A writer
    thread drains the queue into :class:`~seaforce_ros.bags.writer.BagWriter`: one bag
    directory ``<output>/`` with ``metadata.yaml`` (rosbag2 Jazzy, version 9) and the files
    ``<name>_0.mcap``, ``<name>_1.mcap``, ... (``.db3`` for ``storage: sqlite3``), a new file
    every ``split_duration`` seconds of receive time; ``ros2 bag info`` / ``ros2 bag play`` /
    rosbags / the mcap tools read the directory as one bag. Per topic the bag stores the
    message definition, the RIHS01 type hash the publishers announce in the graph and their
    offered QoS (``get_publishers_info_by_topic`` when the first message arrives). A message's
    ``log_time`` is its receive time, its ``publish_time`` the sender's time: the header stamp
    for types that start with a Header (all of this package's), else the receive time.

What survives a crash
    SIGINT/SIGTERM: everything received is written, the open file closed, ``metadata.yaml``
    rewritten. SIGKILL (or power loss): ``metadata.yaml`` is rewritten atomically each time a
    file closes, so the directory stays one valid bag of every closed file; the open mcap
    file keeps its complete chunks (one is written at least every ``chunk_period`` s), an
    open sqlite3 file every committed batch (one per writer wake-up, ~10 ms). The package's
    reader recovers them and says so; ``bag_reindex <output>`` makes the bag whole for every
    other tool.

Write failures (disk full)
    The writer cuts the open file back to what is complete (:class:`~seaforce_ros.bags.errors
    .BagWriteError`), the node logs an ERROR and publishes a ``/diagnostics`` ERROR, drops
    (and counts) what is still queued or arrives, and ends with exit code 1. The queue between
    the subscriptions and the writer is bounded (``queue_limit`` MB): beyond it messages are
    dropped and counted, never buffered without limit.

Counts
    Per topic ``received`` (callbacks), ``written`` (on disk) and ``dropped`` are logged every
    ``report_period`` and at shutdown (``received == written`` after a clean stop), and
    published on ``/diagnostics``. The exit code is 1 when anything received was not written.

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
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, LivelinessPolicy, QoSProfile,
                       ReliabilityPolicy)

from ..bags import BagError, BagWriter, BagWriteError, QosProfile, check_output_directory
from ..bags.typestore import has_header, header_stamp_ns, knows, type_hash
from ..core.schema import RECORDER
from .ros_common import (RECORD_QOS, StartupError, check_undeclared, declare, diagnostic_status,
                         diagnostics_publisher, publish_diagnostics, run)
from . import param_specs as ps

#: relative topic -> message type of the package's own topics
KNOWN_TYPES = {
    'actuator_state': 'seaforce_msgs/msg/ActuatorState',
    'actuator_command': 'seaforce_msgs/msg/ActuatorCommand',
    'controller_status': 'seaforce_msgs/msg/ControllerStatus',
}
#: the writer thread wakes up this often [s] when the queue is empty
WRITE_PERIOD = 0.01
#: after a write failure the node lives this long [s] before it ends, publishing its
#: /diagnostics ERROR every report_period (a subscriber still discovering it on a loaded
#: host gets one)
FAILURE_GRACE = 3.0


def node_specs():
    """bag_recorder's parameters."""
    return ps.node_specs(RECORDER)


def check_output(path: pathlib.Path) -> None:
    """The ``output`` directory must be new or empty and creatable: StartupError naming the
    parameter otherwise (before anything is created or subscribed)."""
    try:
        check_output_directory(path)
    except BagError as exc:
        raise StartupError(f'output: {exc}') from None


def message_class(msgtype: str):
    """The Python message class of ``pkg/msg/Type``."""
    pkg, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{pkg}.{kind}'), name)


def _duration(d):
    ns = int(d.nanoseconds)
    return ns // 1_000_000_000, ns % 1_000_000_000


def offered_qos(profile) -> QosProfile:
    """A publisher's QoS (``TopicEndpointInfo.qos_profile``) as the bag stores it."""
    def name(enum, value):
        try:
            return enum(int(value)).name.lower()
        except ValueError:
            return 'unknown'

    return QosProfile(
        history=name(HistoryPolicy, profile.history), depth=int(profile.depth),
        reliability=name(ReliabilityPolicy, profile.reliability),
        durability=name(DurabilityPolicy, profile.durability),
        deadline=_duration(profile.deadline), lifespan=_duration(profile.lifespan),
        liveliness=name(LivelinessPolicy, profile.liveliness),
        liveliness_lease_duration=_duration(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=bool(profile.avoid_ros_namespace_conventions))


class BagRecorderNode(Node):
    """Records topics into one rosbag2 bag directory off the subscription callbacks."""

    def __init__(self, **kwargs):
        super().__init__('bag_recorder', **kwargs)
        values = declare(self, node_specs())
        check_undeclared(self)
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
            self.writer = BagWriter(self.output, storage=values['storage'],
                                    split_duration=values['split_duration'],
                                    chunk_period=values['chunk_period'])
        except BagError as exc:
            raise StartupError(f'output: {exc}') from None
        self.exit_code = 0
        self.received = {}
        self.dropped = {}             # by the callbacks (executor thread)
        self._lost = {}               # by the writer thread (failed writes, queue drained)
        self._queue = queue.SimpleQueue()
        self._limit = int(values['queue_limit'] * 1e6)
        self._in_bytes = 0            # written by the executor thread only
        self._out_bytes = 0           # written by the writer thread only
        self._failed = False
        self._pending = []            # resolved topics awaiting a publisher
        self._subs = []
        for topic in topics:
            resolved = self.resolve_topic_name(topic)
            self.received[resolved] = 0
            self.dropped[resolved] = 0
            msgtype = KNOWN_TYPES.get(resolved.rsplit('/', 1)[-1])
            if msgtype is None:
                self._pending.append(resolved)
            else:
                self._subscribe(resolved, msgtype)
        if self._pending:
            self.create_timer(0.5, self._discover)
        self._write_error = None
        self._stop = threading.Event()
        self.diag_pub = diagnostics_publisher(self)
        self._thread = threading.Thread(target=self._write_loop, name='bag_writer', daemon=True)
        self._thread.start()
        self.create_timer(values['report_period'], self._report)
        self.get_logger().info(
            f'recording {", ".join(self.received)} into {self.output} '
            f'({values["storage"]}, a new file every {values["split_duration"]:g} s)')

    # --- subscriptions ---------------------------------------------------------------------
    def _subscribe(self, topic, msgtype):
        try:
            cls = message_class(msgtype)
        except (ImportError, AttributeError, ValueError) as exc:
            self.get_logger().error(f'cannot record {topic}: no Python type {msgtype} ({exc})')
            return
        if not knows(msgtype):
            self.get_logger().error(f'cannot record {topic}: no message definition of '
                                    f'{msgtype} for the bag')
            return
        received, dropped = self.received, self.dropped
        put = self._queue.put
        now = time.time_ns
        limit = self._limit
        first = [True]

        def callback(data, topic=topic):
            received[topic] += 1
            if first[0]:
                first[0] = False
                put(('__topic__', topic, self._topic_info(topic, msgtype)))
            if self._failed or self._in_bytes - self._out_bytes > limit:
                dropped[topic] += 1
                if self._failed:
                    self._end_after_failure()
                return
            self._in_bytes += len(data)
            put((topic, now(), data))

        self._subs.append(self.create_subscription(cls, topic, callback, self._qos, raw=True))

    def _topic_info(self, topic, msgtype):
        """``(msgtype, offered QoS list, type hash)`` from the graph (the publishers now)."""
        expected = type_hash(msgtype)
        profiles, digest = [], expected
        try:
            infos = self.get_publishers_info_by_topic(topic)
        except Exception:     # graph query failed: the bag still gets the computed hash
            infos = []
        for info in infos:
            profiles.append(offered_qos(info.qos_profile))
            announced = str(info.topic_type_hash)
            if announced.startswith('RIHS') and announced != expected:
                self.get_logger().warning(
                    f'{topic}: a publisher announces type hash {announced}, the {msgtype} '
                    f'definition this recorder stores has {expected}; the bag keeps the '
                    'announced one')
                digest = announced
        return msgtype, profiles, digest

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
        per message: the executor thread that takes messages from DDS stays responsive); each
        batch ends with :meth:`BagWriter.flush` (sqlite3 commit, mcap chunk when due)."""
        q = self._queue
        writer = self.writer
        get = q.get_nowait
        headers = {}
        try:
            while True:
                batch = []
                try:
                    while len(batch) < 20000:
                        batch.append(get())
                except queue.Empty:
                    pass
                size = 0
                for topic, stamp, data in batch:
                    if topic == '__topic__':
                        msgtype, profiles, digest = data
                        writer.add_topic(stamp, msgtype, profiles, digest)
                        headers[stamp] = has_header(msgtype)
                        continue
                    size += len(data)
                    sent = header_stamp_ns(data) if headers[topic] else None
                    writer.write(topic, stamp, data, stamp if sent is None else sent)
                self._out_bytes += size
                writer.flush(time.time_ns())
                if not batch:
                    if self._stop.is_set():
                        break
                    time.sleep(WRITE_PERIOD)
            writer.close()
        except BagWriteError as exc:
            self._on_write_error(exc)
        except Exception as exc:  # a bug must not pass for a complete recording
            self._on_write_error(BagWriteError(f'writing the bag failed: {exc!r}'))

    def _on_write_error(self, exc):
        self._failed_at = time.monotonic()
        self._failed = True
        self._write_error = str(exc)
        for topic, n in exc.lost.items():
            self._lost[topic] = self._lost.get(topic, 0) + n
        self.get_logger().error(f'{exc}; recording stopped, the recorder ends')
        self._drain_dropped()
        self._report()

    def _drain_dropped(self):
        while True:
            try:
                topic, _stamp, _data = self._queue.get_nowait()
            except queue.Empty:
                return
            if topic != '__topic__':
                self._lost[topic] = self._lost.get(topic, 0) + 1

    def _end_after_failure(self):
        """After a write failure (seen by the next callback or report): end the node, exit
        code 1, FAILURE_GRACE after the failure (the /diagnostics ERROR gets to its
        subscribers first). (No timer or guard condition for this: the EventsExecutor of the
        PyPI build supports no guard conditions, and a second fast timer stalled it here.)"""
        if self._failed and self.exit_code == 0 and \
                time.monotonic() - self._failed_at >= FAILURE_GRACE:
            self.exit_code = 1
            self.context.try_shutdown()

    def counts(self):
        """``{topic: (received, written, dropped)}``."""
        written = self.writer.written
        return {t: (n, written.get(t, 0), self.dropped.get(t, 0) + self._lost.get(t, 0))
                for t, n in self.received.items()}

    def _summary(self):
        return '; '.join(f'{t}: received {r}, written {w}, dropped {d}'
                         for t, (r, w, d) in self.counts().items())

    def _report(self):
        self._end_after_failure()
        counts = self.counts()
        queued = max(0, self._in_bytes - self._out_bytes)
        files = len(self.writer.files)
        self.get_logger().info(f'{self._summary()}; queued {queued / 1e6:.1f} MB; '
                               f'{files} files closed')
        values = {f'{t} received': r for t, (r, _w, _d) in counts.items()}
        values.update({f'{t} written': w for t, (_r, w, _d) in counts.items()})
        values.update({f'{t} dropped': d for t, (_r, _w, d) in counts.items()})
        values.update({'queued_bytes': queued, 'files_closed': files,
                       'output': str(self.output)})
        dropped = sum(d for _r, _w, d in counts.values())
        if self._write_error:
            level, message = DiagnosticStatus.ERROR, self._write_error
        elif dropped:
            level, message = DiagnosticStatus.WARN, (f'{dropped} messages dropped (the writer '
                                                     'fell behind by more than queue_limit)')
        else:
            level, message = DiagnosticStatus.OK, 'recording'
        try:
            publish_diagnostics(self, self.diag_pub, [diagnostic_status(
                'bag_recorder', 'seaforce_bag_recorder', level, message, values)])
        except Exception:   # the context is shutting down
            pass

    def shutdown(self):
        """Stop receiving, write everything queued, close the open file, print the counts."""
        for sub in self._subs:
            self.destroy_subscription(sub)
        self._subs = []
        self._stop.set()
        self._thread.join(timeout=60.0)
        if self._failed:
            self._drain_dropped()     # what callbacks queued while the writer failed
        line = (f'[bag_recorder] final counts: {self._summary()}; '
                f'splits {len(self.writer.files)}')
        if self._write_error:
            line += f'; WRITE ERROR {self._write_error}'
        print(line, flush=True)
        if self._write_error or any(d for _r, _w, d in self.counts().values()):
            self.exit_code = 1


def main(args=None):
    sys.exit(run(BagRecorderNode, args=args, name='bag_recorder'))


if __name__ == '__main__':
    main()
