"""The fixed CDR layout of ``seaforce_msgs/ActuatorState`` (numpy, no per-message objects).

Decoding is the hot part of reading long bags (a 10 min bag at 2 kHz holds 1.2 M messages and
the generic CDR deserialiser takes ~30 us per message). Every ``ActuatorState`` of one recording
has the same byte layout (same channel names and frame_id length), so the layout of the first
message is parsed once (:class:`StateLayout`) and all messages of that length and name bytes
are decoded together with numpy; :func:`serialize_states` does the reverse for writing sampled
data.
"""
from __future__ import annotations

import struct
from typing import Any, Dict, List, Mapping, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

from .typestore import typestore

__all__ = ["ACTUATOR_STATE", "STATE_FIELDS", "StateLayout", "state_template",
           "serialize_states"]

ACTUATOR_STATE = "seaforce_msgs/msg/ActuatorState"
#: message array field -> short name used in :class:`~seaforce_ros.bags.reader.ChannelRecord`
STATE_FIELDS = (("motor_position", "x"), ("motor_velocity", "v"), ("pressure_force", "f_p"),
                ("motor_effort", "f_a"), ("endpoint_position", "x_e"),
                ("external_force", "f_e"))


#: Samples of one signal: a sequence or an array.
Samples = Union[Sequence[float], npt.NDArray[Any]]


class StateLayout:
    """Byte offsets of one ``ActuatorState`` serialisation (CDR, little endian).

    Parameters
    ----------
    data : bytes
        One serialised message; every message with the same length and the same bytes in
        the ranges ``fixed`` (frame_id and channel names) has the same layout.
    """

    def __init__(self, data: Union[bytes, bytearray, memoryview]) -> None:
        data = bytes(data)
        if len(data) < 8 or data[1] != 1:
            raise ValueError("not a little-endian CDR message")
        self.length = len(data)
        pos = 4

        def align(p: int, n: int) -> int:
            return 4 + (-(-(p - 4) // n)) * n

        def u32(p: int) -> int:
            return struct.unpack_from("<I", data, p)[0]

        self.sec = pos
        self.nanosec = pos + 4
        pos += 8
        flen = u32(pos)
        #: byte ranges that must match for the layout to apply (frame_id, channel names)
        self.fixed: List[Tuple[int, int]] = [(pos, pos + 4 + flen)]
        pos += 4 + flen
        pos = align(pos, 8)
        self.cycle = pos
        pos += 8
        pos = align(pos, 4)
        names_start = pos
        count = u32(pos)
        pos += 4
        names: List[str] = []
        for _ in range(count):
            pos = align(pos, 4)
            slen = u32(pos)
            names.append(data[pos + 4:pos + 4 + slen - 1].decode("utf-8", "replace"))
            pos += 4 + slen
        self.fixed.append((names_start, pos))
        self.names = names
        self.arrays: Dict[str, int] = {}
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

    def column(self, rows: npt.NDArray[np.uint8], offset: int,
               dtype: npt.DTypeLike) -> npt.NDArray[Any]:
        """Values of one scalar at ``offset`` from a (n, length) uint8 array."""
        size = np.dtype(dtype).itemsize
        return np.ascontiguousarray(rows[:, offset:offset + size]).view(dtype).ravel()

    def put(self, rows: npt.NDArray[np.uint8], offset: int, values: npt.ArrayLike,
            dtype: npt.DTypeLike) -> None:
        """Write one scalar per row at ``offset`` of a (n, length) uint8 array."""
        size = np.dtype(dtype).itemsize
        rows[:, offset:offset + size] = np.asarray(values, dtype).reshape(-1, 1).view(np.uint8)


def state_template(channels: Sequence[str], frame_id: str = "") -> StateLayout:
    """:class:`StateLayout` of an all-zero message with these channel names."""
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


def serialize_states(channels: Sequence[str], data: Mapping[str, Mapping[str, Samples]],
                     cycle0: int = 0, dt: float = 5e-4,
                     t0: float = 0.0) -> Tuple[npt.NDArray[np.uint8], npt.NDArray[np.int64]]:
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
    layout = state_template(channels)
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
