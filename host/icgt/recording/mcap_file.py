"""The MCAP file itself: a chunk writer that knows what is on disk (used by `McapRecorder` and `icgt recover`).

Crash safety. Messages are collected in memory into one chunk; the chunk is compressed and written
(chunk record + its message indexes in one write call) when closed, then fsync'd. Schemas, channels,
metadata and attachments go to disk between chunks as soon as they are registered, so after kill -9
or a power cut the file is an MCAP prefix that ends at a record boundary. Write errors (disk full,
quota, I/O error) cut the file back to the last complete record and say how far it is readable.
Times are nanoseconds since the Unix epoch (UTC), as Foxglove expects.
"""

from __future__ import annotations

import contextlib
import errno
import io
import logging
import os
import struct
import zlib
from collections.abc import Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from typing import IO, Literal

import lz4.frame  # type: ignore[import-untyped]
import zstandard
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

from icgt.errors import IcgtError
from icgt.spill import Spill
from icgt.version import __version__

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
        spill_dir: str | os.PathLike[str] | None = None,
    ) -> None:
        self._stream = stream
        self._stream_closed = False
        self._compress = _Compressor(compression)
        self.max_chunk_bytes = max_chunk_bytes
        self.committed_bytes = 0
        self._data_crc = 0
        self._schemas: dict[int, Schema] = {}
        self._channels: dict[int, Channel] = {}
        # The summary's ChunkIndex records, encoded as they are made (about 200 B a chunk) and kept on disk until
        # the summary is written: the index grows with the recording, a chunk every chunk_interval_s, and in
        # memory it made the recorder's resident set grow by 0.05 MiB a minute (issue 30's soak).
        self._chunk_indexes = Spill("the MCAP chunk index", spill_dir)
        self._chunk_count = 0
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
        return self._chunk_count

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
            _encode(
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
        )
        self._chunk_count += 1
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
            chunk_count=self._chunk_count,
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
            (Opcode.CHUNK_INDEX, self._chunk_indexes.read_all()),
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
            self._chunk_indexes.close()


def _describe_oserror(exc: BaseException) -> str:
    if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return "disk full"
    if isinstance(exc, OSError) and exc.errno == errno.EFBIG:
        return "file size limit reached"
    if isinstance(exc, OSError):
        return f"write error ({exc.strerror or exc})"
    return f"internal error ({type(exc).__name__}: {exc})"


_RECORD_HEAD = struct.Struct("<BQ")
_CHUNK_TIMES = struct.Struct("<QQ")  # a Chunk record starts with message_start_time, message_end_time


class ChunkTail:
    """Follows a growing (or killed) MCAP file from outside: the newest log time its complete chunks hold.

    Reads only record headers, from where the last call stopped, so polling a file being recorded is cheap;
    a record not yet complete on disk is read again next time. Times: ns since the Unix epoch.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = os.fspath(path)
        self._offset = len(MAGIC)
        self.newest_log_time_ns: int | None = None
        self.chunks = 0

    def poll(self) -> int | None:
        """Reads what was added since the last call; the newest log time on disk (None: no chunk yet)."""
        with open(self.path, "rb") as f:
            f.seek(self._offset)
            data = f.read()
        pos = 0
        while pos + _RECORD_HEAD.size <= len(data):
            opcode, length = _RECORD_HEAD.unpack_from(data, pos)
            end = pos + _RECORD_HEAD.size + length
            if end > len(data):
                break  # not complete yet
            if opcode == Opcode.CHUNK and length >= _CHUNK_TIMES.size:
                _, last = _CHUNK_TIMES.unpack_from(data, pos + _RECORD_HEAD.size)
                self.newest_log_time_ns = (
                    last if self.newest_log_time_ns is None else max(last, self.newest_log_time_ns)
                )
                self.chunks += 1
            pos = end
        self._offset += pos
        return self.newest_log_time_ns
