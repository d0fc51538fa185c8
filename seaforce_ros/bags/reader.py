"""Read rosbag2 bags (mcap, sqlite3) written by this package or by ``ros2 bag record``.

:class:`Bag` takes

* a bag directory with ``metadata.yaml``: the files it lists, in order, then any storage file
  beside them that it does not list (the file that was open when a recorder was killed);
* a directory of storage files without ``metadata.yaml`` (``ros2 bag record`` killed before
  it wrote one);
* a single ``.mcap`` / ``.db3`` file;
* a directory of bag directories (read one after the other, in name order).

Every file is read as far as it is intact: an mcap file without summary (cut short by a kill
or a full disk) gives the messages of all its complete chunks, an sqlite3 file left with its
WAL gives every committed batch. What was recovered this way, from which file, and how to
repair the bag (``bag_reindex``) is said in :attr:`Bag.notes` -- never silently. An empty
file is skipped with a note; a file that cannot be read at all is skipped with a note when the
bag has others, else it is an error.

:func:`read_channel` loads one channel of ``actuator_state`` for the offline tools, decoding
with the fixed layout of :mod:`~seaforce_ros.bags.states`.
"""
from __future__ import annotations

import math
import os
import pathlib
import re
from dataclasses import dataclass, field
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple, Union, cast

import numpy as np
import numpy.typing as npt

from .errors import BagContentError, BagReadError, NotABagError
from .mcapfile import McapScan
from .metadata import METADATA_FILE, read_metadata, storage_of
from .sqlitefile import needs_recovery, open_for_reading
from .states import ACTUATOR_STATE, STATE_FIELDS, StateLayout, state_template
from .typestore import typestore

__all__ = ["Bag", "FileReport", "ChannelRecord", "read_channel", "topic_matches"]

#: Which messages to read: ``select(topic, msgtype)`` (msgtype None: a channel without schema).
Select = Callable[[str, Optional[str]], bool]
#: Progress report: a message and the fraction done.
Progress = Callable[[str, float], object]
#: One message as :meth:`Bag.messages` yields it: ``(topic, msgtype, log_time, data)``
#: (msgtype None: an mcap channel without schema).
BagMessage = Tuple[str, Optional[str], int, bytes]


@dataclass
class FileReport:
    """What reading one storage file gave.

    ``state``: ``complete``, ``recovered`` (cut short or left open: read as far as intact),
    ``empty`` or ``unreadable``; ``listed``: in ``metadata.yaml``; ``messages``: messages
    read (all topics); ``first`` / ``last``: their log time range [ns]; ``problem``: why
    the file is not complete.
    """

    path: pathlib.Path
    storage: str
    listed: bool
    state: str = "unread"
    messages: int = 0
    chunks: int = 0
    first: Optional[int] = None
    last: Optional[int] = None
    problem: Optional[str] = None

    def note(self, bag: Union[str, pathlib.Path]) -> Optional[str]:
        """One line for the user, or None for a complete file."""
        where = f"{self.path}"
        if self.state == "recovered":
            span = ""
            if self.first is not None and self.last is not None:
                span = (f", log time {self.first * 1e-9:.3f}-{self.last * 1e-9:.3f} s "
                        f"({(self.last - self.first) * 1e-9:.1f} s)")
            what = (f"{self.chunks} complete chunks" if self.storage == "mcap"
                    else "committed batches")
            repair = f"; make it readable for every tool with: bag_reindex {bag}"
            return (f"{where}: {self.problem}; recovered {self.messages} messages from its "
                    f"{what}{span}{repair}")
        if self.state == "empty":
            return f"{where}: {self.problem}; skipped"
        if self.state == "unreadable":
            return f"{where}: {self.problem}; skipped (the other files were read)"
        if self.state == "complete" and not self.listed and self.path.parent.joinpath(
                METADATA_FILE).exists():
            return (f"{where}: not listed in metadata.yaml (the file that was open when its "
                    f"writer stopped?): read it too; add it to the bag with: bag_reindex {bag}")
        return None


def topic_matches(name: str, topic: str) -> bool:
    """Whether bag topic ``name`` is ``topic``; a relative one-level ``topic``
    (``actuator_state``) also matches a namespaced name (``/ns/actuator_state``)."""
    topic = topic if topic.startswith("/") else "/" + topic
    name = name if name.startswith("/") else "/" + name
    return name == topic or (not topic[1:].count("/") and name.endswith(topic))


def _split_key(path: pathlib.Path) -> Tuple[int, str, int, str]:
    """Sort key: ``<name>_<n>.<ext>`` by n, others by name."""
    m = re.match(r"^(.*)_(\d+)$", path.stem)
    return (0, m.group(1), int(m.group(2)), path.name) if m else (1, path.stem, 0, path.name)


def _storage_files(directory: pathlib.Path) -> List[pathlib.Path]:
    """The storage files in ``directory``, in split order."""
    return sorted((p for p in directory.iterdir()
                   if p.is_file() and storage_of(p.name) is not None), key=_split_key)


class Bag:
    """A bag to read (see the module docstring for what ``path`` may be).

    Raises
    ------
    NotABagError
        No such path, or nothing in it that is a bag.
    """

    def __init__(self, path: Union[str, "os.PathLike[str]"]) -> None:
        self.path = pathlib.Path(path)
        self.notes: List[str] = []
        self.topics: Dict[str, Optional[str]] = {}
        self.missing_metadata = False
        p = self.path
        if not p.exists():
            raise NotABagError(f"{p}: no such bag (give a rosbag2 directory or an .mcap/.db3 "
                               "file)")
        self.reports: List[FileReport] = []
        if p.is_file():
            storage = storage_of(p.name)
            if storage is None:
                raise NotABagError(f"{p}: not a bag (expected an .mcap or .db3 file, or a "
                                   "rosbag2 directory)")
            self.reports.append(FileReport(p, storage, listed=False))
            self.bag_dir = p.parent
            return
        self.bag_dir = p
        if (p / METADATA_FILE).is_file():
            self._add_bag_dir(p)
        elif _storage_files(p):
            for f in _storage_files(p):
                self.reports.append(FileReport(f, _storage(f), listed=False))
            self.missing_metadata = True
        else:
            subs = sorted(d for d in p.iterdir() if d.is_dir() and (
                (d / METADATA_FILE).is_file() or _storage_files(d)))
            for d in subs:
                if (d / METADATA_FILE).is_file():
                    self._add_bag_dir(d)
                else:
                    for f in _storage_files(d):
                        self.reports.append(FileReport(f, _storage(f), listed=False))
            if not self.reports:
                raise NotABagError(f"{p}: not a bag: no {METADATA_FILE} and no .mcap/.db3 "
                                   "files in it")

    def _add_bag_dir(self, d: pathlib.Path) -> None:
        info = read_metadata(d)
        listed = []
        for name in info.get("relative_file_paths") or []:
            f = d / pathlib.PurePath(str(name)).name
            listed.append(f)
            storage = storage_of(f.name) or info.get("storage_identifier", "")
            self.reports.append(FileReport(f, storage, listed=True))
        for f in _storage_files(d):
            if f not in listed:
                self.reports.append(FileReport(f, _storage(f), listed=False))

    # --- reading ------------------------------------------------------------------------------
    def messages(self, select: Optional[Select] = None,
                 progress: Optional[Progress] = None) -> Iterator[BagMessage]:
        """Yield ``(topic, msgtype, log_time, data)`` of every message whose
        ``select(topic, msgtype)`` is true (all when None), file by file.

        After the loop (or when it is left early), :attr:`reports` says what each file gave and
        :attr:`notes` lists the lines the user must see. :attr:`topics` maps each topic seen
        to its type.
        """
        self.notes = []
        self.topics = {}
        readable = 0
        for i, rep in enumerate(self.reports):
            if not rep.path.exists():
                rep.state, rep.problem = "unreadable", "listed in metadata.yaml but missing"
                self.notes.append(rep.note(self.bag_dir))  # type: ignore[arg-type]  # a line
                continue
            if rep.path.stat().st_size == 0:
                rep.state, rep.problem = "empty", "empty file (nothing was written to it)"
                self.notes.append(rep.note(self.bag_dir))  # type: ignore[arg-type]  # a line
                continue
            try:
                if rep.storage == "mcap":
                    yield from self._mcap(rep, select)
                elif rep.storage == "sqlite3":
                    yield from self._sqlite(rep, select)
                else:
                    raise BagReadError(f"{rep.path}: unknown storage {rep.storage!r}")
                readable += 1
            except BagReadError as exc:
                if len(self.reports) == 1:
                    raise
                rep.state, rep.problem = "unreadable", str(exc).replace(f"{rep.path}: ", "")
            note = rep.note(self.bag_dir)
            if note:
                self.notes.append(note)
            if progress is not None:
                progress(f"read {rep.path.name}", (i + 1) / len(self.reports))
        if not readable:
            reasons = "; ".join(n for n in self.notes if n) or "no storage files"
            raise BagReadError(f"{self.path}: no readable file in this bag ({reasons})")
        if self.missing_metadata:
            self.notes.append(f"{self.bag_dir}: no metadata.yaml (a recorder killed before "
                              f"writing it?); write it with: bag_reindex {self.bag_dir}")

    def _mcap(self, rep: FileReport, select: Optional[Select]) -> Iterator[BagMessage]:
        with McapScan(rep.path) as scan:
            cache: Dict[int, Tuple[Optional[str], Optional[str]]] = {}

            def want(cid: int) -> bool:
                topic, msgtype = scan.topic_of(cid), scan.type_of(cid)
                cache[cid] = (topic, msgtype)
                return topic is not None and (select is None or select(topic, msgtype))

            for cid, log_time, _pub, data in scan.messages(want):
                topic, msgtype = cache[cid]
                yield topic, msgtype, log_time, data  # type: ignore[misc]  # want() had a topic
            for cid in scan.index.channels:
                t, m = scan.index.channels[cid][1], scan.type_of(cid)
                self.topics.setdefault(t, m)
            r = scan.report
            rep.messages, rep.chunks, rep.first, rep.last = r.messages, r.chunks, \
                r.first_time, r.last_time
            if r.complete:
                rep.state = "complete"
            else:
                if not r.messages:
                    raise BagReadError(f"{rep.path}: {r.problem}, and no complete chunk before "
                                       "that: nothing to recover")
                rep.state, rep.problem = "recovered", r.problem

    def _sqlite(self, rep: FileReport, select: Optional[Select]) -> Iterator[BagMessage]:
        left_open = needs_recovery(rep.path)
        with open_for_reading(rep.path) as conn:
            topics = {tid: (name, msgtype) for tid, name, msgtype in
                      conn.execute("SELECT id, name, type FROM topics")}
            for t, m in topics.values():
                self.topics.setdefault(t, m)
            ids = [tid for tid, (t, m) in topics.items() if select is None or select(t, m)]
            n, first, last = conn.execute(
                "SELECT count(*), min(timestamp), max(timestamp) FROM messages").fetchone()
            rep.messages, rep.first, rep.last = n, first, last
            if ids:
                q = ("SELECT topic_id, timestamp, data FROM messages WHERE topic_id IN ("
                     + ",".join("?" * len(ids)) + ") ORDER BY timestamp")
                for tid, ts, data in conn.execute(q, ids):
                    topic, msgtype = topics[tid]
                    yield topic, msgtype, ts, data
        rep.state = "recovered" if left_open else "complete"
        if left_open:
            rep.problem = "was not closed (its writer was killed or failed)"


# --- one channel of actuator_state ------------------------------------------------------------
@dataclass
class ChannelRecord:
    """One channel of ``actuator_state``, sorted by cycle (duplicates removed).

    Arrays ``x, v, f_p, f_a, x_e, f_e`` [rad, rad/s, N m] as published (NaN kept; see
    :meth:`seaforce_ros.identification.timeseries.prepare`), ``cycle`` (uint64 as int64),
    ``stamp`` [s] (header stamps), ``status``. ``sources``: the files that were read;
    ``notes``: what the reader recovered or skipped (print them).
    """

    channel: str
    channels: List[str]
    cycle: npt.NDArray[np.int64]
    stamp: npt.NDArray[np.float64]
    x: npt.NDArray[np.float64]
    v: npt.NDArray[np.float64]
    f_p: npt.NDArray[np.float64]
    f_a: npt.NDArray[np.float64]
    x_e: npt.NDArray[np.float64]
    f_e: npt.NDArray[np.float64]
    status: npt.NDArray[np.uint8]
    sources: List[str] = field(default_factory=list)
    notes: List[str] = field(default_factory=list)
    duplicates: int = 0

    def __len__(self) -> int:
        return int(self.cycle.size)


def _storage(path: pathlib.Path) -> str:
    """The storage of a file :func:`_storage_files` found (so it has one)."""
    return cast(str, storage_of(path.name))


def _names(data: bytes) -> List[str]:
    try:
        return StateLayout(data).names
    except ValueError:
        msg: Any = typestore().deserialize_cdr(data, ACTUATOR_STATE)  # a generated class
        return list(msg.name)


def _unknown_channel(channel: str, names: List[str]) -> BagContentError:
    return BagContentError(
        f"unknown channel {channel!r}: the bag's actuator_state has channels "
        f"{', '.join(names) or '(none)'}; pass one of them with --channel")


def _decode(raws: List[bytes], channel: str) -> Tuple[Dict[str, npt.NDArray[Any]], List[str]]:
    """Decode raw ActuatorState messages for one channel -> dict of arrays + names."""
    store = typestore()
    layout: Optional[StateLayout]
    try:
        layout = StateLayout(raws[0])
    except ValueError:   # unexpected layout: decode every message generically
        layout = None
    names = layout.names if layout is not None else _names(raws[0])
    if channel not in names:
        raise _unknown_channel(channel, names)
    j = names.index(channel)
    n = len(raws)
    if layout is None:
        layout = state_template(names)
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
    out: Dict[str, npt.NDArray[Any]] = {
        "cycle": layout.column(rows, layout.cycle, "<u8").astype(np.int64),
        "stamp": (layout.column(rows, layout.sec, "<i4").astype(float)
                  + 1e-9 * layout.column(rows, layout.nanosec, "<u4"))}
    for msg_field, short in STATE_FIELDS:
        out[short] = layout.column(rows, layout.arrays[msg_field] + 8 * j, "<f8")
    out["status"] = rows[:, layout.status + j].copy()
    if slow:
        extra: Dict[str, List[float]] = {k: [] for k in out}
        for i in slow:
            msg: Any = store.deserialize_cdr(raws[i], ACTUATOR_STATE)  # a generated class
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


def read_channel(path: Union[str, "os.PathLike[str]"], channel: str, topic: str = "actuator_state",
                 progress: Optional[Progress] = None) -> ChannelRecord:
    """Load ``channel`` of ``topic`` (``seaforce_msgs/ActuatorState``) from a bag.

    Parameters
    ----------
    path : str or Path
        Bag directory, storage file or directory of bags (:class:`Bag`).
    channel : str
        Channel name (an entry of ``ActuatorState.name``).
    topic : str
        Topic name; a relative name also matches a namespaced one (``/ns/actuator_state``).
    progress : callable(str, float), optional
        Called with a message and the fraction done.

    Raises
    ------
    NotABagError, BagReadError
        No such bag, nothing readable in it.
    BagContentError
        No ``actuator_state`` in the bag, unknown channel.
    """
    bag = Bag(path)

    def select(name: str, msgtype: Optional[str]) -> bool:
        return msgtype == ACTUATOR_STATE and topic_matches(name, topic)

    raws: List[bytes] = []
    for _t, _m, _ts, data in bag.messages(select, progress):
        if not raws:
            names = _names(data)
            if channel not in names:
                raise _unknown_channel(channel, names)
        raws.append(data)
    if not raws:
        topics = ", ".join(sorted(bag.topics)) or "none"
        raise BagContentError(
            f"{path}: no {topic} messages of type {ACTUATOR_STATE} (topics in the bag: "
            f"{topics}). Record the actuator_state topic of sim_node or hardware_node.")
    arrays, names = _decode(raws, channel)
    order = np.argsort(arrays["cycle"], kind="stable")
    cyc = arrays["cycle"][order]
    keep = np.ones(cyc.size, bool)
    keep[1:] = cyc[1:] != cyc[:-1]
    sel = order[keep]
    return ChannelRecord(channel=channel, channels=names,
                         **{k: v[sel] for k, v in arrays.items()},
                         sources=[str(r.path) for r in bag.reports
                                  if r.state in ("complete", "recovered")],
                         notes=list(bag.notes), duplicates=int(cyc.size - keep.sum()))
