"""sqlite3 storage files as rosbag2's sqlite3 plugin (Jazzy, schema version 4) writes them.

Tables ``schema`` (version 4, ``ros_distro``), ``metadata`` (the bag's metadata YAML),
``topics`` (name, type, ``cdr``, offered QoS as YAML, RIHS01 hash), ``message_definitions`` and
``messages`` (topic id, ``timestamp`` = receive time, CDR bytes); rosbag2's sqlite3 storage has
no publish time.

:class:`Sqlite3Writer` commits once per write batch (:meth:`~Sqlite3Writer.flush`), as rosbag2
does, in rosbag2's "resilient" settings (``journal_mode=WAL``, ``synchronous=NORMAL``): a killed
process keeps every committed batch. :meth:`~Sqlite3Writer.close` checkpoints the WAL and turns
the file back into a single self-contained ``.db3`` (``journal_mode=DELETE``), which is what
every reader expects. A file left with its ``-wal`` (or a rollback ``-journal``) by a killed
writer is read through a temporary copy, on which SQLite itself recovers the committed
transactions (:func:`open_for_reading`); ``bag_reindex`` does the same in place.
"""
from __future__ import annotations

import os
import pathlib
import shutil
import sqlite3
import tempfile
from contextlib import contextmanager
from typing import Dict, Iterator, List, Optional, Set, Tuple, Union

from .errors import BagReadError

__all__ = ["Sqlite3Writer", "open_for_reading", "needs_recovery", "finish_in_place",
           "SCHEMA_VERSION"]

SCHEMA_VERSION = 4

_Path = Union[str, "os.PathLike[str]"]

_TABLES = """
CREATE TABLE schema(schema_version INTEGER PRIMARY KEY, ros_distro TEXT NOT NULL);
CREATE TABLE metadata(id INTEGER PRIMARY KEY, metadata_version INTEGER NOT NULL,
                      metadata TEXT NOT NULL);
CREATE TABLE topics(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,
                    serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL,
                    type_description_hash TEXT NOT NULL);
CREATE TABLE message_definitions(id INTEGER PRIMARY KEY, topic_type TEXT NOT NULL,
                                 encoding TEXT NOT NULL,
                                 encoded_message_definition TEXT NOT NULL,
                                 type_description_hash TEXT NOT NULL);
CREATE TABLE messages(id INTEGER PRIMARY KEY, topic_id INTEGER NOT NULL,
                      timestamp INTEGER NOT NULL, data BLOB NOT NULL);
CREATE INDEX timestamp_idx ON messages (timestamp ASC);
"""


class Sqlite3Writer:
    """Write one rosbag2 sqlite3 file, one transaction per :meth:`flush`.

    Every method that writes raises ``OSError`` or ``sqlite3.Error`` on a failure;
    :meth:`abandon` then rolls the open batch back (committed batches stay) and closes.
    """

    def __init__(self, path: _Path, ros_distro: str) -> None:
        self.path = os.fspath(path)
        if os.path.exists(self.path):
            raise FileExistsError(self.path)
        self._conn = sqlite3.connect(self.path, isolation_level=None, check_same_thread=False)
        self._conn.execute("PRAGMA journal_mode=WAL")
        self._conn.execute("PRAGMA synchronous=NORMAL")
        self._conn.execute("BEGIN")
        for stmt in _TABLES.split(";"):
            if stmt.strip():
                self._conn.execute(stmt)
        self._conn.execute("INSERT INTO schema(schema_version, ros_distro) VALUES (?, ?)",
                           (SCHEMA_VERSION, ros_distro))
        self._conn.execute("COMMIT")
        self._rows: List[Tuple[int, int, bytes]] = []
        self._counts: Dict[int, int] = {}
        self._types: Set[str] = set()
        self.start_time: Optional[int] = None
        self.end_time: Optional[int] = None

    def add_topic(self, name: str, msgtype: str, serialization_format: str, qos_yaml: str,
                  type_hash: str, encoding: str, definition: str) -> int:
        """Add a topic (and its type's definition once); returns its id."""
        conn = self._conn
        conn.execute("BEGIN")
        try:
            cur = conn.execute(
                "INSERT INTO topics(name, type, serialization_format, offered_qos_profiles, "
                "type_description_hash) VALUES (?, ?, ?, ?, ?)",
                (name, msgtype, serialization_format, qos_yaml, type_hash))
            if msgtype not in self._types:
                conn.execute(
                    "INSERT INTO message_definitions(topic_type, encoding, "
                    "encoded_message_definition, type_description_hash) VALUES (?, ?, ?, ?)",
                    (msgtype, encoding, definition, type_hash))
            conn.execute("COMMIT")
        except BaseException:
            self._rollback()
            raise
        self._types.add(msgtype)
        return cur.lastrowid  # type: ignore[return-value]  # an INSERT sets it

    def write(self, topic_id: int, log_time: int, data: bytes) -> None:
        """Queue a message for the next :meth:`flush` (the batch's transaction)."""
        self._rows.append((topic_id, log_time, data))
        self._counts[topic_id] = self._counts.get(topic_id, 0) + 1

    @property
    def pending(self) -> int:
        """Messages queued for the next :meth:`flush`."""
        return len(self._rows)

    def flush(self) -> Dict[int, int]:
        """Commit the queued messages in one transaction; returns per-topic-id counts."""
        if not self._rows:
            return {}
        conn = self._conn
        conn.execute("BEGIN")
        try:
            conn.executemany("INSERT INTO messages(topic_id, timestamp, data) VALUES (?, ?, ?)",
                             self._rows)
            conn.execute("COMMIT")
        except BaseException:
            self._rollback()
            raise
        times = [r[1] for r in self._rows]
        lo, hi = min(times), max(times)
        self.start_time = lo if self.start_time is None else min(self.start_time, lo)
        self.end_time = hi if self.end_time is None else max(self.end_time, hi)
        counts, self._rows, self._counts = self._counts, [], {}
        return counts

    def close(self, metadata_version: int, metadata_yaml: str) -> Dict[int, int]:
        """Commit, store the bag metadata, checkpoint and leave one ``.db3`` file."""
        counts = self.flush()
        conn = self._conn
        conn.execute("INSERT INTO metadata(metadata_version, metadata) VALUES (?, ?)",
                     (metadata_version, metadata_yaml))
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        mode = conn.execute("PRAGMA journal_mode=DELETE").fetchone()[0]
        if mode.lower() != "delete":
            raise sqlite3.OperationalError(f"cannot leave WAL mode ({mode})")
        conn.close()
        self._conn = None  # type: ignore[assignment]  # closed: only abandon() looks again
        return counts

    def _rollback(self) -> None:
        try:
            self._conn.execute("ROLLBACK")
        except sqlite3.Error:
            pass

    def abandon(self) -> Dict[int, int]:
        """After a failure: drop the uncommitted batch and close (committed ones stay, in the
        file or its WAL). Returns per-topic-id counts of the dropped batch."""
        lost, self._rows, self._counts = self._counts, [], {}
        if self._conn is not None:
            self._rollback()
            try:
                self._conn.close()
            except sqlite3.Error:
                pass
            self._conn = None  # type: ignore[assignment]  # closed (see close)
        return lost


def needs_recovery(path: _Path) -> bool:
    """Whether ``path`` has a WAL or a rollback journal beside it (a writer that did not
    close it: its committed transactions are only visible to a SQLite that recovers them)."""
    return any(os.path.exists(os.fspath(path) + s) and os.path.getsize(os.fspath(path) + s) > 0
               for s in ("-wal", "-journal"))


@contextmanager
def open_for_reading(path: _Path) -> Iterator[sqlite3.Connection]:
    """A read-only ``sqlite3`` connection to a rosbag2 sqlite3 file.

    A file with a WAL or journal beside it is copied (with them) to a temporary directory and
    opened there read-write, so SQLite recovers the committed transactions without touching
    the original. Raises :class:`BagReadError` for a file that is not a rosbag2 sqlite3 bag.
    """
    path = os.fspath(path)
    tmpdir: Optional[str] = None
    try:
        if needs_recovery(path):
            tmpdir = tempfile.mkdtemp(prefix="seaforce_bag_")
            copy = os.path.join(tmpdir, os.path.basename(path))
            for s in ("", "-wal", "-journal"):
                if os.path.exists(path + s):
                    shutil.copyfile(path + s, copy + s)
            conn = sqlite3.connect(copy)
        else:
            uri = pathlib.Path(os.path.abspath(path)).as_uri() + "?mode=ro&immutable=1"
            conn = sqlite3.connect(uri, uri=True)
        try:
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
        except sqlite3.DatabaseError as exc:
            conn.close()
            raise BagReadError(f"{path}: not a sqlite3 bag ({exc})") from None
        if not {"messages", "topics"} <= tables:
            conn.close()
            raise BagReadError(f"{path}: not a rosbag2 sqlite3 file (no messages/topics "
                               "tables)")
        try:
            yield conn
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise BagReadError(f"{path}: cannot read ({exc})") from None
    finally:
        if tmpdir is not None:
            shutil.rmtree(tmpdir, ignore_errors=True)


def finish_in_place(path: _Path, metadata_version: int, metadata_yaml: str) -> None:
    """Recover a sqlite3 file left open by a killed writer, in place: SQLite replays its WAL
    (or rolls back its journal), the bag metadata row is added, and the file is left as one
    ``.db3`` in rollback-journal mode."""
    path = os.fspath(path)
    try:
        conn = sqlite3.connect(path, isolation_level=None)
        try:
            conn.execute("SELECT count(*) FROM messages").fetchone()
            tables = {r[0] for r in conn.execute(
                "SELECT name FROM sqlite_master WHERE type='table'")}
            if "metadata" in tables:
                conn.execute("INSERT INTO metadata(metadata_version, metadata) VALUES (?, ?)",
                             (metadata_version, metadata_yaml))
            conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            conn.execute("PRAGMA journal_mode=DELETE")
        finally:
            conn.close()
    except sqlite3.Error as exc:
        raise BagReadError(f"{path}: cannot repair ({exc})") from None
