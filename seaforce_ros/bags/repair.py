"""Make a bag that a kill or a full disk left incomplete readable by every tool.

Like ``ros2 bag reindex``, for the two ways this package's (and rosbag2's) recordings end up
incomplete:

* an mcap file without summary (its writer was killed, or the disk filled): cut back to its
  last complete chunk (rebuilding that chunk's message indexes when they were cut off), then
  given its ``rosbag2`` metadata record, DataEnd, summary (schemas, channels, statistics, chunk
  and metadata indexes, summary offsets) and footer -- after which the ``mcap`` library's
  default reader, rosbags and rosbag2 open it;
* an sqlite3 file left with its WAL (or journal): SQLite recovers the committed transactions in
  place and the file becomes one self-contained ``.db3``;

and then writes the bag's ``metadata.yaml`` (atomically) listing every readable file in split
order, with topics, QoS, type hashes, counts and times taken from the files. Files that are
complete are not changed. An empty file (a split that never got a message) or one with nothing
recoverable is left where it is, out of the metadata, and named in the output.
"""
from __future__ import annotations

import pathlib
from dataclasses import dataclass, field
import os
from typing import Dict, List, Mapping, Optional, Tuple, Union

from . import mcapfile
from .errors import BagError, BagReadError, NotABagError
from .metadata import (METADATA_FILE, VERSION, BagMetadata, FileInfo, TopicInfo,
                       qos_list_from_yaml, read_metadata, storage_of, write_metadata)
from .reader import _storage_files
from .sqlitefile import finish_in_place, needs_recovery, open_for_reading

__all__ = ["reindex_bag", "RepairReport"]


@dataclass
class _FileScan:
    path: pathlib.Path
    storage: str
    info: Optional[FileInfo] = None
    topics: Dict[str, TopicInfo] = field(default_factory=dict)
    incomplete: Optional[str] = None        # why the file needs repair
    skipped: Optional[str] = None           # why it is left out


@dataclass
class RepairReport:
    """What :func:`reindex_bag` did: ``lines`` to print, ``metadata`` written, the files
    ``repaired`` and ``skipped`` (path -> reason)."""

    metadata: BagMetadata
    lines: List[str] = field(default_factory=list)
    repaired: Dict[str, str] = field(default_factory=dict)
    skipped: Dict[str, str] = field(default_factory=dict)


def _files(directory: pathlib.Path) -> Tuple[List[pathlib.Path], Optional[str]]:
    """The bag's files (those metadata.yaml lists first) and the storage it names."""
    listed: List[pathlib.Path] = []
    storage = None
    if (directory / METADATA_FILE).is_file():
        try:
            info = read_metadata(directory)
            storage = info.get("storage_identifier")
            listed = [directory / pathlib.PurePath(str(n)).name
                      for n in info.get("relative_file_paths") or []]
        except NotABagError:
            listed = []          # a damaged metadata.yaml is rebuilt from the files
    out = [p for p in listed if p.exists()]
    out += [p for p in _storage_files(directory) if p not in out]
    return out, storage


def _scan_mcap(path: pathlib.Path) -> _FileScan:
    fs = _FileScan(path, "mcap")
    with mcapfile.McapScan(path) as scan:
        for _ in scan.messages(want=lambda cid: False):
            pass
        rep, index = scan.report, scan.index
        if not rep.complete:
            if not rep.messages:
                raise BagReadError(f"{rep.problem}, with no complete chunk before it")
            fs.incomplete = rep.problem
        counts = index.channel_counts()
        for cid, (sid, topic, encoding, meta) in index.channels.items():
            schema = index.schemas.get(sid)
            if schema is None:
                continue
            t = fs.topics.setdefault(topic, TopicInfo(
                topic, schema[0], meta.get("topic_type_hash", ""),
                qos_list_from_yaml(meta.get("offered_qos_profiles", "")), encoding or "cdr"))
            t.message_count += counts.get(cid, 0)
        n = sum(counts.values())
        start = index.start_time or 0
        # a file with messages has their time range
        fs.info = FileInfo(path.name, start,
                           (index.end_time - start) if n else 0, n)  # type: ignore[operator]
    return fs


def _scan_sqlite(path: pathlib.Path) -> _FileScan:
    fs = _FileScan(path, "sqlite3")
    if needs_recovery(path):
        fs.incomplete = "was not closed (WAL or journal left beside it)"
    with open_for_reading(path) as conn:
        cols = {r[1] for r in conn.execute("PRAGMA table_info(topics)")}
        qos_col = "offered_qos_profiles" if "offered_qos_profiles" in cols else "''"
        hash_col = "type_description_hash" if "type_description_hash" in cols else "''"
        counts = dict(conn.execute("SELECT topic_id, count(*) FROM messages GROUP BY topic_id"))
        for tid, name, msgtype, fmt, qos, digest in conn.execute(
                f"SELECT id, name, type, serialization_format, {qos_col}, {hash_col} "
                "FROM topics ORDER BY id"):
            t = fs.topics.setdefault(name, TopicInfo(name, msgtype, digest or "",
                                                     qos_list_from_yaml(qos), fmt or "cdr"))
            t.message_count += counts.get(tid, 0)
        n, lo, hi = conn.execute(
            "SELECT count(*), min(timestamp), max(timestamp) FROM messages").fetchone()
        fs.info = FileInfo(path.name, lo or 0, (hi - lo) if n else 0, n)
    return fs


def reindex_bag(path: Union[str, "os.PathLike[str]"],
                custom_data: Optional[Mapping[str, str]] = None) -> RepairReport:
    """Repair the bag directory ``path`` in place (see the module docstring).

    Raises
    ------
    NotABagError
        ``path`` is no directory, or holds no .mcap/.db3 file.
    BagError
        The files are of mixed storage, or none of them is readable.
    """
    directory = pathlib.Path(path)
    if not directory.is_dir():
        raise NotABagError(f"{directory}: not a bag directory" + (
            " (give the directory that holds the .mcap/.db3 files)" if directory.exists()
            else " (no such directory)"))
    files, storage = _files(directory)
    if not files:
        raise NotABagError(f"{directory}: not a bag: no .mcap or .db3 files in it")
    kinds = {storage_of(p.name) for p in files}
    if len(kinds) > 1:
        raise BagError(f"{directory}: holds both .mcap and .db3 files; a bag has one storage "
                       "format (move one kind elsewhere)")
    storage = kinds.pop()
    scans: List[_FileScan] = []
    # (a file of no storage is not readable: the loop below skips it, and raises if none is)
    report = RepairReport(BagMetadata(storage))  # type: ignore[arg-type]
    for p in files:
        if p.stat().st_size == 0:
            report.skipped[str(p)] = "empty file (a split that never got a message)"
            continue
        try:
            scans.append(_scan_mcap(p) if storage == "mcap" else _scan_sqlite(p))
        except BagReadError as exc:
            report.skipped[str(p)] = str(exc).replace(f"{p}: ", "")
    if not scans:
        reasons = "; ".join(f"{pathlib.Path(k).name}: {v}" for k, v in report.skipped.items())
        raise BagReadError(f"{directory}: no readable file ({reasons})")
    # the bag's metadata from what the files hold
    topics: Dict[str, TopicInfo] = {}
    for fs in scans:
        for name, t in fs.topics.items():
            if name in topics:
                topics[name].message_count += t.message_count
            else:
                topics[name] = TopicInfo(**{**t.__dict__})
    old_custom: Dict[str, str] = {}
    try:
        old_custom = read_metadata(directory).get("custom_data") or {}
    except NotABagError:
        pass
    meta = BagMetadata(storage,  # type: ignore[arg-type]  # (see above)
                       [fs.info for fs in scans],  # type: ignore[misc]  # every scan sets it
                       list(topics.values()), dict(custom_data or old_custom))
    serialized = meta.dump()
    for fs in scans:
        if fs.incomplete is None:
            continue
        if storage == "mcap":
            mcapfile.reindex(fs.path, [("rosbag2", {"serialized_metadata": serialized})])
        else:
            finish_in_place(fs.path, VERSION, serialized)
        report.repaired[str(fs.path)] = fs.incomplete
    write_metadata(directory, meta)
    report.metadata = meta
    for fs in scans:
        i: FileInfo = fs.info  # type: ignore[assignment]  # every scan sets it
        span = f", {i.duration * 1e-9:.2f} s" if i.message_count else ""
        if fs.incomplete:
            what = ("summary written" if storage == "mcap" else "committed batches recovered")
            report.lines.append(f"{fs.path.name}: {fs.incomplete}: kept {i.message_count} "
                                f"messages{span}; {what}")
        else:
            report.lines.append(f"{fs.path.name}: complete, {i.message_count} messages{span}")
    for skipped, why in report.skipped.items():
        report.lines.append(f"{pathlib.Path(skipped).name}: left out: {why}")
    report.lines.append(f"{directory / METADATA_FILE}: {len(meta.files)} files, "
                        f"{meta.message_count} messages, {meta.duration * 1e-9:.2f} s, "
                        f"topics " + ", ".join(f"{t.name} ({t.message_count})"
                                               for t in meta.topics))
    return report
