"""Crash-safe MCAP recording: a chunk writer that knows what is on disk, and a thread-safe recorder on top.

Times: every `log_time_ns` / `publish_time_ns` is nanoseconds since the Unix epoch (UTC), as Foxglove
expects; wall-clock intervals (`max_chunk_interval_s`) are seconds of `time.monotonic()`.

Crash safety. Messages are collected in memory into one chunk; the chunk is compressed and written
(chunk record + its message indexes in one write call) when it is `max_chunk_interval_s` old or
`max_chunk_bytes` large, whichever comes first, even if no further message arrives, and then fsync'd.
Schemas, channels, metadata and attachments go to disk between chunks as soon as they are
registered. So after kill -9 or a power cut the file is an MCAP prefix that ends at a record boundary
and holds everything up to the last closed chunk: at most `max_chunk_interval_s` (+ one write and one
fsync) of messages are lost, and `icgt recover` (recover.py) turns it into a complete, indexed file.

Write errors (disk full, quota, I/O error) stop the recording: the file is cut back to the last complete
record, the summary is written if it fits, and a RecordingError says how far the file is readable.
"""

from __future__ import annotations

import contextlib
import dataclasses
import errno
import io
import json
import logging
import math
import os
import struct
import threading
import time
import zlib
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from itertools import count
from pathlib import Path
from typing import IO, Any, Literal

import lz4.frame  # type: ignore[import-untyped]
import msgspec
import zstandard
from foxglove_schemas_protobuf.Log_pb2 import Log
from google.protobuf.message import Message as ProtobufMessage
from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import (
    Attachment,
    AttachmentIndex,
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    McapRecord,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap_protobuf.schema import build_file_descriptor_set

from icgt import __version__
from icgt.errors import IcgtError
from icgt.recording.schemas import json_encoder, json_schema_bytes, schema_name

Compression = Literal["zstd", "lz4", "none"]

MAGIC = b"\x89MCAP0\r\n"
LIBRARY = f"icgt-recorder/{__version__}"
# opcode, record length, channel id, sequence, log time, publish time: the fixed part of a Message record
_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = _MESSAGE_HEADER.size - 9
_FOOTER_PREFIX = struct.Struct("<BQQQ")

logger = logging.getLogger(__name__)


class RecordingError(IcgtError):
    """The recording cannot go on or cannot be made (file exists, disk full, bad input to recover)."""


def _encode(*records: McapRecord) -> bytes:
    builder = RecordBuilder()
    for record in records:
        record.write(builder)
    data: bytes = builder.end()  # type: ignore[no-untyped-call]  # mcap's RecordBuilder.end is unannotated
    return data


def iso_utc(time_ns: int | None) -> str:
    """A Unix-epoch nanosecond time as ISO 8601 UTC with milliseconds, for messages to people."""
    if time_ns is None:
        return "the start (no message was saved)"
    return datetime.fromtimestamp(time_ns / 1e9, UTC).isoformat(timespec="milliseconds")


def message_record(channel_id: int, sequence: int, log_time_ns: int, publish_time_ns: int, data: bytes) -> bytes:
    """One MCAP Message record; raises struct.error if an id or time is out of range (times: u64 ns)."""
    return (
        _MESSAGE_HEADER.pack(
            Opcode.MESSAGE, _MESSAGE_FIXED + len(data), channel_id, sequence, log_time_ns, publish_time_ns
        )
        + data
    )


class _Compressor:
    def __init__(self, kind: Compression) -> None:
        if kind not in ("zstd", "lz4", "none"):
            raise RecordingError(f"unknown chunk compression {kind!r}: use zstd, lz4 or none")
        self.name = "" if kind == "none" else kind
        # One compressor per writer: zstandard's are not thread-safe, and each writer has one thread.
        self._zstd = zstandard.ZstdCompressor(level=3) if kind == "zstd" else None

    def __call__(self, data: bytes) -> bytes:
        if self._zstd is not None:
            return self._zstd.compress(data)
        if self.name == "lz4":
            compressed: bytes = lz4.frame.compress(data)
            return compressed
        return data


@dataclass
class _OpenChunk:
    data: bytearray = field(default_factory=bytearray)
    index: dict[int, list[tuple[int, int]]] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0
    messages: int = 0


class McapFileWriter:
    """A single-threaded chunked MCAP writer that tracks exactly which bytes are safely written.

    Everything reaches the stream in whole records through one `write` call per unit (a chunk and its
    message indexes, a schema, a metadata record...). `committed_bytes`, the statistics and the indexes
    only ever describe units written completely, so after an OSError `salvage()` can cut the file back
    and still write a truthful summary. The stream should be unbuffered (`open(path, "xb", buffering=0)`).
    """

    def __init__(
        self,
        stream: IO[bytes],
        *,
        profile: str = "",
        library: str = LIBRARY,
        compression: Compression = "zstd",
        max_chunk_bytes: int = 4 * 1024 * 1024,
    ) -> None:
        self._stream = stream
        self._stream_closed = False
        self._compress = _Compressor(compression)
        self.max_chunk_bytes = max_chunk_bytes
        self.committed_bytes = 0
        self._data_crc = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        self._chunk_indexes: list[ChunkIndex] = []
        self._metadata_indexes: list[MetadataIndex] = []
        self._attachment_indexes: list[AttachmentIndex] = []
        self._channel_counts: dict[int, int] = {}
        self.message_count = 0
        self.first_log_time_ns: int | None = None
        self.last_log_time_ns: int | None = None
        self._chunk = _OpenChunk()
        self.finished = False
        self._commit(MAGIC + _encode(Header(profile=profile, library=library)))

    # --- what is in memory ---------------------------------------------------------------------

    @property
    def pending_messages(self) -> int:
        """Messages in the open chunk: in memory only, lost if the process dies now."""
        return self._chunk.messages

    @property
    def chunk_count(self) -> int:
        return len(self._chunk_indexes)

    def add_message_record(self, channel_id: int, log_time_ns: int, record: bytes) -> bool:
        """Appends a record made by `message_record` to the open chunk; True when the chunk is full."""
        chunk = self._chunk
        chunk.index.setdefault(channel_id, []).append((log_time_ns, len(chunk.data)))
        chunk.data += record
        if chunk.messages == 0:
            chunk.start_ns = chunk.end_ns = log_time_ns
        else:
            chunk.start_ns = min(chunk.start_ns, log_time_ns)
            chunk.end_ns = max(chunk.end_ns, log_time_ns)
        chunk.messages += 1
        return len(chunk.data) >= self.max_chunk_bytes

    def add_message(self, channel_id: int, log_time_ns: int, publish_time_ns: int, data: bytes, sequence: int) -> None:
        """Adds one message, closing the chunk when it is full."""
        record = message_record(channel_id, sequence, log_time_ns, publish_time_ns, data)
        if self.add_message_record(channel_id, log_time_ns, record):
            self.close_chunk()

    # --- what goes to disk ---------------------------------------------------------------------

    def _commit(self, data: bytes) -> None:
        view = memoryview(data)
        done = 0
        while done < len(data):
            n = self._stream.write(view[done:])
            if not n:
                raise OSError(errno.EIO, "the file accepted no bytes")
            done += n
        self.committed_bytes += len(data)
        self._data_crc = zlib.crc32(data, self._data_crc)

    def has_schema(self, schema_id: int) -> bool:
        return schema_id in self._schemas

    def add_schema(self, schema_id: int, name: str, encoding: str, data: bytes) -> None:
        if schema_id in self._schemas:
            return
        schema = Schema(id=schema_id, name=name, encoding=encoding, data=data)
        self._commit(_encode(schema))
        self._schemas[schema_id] = schema

    def add_channel(
        self, channel_id: int, topic: str, message_encoding: str, schema_id: int, metadata: Mapping[str, str]
    ) -> None:
        if channel_id in self._channels:
            return
        channel = Channel(
            id=channel_id,
            topic=topic,
            message_encoding=message_encoding,
            schema_id=schema_id,
            metadata=dict(metadata),
        )
        self._commit(_encode(channel))
        self._channels[channel_id] = channel

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        offset = self.committed_bytes
        record = _encode(Metadata(name=name, metadata=dict(data)))
        self._commit(record)
        self._metadata_indexes.append(MetadataIndex(offset=offset, length=len(record), name=name))

    def add_attachment(self, name: str, media_type: str, data: bytes, log_time_ns: int, create_time_ns: int) -> None:
        offset = self.committed_bytes
        attachment = Attachment(
            create_time=create_time_ns, log_time=log_time_ns, name=name, media_type=media_type, data=data
        )
        record = _encode(attachment)
        self._commit(record)
        self._attachment_indexes.append(
            AttachmentIndex(
                offset=offset,
                length=len(record),
                log_time=log_time_ns,
                create_time=create_time_ns,
                data_size=len(data),
                name=name,
                media_type=media_type,
            )
        )

    def close_chunk(self) -> bool:
        """Compresses and writes the open chunk and its message indexes; False if it held no message."""
        chunk = self._chunk
        if chunk.messages == 0:
            return False
        raw = bytes(chunk.data)
        compressed = self._compress(raw)
        chunk_record = _encode(
            Chunk(
                compression=self._compress.name,
                data=compressed,
                message_start_time=chunk.start_ns,
                message_end_time=chunk.end_ns,
                uncompressed_crc=zlib.crc32(raw),
                uncompressed_size=len(raw),
            )
        )
        start = self.committed_bytes
        offsets: dict[int, int] = {}
        indexes = bytearray()
        for channel_id, entries in chunk.index.items():
            entries.sort()  # several threads feed one chunk: keep each channel's index in time order
            offsets[channel_id] = start + len(chunk_record) + len(indexes)
            indexes += _encode(MessageIndex(channel_id=channel_id, records=entries))
        self._commit(chunk_record + indexes)
        self._chunk_indexes.append(
            ChunkIndex(
                message_start_time=chunk.start_ns,
                message_end_time=chunk.end_ns,
                chunk_start_offset=start,
                chunk_length=len(chunk_record),
                message_index_offsets=offsets,
                message_index_length=len(indexes),
                compression=self._compress.name,
                compressed_size=len(compressed),
                uncompressed_size=len(raw),
            )
        )
        for channel_id, entries in chunk.index.items():
            self._channel_counts[channel_id] = self._channel_counts.get(channel_id, 0) + len(entries)
        self.message_count += chunk.messages
        first, last = self.first_log_time_ns, self.last_log_time_ns
        self.first_log_time_ns = chunk.start_ns if first is None else min(first, chunk.start_ns)
        self.last_log_time_ns = chunk.end_ns if last is None else max(last, chunk.end_ns)
        self._chunk = _OpenChunk()
        return True

    def sync(self) -> None:
        """Pushes what was written to the storage device (fsync), where the stream has a file descriptor."""
        self._stream.flush()
        try:
            fd = self._stream.fileno()
        except (AttributeError, io.UnsupportedOperation):
            return  # an in-memory stream: nothing to sync
        os.fsync(fd)

    def finish(self) -> None:
        """Writes the open chunk, the summary (schemas, channels, statistics, indexes) and the footer."""
        self.close_chunk()
        self._commit(self._ending(with_summary=True))
        self.finished = True

    def _statistics(self) -> Statistics:
        return Statistics(
            message_count=self.message_count,
            schema_count=len(self._schemas),
            channel_count=len(self._channels),
            attachment_count=len(self._attachment_indexes),
            metadata_count=len(self._metadata_indexes),
            chunk_count=len(self._chunk_indexes),
            message_start_time=self.first_log_time_ns or 0,
            message_end_time=self.last_log_time_ns or 0,
            channel_message_counts=dict(self._channel_counts),
        )

    def _ending(self, *, with_summary: bool) -> bytes:
        """DataEnd, the summary section if asked, the footer and the closing magic."""
        data_end = _encode(DataEnd(data_section_crc=self._data_crc))
        if not with_summary:
            return data_end + _encode(Footer(summary_start=0, summary_offset_start=0, summary_crc=0)) + MAGIC
        summary_start = self.committed_bytes + len(data_end)
        groups = [
            (Opcode.SCHEMA, _encode(*self._schemas.values())),
            (Opcode.CHANNEL, _encode(*self._channels.values())),
            (Opcode.STATISTICS, _encode(self._statistics())),
            (Opcode.CHUNK_INDEX, _encode(*self._chunk_indexes)),
            (Opcode.ATTACHMENT_INDEX, _encode(*self._attachment_indexes)),
            (Opcode.METADATA_INDEX, _encode(*self._metadata_indexes)),
        ]
        summary = bytearray()
        offsets: list[McapRecord] = []
        for opcode, group in groups:
            if group:
                offsets.append(
                    SummaryOffset(
                        group_opcode=opcode, group_start=summary_start + len(summary), group_length=len(group)
                    )
                )
                summary += group
        offsets_start = summary_start + len(summary)
        summary += _encode(*offsets)
        crc = zlib.crc32(_FOOTER_PREFIX.pack(Opcode.FOOTER, 20, summary_start, offsets_start), zlib.crc32(summary))
        footer = _encode(Footer(summary_start=summary_start, summary_offset_start=offsets_start, summary_crc=crc))
        return data_end + bytes(summary) + footer + MAGIC

    def salvage(self) -> str:
        """After a write error: makes the file as complete as the disk allows; never raises.

        Drops the open chunk, cuts the file back to the last complete record, then tries the full
        summary, else a bare footer (still a complete MCAP, read linearly), else leaves the prefix
        (readable in stream mode; `icgt recover` completes it). Returns which of the three it got.
        """
        self._chunk = _OpenChunk()
        for ending, outcome in ((True, "complete and indexed"), (False, "complete but not indexed")):
            try:
                self._stream.truncate(self.committed_bytes)
                self._stream.seek(self.committed_bytes)
                self._commit(self._ending(with_summary=ending))
                self.sync()
                self.finished = True
                return outcome
            except (OSError, ValueError):  # ValueError: the stream is already closed
                continue
        try:
            self._stream.truncate(self.committed_bytes)
        except (OSError, ValueError):
            return "unfinished and possibly ending in a partial record: run `icgt recover`"
        return "unfinished (no summary): `icgt recover` makes it complete"

    def close_stream(self) -> None:
        """Closes the stream once; never raises (an unbuffered file has nothing left to flush)."""
        if not self._stream_closed:
            self._stream_closed = True
            with contextlib.suppress(OSError, ValueError):
                self._stream.close()


def _describe_oserror(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return "disk full"
    if isinstance(exc, OSError) and exc.errno == errno.EFBIG:
        return "file size limit reached"
    if isinstance(exc, OSError):
        return f"write error ({exc.strerror or exc})"
    return f"internal error ({type(exc).__name__}: {exc})"


@dataclass(frozen=True)
class RecordingStats:
    """What a recording holds on disk. Times: ns since the Unix epoch; None before the first saved message."""

    path: Path
    bytes_written: int
    messages: int
    chunks: int
    first_log_time_ns: int | None
    last_log_time_ns: int | None
    complete: bool
    error: str | None


@dataclass
class _Topic:
    channel_id: int
    schema_id: int
    kind: type | None  # the Python type its messages must have; None: mappings for a register_json topic
    encode: Callable[[Any], bytes]
    sequence: count[int] = field(default_factory=count)


@dataclass
class _Control:
    """Work for the writer thread other than a message: register, metadata, flush, stop."""

    action: Callable[[McapFileWriter], None] | None
    done: threading.Event | None = None
    stop: bool = False


_Item = tuple[int, int, bytes, float] | _Control  # a message: channel id, log time ns, record, enqueue monotonic s


class McapRecorder:
    """A thread-safe, crash-safe MCAP recorder for one file.

    Threading: `write()` encodes the message in the calling thread (so a bad message fails where it was
    made) and appends the finished record to a bounded queue; one writer thread owns the file and does
    the chunking, compression, write and fsync. Why not one lock around the file: the serial and MAVLink
    readers call `write()`, and a lock would make them wait out compression, a disk stall or an fsync
    (milliseconds, on SD cards far more), delaying their host receive timestamps, on which the clock
    estimates depend. The queue (`queue_size` messages) absorbs a slow disk; if it stays full for
    `put_timeout_s`, `write()` raises RecordingError rather than block forever. The queue is a deque the
    writer drains in batches: it is woken by the first message of a chunk, by control requests
    (metadata, flush, close), by a filling queue and by the chunk deadline, not by every message
    (measured against queue.Queue: 8.5 -> 5.5-6.8 us of CPU per LocationFix written).
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        *,
        profile: str = "",
        max_chunk_interval_s: float = 1.0,
        max_chunk_bytes: int = 4 * 1024 * 1024,
        compression: Compression = "zstd",
        fsync: bool = True,
        queue_size: int = 50_000,
        put_timeout_s: float = 5.0,
        opener: Callable[[Path], IO[bytes]] | None = None,
    ) -> None:
        """Creates `path` (never overwriting) and starts the writer thread.

        `profile` is the MCAP header profile: empty, since the file mixes protobuf and JSON channels,
        which no well-known profile describes. `opener` replaces `open(path, "xb", buffering=0)`
        (tests, special sinks).
        """
        if not (max_chunk_interval_s > 0 and math.isfinite(max_chunk_interval_s)):
            raise RecordingError(
                f"max_chunk_interval_s must be a positive number of seconds, not {max_chunk_interval_s}"
            )
        self.path = Path(path)
        self._interval = max_chunk_interval_s
        self._fsync = fsync
        self._put_timeout_s = put_timeout_s
        self._file = self._create(opener, profile, compression, max_chunk_bytes)
        self._pending: deque[_Item] = deque()
        self._max_pending = queue_size
        self._drain_at = max(1, queue_size // 4)  # wake the writer well before producers would have to wait
        self._wake = threading.Event()
        self._writer_idle = False  # True while the writer waits with no open chunk: the next message wakes it
        self._lock = threading.RLock()  # guards registration and closing; held only for an append
        self._topics: dict[str, _Topic] = {}
        self._schema_ids: dict[tuple[str, str, bytes], int] = {}
        self._closing = False
        self._error: RecordingError | None = None
        self._error_raised_by_close = False
        self._thread = threading.Thread(target=self._run, name=f"mcap-writer {self.path.name}", daemon=True)
        self._thread.start()
        self.add_metadata(
            "icgt.recording",
            {
                "recorder": LIBRARY,
                "time_base": "log_time and publish_time: nanoseconds since the Unix epoch (UTC)",
                "max_chunk_interval_s": repr(max_chunk_interval_s),
                "compression": compression,
                "started_utc": iso_utc(time.time_ns()),
            },
        )

    def _create(
        self, opener: Callable[[Path], IO[bytes]] | None, profile: str, compression: Compression, max_chunk_bytes: int
    ) -> McapFileWriter:
        try:
            stream = opener(self.path) if opener else open(self.path, "xb", buffering=0)  # noqa: SIM115
        except FileExistsError:
            raise RecordingError(f"refusing to overwrite {self.path}: it already exists") from None
        except OSError as exc:
            raise RecordingError(f"cannot create {self.path}: {exc.strerror or exc}") from None
        try:
            return McapFileWriter(stream, profile=profile, compression=compression, max_chunk_bytes=max_chunk_bytes)
        except (OSError, RecordingError) as exc:
            stream.close()
            if opener is None:  # we created it, and it holds nothing worth keeping
                self.path.unlink(missing_ok=True)
            if isinstance(exc, RecordingError):
                raise
            raise RecordingError(f"cannot start {self.path}: {_describe_oserror(exc)}") from None

    # --- registration -----------------------------------------------------------------------------

    def register_protobuf(
        self, topic: str, message_type: type[ProtobufMessage], metadata: Mapping[str, str] | None = None
    ) -> None:
        """Declares a protobuf topic (e.g. foxglove.LocationFix); `write` would do it on first use."""
        fds = build_file_descriptor_set(message_type).SerializeToString()
        name = message_type.DESCRIPTOR.full_name
        self._register(topic, (name, "protobuf", fds), "protobuf", message_type, _serialize_protobuf, metadata)

    def register_dataclass(self, topic: str, record_type: type, metadata: Mapping[str, str] | None = None) -> None:
        """Declares a JSON topic whose messages are instances of a dataclass described by `schemas.Doc`."""
        key = (schema_name(record_type), "jsonschema", json_schema_bytes(record_type))
        self._register(topic, key, "json", record_type, json_encoder(record_type), metadata)

    def register_json(
        self, topic: str, name: str, json_schema: Mapping[str, Any], metadata: Mapping[str, str] | None = None
    ) -> None:
        """Declares a JSON topic carrying mappings described by `json_schema` (the caller keeps them valid)."""
        data = json.dumps(json_schema, sort_keys=True, separators=(",", ":")).encode()
        self._register(topic, (name, "jsonschema", data), "json", None, _dump_mapping, metadata)

    def _register(
        self,
        topic: str,
        schema: tuple[str, str, bytes],
        message_encoding: str,
        kind: type | None,
        encode: Callable[[Any], bytes],
        metadata: Mapping[str, str] | None,
    ) -> _Topic:
        with self._lock:
            existing = self._topics.get(topic)
            if existing is not None:
                if self._schema_ids.get(schema) != existing.schema_id:
                    raise RecordingError(f"topic {topic} is already recorded with another schema than {schema[0]}")
                return existing
            schema_id = self._schema_ids.get(schema) or len(self._schema_ids) + 1
            channel_id = len(self._topics) + 1
            if channel_id > 0xFFFF:
                raise RecordingError("too many topics: MCAP channel ids are 16-bit")
            meta = dict(metadata or {})

            def declare(f: McapFileWriter) -> None:
                f.add_schema(schema_id, *schema)
                f.add_channel(channel_id, topic, message_encoding, schema_id, meta)

            self._enqueue(_Control(declare))
            self._schema_ids[schema] = schema_id
            entry = _Topic(channel_id, schema_id, kind, encode)
            self._topics[topic] = entry
            return entry

    # --- writing ----------------------------------------------------------------------------------

    def write(self, topic: str, message: Any, log_time_ns: int, publish_time_ns: int | None = None) -> None:
        """Records one message; thread-safe, returns once queued (not yet on disk).

        `message`: a protobuf message, a dataclass instance, or a mapping for a `register_json` topic.
        `log_time_ns`: when the host received the data, ns since the Unix epoch; `publish_time_ns`: when
        its source produced it, same epoch (defaults to log_time_ns). Raises RecordingError after a
        write error, after close(), or for a message that does not fit its topic.
        """
        entry = self._topics.get(topic)
        if entry is None:
            entry = self._auto_register(topic, message)
        elif entry.kind is not None and type(message) is not entry.kind:
            raise RecordingError(f"topic {topic} records {entry.kind.__name__}, not {type(message).__name__}")
        try:
            data = entry.encode(message)
        except (TypeError, ValueError) as exc:
            raise RecordingError(f"cannot encode a message for {topic}: {exc}") from exc
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        try:
            record = message_record(entry.channel_id, next(entry.sequence) & 0xFFFFFFFF, log_time_ns, publish, data)
        except struct.error:
            raise RecordingError(
                f"times must be integers in [0, 2**64) ns since the Unix epoch, got {log_time_ns!r}, {publish!r}"
            ) from None
        self._enqueue((entry.channel_id, log_time_ns, record, time.monotonic()))

    def _auto_register(self, topic: str, message: Any) -> _Topic:
        if isinstance(message, ProtobufMessage):
            self.register_protobuf(topic, type(message))
        elif dataclasses.is_dataclass(message) and not isinstance(message, type):
            self.register_dataclass(topic, type(message))
        else:
            raise RecordingError(
                f"topic {topic}: call register_json() before writing {type(message).__name__} messages"
            )
        return self._topics[topic]

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """A metadata record (e.g. firmware and protocol versions, serial, configuration, calibration)."""
        values = dict(data)
        if not all(isinstance(k, str) and isinstance(v, str) for k, v in values.items()):
            raise RecordingError(f"metadata {name}: keys and values must be strings")
        self._enqueue(_Control(lambda f: f.add_metadata(name, values)))

    def add_attachment(
        self, name: str, media_type: str, data: bytes, log_time_ns: int | None = None, create_time_ns: int = 0
    ) -> None:
        """A file stored whole in the recording (e.g. the configuration file); times: ns since the Unix epoch."""
        log_time = time.time_ns() if log_time_ns is None else log_time_ns
        payload = bytes(data)
        self._enqueue(_Control(lambda f: f.add_attachment(name, media_type, payload, log_time, create_time_ns)))

    def flush(self, timeout_s: float = 10.0) -> None:
        """Blocks until everything written before the call is on disk (chunk closed, fsync'd)."""
        done = threading.Event()
        self._enqueue(_Control(None, done))
        if not done.wait(timeout_s):
            raise RecordingError(f"{self.path}: the disk did not take the data within {timeout_s} s")
        self._raise_if_failed()

    def _enqueue(self, item: _Item) -> None:
        deadline = None
        while True:
            with self._lock:
                self._raise_if_failed()
                if self._closing:
                    raise RecordingError(f"{self.path} is closed")
                if len(self._pending) < self._max_pending:
                    self._pending.append(item)
                    # Read after the append: the writer sets _writer_idle before its last look at the
                    # queue, so either it sees this item or we see the flag (see _wait_for_work).
                    if self._writer_idle or not isinstance(item, tuple) or len(self._pending) >= self._drain_at:
                        self._wake.set()
                    return
            self._wake.set()  # full: make the writer drain now
            if threading.current_thread() is self._thread:
                return  # e.g. the log handler on the writer thread: waiting would wait for ourselves
            now = time.monotonic()
            deadline = now + self._put_timeout_s if deadline is None else deadline
            if now > deadline:
                raise RecordingError(
                    f"{self.path}: the disk has not kept up for {self._put_timeout_s} s "
                    f"({self._max_pending} messages waiting)"
                )
            time.sleep(0.005)

    def _raise_if_failed(self) -> None:
        if self._error is not None:
            raise RecordingError(str(self._error))

    # --- the writer thread --------------------------------------------------------------------------

    def _wait_for_work(self, deadline: float) -> None:
        """Sleeps until the chunk deadline, a control request or a full queue; with no open chunk, until work.

        The wake-up is consumed (cleared) after waking, not before sleeping, so a request made while the
        writer was busy is never lost; its item is in the queue before the event is set, so the drain
        that follows the clear sees it. A stale wake-up only costs one empty pass.
        """
        if deadline == math.inf:
            self._writer_idle = True
            if not self._pending:  # looked at after setting the flag: a racing append sees the flag and wakes us
                self._wake.wait()
            self._writer_idle = False
        else:
            timeout = deadline - time.monotonic()
            if timeout > 0:
                self._wake.wait(timeout)
        self._wake.clear()

    def _run(self) -> None:
        deadline = math.inf  # monotonic time by which the open chunk must be on disk
        while True:
            self._wait_for_work(deadline)
            while self._pending:
                item = self._pending.popleft()
                try:
                    if isinstance(item, tuple):
                        deadline = self._add(item, deadline)
                    elif item.stop:
                        self._finish()  # handles its own errors: the thread must end here
                        return
                    else:
                        deadline = self._control(item, deadline)
                except Exception as exc:  # any failure must end in a clean stop, never a dead thread
                    self._fail(exc)
                    deadline = math.inf
                    if isinstance(item, _Control) and item.done is not None:
                        item.done.set()
            if time.monotonic() >= deadline:
                try:
                    deadline = self._close_chunk()
                except Exception as exc:  # see above
                    self._fail(exc)
                    deadline = math.inf

    def _add(self, item: tuple[int, int, bytes, float], deadline: float) -> float:
        if self._error is not None:
            return math.inf  # stopped: drain and drop
        file = self._file
        if file.pending_messages == 0:
            deadline = item[3] + self._interval  # counted from when the first message was handed over
        if file.add_message_record(item[0], item[1], item[2]):
            return self._close_chunk()
        return deadline

    def _control(self, item: _Control, deadline: float) -> float:
        if self._error is None:
            if item.action is not None:
                item.action(self._file)
            if item.done is not None:  # a flush: everything so far to the device, metadata too
                self._file.close_chunk()
                if self._fsync:
                    self._file.sync()
                deadline = math.inf
        if item.done is not None:
            item.done.set()
        return deadline

    def _close_chunk(self) -> float:
        if self._file.close_chunk() and self._fsync:
            self._file.sync()  # one fsync per chunk: ~0.4 ms here, and at most a few per second
        return math.inf

    def _finish(self) -> None:
        if self._error is None:
            try:
                self._file.finish()
                if self._fsync:
                    self._file.sync()
            except Exception as exc:  # see _run
                self._fail(exc)
        self._file.close_stream()

    def _fail(self, exc: BaseException) -> None:
        if self._error is not None:
            return
        lost = self._file.pending_messages + sum(isinstance(item, tuple) for item in list(self._pending))
        file = self._file
        outcome = file.salvage()
        file.close_stream()
        self._error = RecordingError(
            f"{_describe_oserror(exc)} at {self.path} after {file.committed_bytes} bytes: recording stopped, "
            f"file is readable up to {iso_utc(file.last_log_time_ns)} ({file.message_count} messages, {outcome}); "
            f"about {lost} newer messages were not saved"
        )
        logger.error("%s", self._error)

    # --- the end ------------------------------------------------------------------------------------

    @property
    def error(self) -> RecordingError | None:
        """The failure that stopped the recording, if any (write() and close() raise it too)."""
        return self._error

    def stats(self) -> RecordingStats:
        """What is on disk now (read without locking: a snapshot good for status displays)."""
        f = self._file
        return RecordingStats(
            path=self.path,
            bytes_written=f.committed_bytes,
            messages=f.message_count,
            chunks=f.chunk_count,
            first_log_time_ns=f.first_log_time_ns,
            last_log_time_ns=f.last_log_time_ns,
            complete=f.finished,
            error=None if self._error is None else str(self._error),
        )

    def close(self) -> RecordingStats:
        """Writes what is queued, the summary and the footer; idempotent.

        Raises RecordingError (once) if the recording stopped on an error; the file is then as complete
        as the disk allowed and the writer thread has ended either way.
        """
        with self._lock:
            first_close = not self._closing
            self._closing = True
        if first_close:
            self._pending.append(_Control(None, stop=True))  # past the size bound: stopping must not wait
            self._wake.set()
        self._thread.join()
        if self._error is not None and not self._error_raised_by_close:
            self._error_raised_by_close = True
            raise RecordingError(str(self._error))
        return self.stats()

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: object) -> None:
        try:
            self.close()
        except RecordingError:
            if exc_type is None:
                raise
            # an exception is already on its way out; ours is in the log and in self.error


def _serialize_protobuf(message: Any) -> bytes:
    data: bytes = message.SerializeToString()
    return data


# msgspec's encoder: compact JSON like json.dumps(separators=(",", ":")) at several times its speed (the
# recorder writes every raw message as JSON). A non-finite float becomes null (json.dumps would raise and
# stop the recording); the payload builders leave non-finite values out before they get here.
_JSON_ENCODE = msgspec.json.Encoder().encode


def _dump_mapping(message: Any) -> bytes:
    if not isinstance(message, Mapping):
        raise TypeError(f"a JSON topic registered with register_json takes mappings, not {type(message).__name__}")
    return _JSON_ENCODE(message)


_LOG_LEVELS = (
    (logging.CRITICAL, Log.FATAL),
    (logging.ERROR, Log.ERROR),
    (logging.WARNING, Log.WARNING),
    (logging.INFO, Log.INFO),
)


class McapLogHandler(logging.Handler):
    """Records Python log records on a foxglove.Log topic of a recorder (Foxglove's Log panel shows them)."""

    def __init__(self, recorder: McapRecorder, topic: str = "/icgt/log", level: int = logging.INFO) -> None:
        super().__init__(level)
        self._recorder = recorder
        self._topic = topic

    def emit(self, record: logging.LogRecord) -> None:
        try:
            time_ns = int(record.created * 1e9)  # LogRecord.created: float seconds since the Unix epoch
            level = next((fox for py, fox in _LOG_LEVELS if record.levelno >= py), Log.DEBUG)
            message = Log(
                level=level, message=self.format(record), name=record.name, file=record.pathname, line=record.lineno
            )
            message.timestamp.FromNanoseconds(time_ns)
            self._recorder.write(self._topic, message, time_ns)
        except RecordingError:
            pass  # the recorder has stopped and reports that itself; logging it here would loop
        except Exception:  # logging must never take the program down
            self.handleError(record)
