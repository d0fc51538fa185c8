"""Reading recorded ActuatorState messages in tests."""
import struct
from typing import Iterable, List

import numpy as np
from seaforce_msgs.msg import ActuatorState


def serialized_cycle(data: bytes) -> int:
    """``cycle`` of a serialised ActuatorState/ActuatorCommand/ControllerStatus (all start
    with a Header and the uint64 cycle): read from the CDR bytes, no message built."""
    flen = struct.unpack_from('<I', data, 12)[0]
    pos = 16 + flen
    pos = 4 + -(-(pos - 4) // 8) * 8
    return struct.unpack_from('<Q', data, pos)[0]


def has_cycle(msg_type) -> bool:
    """Whether ``msg_type`` starts with a Header and the uint64 cycle
    (:func:`serialized_cycle` reads it)."""
    fields = list(getattr(msg_type, 'get_fields_and_field_types', dict)())
    return fields[:2] == ['header', 'cycle']


def value(msg, channel: str, field: str):
    """``msg.<field>`` of one channel, looked up by name."""
    return getattr(msg, field)[list(msg.name).index(channel)]


def stamp_ns(msg) -> int:
    """The header stamp in ns (system time: the plants stamp with time.time_ns())."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def by_cycle(msgs: Iterable) -> List:
    """One message per cycle (the last one received), in cycle order."""
    return sorted({m.cycle: m for m in msgs}.values(), key=lambda m: m.cycle)


def torque_off_after_commands_stop(states: List, channel: str):
    """Where the plant zeroed ``channel``'s torque after its commands stopped.

    Returns ``(cycles, flags, efforts, last_driven, first_off)``: arrays over ``states``
    (STATUS_COMMAND_TIMEOUT bit, applied effort), the index of the last state whose torque came
    from a command, and the index of the first flagged state after it.
    """
    cycles = np.array([m.cycle for m in states])
    flags = np.array([value(m, channel, 'status') & ActuatorState.STATUS_COMMAND_TIMEOUT
                      for m in states])
    efforts = np.array([value(m, channel, 'motor_effort') for m in states])
    last_driven = int(np.flatnonzero(efforts != 0.0)[-1])
    first_off = last_driven + int(np.argmax(flags[last_driven:] > 0))
    return cycles, flags, efforts, last_driven, first_off


def counted_past(states: List, cycles, killed_ns: int, steps: int):
    """Mask of ``states`` more than ``steps`` plant cycles past the cycle the plant ran when a
    process was killed at ``killed_ns`` (the first state stamped at or after it). The plant
    counts its command timeout in its own cycles: a plant whose cycle stalled over the kill
    flags the timeout on schedule in cycles, later in wall time (a loaded CI host: 33 cycles
    stamped 50 ms after the kill still carried the last command, legitimately)."""
    stamps = np.array([stamp_ns(m) for m in states])
    at = np.flatnonzero(stamps >= killed_ns)
    if at.size == 0:
        return np.zeros(len(states), dtype=bool)
    return np.asarray(cycles) > cycles[at[0]] + steps
