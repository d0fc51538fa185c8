"""Write one rosbag2 bag directory as ``ros2 bag record`` does, kept valid after every split.

Layout: ``<directory>/metadata.yaml`` and the storage files ``<name>_0.mcap``, ``<name>_1.mcap``,
... (``.db3`` for sqlite3), ``<name>`` being the directory's name. A new file is started when a
message's log time is ``split_duration`` past the first message of the open file.
``metadata.yaml`` (Jazzy, version 9) is written when the bag opens (no files yet) and replaced
atomically each time a file is closed, listing the closed files only: after a SIGKILL the
directory is one valid bag of every closed file, and the file that was open is left beside
them (its complete chunks or committed batches are readable; ``bag_reindex`` adds it).

Durability of the open file: mcap chunks are written whole (:class:`~.mcapfile.McapWriter`)
when they reach ``chunk_size`` bytes or when :meth:`BagWriter.flush` finds the open chunk older
than ``chunk_period`` (the recorder calls it after each batch); sqlite3 commits each batch.

A write failure (disk full, a file-size limit) raises :class:`~.errors.BagWriteError` after
saving what can be saved: the open mcap file is cut back to its last complete chunk and, if
there is room, given its summary and listed in ``metadata.yaml``; an sqlite3 file keeps its
committed batches. The writer then refuses further writes.
"""
from __future__ import annotations

import errno
import os
import pathlib
import sqlite3
from dataclasses import dataclass, field
from typing import (Any, Callable, Dict, Iterable, List, Mapping, Optional, Sequence, TypeVar,
                    Union)

from . import mcapfile
from .errors import BagUsageError, BagWriteError
from .metadata import (ROS_DISTRO, VERSION, BagMetadata, FileInfo, QosProfile, TopicInfo,
                       qos_list_yaml, write_metadata)
from .sqlitefile import Sqlite3Writer
from .states import ACTUATOR_STATE, Samples, serialize_states
from .typestore import message_definition, type_hash

__all__ = ["BagWriter", "STORAGES", "write_state_bag", "check_output_directory"]

#: storage id -> file extension
STORAGES = {"mcap": ".mcap", "sqlite3": ".db3"}
#: default longest time a message waits in the open mcap chunk [s]
CHUNK_PERIOD = 0.5

_Path = Union[str, "os.PathLike[str]"]
_T = TypeVar("_T")


def _library() -> str:
    try:
        from importlib.metadata import version
        return f"seaforce_ros {version('seaforce_ros')}"
    except Exception:
        return "seaforce_ros"


def check_output_directory(directory: _Path) -> None:
    """A bag directory must be new or empty, and creatable: :class:`BagUsageError` naming the
    path otherwise."""
    path = pathlib.Path(directory)
    if path.exists() and not path.is_dir():
        raise BagUsageError(f"{path} exists and is not a directory; give a new directory for "
                            "the bag")
    if path.is_dir() and any(path.iterdir()):
        raise BagUsageError(f"{path} exists and is not empty; give a new or empty directory")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise BagUsageError(f"cannot create {path}: {parent} is not a directory")


@dataclass
class _Topic:
    info: TopicInfo
    written: int = 0          # committed, all files


@dataclass
class _OpenFile:
    path: pathlib.Path
    # McapWriter or Sqlite3Writer, as BagWriter.storage says (the methods differ: the writer
    # calls them by its storage name, not by type, on the per-message path)
    storage: Any
    ids: Dict[str, int] = field(default_factory=dict)    # topic -> channel / topic id
    topics: Dict[int, str] = field(default_factory=dict)
    counts: Dict[str, int] = field(default_factory=dict)  # committed in this file
    first: Optional[int] = None                           # log time of the first message
    start: Optional[int] = None                           # committed min / max log time
    end: Optional[int] = None


class BagWriter:
    """One rosbag2 bag directory, split into files by time.

    Parameters
    ----------
    directory : path
        Created; must be new or empty.
    storage : 'mcap' or 'sqlite3'
    split_duration : float > 0 or None
        Seconds of log time per file (None: one file).
    chunk_size : int > 0
        mcap: bytes per chunk at most (rosbag2's default 768 KiB).
    chunk_period : float > 0
        mcap: :meth:`flush` writes the open chunk once its first message is this old [s].
    custom_data : dict str -> str, optional
        ``custom_data`` of the metadata.

    Attributes
    ----------
    written : dict topic -> int
        Messages on disk (complete chunks, committed batches), over all files.
    files : list of FileInfo
        Closed files.
    """

    def __init__(self, directory: _Path, storage: str = "mcap",
                 split_duration: Optional[float] = None, chunk_size: Optional[int] = None,
                 chunk_period: float = CHUNK_PERIOD,
                 custom_data: Optional[Mapping[str, str]] = None) -> None:
        if storage not in STORAGES:
            raise BagUsageError(f"storage must be mcap or sqlite3, not {storage!r}")
        if split_duration is not None and not split_duration > 0:
            raise BagUsageError(f"split_duration must be > 0 s, not {split_duration!r}")
        if not chunk_period > 0:
            raise BagUsageError(f"chunk_period must be > 0 s, not {chunk_period!r}")
        self.directory = pathlib.Path(directory)
        check_output_directory(self.directory)
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BagUsageError(f"cannot create {self.directory}: {exc.strerror}") from None
        self.storage = storage
        self.name = self.directory.name
        self.split_ns = None if split_duration is None else int(round(split_duration * 1e9))
        self.chunk_size = int(chunk_size or mcapfile.DEFAULT_CHUNK_SIZE)
        self.chunk_period_ns = int(round(chunk_period * 1e9))
        self.custom_data = dict(custom_data or {})
        self._topics: Dict[str, _Topic] = {}
        self.files: List[FileInfo] = []
        self._per_file_topics: List[Dict[str, int]] = []
        self._open: Optional[_OpenFile] = None
        self.failed: Optional[BagWriteError] = None
        self._closed = False
        try:
            write_metadata(self.directory, self.metadata())
        except OSError as exc:
            raise BagUsageError(f"cannot write {self.directory / 'metadata.yaml'}: "
                                f"{exc.strerror}") from None

    # --- bookkeeping ------------------------------------------------------------------------
    @property
    def written(self) -> Dict[str, int]:
        """Messages on disk per topic, over all files."""
        return {t: v.written for t, v in self._topics.items()}

    @property
    def current(self) -> Optional[pathlib.Path]:
        """Path of the open file (None between files)."""
        return None if self._open is None else self._open.path

    def metadata(self, extra: Optional[FileInfo] = None,
                 extra_counts: Optional[Dict[str, int]] = None) -> BagMetadata:
        """BagMetadata of the closed files (plus ``extra``, a file being closed)."""
        files = list(self.files) + ([extra] if extra is not None else [])
        per: List[Dict[str, int]] = list(self._per_file_topics) + (
            [extra_counts] if extra is not None else [])  # type: ignore[list-item]  # with extra
        topics: List[TopicInfo] = []
        for name, t in self._topics.items():
            info = TopicInfo(**{**t.info.__dict__})
            info.message_count = sum(c.get(name, 0) for c in per)
            topics.append(info)
        return BagMetadata(self.storage, files, topics, self.custom_data)

    def add_topic(self, topic: str, msgtype: str, offered_qos: Iterable[QosProfile] = (),
                  type_description_hash: Optional[str] = None) -> None:
        """Register a topic (in the open file too). ``type_description_hash`` defaults to the
        RIHS01 hash of the type's definition; ``offered_qos`` is a list of QosProfile."""
        if topic in self._topics:
            return
        info = TopicInfo(topic, msgtype, type_description_hash or type_hash(msgtype),
                         list(offered_qos))
        self._topics[topic] = _Topic(info)
        if self._open is not None:
            self._guard(lambda: self._register(self._open, info))  # type: ignore[arg-type]

    # --- files --------------------------------------------------------------------------------
    def _register(self, f: _OpenFile, info: TopicInfo) -> None:
        encoding, text = message_definition(info.type)
        qos = qos_list_yaml(info.offered_qos_profiles)
        if self.storage == "mcap":
            st: mcapfile.McapWriter = f.storage
            sid = next((i for i, s in st.index.schemas.items() if s[0] == info.type), None)
            if sid is None:
                sid = st.add_schema(info.type, encoding, text)
            cid = st.add_channel(info.name, sid, info.serialization_format,
                                 {"offered_qos_profiles": qos,
                                  "topic_type_hash": info.type_description_hash})
        else:
            cid = f.storage.add_topic(info.name, info.type, info.serialization_format, qos,
                                      info.type_description_hash, encoding, text)
        f.ids[info.name] = cid
        f.topics[cid] = info.name

    def _open_file(self) -> None:
        path = self.directory / f"{self.name}_{len(self.files)}{STORAGES[self.storage]}"
        storage: Union[mcapfile.McapWriter, Sqlite3Writer]
        if self.storage == "mcap":
            storage = mcapfile.McapWriter(path, _library(), self.chunk_size)
        else:
            storage = Sqlite3Writer(path, ROS_DISTRO)
        f = _OpenFile(path, storage)
        self._open = f
        for t in self._topics.values():
            self._register(f, t.info)

    def _commit(self, f: _OpenFile, counts: Mapping[int, int]) -> None:
        for cid, n in counts.items():
            topic = f.topics[cid]
            f.counts[topic] = f.counts.get(topic, 0) + n
            self._topics[topic].written += n

    def _file_info(self, f: _OpenFile) -> FileInfo:
        st = f.storage
        if self.storage == "mcap":
            start, end = st.index.start_time, st.index.end_time
        else:
            start, end = st.start_time, st.end_time
        n = sum(f.counts.values())
        return FileInfo(f.path.name, start or 0, (end - start) if n else 0, n)

    def _close_file(self) -> None:
        f: _OpenFile = self._open  # type: ignore[assignment]  # called with a file open
        if self.storage == "mcap":
            self._commit(f, f.storage.flush())
        else:
            self._commit(f, f.storage.flush())
        info = self._file_info(f)
        meta = self.metadata(info, dict(f.counts))
        if self.storage == "mcap":
            f.storage.close([("rosbag2", {"serialized_metadata": meta.dump()})])
        else:
            f.storage.close(VERSION, meta.dump())
        self.files.append(info)
        self._per_file_topics.append(dict(f.counts))
        self._open = None
        write_metadata(self.directory, self.metadata())

    # --- writing --------------------------------------------------------------------------------
    def write(self, topic: str, log_time: int, data: bytes,
              publish_time: Optional[int] = None) -> None:
        """Write one serialised message (``log_time``, ``publish_time`` in ns since epoch;
        ``publish_time`` defaults to ``log_time``)."""
        if self.failed is not None:
            raise self.failed
        # None until the first message: _roll opens a file then (or raises)
        f: _OpenFile = self._open  # type: ignore[assignment]
        if f is None or (self.split_ns is not None and f.first is not None
                         and log_time - f.first >= self.split_ns):
            self._guard(self._roll)
            f = self._open  # type: ignore[assignment]
        if f.first is None:
            f.first = log_time
        cid = f.ids[topic]
        if self.storage == "mcap":
            counts = self._guard(lambda: f.storage.write(
                cid, log_time, log_time if publish_time is None else publish_time, data))
            if counts:
                self._commit(f, counts)
        else:
            f.storage.write(cid, log_time, data)

    def _roll(self) -> None:
        if self._open is not None:
            self._close_file()
        self._open_file()

    def flush(self, now: Optional[int] = None) -> None:
        """End of a write batch: sqlite3 commits it; mcap writes the open chunk when its first
        message is ``chunk_period`` older than ``now`` [ns] (always when ``now`` is None)."""
        if self.failed is not None:
            raise self.failed
        f = self._open
        if f is None:
            return
        st = f.storage
        if self.storage == "mcap":
            t0 = st.chunk_start_time
            if t0 is None or (now is not None and now - t0 < self.chunk_period_ns):
                return
        self._commit(f, self._guard(st.flush))

    def close(self) -> BagMetadata:
        """Write everything, close the open file, write ``metadata.yaml``. Idempotent.
        Returns the final BagMetadata."""
        if self.failed is not None:
            raise self.failed
        if not self._closed:
            if self._open is not None:
                self._guard(self._close_file)
            self._closed = True
        return self.metadata()

    # --- failures --------------------------------------------------------------------------------
    def _guard(self, action: Callable[[], _T]) -> _T:
        try:
            return action()
        except (OSError, sqlite3.Error) as exc:
            raise self._fail(exc) from None

    def _fail(self, exc: BaseException) -> BagWriteError:
        """Save what can be saved after a failed write; returns the BagWriteError to raise."""
        f = self._open
        lost: Dict[str, int] = {}
        kept = ""
        if f is not None:
            ids = f.topics
            raw_lost = f.storage.abandon()
            lost = {ids[c]: n for c, n in raw_lost.items()}
            info = self._file_info(f)
            if self.storage == "mcap":
                meta = self.metadata(info, dict(f.counts))
                try:
                    mcapfile.reindex(f.path, [("rosbag2", {"serialized_metadata": meta.dump()})])
                    self.files.append(info)
                    self._per_file_topics.append(dict(f.counts))
                    kept = (f"{f.path.name} keeps its {info.message_count} messages "
                            "(complete chunks) with its summary")
                except (OSError, Exception):
                    kept = (f"{f.path.name} keeps its {info.message_count} messages in "
                            f"complete chunks but has no summary: run bag_reindex "
                            f"{self.directory} once there is room")
            else:
                kept = (f"{f.path.name} keeps its {info.message_count} committed messages "
                        f"(run bag_reindex {self.directory} once there is room)")
            self._open = None
        try:
            write_metadata(self.directory, self.metadata())
        except OSError:
            kept += "; metadata.yaml could not be rewritten (it lists the files closed before)"
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        if getattr(exc, "sqlite_errorname", None):
            reason += f" ({exc.sqlite_errorname})"  # type: ignore[attr-defined]
        code = errno.errorcode.get(getattr(exc, "errno", None) or -1, "")
        n_closed = len(self.files)
        msg = (f"writing the bag {self.directory} failed: {reason}"
               + (f" ({code})" if code else "")
               + f"; {n_closed} file(s) listed in metadata.yaml"
               + (f"; {kept}" if kept else "")
               + (f"; lost {sum(lost.values())} messages not yet on disk" if lost else ""))
        self.failed = BagWriteError(msg, lost)
        return self.failed


def write_state_bag(path: _Path, channels: Sequence[str],
                    data: Mapping[str, Mapping[str, Samples]], dt: float = 5e-4,
                    storage: str = "mcap", split_duration: Optional[float] = None,
                    topic: str = "/actuator_state", cycle0: int = 0,
                    t0: float = 0.0) -> BagMetadata:
    """Write sampled channel data as ``actuator_state`` messages into one bag directory.

    Parameters as :func:`~seaforce_ros.bags.states.serialize_states`; ``split_duration`` [s]
    splits the bag into files. Returns the bag's :class:`BagMetadata`.
    """
    rows, stamps = serialize_states(channels, data, cycle0=cycle0, dt=dt, t0=t0)
    writer = BagWriter(path, storage=storage, split_duration=split_duration)
    writer.add_topic(topic, ACTUATOR_STATE)
    batch = 20000
    for i in range(rows.shape[0]):
        stamp = int(stamps[i])
        writer.write(topic, stamp, rows[i].tobytes(), stamp)
        if (i + 1) % batch == 0:
            writer.flush(None if storage == "sqlite3" else stamp)
    return writer.close()
