"""Errors of :mod:`seaforce_ros.bags`: one root, :class:`BagError`.

Every message says what is wrong, with which path, and what to do; the command-line tools print
it as one line (no traceback). The subclasses tell a caller where the problem lies:

* :class:`NotABagError` -- the path is no bag (missing, not a rosbag2 directory or storage
  file, unreadable ``metadata.yaml``); also a :class:`ValueError`.
* :class:`BagReadError` -- a storage file of a bag cannot be read at all (empty, not mcap or
  sqlite3, damaged before its first complete chunk).
* :class:`BagContentError` -- the bag is fine but lacks what was asked for (a topic, a
  channel); also a :class:`LookupError`.
* :class:`BagUsageError` -- a bad argument to the writer (storage name, split duration, an
  output directory that is not new or empty); also a :class:`ValueError`.
* :class:`BagWriteError` -- writing failed (disk full, file-size limit, permissions). What was
  written before stays readable; the message says what was kept.
"""
from typing import Mapping, Optional

__all__ = ["BagError", "NotABagError", "BagReadError", "BagContentError", "BagUsageError",
           "BagWriteError"]


class BagError(Exception):
    """Root of every error raised by :mod:`seaforce_ros.bags`."""


class NotABagError(BagError, ValueError):
    """The path is not a rosbag2 bag (directory or storage file)."""


class BagReadError(BagError):
    """A storage file cannot be read (nothing in it is recoverable)."""


class BagContentError(BagError, LookupError):
    """The bag lacks the topic or channel that was asked for."""


class BagUsageError(BagError, ValueError):
    """A writer argument that cannot be used (the message names it)."""


class BagWriteError(BagError):
    """Writing a bag failed; ``lost`` maps topic -> messages that were not written.

    Parameters
    ----------
    message : str
    lost : dict topic -> int, optional
        Messages accepted by the writer but not on disk when it failed (the open chunk or
        transaction).
    """

    def __init__(self, message: str, lost: Optional[Mapping[str, int]] = None) -> None:
        super().__init__(message)
        self.lost = dict(lost or {})
