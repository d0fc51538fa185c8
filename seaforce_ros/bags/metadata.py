"""``metadata.yaml`` of a rosbag2 bag, as ROS 2 Jazzy writes it (version 9).

The layout follows rosbag2_storage's YAML encoding of ``BagMetadata`` in Jazzy: the mapping
``rosbag2_bagfile_information`` with ``version``, ``storage_identifier``, ``duration``,
``starting_time``, ``message_count``, ``topics_with_message_count`` (each ``topic_metadata``:
``name``, ``type``, ``serialization_format``, ``offered_qos_profiles`` -- from version 9 a YAML
list of QoS mappings with policy names as strings -- and ``type_description_hash``; and its
``message_count``), ``compression_format``, ``compression_mode``, ``relative_file_paths``
(file names in the bag directory), ``files`` (per file ``path``, ``starting_time``,
``duration``, ``message_count``), ``custom_data`` and ``ros_distro``.

:func:`write_metadata` replaces the file atomically (temporary file + rename), so a reader never
sees half a file and a process killed while writing leaves the previous version.
"""
from __future__ import annotations

import os
import pathlib
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple, Union

import yaml

from .errors import NotABagError

__all__ = ["VERSION", "ROS_DISTRO", "QosProfile", "TopicInfo", "FileInfo", "BagMetadata",
           "write_metadata", "read_metadata", "qos_list_yaml"]

VERSION = 9
ROS_DISTRO = "jazzy"
METADATA_FILE = "metadata.yaml"
#: RMW_DURATION_INFINITE as rmw_time_t (what the graph reports for "no deadline")
INFINITE = (9223372036, 854775807)

#: A path as the functions here take it.
PathLike = Union[str, "os.PathLike[str]"]


@dataclass(frozen=True)
class QosProfile:
    """One offered QoS profile as rosbag2 stores it (``rmw_qos_profile_t``).

    Policies are the rmw names (``keep_last``, ``reliable``, ``volatile``, ``automatic``,
    ``unknown``, ...); durations are ``(sec, nsec)``. The graph reports a publisher's history as
    ``unknown`` with depth 0 (DDS does not announce it); rosbag2 stores it so.
    """

    history: str = "unknown"
    depth: int = 0
    reliability: str = "reliable"
    durability: str = "volatile"
    deadline: Tuple[int, int] = INFINITE
    lifespan: Tuple[int, int] = INFINITE
    liveliness: str = "automatic"
    liveliness_lease_duration: Tuple[int, int] = INFINITE
    avoid_ros_namespace_conventions: bool = False

    def to_dict(self) -> Dict[str, Any]:
        """The stored mapping (version 9 names)."""
        def t(v: Tuple[int, int]) -> Dict[str, int]:
            return {"sec": int(v[0]), "nsec": int(v[1])}
        return {"history": self.history, "depth": int(self.depth),
                "reliability": self.reliability, "durability": self.durability,
                "deadline": t(self.deadline), "lifespan": t(self.lifespan),
                "liveliness": self.liveliness,
                "liveliness_lease_duration": t(self.liveliness_lease_duration),
                "avoid_ros_namespace_conventions": bool(self.avoid_ros_namespace_conventions)}


_POLICIES = {
    "history": ("system_default", "keep_last", "keep_all", "unknown"),
    "reliability": ("system_default", "reliable", "best_effort", "unknown", "best_available"),
    "durability": ("system_default", "transient_local", "volatile", "unknown",
                   "best_available"),
    "liveliness": ("system_default", "automatic", "manual_by_node", "manual_by_topic", "unknown",
                   "best_available"),
}


def qos_from_dict(d: Mapping[str, Any]) -> QosProfile:
    """A QosProfile from a stored mapping (version 9 names or version 8 numbers)."""
    def policy(key: str) -> str:
        v = d.get(key, "unknown")
        if isinstance(v, int):
            names = _POLICIES[key]
            return names[v] if 0 <= v < len(names) else "unknown"
        return str(v)

    def t(key: str) -> Tuple[int, int]:
        v = d.get(key) or {}
        return (int(v.get("sec", INFINITE[0])), int(v.get("nsec", INFINITE[1])))

    return QosProfile(policy("history"), int(d.get("depth", 0)), policy("reliability"),
                      policy("durability"), t("deadline"), t("lifespan"), policy("liveliness"),
                      t("liveliness_lease_duration"),
                      bool(d.get("avoid_ros_namespace_conventions", False)))


def qos_list_from_yaml(text: Optional[str]) -> List[QosProfile]:
    """Offered QoS profiles from their stored YAML text (empty or unreadable: [])."""
    if not text:
        return []
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError:
        return []
    return [qos_from_dict(d) for d in data if isinstance(d, dict)] if isinstance(
        data, list) else []


def qos_list_yaml(profiles: Iterable[QosProfile]) -> str:
    """The offered QoS profiles as one YAML text (what rosbag2 puts into the mcap channel's
    ``offered_qos_profiles`` entry and the sqlite3 ``topics`` table); ``[]`` for none."""
    return _dump([p.to_dict() for p in profiles]).strip()


@dataclass
class TopicInfo:
    """One topic of a bag (``topic_metadata`` + ``message_count``)."""

    name: str
    type: str
    type_description_hash: str
    offered_qos_profiles: List[QosProfile] = field(default_factory=list)
    serialization_format: str = "cdr"
    message_count: int = 0

    def to_dict(self) -> Dict[str, Any]:
        """The ``topics_with_message_count`` entry."""
        return {"topic_metadata": {
                    "name": self.name, "type": self.type,
                    "serialization_format": self.serialization_format,
                    "offered_qos_profiles": [q.to_dict() for q in self.offered_qos_profiles],
                    "type_description_hash": self.type_description_hash},
                "message_count": int(self.message_count)}


@dataclass
class FileInfo:
    """One storage file of a bag: name in the bag directory, first message [ns since epoch],
    duration [ns] (last - first message), message count."""

    path: str
    starting_time: int
    duration: int
    message_count: int

    def to_dict(self) -> Dict[str, Any]:
        """The ``files`` entry."""
        return {"path": self.path,
                "starting_time": {"nanoseconds_since_epoch": int(self.starting_time)},
                "duration": {"nanoseconds": int(self.duration)},
                "message_count": int(self.message_count)}


@dataclass
class BagMetadata:
    """Everything ``metadata.yaml`` says about a bag.

    ``topics`` carry the message counts summed over ``files``; ``starting_time`` and
    ``duration`` span all files (a bag without messages has both 0).
    """

    storage_identifier: str
    files: List[FileInfo] = field(default_factory=list)
    topics: List[TopicInfo] = field(default_factory=list)
    custom_data: Dict[str, str] = field(default_factory=dict)
    ros_distro: str = ROS_DISTRO
    version: int = VERSION

    @property
    def message_count(self) -> int:
        """Messages in all files."""
        return sum(f.message_count for f in self.files)

    @property
    def starting_time(self) -> int:
        """First message of any file [ns since epoch] (0 without messages)."""
        starts = [f.starting_time for f in self.files if f.message_count]
        return min(starts) if starts else 0

    @property
    def duration(self) -> int:
        """First to last message over all files [ns] (0 without messages)."""
        ends = [f.starting_time + f.duration for f in self.files if f.message_count]
        return max(ends) - self.starting_time if ends else 0

    def to_dict(self) -> Dict[str, Any]:
        """The ``rosbag2_bagfile_information`` mapping, in Jazzy's key order."""
        return {"version": self.version,
                "storage_identifier": self.storage_identifier,
                "duration": {"nanoseconds": int(self.duration)},
                "starting_time": {"nanoseconds_since_epoch": int(self.starting_time)},
                "message_count": int(self.message_count),
                "topics_with_message_count": [t.to_dict() for t in self.topics],
                "compression_format": "",
                "compression_mode": "",
                "relative_file_paths": [f.path for f in self.files],
                "files": [f.to_dict() for f in self.files],
                "custom_data": dict(self.custom_data) or None,
                "ros_distro": self.ros_distro}

    def dump(self) -> str:
        """The bag-level YAML (what rosbag2 stores inside each storage file too)."""
        return _dump(self.to_dict())

    def text(self) -> str:
        """The whole ``metadata.yaml`` text."""
        return _dump({"rosbag2_bagfile_information": self.to_dict()})


def _dump(data: Any) -> str:
    return yaml.safe_dump(data, sort_keys=False, default_flow_style=False, allow_unicode=True)


def write_metadata(directory: PathLike, metadata: BagMetadata) -> None:
    """Replace ``<directory>/metadata.yaml`` atomically with ``metadata`` (BagMetadata).

    Raises OSError when the file cannot be written; the previous file is then unchanged."""
    directory = pathlib.Path(directory)
    target = directory / METADATA_FILE
    tmp = directory / (METADATA_FILE + ".tmp")
    data = metadata.text().encode()
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
        os.replace(tmp, target)
    except BaseException:
        try:
            tmp.unlink()
        except OSError:
            pass
        raise


def read_metadata(directory: PathLike) -> Dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of ``<directory>/metadata.yaml``.

    Raises
    ------
    NotABagError
        No such file, not YAML, or not a rosbag2 metadata file.
    """
    path = pathlib.Path(directory) / METADATA_FILE
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise NotABagError(f"{path.parent}: no {METADATA_FILE}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise NotABagError(f"{path}: cannot read ({exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise NotABagError(f"{path}: not YAML ({str(exc).splitlines()[0]}); a damaged bag "
                           f"can be repaired with: bag_reindex {path.parent}") from None
    info = data.get("rosbag2_bagfile_information") if isinstance(data, dict) else None
    if not isinstance(info, dict) or not isinstance(info.get("relative_file_paths"), list):
        raise NotABagError(f"{path}: not a rosbag2 metadata file (no "
                           "rosbag2_bagfile_information.relative_file_paths)")
    return info


def storage_of(filename: PathLike) -> Optional[str]:
    """``'mcap'`` or ``'sqlite3'`` from a storage file name, else None."""
    suffix = pathlib.PurePath(str(filename)).suffix
    return {".mcap": "mcap", ".db3": "sqlite3"}.get(suffix)
