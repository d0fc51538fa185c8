"""MCAP files as rosbag2's mcap storage plugin writes them, and reading ones cut short.

Format: the MCAP specification (magic, Header, data section of Schema / Channel / Chunk /
MessageIndex / Metadata records, DataEnd, summary section of Schema, Channel, Statistics,
ChunkIndex, MetadataIndex and SummaryOffset records, Footer, magic). As rosbag2_storage_mcap
(Jazzy) writes it: profile ``ros2``, schema encoding ``ros2msg``, message encoding ``cdr``,
channel metadata ``offered_qos_profiles`` (YAML list) and ``topic_type_hash`` (RIHS01), a
``rosbag2`` Metadata record holding the bag's metadata YAML under ``serialized_metadata``,
uncompressed chunks; messages carry ``log_time`` = receive time and ``publish_time`` = the
sender's time.

:class:`McapWriter` keeps the open chunk in memory and writes a finished chunk together with its
message indexes in one ``write`` call, so a process killed at any moment leaves a file of
complete chunks followed by at most one partial record. Schemas and channels are written to the
data section (outside chunks) as soon as they are added. The summary is written by
:meth:`McapWriter.close` -- or, for a file cut short, by :func:`reindex` (``bag_reindex``).

:class:`McapScan` reads the data section sequentially, whether or not the file has a summary:
it yields the messages of every complete chunk, stops at the first incomplete or damaged record,
and reports what it found (:class:`ScanReport`).
"""
from __future__ import annotations

import mmap
import os
import struct
import zlib
from array import array
from dataclasses import dataclass, field
from typing import (Callable, Dict, Iterable, Iterator, List, Literal, Mapping, Optional,
                    Tuple, Union)

from .errors import BagReadError

__all__ = ["MAGIC", "McapWriter", "McapScan", "ScanReport", "ChunkIndex", "McapIndex",
           "reindex"]

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, \
    0x05, 0x06
OP_MESSAGE_INDEX, OP_CHUNK_INDEX, OP_ATTACHMENT, OP_ATTACHMENT_INDEX = 0x07, 0x08, 0x09, 0x0A
OP_STATISTICS, OP_METADATA, OP_METADATA_INDEX, OP_SUMMARY_OFFSET, OP_DATA_END = 0x0B, 0x0C, \
    0x0D, 0x0E, 0x0F
#: rosbag2's mcap writer default chunk size [bytes] (libmcap's default)
DEFAULT_CHUNK_SIZE = 768 * 1024

_REC = struct.Struct("<BQ")                      # opcode, record length
_MSG = struct.Struct("<BQHIQQ")                  # message record header
_MSG_BODY = struct.Struct("<HIQQ")
_U16, _U32, _U64 = struct.Struct("<H"), struct.Struct("<I"), struct.Struct("<Q")
_CHUNK_HEAD = struct.Struct("<QQQI")             # start, end, uncompressed size, crc

#: What records are read from: a file's bytes (mapped or read) or a chunk's.
Buffer = Union[bytes, mmap.mmap]
#: One message as read: ``(channel_id, log_time, publish_time, data)``.
Message = Tuple[int, int, int, bytes]
#: Metadata records to write: ``(name, {key: value})``.
MetadataRecords = Iterable[Tuple[str, Mapping[str, str]]]


# --- encoding helpers ---------------------------------------------------------------------
def _string(s: Union[str, bytes]) -> bytes:
    b = s.encode() if isinstance(s, str) else bytes(s)
    return _U32.pack(len(b)) + b


def _map(d: Mapping[str, str]) -> bytes:
    body = b"".join(_string(k) + _string(v) for k, v in d.items())
    return _U32.pack(len(body)) + body


def _record(op: int, body: bytes) -> bytes:
    return _REC.pack(op, len(body)) + body


class _Cursor:
    """Reads MCAP primitives from a buffer; IndexError/struct.error on running out."""

    __slots__ = ("buf", "pos")

    def __init__(self, buf: Buffer, pos: int = 0) -> None:
        self.buf, self.pos = buf, pos

    def u16(self) -> int:
        v = _U16.unpack_from(self.buf, self.pos)[0]
        self.pos += 2
        return v

    def u32(self) -> int:
        v = _U32.unpack_from(self.buf, self.pos)[0]
        self.pos += 4
        return v

    def u64(self) -> int:
        v = _U64.unpack_from(self.buf, self.pos)[0]
        self.pos += 8
        return v

    def raw(self, n: int) -> bytes:
        if self.pos + n > len(self.buf):
            raise struct.error("record shorter than its fields")
        v = bytes(self.buf[self.pos:self.pos + n])
        self.pos += n
        return v

    def string(self) -> str:
        return self.raw(self.u32()).decode()

    def map(self) -> Dict[str, str]:
        end = self.pos + self.u32()
        out = {}
        while self.pos < end:
            key = self.string()
            out[key] = self.string()
        return out


def _schema_body(sid: int, name: str, encoding: str, data: bytes) -> bytes:
    return _U16.pack(sid) + _string(name) + _string(encoding) + _U32.pack(len(data)) + data


def _channel_body(cid: int, sid: int, topic: str, encoding: str,
                  metadata: Mapping[str, str]) -> bytes:
    return _U16.pack(cid) + _U16.pack(sid) + _string(topic) + _string(encoding) + _map(metadata)


@dataclass
class ChunkIndex:
    """Where a chunk is and what it holds (the summary's ChunkIndex record)."""

    start_time: int
    end_time: int
    offset: int
    length: int
    uncompressed_size: int
    compressed_size: int
    compression: str = ""
    message_index_offsets: Dict[int, int] = field(default_factory=dict)
    message_index_length: int = 0
    counts: Dict[int, int] = field(default_factory=dict)

    def body(self) -> bytes:
        """The ChunkIndex record's body."""
        offsets = b"".join(_U16.pack(c) + _U64.pack(o)
                           for c, o in sorted(self.message_index_offsets.items()))
        return (_U64.pack(self.start_time) + _U64.pack(self.end_time) + _U64.pack(self.offset)
                + _U64.pack(self.length) + _U32.pack(len(offsets)) + offsets
                + _U64.pack(self.message_index_length) + _string(self.compression)
                + _U64.pack(self.compressed_size) + _U64.pack(self.uncompressed_size))


@dataclass
class McapIndex:
    """What a summary section indexes: schemas, channels, chunks, metadata records.

    ``schemas``: id -> (name, encoding, data bytes); ``channels``: id -> (schema id, topic,
    message encoding, metadata dict); ``metadata``: (name, offset, length) of Metadata records.
    """

    schemas: Dict[int, Tuple[str, str, bytes]] = field(default_factory=dict)
    channels: Dict[int, Tuple[int, str, str, Dict[str, str]]] = field(default_factory=dict)
    chunks: List[ChunkIndex] = field(default_factory=list)
    metadata: List[Tuple[str, int, int]] = field(default_factory=list)
    unchunked: Dict[int, int] = field(default_factory=dict)
    start_time: Optional[int] = None
    end_time: Optional[int] = None

    def channel_counts(self) -> Dict[int, int]:
        """Messages per channel id, chunked and not."""
        out = dict(self.unchunked)
        for c in self.chunks:
            for cid, n in c.counts.items():
                out[cid] = out.get(cid, 0) + n
        return out

    def note_times(self, start: int, end: int) -> None:
        """Widen the time range [ns] to hold ``start``..``end``."""
        self.start_time = start if self.start_time is None else min(self.start_time, start)
        self.end_time = end if self.end_time is None else max(self.end_time, end)

    def tail(self, offset: int) -> bytes:
        """DataEnd, summary section and footer for a data section that ends at ``offset``."""
        out = bytearray(_record(OP_DATA_END, _U32.pack(0)))
        summary_start = offset + len(out)
        groups: List[Tuple[int, int, int]] = []

        def group(op: int, records: List[bytes]) -> None:
            if records:
                start = offset + len(out)
                for body in records:
                    out.extend(_record(op, body))
                groups.append((op, start, offset + len(out) - start))

        group(OP_SCHEMA, [_schema_body(i, *s) for i, s in sorted(self.schemas.items())])
        group(OP_CHANNEL, [_channel_body(i, *c) for i, c in sorted(self.channels.items())])
        counts = self.channel_counts()
        stats = (_U64.pack(sum(counts.values())) + _U16.pack(len(self.schemas))
                 + _U32.pack(len(self.channels)) + _U32.pack(0) + _U32.pack(len(self.metadata))
                 + _U32.pack(len(self.chunks)) + _U64.pack(self.start_time or 0)
                 + _U64.pack(self.end_time or 0))
        per = b"".join(_U16.pack(c) + _U64.pack(n) for c, n in sorted(counts.items()))
        group(OP_STATISTICS, [stats + _U32.pack(len(per)) + per])
        group(OP_CHUNK_INDEX, [c.body() for c in self.chunks])
        group(OP_METADATA_INDEX, [_U64.pack(o) + _U64.pack(n) + _string(name)
                                  for name, o, n in self.metadata])
        summary_offset_start = offset + len(out)
        for op, start, length in groups:
            out.extend(_record(OP_SUMMARY_OFFSET, bytes([op]) + _U64.pack(start)
                               + _U64.pack(length)))
        footer = bytearray(_REC.pack(OP_FOOTER, 20) + _U64.pack(summary_start)
                           + _U64.pack(summary_offset_start))
        crc = zlib.crc32(bytes(out[summary_start - offset:]) + footer)
        out.extend(footer + _U32.pack(crc) + MAGIC)
        return bytes(out)


def metadata_record(name: str, values: Mapping[str, str]) -> bytes:
    """A Metadata record ``name`` with ``{key: value}``."""
    return _record(OP_METADATA, _string(name) + _map(values))


# --- writing -------------------------------------------------------------------------------
class McapWriter:
    """Write one MCAP file in chunks; every finished chunk reaches the file at once.

    Parameters
    ----------
    path : path
        New file (must not exist).
    library : str
        Header ``library`` field.
    chunk_size : int > 0
        A chunk is finished when its records reach this many bytes (or by :meth:`flush`).

    Every method that writes raises OSError on a write failure; :meth:`abandon` then cuts the
    file back to its last complete record, so what was written stays readable.
    """

    def __init__(self, path: Union[str, "os.PathLike[str]"], library: str,
                 chunk_size: int = DEFAULT_CHUNK_SIZE) -> None:
        self.path = os.fspath(path)
        self.chunk_size = int(chunk_size)
        self._fd: Optional[int] = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        self._size = 0                     # bytes completely written
        self.index = McapIndex()
        self._new_chunk()
        self._write(MAGIC + _record(OP_HEADER, _string("ros2") + _string(library)))

    def _new_chunk(self) -> None:
        self._buf = bytearray()
        self._msg_index: Dict[int, array] = {}
        self._counts: Dict[int, int] = {}
        self._start: Optional[int] = None
        self._end: Optional[int] = None

    def _write(self, data: Union[bytes, bytearray]) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self._fd, view)  # type: ignore[arg-type]  # open until close()
            view = view[n:]
        self._size += len(data)

    @property
    def size(self) -> int:
        """Bytes in the file (complete records) plus the open chunk."""
        return self._size + len(self._buf)

    @property
    def chunk_start_time(self) -> Optional[int]:
        """log_time of the open chunk's first message [ns], None when it is empty."""
        return self._start

    def add_schema(self, name: str, encoding: str, data: Union[str, bytes]) -> int:
        """Write a Schema record; returns its id."""
        sid = len(self.index.schemas) + 1
        data = data.encode() if isinstance(data, str) else bytes(data)
        self._write(_record(OP_SCHEMA, _schema_body(sid, name, encoding, data)))
        self.index.schemas[sid] = (name, encoding, data)
        return sid

    def add_channel(self, topic: str, schema_id: int, encoding: str,
                    metadata: Mapping[str, str]) -> int:
        """Write a Channel record; returns its id."""
        cid = len(self.index.channels) + 1
        metadata = dict(metadata)
        self._write(_record(OP_CHANNEL, _channel_body(cid, schema_id, topic, encoding,
                                                      metadata)))
        self.index.channels[cid] = (schema_id, topic, encoding, metadata)
        return cid

    def write(self, channel_id: int, log_time: int, publish_time: int,
              data: bytes) -> Dict[int, int]:
        """Add a message to the open chunk; the chunk is written when it is full.

        Returns the per-channel counts of the chunk written now ({} if none was)."""
        buf = self._buf
        idx = self._msg_index.get(channel_id)
        if idx is None:
            idx = self._msg_index[channel_id] = array("Q")
            self._counts[channel_id] = 0
        idx.append(log_time)
        idx.append(len(buf))
        self._counts[channel_id] += 1
        buf += _MSG.pack(OP_MESSAGE, 22 + len(data), channel_id, 0, log_time, publish_time)
        buf += data
        if self._start is None:
            self._start = self._end = log_time
        elif log_time < self._start:
            self._start = log_time
        elif log_time > self._end:  # type: ignore[operator]  # set with _start
            self._end = log_time
        if len(buf) >= self.chunk_size:
            return self.flush()
        return {}

    def flush(self) -> Dict[int, int]:
        """Write the open chunk (if any) with its message indexes, in one write.

        Returns the per-channel message counts now on disk ({} for an empty chunk)."""
        if not self._buf:
            return {}
        records = bytes(self._buf)
        head = (_CHUNK_HEAD.pack(self._start, self._end, len(records), zlib.crc32(records))
                + _string("") + _U64.pack(len(records)))
        chunk = _record(OP_CHUNK, head + records)
        offset = self._size
        out = bytearray(chunk)
        offsets: Dict[int, int] = {}
        for cid, idx in self._msg_index.items():
            offsets[cid] = offset + len(out)
            entries = idx.tobytes()   # (log_time, offset) pairs, little-endian u64
            out += _record(OP_MESSAGE_INDEX, _U16.pack(cid) + _U32.pack(len(entries)) + entries)
        counts = dict(self._counts)
        # a chunk with messages has their time range (set with its first message)
        ci = ChunkIndex(self._start, self._end,  # type: ignore[arg-type]
                        offset, len(chunk), len(records), len(records),
                        "", offsets, len(out) - len(chunk), counts)
        self._write(out)
        self.index.chunks.append(ci)
        self.index.note_times(self._start, self._end)  # type: ignore[arg-type]
        self._new_chunk()
        return counts

    def close(self, metadata: MetadataRecords = ()) -> Dict[int, int]:
        """Write the open chunk, the Metadata records ``(name, {key: value})``, DataEnd,
        summary and footer; close the file. Returns the counts of the last chunk."""
        counts = self.flush()
        out = bytearray()
        for name, values in metadata:
            rec = metadata_record(name, values)
            self.index.metadata.append((name, self._size + len(out), len(rec)))
            out += rec
        out += self.index.tail(self._size + len(out))
        self._write(out)
        os.close(self._fd)  # type: ignore[arg-type]  # open until here
        self._fd = None
        return counts

    def abandon(self) -> Dict[int, int]:
        """After a failed write: cut the file back to its last complete record and close it
        (the open chunk is dropped). Returns its per-channel counts (messages lost)."""
        lost = dict(self._counts)
        self._new_chunk()
        if self._fd is not None:
            try:
                os.ftruncate(self._fd, self._size)
            except OSError:
                pass
            os.close(self._fd)
            self._fd = None
        return lost


# --- reading --------------------------------------------------------------------------------
@dataclass
class ScanReport:
    """What a sequential read of an MCAP file found.

    ``complete``: the data section ended with DataEnd and the file with a valid footer.
    ``data_end``: offset just past the last complete record of the data section (where
    :func:`reindex` cuts). ``problem``: why the read stopped early (None when complete).
    ``messages``: messages read (all channels); ``chunks``: complete chunks.
    """

    path: str
    size: int = 0
    complete: bool = False
    data_end: int = 0
    problem: Optional[str] = None
    messages: int = 0
    chunks: int = 0
    first_time: Optional[int] = None
    last_time: Optional[int] = None


class McapScan:
    """Sequential reader of one MCAP file, with or without its summary.

    Raises :class:`BagReadError` on open when the file is empty or no MCAP file of the
    ``ros2`` profile.
    """

    def __init__(self, path: Union[str, "os.PathLike[str]"]) -> None:
        self.path = os.fspath(path)
        self._data: Union[bytes, mmap.mmap] = b""
        try:
            with open(self.path, "rb") as fh:
                size = os.fstat(fh.fileno()).st_size
                if size:
                    self._data = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
        except OSError as exc:
            raise BagReadError(f"{self.path}: cannot read ({exc.strerror})") from None
        data = self._data
        if not data:
            raise BagReadError(f"{self.path}: empty file (a split that never received a "
                               "message); delete it or run bag_reindex on the bag")
        if len(data) < 8 or data[:8] != MAGIC:
            self.close()
            raise BagReadError(f"{self.path}: not an MCAP file (bad magic)")
        self.index = McapIndex()
        self.report = ScanReport(self.path, size=len(data))
        self.header: Optional[Tuple[str, str]] = None
        try:
            op, length = _REC.unpack_from(data, 8)
            if op != OP_HEADER:
                raise BagReadError(f"{self.path}: not an MCAP file (no header record)")
            cur = _Cursor(data[17:17 + length])
            self.header = (cur.string(), cur.string())
            self._pos = 17 + length
            if self._pos > len(data):
                raise struct.error
        except (struct.error, UnicodeDecodeError):
            self.close()
            raise BagReadError(f"{self.path}: cut short inside its header: nothing to "
                               "recover") from None
        self.report.data_end = self._pos
        self.metadata: Dict[str, Dict[str, str]] = {}

    def close(self) -> None:
        """Release the file (the report and index stay)."""
        if isinstance(self._data, mmap.mmap):
            self._data.close()
        self._data = b""

    def __enter__(self) -> "McapScan":
        return self

    def __exit__(self, *exc: object) -> Literal[False]:
        self.close()
        return False

    def topic_of(self, channel_id: int) -> Optional[str]:
        """The topic of a channel, None for an unknown id."""
        ch = self.index.channels.get(channel_id)
        return None if ch is None else ch[1]

    def type_of(self, channel_id: int) -> Optional[str]:
        """The message type (schema name) of a channel, None when unknown."""
        ch = self.index.channels.get(channel_id)
        if ch is None:
            return None
        schema = self.index.schemas.get(ch[0])
        return None if schema is None else schema[0]

    def messages(self, want: Optional[Callable[[int], bool]] = None) -> Iterator[Message]:
        """Yield ``(channel_id, log_time, publish_time, data)`` of every message in file
        order (chunk by chunk) for which ``want(channel_id)`` is true (all when None).

        Stops at DataEnd or at the first record that is incomplete or damaged; ``report``
        and ``index`` describe what was read once the generator is exhausted."""
        data = self._data
        n = len(data)
        pos = self._pos
        report = self.report
        index = self.index
        cache: Dict[int, bool] = {}

        def wanted(cid: int) -> bool:
            w = cache.get(cid)
            if w is None:
                w = cache[cid] = want is None or bool(want(cid))
            return w

        last_chunk: Optional[ChunkIndex] = None
        while True:
            if pos + 9 > n:
                if pos < n:
                    report.problem = f"cut short at byte {pos} (incomplete record)"
                else:
                    report.problem = "ends without summary (no DataEnd record)"
                break
            op, length = _REC.unpack_from(data, pos)
            body_start = pos + 9
            end = body_start + length
            if end > n:
                report.problem = (f"cut short at byte {pos}: a record of {length} bytes "
                                  f"(opcode 0x{op:02x}) has only {n - body_start}")
                break
            if op == OP_DATA_END:
                report.data_end = pos
                report.complete = self._footer_ok()
                if not report.complete:
                    report.problem = "has DataEnd but no valid footer"
                break
            try:
                if op == OP_CHUNK:
                    chunk = self._chunk(data, body_start, end, pos, wanted)
                    msgs = chunk[1]
                    last_chunk = chunk[0]
                    for item in msgs:
                        yield item
                elif op == OP_MESSAGE_INDEX:
                    cid = _U16.unpack_from(data, body_start)[0]
                    if last_chunk is not None and cid in last_chunk.counts:
                        last_chunk.message_index_offsets[cid] = pos
                        last_chunk.message_index_length = end - (last_chunk.offset
                                                                 + last_chunk.length)
                elif op == OP_MESSAGE:
                    cid, _seq, log_time, pub = _MSG_BODY.unpack_from(data, body_start)
                    index.unchunked[cid] = index.unchunked.get(cid, 0) + 1
                    index.note_times(log_time, log_time)
                    self._count(log_time)
                    if wanted(cid):
                        yield cid, log_time, pub, data[body_start + 22:end]
                else:
                    self._other(op, data, body_start, end, pos)
            except _Damaged as exc:
                report.problem = f"damaged record at byte {pos}: {exc}"
                break
            except (struct.error, UnicodeDecodeError, ValueError) as exc:
                report.problem = f"damaged record at byte {pos} (opcode 0x{op:02x}: {exc})"
                break
            pos = end
            report.data_end = pos
        # a chunk whose message indexes were cut off: keep the chunk, drop its partial indexes
        if last_chunk is not None and not report.complete and \
                set(last_chunk.message_index_offsets) != set(last_chunk.counts):
            last_chunk.message_index_offsets = {}
            last_chunk.message_index_length = 0
            report.data_end = last_chunk.offset + last_chunk.length

    def _count(self, log_time: int) -> None:
        r = self.report
        r.messages += 1
        r.first_time = log_time if r.first_time is None else min(r.first_time, log_time)
        r.last_time = log_time if r.last_time is None else max(r.last_time, log_time)

    def _other(self, op: int, data: Buffer, start: int, end: int, pos: int) -> None:
        body = data[start:end]
        if op == OP_SCHEMA:
            cur = _Cursor(body)
            sid = cur.u16()
            name, encoding = cur.string(), cur.string()
            self.index.schemas[sid] = (name, encoding, cur.raw(cur.u32()))
        elif op == OP_CHANNEL:
            cur = _Cursor(body)
            cid, sid = cur.u16(), cur.u16()
            self.index.channels[cid] = (sid, cur.string(), cur.string(), cur.map())
        elif op == OP_METADATA:
            cur = _Cursor(body)
            name = cur.string()
            self.metadata[name] = cur.map()
            self.index.metadata.append((name, pos, end - pos))

    def _chunk(self, data: Buffer, start: int, end: int, pos: int,
               wanted: Callable[[int], bool]) -> Tuple[ChunkIndex, List[Message]]:
        cur = _Cursor(data, start)
        t0, t1, usize, crc = _CHUNK_HEAD.unpack_from(data, start)
        cur.pos += _CHUNK_HEAD.size
        compression = cur.string()
        csize = cur.u64()
        if cur.pos + csize != end:
            raise _Damaged("chunk length does not match its records")
        raw = data[cur.pos:end]
        if compression == "":
            records = raw
        elif compression == "zstd":
            try:
                from compression import zstd
            except ImportError:
                from backports import zstd
            records = zstd.decompress(raw)
        elif compression == "lz4":
            import lz4.frame
            records = lz4.frame.decompress(raw)
        else:
            raise _Damaged(f"unsupported chunk compression {compression!r}")
        if len(records) != usize:
            raise _Damaged("chunk size does not match its header")
        if crc and zlib.crc32(records) != crc:
            raise _Damaged("chunk CRC mismatch")
        counts: Dict[int, int] = {}
        out: List[Message] = []
        p = 0
        m = len(records)
        schemas_before = dict(self.index.schemas)
        channels_before = dict(self.index.channels)
        try:
            while p < m:
                op, length = _REC.unpack_from(records, p)
                b = p + 9
                e = b + length
                if e > m:
                    raise _Damaged("a record inside a chunk runs past its end")
                if op == OP_MESSAGE:
                    cid, _seq, log_time, pub = _MSG_BODY.unpack_from(records, b)
                    counts[cid] = counts.get(cid, 0) + 1
                    if wanted(cid):
                        out.append((cid, log_time, pub, records[b + 22:e]))
                elif op in (OP_SCHEMA, OP_CHANNEL):
                    self._other(op, records, b, e, -1)
                p = e
        except (_Damaged, struct.error, UnicodeDecodeError):
            self.index.schemas, self.index.channels = schemas_before, channels_before
            raise
        ci = ChunkIndex(t0, t1, pos, end - pos, usize, csize, compression, {}, 0, counts)
        self.index.chunks.append(ci)
        if counts:
            self.index.note_times(t0, t1)
        r = self.report
        r.chunks += 1
        n = sum(counts.values())
        if n:
            r.messages += n
            r.first_time = t0 if r.first_time is None else min(r.first_time, t0)
            r.last_time = t1 if r.last_time is None else max(r.last_time, t1)
        return ci, out

    def _footer_ok(self) -> bool:
        data = self._data
        if len(data) < 8 + 29 or data[-8:] != MAGIC:
            return False
        op, length = _REC.unpack_from(data, len(data) - 37)
        return op == OP_FOOTER and length == 20


class _Damaged(ValueError):
    pass


def reindex(path: Union[str, "os.PathLike[str]"], metadata: MetadataRecords = ()) -> ScanReport:
    """Give an MCAP file cut short a summary: keep every complete chunk, cut the rest, append
    the Metadata records ``(name, {key: value})``, DataEnd, summary and footer.

    Returns the :class:`ScanReport` of the file as it was. A complete file is left as it is.
    Raises :class:`BagReadError` when nothing is recoverable (see :class:`McapScan`)."""
    with McapScan(path) as scan:
        for _ in scan.messages(want=lambda cid: False):
            pass
        report = scan.report
        if report.complete:
            return report
        index = scan.index
        index.metadata = []
        cut = report.data_end
        tail = bytearray()
        # the last chunk lost its message indexes: new ones (rosbags finds a chunk's channels
        # through them)
        last = index.chunks[-1] if index.chunks else None
        if last is not None and last.counts and not last.message_index_offsets and \
                last.offset + last.length == cut:
            tail += _rebuild_message_indexes(scan._data, last, cut)
    for name, values in metadata:
        rec = metadata_record(name, values)
        index.metadata.append((name, cut + len(tail), len(rec)))
        tail += rec
    tail += index.tail(cut + len(tail))
    with open(path, "r+b") as fh:
        fh.truncate(cut)
        fh.seek(cut)
        fh.write(tail)
    return report


def _rebuild_message_indexes(data: Buffer, chunk: ChunkIndex, offset: int) -> bytes:
    """MessageIndex records for ``chunk`` (which must be the last chunk before ``offset``)."""
    start = chunk.offset + 9 + _CHUNK_HEAD.size
    clen = _U32.unpack_from(data, start)[0]
    start += 4 + clen + 8
    records = data[start:chunk.offset + chunk.length]
    if chunk.compression:
        raise BagReadError("cannot re-index a compressed chunk without its message indexes")
    entries: Dict[int, array] = {}
    p = 0
    while p < len(records):
        op, length = _REC.unpack_from(records, p)
        if op == OP_MESSAGE:
            cid, _seq, log_time, _pub = _MSG_BODY.unpack_from(records, p + 9)
            entries.setdefault(cid, array("Q")).extend((log_time, p))
        p += 9 + length
    out = bytearray()
    for cid, arr in entries.items():
        chunk.message_index_offsets[cid] = offset + len(out)
        b = arr.tobytes()
        out += _record(OP_MESSAGE_INDEX, _U16.pack(cid) + _U32.pack(len(b)) + b)
    chunk.message_index_length = len(out)
    return bytes(out)
