"""`icgt recover`: turn an unfinished MCAP file (recorder killed, power cut, disk full) into a complete one.

The source is walked record by record (MCAP's framing: opcode, 64-bit length, body), each body
parsed by the official library's record classes (`mcap.records`) through a strict byte source
that refuses short reads, so a record cut off by the crash is never half-parsed. Every chunk is
checked against its CRC and unpacked on its own: a damaged chunk is skipped and counted, the ones
after it are still kept. A record that cannot be parsed at all (zeroed or overwritten bytes, a bad
length) does not end the reading: the walk resynchronises at the next offset that holds a whole
chunk record whose CRC checks (a scan for the chunk opcode), and the skipped byte range is
reported (`RecoveryReport.skipped`). Only a damaged tail with no intact chunk after it is discarded.
The mcap library's StreamReader stops at the first bad record, hence this walk (the framing is
MCAP's, the parsing the library's).
Schemas, channels, messages (with their original ids, sequence numbers and times), metadata and
attachments go into a new file with a summary, chunk and message indexes and statistics.
Times in the report: nanoseconds since the Unix epoch, as recorded.
"""

from __future__ import annotations

import io
import mmap
import os
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, cast

from mcap.data_stream import ReadDataStream
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
    Message,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import breakup_chunk

from icgt.recording.writer import LIBRARY, MAGIC, McapFileWriter, RecordingError, iso_utc


class _TruncatedError(Exception):
    """The source ended inside a record."""


class _StrictSource:
    """A read-only byte source that raises instead of returning fewer bytes than asked for.

    mcap's ReadDataStream only notices an empty read, so a record cut off by a crash would come back
    with short fields; failing the short read keeps the boundary of the last complete record exact.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self._stream = stream
        self._size = size
        self.position = 0

    def read(self, n: int = -1) -> bytes:
        if n > self._size - self.position:  # also keeps a garbage length from allocating gigabytes
            raise _TruncatedError(f"a {n}-byte read at offset {self.position} runs past the end of the file")
        data = self._stream.read(n)
        if n >= 0 and len(data) < n:
            raise _TruncatedError(f"the file ends {len(data)} bytes into a {n}-byte read at offset {self.position}")
        self.position += len(data)
        return data


@dataclass
class RecoveryReport:
    """What recover() kept and what it left behind."""

    source: Path
    destination: Path
    messages_per_topic: dict[str, int] = field(default_factory=dict)
    first_log_time_ns: int | None = None
    last_log_time_ns: int | None = None
    source_bytes: int = 0
    good_bytes: int = 0  # the source is intact up to this offset (end of the last complete record)
    chunks_kept: int = 0
    chunks_damaged: int = 0
    damaged_chunks: list[tuple[int, str]] = field(default_factory=list)
    """(offset in the source [bytes], why) of each chunk skipped because its content is damaged."""
    messages_without_channel: int = 0
    metadata_records: int = 0
    attachments: int = 0
    source_was_complete: bool = False
    end_reason: str = ""
    skipped: list[tuple[int, int, str]] = field(default_factory=list)
    """Damaged byte ranges [start, end) in the middle of the file that were skipped, and why."""

    @property
    def lossy(self) -> bool:
        """Something in the middle of the file was unreadable (skipped ranges or damaged chunks)."""
        return bool(self.skipped or self.chunks_damaged)

    @property
    def bytes_discarded(self) -> int:
        """Bytes of the damaged tail after the last complete record."""
        return self.source_bytes - self.good_bytes

    @property
    def messages(self) -> int:
        return sum(self.messages_per_topic.values())

    def describe(self) -> str:
        if self.source_was_complete:
            state = "had its end (footer) but damage inside" if self.lossy else "was already complete"
        else:
            state = "was unfinished"
        lines = [
            f"{self.source} -> {self.destination}: {self.messages} messages in {self.chunks_kept} chunks, "
            f"from {iso_utc(self.first_log_time_ns)} to {iso_utc(self.last_log_time_ns)}",
            f"source {state}: {self.end_reason}; "
            f"{self.bytes_discarded} bytes of damaged tail discarded, {self.chunks_damaged} damaged chunks skipped",
        ]
        for offset, why in self.damaged_chunks:
            lines.append(f"damaged chunk at byte {offset} skipped (its messages are lost): {why}")
        for start, end, why in self.skipped:
            lines.append(f"skipped bytes {start}-{end} ({end - start} bytes): {why}")
        if self.messages_without_channel:
            lines.append(f"{self.messages_without_channel} messages dropped: their channel record was lost")
        lines += [f"  {topic}: {n}" for topic, n in sorted(self.messages_per_topic.items())]
        return "\n".join(lines)


def recover(src: str | os.PathLike[str], dst: str | os.PathLike[str]) -> RecoveryReport:
    """Reads the unfinished MCAP `src` and writes every complete message into the new, indexed file `dst`.

    Raises RecordingError (and leaves no `dst`) when `src` is unreadable, not an MCAP file or holds no
    complete chunk, or `dst` exists or cannot be written.
    """
    source, destination = Path(src), Path(dst)
    if source.resolve() == destination.resolve():
        raise RecordingError(f"recover writes a new file: {destination} is the source itself")
    try:
        handle = source.open("rb")
    except OSError as exc:
        raise RecordingError(f"cannot read {source}: {exc.strerror or exc}") from None
    with handle:
        report = RecoveryReport(source, destination, source_bytes=os.fstat(handle.fileno()).st_size)
        _check_magic(handle.read(len(MAGIC)), source)
        handle.seek(0)
        try:
            out = destination.open("xb", buffering=0)
        except FileExistsError:
            raise RecordingError(f"refusing to overwrite {destination}: it already exists") from None
        except OSError as exc:
            raise RecordingError(f"cannot create {destination}: {exc.strerror or exc}") from None
        try:
            with out:
                _copy(handle, out, report)
        except BaseException:
            destination.unlink(missing_ok=True)
            raise
    return report


def _check_magic(head: bytes, source: Path) -> None:
    if not head:
        raise RecordingError(f"{source} is empty: not an MCAP file")
    if head != MAGIC[: len(head)] or len(head) < len(MAGIC):
        raise RecordingError(f"{source} is not an MCAP file (it does not start with the MCAP magic bytes)")


_RECORDS: dict[int, type[McapRecord]] = {
    Opcode.ATTACHMENT: Attachment,
    Opcode.ATTACHMENT_INDEX: AttachmentIndex,
    Opcode.CHANNEL: Channel,
    Opcode.CHUNK: Chunk,
    Opcode.CHUNK_INDEX: ChunkIndex,
    Opcode.DATA_END: DataEnd,
    Opcode.FOOTER: Footer,
    Opcode.HEADER: Header,
    Opcode.MESSAGE: Message,
    Opcode.MESSAGE_INDEX: MessageIndex,
    Opcode.METADATA: Metadata,
    Opcode.METADATA_INDEX: MetadataIndex,
    Opcode.SCHEMA: Schema,
    Opcode.STATISTICS: Statistics,
    Opcode.SUMMARY_OFFSET: SummaryOffset,
}
_CHUNK_COMPRESSIONS = ("", "zstd", "lz4")


class _DamagedError(Exception):
    """No whole, parsable record at an offset."""


def _parse_at(buf: bytes | mmap.mmap, pos: int, size: int) -> tuple[McapRecord, int]:
    """The record at `pos` and the offset after it; raises _DamagedError (cut off, unknown opcode, unparsable)."""
    if pos + 9 > size:
        raise _DamagedError(f"the file ends inside a record header at offset {pos}")
    opcode = buf[pos]
    length = int.from_bytes(buf[pos + 1 : pos + 9], "little")
    cls = _RECORDS.get(opcode)
    if cls is None:
        raise _DamagedError(f"no MCAP record at offset {pos} (opcode {opcode:#04x})")
    end = pos + 9 + length
    if end > size:
        raise _DamagedError(f"a {cls.__name__} record at offset {pos} runs {end - size} bytes past the end of the file")
    body = bytes(buf[pos + 9 : end])
    stream = ReadDataStream(cast(IO[bytes], _StrictSource(io.BytesIO(body), length)))
    try:
        record = Message.read(stream, length) if cls is Message else cls.read(stream)  # type: ignore[attr-defined]
    except Exception as exc:  # garbage can fail in any way inside the library's parsers
        raise _DamagedError(f"unreadable {cls.__name__} record at offset {pos} ({_why(exc)})") from None
    return cast(McapRecord, record), end


def _intact_chunk_at(buf: bytes | mmap.mmap, pos: int, size: int) -> bool:
    try:
        record, _ = _parse_at(buf, pos, size)
    except _DamagedError:
        return False
    if not isinstance(record, Chunk) or record.compression not in _CHUNK_COMPRESSIONS:
        return False
    try:
        return bool(breakup_chunk(record, validate_crc=True))
    except Exception:  # not a chunk after all: keep scanning
        return False


def _next_chunk(buf: bytes | mmap.mmap, start: int, size: int) -> int | None:
    """Offset of the next whole chunk record with a good CRC at or after `start` (scanning for its opcode)."""
    pos = buf.find(bytes((Opcode.CHUNK,)), start)
    while 0 <= pos < size:
        if _intact_chunk_at(buf, pos, size):
            return pos
        pos = buf.find(bytes((Opcode.CHUNK,)), pos + 1)
    return None


def _walk(buf: bytes | mmap.mmap, size: int, report: RecoveryReport) -> Iterator[tuple[int, McapRecord]]:
    """(offset in the source [bytes], record) of each readable record, in file order."""
    pos = len(MAGIC)
    while pos < size:
        try:
            record, end = _parse_at(buf, pos, size)
        except _DamagedError as exc:
            nxt = _next_chunk(buf, pos + 1, size)
            if nxt is None:
                report.end_reason = f"stopped at offset {pos}: {exc}"
                return
            report.skipped.append((pos, nxt, str(exc)))
            pos = nxt
            continue
        at, pos = pos, end
        report.good_bytes = end
        yield at, record
        if isinstance(record, Footer):
            if bytes(buf[end : end + len(MAGIC)]) == MAGIC:
                report.good_bytes = end + len(MAGIC)
                report.end_reason = "read to the end"
            else:
                report.end_reason = f"the footer at offset {pos} is not followed by the closing magic"
            return
    report.end_reason = "the file ends after a complete record (no footer)"


def _copy(handle: IO[bytes], out: IO[bytes], report: RecoveryReport) -> None:
    size = report.source_bytes
    buf: bytes | mmap.mmap = mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ) if size else b""
    writer: McapFileWriter | None = None
    channels: dict[int, Channel] = {}  # channels whose schema is known: their messages can be kept
    counts: Counter[str] = Counter()
    try:
        try:
            report.good_bytes = len(MAGIC)
            for offset, record in _walk(buf, size, report):
                if writer is None:
                    if not isinstance(record, Header):
                        raise RecordingError(f"{report.source} is not an MCAP file: it does not begin with a header")
                    writer = McapFileWriter(
                        out, profile=record.profile, library=f"{record.library}; recovered by {LIBRARY}"
                    )
                    continue
                if isinstance(record, Footer):
                    report.source_was_complete = not report.skipped
                _copy_record(record, writer, channels, counts, report, offset)
            if writer is None:
                raise RecordingError(f"{report.source} is not an MCAP file: {report.end_reason}")
            if not counts:
                raise RecordingError(
                    f"{report.source} holds no complete chunk: nothing to recover ({report.end_reason})"
                )
            writer.finish()
            writer.sync()
        except OSError as exc:
            raise RecordingError(f"cannot write {report.destination}: {exc.strerror or exc}") from None
    finally:
        if isinstance(buf, mmap.mmap):
            buf.close()
    report.messages_per_topic = dict(counts)


def _why(exc: BaseException) -> str:
    return str(exc) or type(exc).__name__


def _copy_record(
    record: McapRecord,
    writer: McapFileWriter,
    channels: dict[int, Channel],
    counts: Counter[str],
    report: RecoveryReport,
    offset: int,
) -> None:
    """Copy one record (a chunk's messages one by one); `offset`: where it starts in the source [bytes]."""
    if isinstance(record, Chunk):
        try:
            inner = breakup_chunk(record, validate_crc=True)
        except Exception as exc:  # a corrupt chunk (bad CRC, bad compression) is skipped, not fatal
            report.chunks_damaged += 1
            report.damaged_chunks.append((offset, str(exc) or type(exc).__name__))
            return
        report.chunks_kept += 1
        for item in inner:
            _copy_record(item, writer, channels, counts, report, offset)
    elif isinstance(record, Schema):
        writer.add_schema(record.id, record.name, record.encoding, record.data)
    elif isinstance(record, Channel):
        if record.schema_id != 0 and not writer.has_schema(record.schema_id):
            return  # its schema was in a lost chunk: its messages could not be decoded
        channels[record.id] = record
        writer.add_channel(record.id, record.topic, record.message_encoding, record.schema_id, record.metadata)
    elif isinstance(record, Message):
        channel = channels.get(record.channel_id)
        if channel is None:
            report.messages_without_channel += 1
            return
        writer.add_message(record.channel_id, record.log_time, record.publish_time, record.data, record.sequence)
        counts[channel.topic] += 1
        first, last = report.first_log_time_ns, report.last_log_time_ns
        report.first_log_time_ns = record.log_time if first is None else min(first, record.log_time)
        report.last_log_time_ns = record.log_time if last is None else max(last, record.log_time)
    elif isinstance(record, Metadata):
        writer.add_metadata(record.name, record.metadata)
        report.metadata_records += 1
    elif isinstance(record, Attachment):
        writer.add_attachment(record.name, record.media_type, record.data, record.log_time, record.create_time)
        report.attachments += 1
    # Message indexes, the summary and the footer of the source are rebuilt, not copied.
