"""Message types for bags: definitions, RIHS01 type hashes, header stamps (``rosbags``).

One shared typestore of the ROS 2 Jazzy standard types plus ``seaforce_msgs``
(:func:`seaforce_ros.bags.definitions.make_typestore`). The RIHS01 hash computed here from the
definitions is the one rosidl generates for the type (``share/<pkg>/msg/<Type>.json``) and the
one the ROS graph reports for a publisher (``TopicEndpointInfo.topic_type_hash``).
"""
from __future__ import annotations

import struct
from functools import lru_cache
from typing import TYPE_CHECKING, Optional, Tuple

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = ["typestore", "message_definition", "type_hash", "has_header"]

HEADER = "std_msgs/msg/Header"
_STORE: Optional[Typestore] = None


def typestore() -> Typestore:
    """The shared rosbags typestore (ROS 2 Jazzy + ``seaforce_msgs``)."""
    global _STORE
    if _STORE is None:
        from .definitions import make_typestore
        _STORE = make_typestore()
    return _STORE


def knows(msgtype: str) -> bool:
    """Whether the typestore has ``msgtype`` (``pkg/msg/Type``)."""
    return msgtype in typestore().fielddefs


@lru_cache(maxsize=None)
def message_definition(msgtype: str) -> Tuple[str, str]:
    """``(encoding, text)`` of ``msgtype`` as rosbag2 stores it: ``ros2msg`` and the type's
    ``.msg`` text followed by the definitions it depends on (``MSG: pkg/msg/Type`` sections)."""
    text, _digest = typestore().generate_msgdef(msgtype, ros_version=2)
    return "ros2msg", text


@lru_cache(maxsize=None)
def type_hash(msgtype: str) -> str:
    """``RIHS01_<64 hex>`` type description hash of ``msgtype``."""
    return typestore().hash_rihs01(msgtype)


@lru_cache(maxsize=None)
def has_header(msgtype: str) -> bool:
    """Whether the first field of ``msgtype`` is a ``std_msgs/Header`` (so the first 8 bytes
    after the CDR encapsulation are its stamp)."""
    if not knows(msgtype):
        return False
    fields = typestore().fielddefs[msgtype][1]
    if not fields:
        return False
    _name, (kind, rest) = fields[0]
    return rest == HEADER or (isinstance(rest, tuple) and rest and rest[0] == HEADER)


_STAMP = struct.Struct("<iI")


def header_stamp_ns(data: bytes) -> Optional[int]:
    """Header stamp [ns] of a serialised (little-endian CDR) message whose type starts with a
    Header, or None when the bytes are too short or not little-endian CDR."""
    if len(data) < 12 or data[1] != 1:
        return None
    sec, nanosec = _STAMP.unpack_from(data, 4)
    return sec * 1_000_000_000 + nanosec
