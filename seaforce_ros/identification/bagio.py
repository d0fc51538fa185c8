"""rosbag2 input/output for the offline tools and the recorder (``rosbags``, no rclpy).

Reading
    :func:`read_channel` loads one channel of ``actuator_state`` from a bag written by this
    package or by ``ros2 bag record``: a rosbag2 directory (mcap or sqlite3, any number of
    storage files), a bare ``.mcap`` / ``.db3`` file, or a directory of such bags (the splits of
    :class:`SplitBagWriter`; a split without ``metadata.yaml`` -- the one being written when a
    recorder was killed -- is read from its storage file when that is readable).

    Decoding is the hot part for long bags (a 10 min bag at 2 kHz holds 1.2 M messages and the
    generic CDR deserialiser takes ~30 us per message). Every ``ActuatorState`` of one recording
    has the same byte layout (same channel names and frame_id length), so the layout of the
    first message is parsed once and all messages of that length and name bytes are decoded
    together with numpy (:class:`StateLayout`); any other message goes through the generic
    deserialiser.

Writing
    :class:`SplitBagWriter` writes a sequence of complete bags ``<dir>/<prefix>_<k>/`` (one
    ``metadata.yaml`` each), a new one every ``split_duration`` seconds of message time: a
    process killed while writing loses at most the open split. :func:`write_state_bag` writes
    sampled channel data (e.g. from :class:`~seaforce_ros.core.simulator.ChannelSimulator`) as
    ``actuator_state`` messages with the same numpy layout trick.
"""

from __future__ import annotations

import math
import pathlib
import struct
from dataclasses import dataclass, field
from typing import Callable, Dict, Iterable, List, Optional, Sequence

import numpy as np

from .errors import IdentificationError

__all__ = ["ACTUATOR_STATE", "STATE_FIELDS", "ChannelRecord", "StateLayout", "bag_sources",
           "read_channel", "SplitBagWriter", "write_state_bag", "storage_plugin"]

ACTUATOR_STATE = "seaforce_msgs/msg/ActuatorState"
#: message array field -> short name used in :class:`ChannelRecord`
STATE_FIELDS = (("motor_position", "x"), ("motor_velocity", "v"), ("pressure_force", "f_p"),
                ("motor_effort", "f_a"), ("endpoint_position", "x_e"),
                ("external_force", "f_e"))

_TYPESTORE = None


def typestore():
    """The shared rosbags typestore (ROS 2 Jazzy + seaforce_msgs)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from ..interfaces import make_typestore
        _TYPESTORE = make_typestore()
    return _TYPESTORE


def storage_plugin(name):
    """rosbags ``StoragePlugin`` for ``'mcap'`` or ``'sqlite3'``."""
    from rosbags.rosbag2.enums import StoragePlugin
    try:
        return {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[name]
    except KeyError:
        raise IdentificationError(f"storage must be mcap or sqlite3, not {name!r}") from None


# --- fixed CDR layout of ActuatorState ----------------------------------------------------
class StateLayout:
    """Byte offsets of one ``ActuatorState`` serialisation (CDR, little endian).

    Parameters
    ----------
    data : bytes
        One serialised message; every message with the same length and the same bytes in
        the ranges ``fixed`` (frame_id and channel names) has the same layout.
    """

    def __init__(self, data):
        data = bytes(data)
        if len(data) < 8 or data[1] != 1:
            raise ValueError("not a little-endian CDR message")
        self.length = len(data)
        pos = 4

        def align(p, n):
            return 4 + (-(-(p - 4) // n)) * n

        def u32(p):
            return struct.unpack_from("<I", data, p)[0]

        self.sec = pos
        self.nanosec = pos + 4
        pos += 8
        flen = u32(pos)
        #: byte ranges that must match for the layout to apply (frame_id, channel names)
        self.fixed = [(pos, pos + 4 + flen)]
        pos += 4 + flen
        pos = align(pos, 8)
        self.cycle = pos
        pos += 8
        pos = align(pos, 4)
        names_start = pos
        count = u32(pos)
        pos += 4
        names = []
        for _ in range(count):
            pos = align(pos, 4)
            slen = u32(pos)
            names.append(data[pos + 4:pos + 4 + slen - 1].decode("utf-8", "replace"))
            pos += 4 + slen
        self.fixed.append((names_start, pos))
        self.names = names
        self.arrays = {}
        for msg_field, _short in STATE_FIELDS:
            pos = align(pos, 4)
            n = u32(pos)
            if n != count:
                raise ValueError(f"{msg_field} has {n} entries for {count} names")
            pos += 4
            if n:
                pos = align(pos, 8)
            self.arrays[msg_field] = pos
            pos += 8 * n
        pos = align(pos, 4)
        n = u32(pos)
        if n != count:
            raise ValueError(f"status has {n} entries for {count} names")
        self.status = pos + 4
        # serialisers pad the message to a multiple of 4 bytes (Fast DDS does)
        if not 0 <= self.length - (self.status + n) < 4:
            raise ValueError("unexpected trailing bytes")
        self.template = np.frombuffer(data, dtype=np.uint8).copy()

    def column(self, rows, offset, dtype):
        """Values of one scalar at ``offset`` from a (n, length) uint8 array."""
        size = np.dtype(dtype).itemsize
        return np.ascontiguousarray(rows[:, offset:offset + size]).view(dtype).ravel()

    def put(self, rows, offset, values, dtype):
        size = np.dtype(dtype).itemsize
        rows[:, offset:offset + size] = np.asarray(values, dtype).reshape(-1, 1).view(np.uint8)


# --- reading --------------------------------------------------------------------------------
@dataclass
class ChannelRecord:
    """One channel of ``actuator_state``, sorted by cycle (duplicates removed).

    Arrays ``x, v, f_p, f_a, x_e, f_e`` [rad, rad/s, N m] as published (NaN kept; see
    :meth:`seaforce_ros.identification.timeseries.prepare`), ``cycle`` (uint64 as int64),
    ``stamp`` [s] (header stamps), ``status``.
    """

    channel: str
    channels: List[str]
    cycle: np.ndarray
    stamp: np.ndarray
    x: np.ndarray
    v: np.ndarray
    f_p: np.ndarray
    f_a: np.ndarray
    x_e: np.ndarray
    f_e: np.ndarray
    status: np.ndarray
    sources: List[str] = field(default_factory=list)
    skipped_sources: List[str] = field(default_factory=list)
    duplicates: int = 0

    def __len__(self):
        return int(self.cycle.size)


def bag_sources(path):
    """The readable bag paths under ``path`` in recording order.

    A rosbag2 directory or a storage file is returned as is; a directory of split bags gives
    its sub-bags (sorted by name); storage files directly in a directory without
    ``metadata.yaml`` (a killed ``ros2 bag record``) are returned one by one.
    """
    p = pathlib.Path(path)
    if not p.exists():
        raise IdentificationError(f"{p}: no such bag (give a rosbag2 directory, an .mcap/.db3 "
                                  "file or a directory of split bags)")
    if p.is_file():
        if p.suffix not in (".mcap", ".db3"):
            raise IdentificationError(f"{p}: not a bag (expected .mcap or .db3, or a rosbag2 "
                                      "directory)")
        return [p]
    if (p / "metadata.yaml").is_file():
        return [p]
    out = []
    for child in sorted(p.iterdir()):
        if child.is_dir():
            if (child / "metadata.yaml").is_file():
                out.append(child)
            else:
                out.extend(sorted(f for f in child.iterdir()
                                  if f.suffix in (".mcap", ".db3") and f.stat().st_size > 0))
        elif child.suffix in (".mcap", ".db3") and child.stat().st_size > 0:
            out.append(child)
    if not out:
        raise IdentificationError(f"{p}: no rosbag2 bag in this directory (no metadata.yaml, "
                                  "no .mcap/.db3 files)")
    return out


def _topic_matches(name, topic):
    topic = topic if topic.startswith("/") else "/" + topic
    name = name if name.startswith("/") else "/" + name
    return name == topic or (not topic[1:].count("/") and name.endswith(topic))


def _names(data):
    try:
        return StateLayout(data).names
    except ValueError:
        return list(typestore().deserialize_cdr(data, ACTUATOR_STATE).name)


def _check_channel(data, channel):
    names = _names(data)
    if channel not in names:
        raise IdentificationError(
            f"unknown channel {channel!r}: the bag's actuator_state has channels "
            f"{', '.join(names) or '(none)'}; pass one of them with --channel")


def _raw_messages(path, topic, progress=None, channel=None):
    """Raw ``actuator_state`` bytes from every source under ``path`` (list, sources, skipped).

    With ``channel``, the first message is checked for it before the rest is read."""
    from rosbags.rosbag2 import Reader

    raws, used, skipped, seen_topics = [], [], [], set()
    sources = bag_sources(path)
    for i, src in enumerate(sources):
        try:
            with Reader(src) as reader:
                seen_topics.update(c.topic for c in reader.connections)
                conns = [c for c in reader.connections if _topic_matches(c.topic, topic)
                         and c.msgtype == ACTUATOR_STATE]
                if not conns:
                    continue
                for _conn, _ts, data in reader.messages(connections=conns):
                    if channel is not None and not raws:
                        _check_channel(data, channel)
                    raws.append(data)
                used.append(str(src))
        except IdentificationError:
            raise
        except Exception as exc:  # an unreadable split (killed writer): keep the others
            if len(sources) == 1:
                raise IdentificationError(f"{src}: cannot read this bag ({exc})") from None
            skipped.append(f"{src} ({type(exc).__name__}: {exc})")
        if progress is not None:
            progress(f"read {src.name}: {len(raws)} actuator_state messages so far",
                     (i + 1) / len(sources))
    if not raws:
        topics = ", ".join(sorted(seen_topics)) or "none"
        raise IdentificationError(
            f"{path}: no {topic} messages of type {ACTUATOR_STATE} (topics in the bag: "
            f"{topics}). Record the actuator_state topic of sim_node or hardware_node.")
    return raws, used, skipped


def _decode(raws, channel):
    """Decode raw ActuatorState messages for one channel -> dict of arrays + names."""
    store = typestore()
    try:
        layout = StateLayout(raws[0])
    except ValueError:   # unexpected layout: decode every message generically
        layout = None
    names = layout.names if layout is not None else _names(raws[0])
    if channel not in names:
        raise IdentificationError(
            f"unknown channel {channel!r}: the bag's actuator_state has channels "
            f"{', '.join(names) or '(none)'}; pass one of them with --channel")
    j = names.index(channel)
    n = len(raws)
    if layout is None:
        layout = _state_template(names)
    lengths = np.fromiter((len(r) for r in raws), dtype=np.int64, count=n)
    same = lengths == layout.length
    idx_fast = np.flatnonzero(same)
    rows = np.frombuffer(b"".join(raws[i] for i in idx_fast), dtype=np.uint8).reshape(
        idx_fast.size, layout.length)
    good = np.ones(rows.shape[0], bool)
    for a, b in layout.fixed:
        good &= np.all(rows[:, a:b] == layout.template[a:b], axis=1)
    slow = sorted(set(np.flatnonzero(~same).tolist()) | set(idx_fast[~good].tolist()))
    rows = rows[good]
    out = {"cycle": layout.column(rows, layout.cycle, "<u8").astype(np.int64),
           "stamp": (layout.column(rows, layout.sec, "<i4").astype(float)
                     + 1e-9 * layout.column(rows, layout.nanosec, "<u4"))}
    for msg_field, short in STATE_FIELDS:
        out[short] = layout.column(rows, layout.arrays[msg_field] + 8 * j, "<f8")
    out["status"] = rows[:, layout.status + j].copy()
    if slow:
        extra = {k: [] for k in out}
        for i in slow:
            msg = store.deserialize_cdr(raws[i], ACTUATOR_STATE)
            if channel not in list(msg.name):
                continue
            k = list(msg.name).index(channel)
            extra["cycle"].append(int(msg.cycle))
            extra["stamp"].append(msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec)
            for msg_field, short in STATE_FIELDS:
                arr = getattr(msg, msg_field)
                extra[short].append(float(arr[k]) if len(arr) > k else math.nan)
            extra["status"].append(int(msg.status[k]) if len(msg.status) > k else 0)
        for key in out:
            out[key] = np.concatenate([out[key], np.asarray(extra[key], out[key].dtype)])
    return out, names


def read_channel(path, channel, topic="actuator_state", progress=None):
    """Load ``channel`` of ``topic`` (``seaforce_msgs/ActuatorState``) from a bag.

    Parameters
    ----------
    path : str or Path
        Bag directory, storage file or directory of split bags (:func:`bag_sources`).
    channel : str
        Channel name (an entry of ``ActuatorState.name``).
    topic : str
        Topic name; a relative name also matches a namespaced one (``/ns/actuator_state``).
    progress : callable(str, float), optional
        Called with a message and the fraction done.

    Raises
    ------
    IdentificationError
        No such bag, no ``actuator_state`` in it, unknown channel.
    """
    raws, used, skipped = _raw_messages(path, topic, progress, channel)
    arrays, names = _decode(raws, channel)
    order = np.argsort(arrays["cycle"], kind="stable")
    cyc = arrays["cycle"][order]
    keep = np.ones(cyc.size, bool)
    keep[1:] = cyc[1:] != cyc[:-1]
    sel = order[keep]
    rec = ChannelRecord(channel=channel, channels=names,
                        **{k: v[sel] for k, v in arrays.items()},
                        sources=used, skipped_sources=skipped,
                        duplicates=int(cyc.size - keep.sum()))
    return rec


# --- writing ----------------------------------------------------------------------------------
class SplitBagWriter:
    """Write messages into consecutive complete rosbag2 bags, one per ``split_duration``.

    The bags are ``<directory>/<prefix>_<k>/`` (k = 0, 1, ...), each closed (index, summary,
    ``metadata.yaml``) before the next one opens, so each closed split survives a SIGKILL of
    the writing process; only the open split is lost (an mcap split being written may still be
    partly readable from its storage file).

    Parameters
    ----------
    directory : path
        Created; must not hold bags already.
    topics : dict topic -> msgtype
        Topics to write (their definitions come from :func:`typestore`, so the message
        definitions of ``seaforce_msgs`` are stored in every split).
    storage : 'mcap' or 'sqlite3'
    split_duration : float > 0 or None
        Seconds of message time per split (None: one bag).
    prefix : str
    offered_qos : dict topic -> list of rosbags Qos, optional
    """

    def __init__(self, directory, topics, storage="mcap", split_duration=10.0,
                 prefix="split", offered_qos=None):
        self.directory = pathlib.Path(directory)
        if self.directory.exists() and any(self.directory.iterdir()):
            raise IdentificationError(f"{self.directory} exists and is not empty; choose a new "
                                      "output directory")
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise IdentificationError(f"cannot create {self.directory}: {exc.strerror}") from None
        if split_duration is not None and not split_duration > 0:
            raise IdentificationError("split_duration must be > 0")
        self.topics = dict(topics)
        self.storage = storage
        self._plugin = storage_plugin(storage)
        self.split_ns = None if split_duration is None else int(split_duration * 1e9)
        self.prefix = prefix
        self.offered_qos = offered_qos or {}
        self._writer = None
        self._conns = {}
        self._split_start = None
        self.splits = []            # closed split paths
        self.current = None
        self.written = {t: 0 for t in self.topics}

    def _open(self, timestamp):
        from rosbags.rosbag2 import Writer
        path = self.directory / f"{self.prefix}_{len(self.splits):04d}"
        writer = Writer(path, version=8, storage_plugin=self._plugin)
        writer.open()
        store = typestore()
        self._conns = {t: writer.add_connection(t, mt, typestore=store,
                                                offered_qos_profiles=self.offered_qos.get(t, ()))
                       for t, mt in self.topics.items()}
        self._writer, self.current, self._split_start = writer, path, timestamp

    def add_topic(self, topic, msgtype):
        """Add a topic (also to the open split)."""
        if topic in self.topics:
            return
        self.topics[topic] = msgtype
        self.written.setdefault(topic, 0)
        if self._writer is not None:
            self._conns[topic] = self._writer.add_connection(
                topic, msgtype, typestore=typestore(),
                offered_qos_profiles=self.offered_qos.get(topic, ()))

    def _close_current(self):
        if self._writer is not None:
            self._writer.close()
            self.splits.append(self.current)
            self._writer, self.current = None, None

    def write(self, topic, timestamp, data):
        """Write one serialised message (``timestamp`` in ns)."""
        if self._writer is None:
            self._open(timestamp)
        elif self.split_ns is not None and timestamp - self._split_start >= self.split_ns:
            self._close_current()
            self._open(timestamp)
        self._writer.write(self._conns[topic], timestamp, data)
        self.written[topic] += 1

    def close(self):
        """Close the open split (writes its metadata). Idempotent."""
        self._close_current()
        return self.splits


def _state_template(channels, frame_id=""):
    store = typestore()
    M = store.types[ACTUATOR_STATE]
    H = store.types["std_msgs/msg/Header"]
    T = store.types["builtin_interfaces/msg/Time"]
    n = len(channels)
    z = np.zeros(n)
    msg = M(header=H(stamp=T(sec=0, nanosec=0), frame_id=frame_id), cycle=0,
            name=list(channels), motor_position=z, motor_velocity=z, pressure_force=z,
            motor_effort=z, endpoint_position=z, external_force=z,
            status=np.zeros(n, np.uint8))
    return StateLayout(store.serialize_cdr(msg, ACTUATOR_STATE))


def serialize_states(channels, data, cycle0=0, dt=5e-4, t0=0.0):
    """Serialise samples as ``ActuatorState`` messages (numpy, fixed layout).

    Parameters
    ----------
    channels : sequence of str
    data : dict channel -> dict with arrays ``x v f_p f_a x_e f_e`` (same length n;
        ``status`` optional)
    cycle0 : int
        Cycle number of the first sample.
    dt : float
        Sample period [s]; header stamp of sample i is ``t0 + i dt``.

    Returns
    -------
    (n, L) uint8 array, one message per row; and the stamps [ns] (int64).
    """
    layout = _state_template(channels)
    n = len(next(iter(data.values()))["x"])
    rows = np.repeat(layout.template[None, :], n, axis=0)
    stamps_ns = np.round((t0 + np.arange(n) * dt) * 1e9).astype(np.int64)
    layout.put(rows, layout.sec, stamps_ns // 1_000_000_000, "<i4")
    layout.put(rows, layout.nanosec, stamps_ns % 1_000_000_000, "<u4")
    layout.put(rows, layout.cycle, cycle0 + np.arange(n, dtype=np.uint64), "<u8")
    for j, ch in enumerate(channels):
        d = data[ch]
        for msg_field, short in STATE_FIELDS:
            values = np.asarray(d[short], float)
            if values.shape != (n,):
                raise ValueError(f"{ch}.{short} must have {n} samples")
            layout.put(rows, layout.arrays[msg_field] + 8 * j, values, "<f8")
        if "status" in d:
            rows[:, layout.status + j] = np.asarray(d["status"], np.uint8)
    return rows, stamps_ns


def write_state_bag(path, channels, data, dt=5e-4, storage="mcap", split_duration=None,
                    topic="/actuator_state", cycle0=0, t0=0.0):
    """Write sampled channel data as ``actuator_state`` messages into a bag (or splits).

    With ``split_duration`` None, ``path`` becomes one rosbag2 directory; otherwise a
    directory of split bags (:class:`SplitBagWriter`). Returns the written bag paths.
    """
    rows, stamps = serialize_states(channels, data, cycle0=cycle0, dt=dt, t0=t0)
    path = pathlib.Path(path)
    if split_duration is None:
        from rosbags.rosbag2 import Writer
        if path.exists():
            raise IdentificationError(f"{path} exists; choose a new bag path")
        writer = Writer(path, version=8, storage_plugin=storage_plugin(storage))
        writer.open()
        conn = writer.add_connection(topic, ACTUATOR_STATE, typestore=typestore())
        for i in range(rows.shape[0]):
            writer.write(conn, int(stamps[i]), rows[i].tobytes())
        writer.close()
        return [path]
    w = SplitBagWriter(path, {topic: ACTUATOR_STATE}, storage=storage,
                       split_duration=split_duration)
    for i in range(rows.shape[0]):
        w.write(topic, int(stamps[i]), rows[i].tobytes())
    return w.close()
