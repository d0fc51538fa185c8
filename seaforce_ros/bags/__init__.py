"""rosbag2 bags (mcap, sqlite3) without ROS: reading, writing, repair (no rclpy).

Modules: :mod:`~.reader` (:class:`Bag`, :func:`read_channel`), :mod:`~.writer`
(:class:`BagWriter`: one bag directory as ``ros2 bag record`` writes it, valid after every
split; :func:`write_state_bag`), :mod:`~.repair` (``bag_reindex``), :mod:`~.metadata`
(``metadata.yaml``, Jazzy version 9), :mod:`~.mcapfile` and :mod:`~.sqlitefile` (the two
storage formats), :mod:`~.states` (the fixed layout of ``ActuatorState``),
:mod:`~.typestore` (definitions and RIHS01 hashes) and :mod:`~.errors` (one root,
:class:`BagError`).
"""
from .errors import (BagContentError, BagError, BagReadError, BagUsageError, BagWriteError,
                     NotABagError)
from .metadata import BagMetadata, FileInfo, QosProfile, TopicInfo
from .reader import Bag, ChannelRecord, read_channel, topic_matches
from .repair import reindex_bag
from .states import ACTUATOR_STATE, STATE_FIELDS, StateLayout, serialize_states
from .typestore import typestore
from .writer import BagWriter, check_output_directory, write_state_bag

__all__ = ["BagError", "NotABagError", "BagReadError", "BagContentError", "BagUsageError",
           "BagWriteError", "BagMetadata", "FileInfo", "QosProfile", "TopicInfo", "Bag",
           "ChannelRecord", "read_channel", "topic_matches", "reindex_bag", "ACTUATOR_STATE",
           "STATE_FIELDS", "StateLayout", "serialize_states", "typestore", "BagWriter",
           "check_output_directory", "write_state_bag"]
