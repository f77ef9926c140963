"""Read a recording: its frames as `FrameRecord`s or numpy columns, its metadata and its raw streams.

    rec = icgt.read("flight.mcap")
    for frame in rec.frames(): ...            # streaming, one chunk in memory at a time, in log order
    table = rec.frame_table()                  # one numpy array per FrameRecord field
    for log_time_ns, msg in rec.messages("/device/imu"): ...

A complete recording (with its summary) is read through its index, topic by topic. An unfinished
one (the recorder was killed, the power went) has no summary: `read` refuses it with the
`icgt recover` command that repairs it, unless `allow_unfinished=True`, which reads it front to
back up to its last complete record (`Recording.complete` is then False and `Recording.note`
says so). Every problem with the file surfaces as an `IngestError` that says what to do.

Times: `log_time_ns` is nanoseconds since the Unix epoch as recorded (host CLOCK_MONOTONIC plus
the fixed offset in metadata ``icgt.time_bases``); the frame fields name their own clocks.
"""

from __future__ import annotations

import json
import struct
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import IO, Any, NamedTuple, cast

from icgt.geotag.record import FrameRecord
from icgt.ingest.errors import IngestError
from icgt.ingest.frame_table import FLAG_BITS, INT_MISSING, FrameTable, decode_frame
from icgt.recording import layout

__all__ = [
    "FLAG_BITS",
    "FRAMES_TOPIC",
    "INT_MISSING",
    "FrameTable",
    "IngestError",
    "LogMessage",
    "Recording",
    "decode_frame",
    "read",
]

FRAMES_TOPIC = layout.FRAMES
MAGIC = b"\x89MCAP0\r\n"
_FOOTER_RECORD_SIZE = 1 + 8 + 8 + 8 + 4  # opcode, length, summary start, summary offset start, summary CRC
_OPCODE_FOOTER = 0x02


class LogMessage(NamedTuple):
    """One message of a recording: its topic, log time [ns since the Unix epoch], decoded content, publish time."""

    topic: str
    log_time_ns: int
    data: dict[str, Any]
    publish_time_ns: int | None = None

    @property
    def time_ns(self) -> int:
        """The time of the data [ns since the Unix epoch]: its publish time (an input's receipt, a frame's
        mid-exposure). Logs made before log time meant "when logged" have publish time = log time."""
        return self.log_time_ns if self.publish_time_ns is None else self.publish_time_ns


# ----------------------------------------------------------------------------- reading the file
class _TruncatedError(Exception):
    """The file ends inside a record."""


class _StrictSource:
    """A byte source that raises instead of returning fewer bytes than asked for.

    mcap's stream reader only notices an empty read; a record cut off at the end of an unfinished
    file would otherwise be parsed from short fields.
    """

    def __init__(self, stream: IO[bytes], size: int) -> None:
        self._stream = stream
        self._size = size
        self.position = 0

    def read(self, n: int = -1) -> bytes:
        if n < 0:
            n = self._size - self.position
        if n > self._size - self.position:
            raise _TruncatedError(f"the file ends inside a record at offset {self.position}")
        data = self._stream.read(n)
        if len(data) < n:
            raise _TruncatedError(f"the file ends inside a record at offset {self.position}")
        self.position += len(data)
        return data


def _unfinished_message(path: Path) -> str:
    return f"{path}: unfinished recording (the recorder was killed?): run `icgt recover {path}`"


def _damaged_message(path: Path, exc: BaseException) -> str:
    detail = str(exc) or type(exc).__name__
    return f"{path}: damaged recording ({detail}): `icgt recover {path}` keeps every intact chunk"


# Errors the mcap reader and its decompressors raise on damaged input.
_READ_ERRORS: tuple[type[BaseException], ...] = (
    OSError,
    ValueError,  # also json.JSONDecodeError and mcap's CRCValidationError
    struct.error,
    EOFError,
    KeyError,
    IndexError,
    RuntimeError,  # lz4
    MemoryError,
)


def _mcap_errors() -> tuple[type[BaseException], ...]:
    from mcap.exceptions import McapError

    extra: list[type[BaseException]] = [McapError]
    try:
        import zstandard

        extra.append(zstandard.ZstdError)
    except ImportError:  # pragma: no cover - a dependency of the recorder
        pass
    return (*_READ_ERRORS, *extra)


def _decode_json(topic: str, data: bytes) -> dict[str, Any]:
    try:
        obj = json.loads(data)
    except ValueError as exc:
        raise IngestError(f"a message on {topic} is not valid JSON: {exc}") from None
    if not isinstance(obj, dict):
        raise IngestError(f"a message on {topic} is not a JSON object")
    return obj


class Recording:
    """One MCAP recording, opened by `read`. Methods stream from the file; nothing is held open between calls."""

    def __init__(self, path: Path, *, complete: bool, note: str | None = None) -> None:
        self.path = path
        self.complete = complete
        """False: no summary (unfinished file read front to back up to its last complete record)."""
        self.note = note
        """What to know about how this file was read (unfinished: the recover hint), else None."""
        self._metadata: dict[str, dict[str, str]] | None = None
        self._counts: dict[str, int] | None = None
        self._errors = _mcap_errors()

    def __repr__(self) -> str:
        return f"Recording({str(self.path)!r}, complete={self.complete})"

    # --- metadata ---------------------------------------------------------------------------------
    @property
    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (icgt.device, icgt.config, icgt.calibration, icgt.enu_origin, ...)."""
        if self._metadata is None:
            self._metadata = self._read_metadata()
        return self._metadata

    @property
    def enu_origin(self) -> tuple[float, float, float] | None:
        """(lat [deg], lon [deg], alt MSL [m]) of the frames' east/north/up origin; None if never written."""
        m = self.metadata.get("icgt.enu_origin")
        if not m:
            return None
        try:
            return float(m["lat_deg"]), float(m["lon_deg"]), float(m["alt_msl_m"])
        except (KeyError, ValueError) as exc:
            raise IngestError(f"{self.path}: metadata icgt.enu_origin is malformed ({exc})") from None

    @property
    def monotonic_to_utc_offset_ns(self) -> int | None:
        """log_time_ns minus host CLOCK_MONOTONIC [ns] (metadata icgt.time_bases), None if absent."""
        value = self.metadata.get("icgt.time_bases", {}).get("monotonic_to_utc_offset_ns")
        try:
            return int(value) if value is not None else None
        except ValueError:
            return None

    # --- messages ---------------------------------------------------------------------------------
    def topics(self) -> dict[str, int]:
        """Message count per topic."""
        if self._counts is None:
            self._counts = self._count_messages()
        return dict(self._counts)

    def frames(self) -> Iterator[FrameRecord]:
        """The /frames records in log order (as the recorder emitted them), streaming.

        Raises IngestError for a file that is not an ICGT recording (its /frames is not ICGT's JSON
        FrameRecord, or it has neither /frames nor icgt.* metadata).
        """
        self._check_icgt()
        for msg in self._iter(frozenset({FRAMES_TOPIC}), decode=True):
            try:
                yield decode_frame(msg.data)
            except IngestError as exc:
                raise IngestError(f"{self.path}: {exc}") from None

    def frame_table(self) -> FrameTable:
        """All frames as columns (see FrameTable)."""
        return FrameTable.from_frames(self.frames())

    def messages(self, topic: str) -> Iterator[tuple[int, dict[str, Any]]]:
        """(time of the data [ns], decoded message) of one topic in file order (`LogMessage.time_ns`): JSON
        topics as parsed, protobuf ones as dicts."""
        for msg in self._iter(frozenset({topic}), decode=True):
            yield msg.time_ns, msg.data

    def records(self, topics: Iterable[str] | None = None) -> Iterator[LogMessage]:
        """The messages of several topics (None: all) interleaved exactly as they are in the file."""
        yield from self._iter(frozenset(topics) if topics is not None else None, decode=True)

    # --- internals --------------------------------------------------------------------------------
    def _check_icgt(self) -> None:
        """IngestError unless this looks like an ICGT recording (what else the file holds is said)."""
        channels = self._channels()
        frames = [c for c in channels if c[0] == FRAMES_TOPIC]
        foreign = [c for c in frames if c[1] != "json"]
        other_schema = [c for c in frames if c[1] == "json" and c[2] and not str(c[2]).startswith("icgt.")]
        if other_schema and not foreign:
            topic, _encoding, schema = other_schema[0]
            raise IngestError(
                f"{self.path}: not an ICGT recording: its {topic} channel has the JSON schema {schema!r}, "
                "ICGT records frames as icgt.FrameRecord"
            )
        if foreign:
            topic, encoding, schema = foreign[0]
            raise IngestError(
                f"{self.path}: not an ICGT recording: its {topic} channel carries {encoding} messages "
                f"(schema {schema!r}), ICGT records frames as JSON FrameRecords"
            )
        # icgt.recording is written by the MCAP writer itself, whatever it records: not a sign of the recorder
        recorder = [n for n in self.metadata if n.startswith("icgt.") and n != "icgt.recording"]
        if not frames and not recorder:
            topics = ", ".join(sorted({c[0] for c in channels})[:8]) or "none"
            raise IngestError(
                f"{self.path}: not an ICGT recording: no {FRAMES_TOPIC} channel and no metadata of the ICGT "
                f"recorder (icgt.config, icgt.device, ...; its topics: {topics})"
            )

    def _channels(self) -> list[tuple[str, str, str]]:
        """(topic, message encoding, schema name) of every channel."""
        if self.complete:
            from mcap.reader import SeekingReader

            with self._open() as f:
                try:
                    summary = SeekingReader(f).get_summary()
                except self._errors as exc:
                    raise IngestError(_damaged_message(self.path, exc)) from None
            if summary is not None:
                return [
                    (c.topic, c.message_encoding, getattr(summary.schemas.get(c.schema_id), "name", ""))
                    for c in summary.channels.values()
                ]
        from mcap.records import Channel, Schema

        names: dict[int, str] = {}
        out: list[tuple[int, str, str]] = []
        for record in self._stream_records():
            if isinstance(record, Schema):
                names[record.id] = record.name
            elif isinstance(record, Channel):
                out.append((record.schema_id, record.topic, record.message_encoding))
        return [(topic, enc, names.get(sid, "")) for sid, topic, enc in out]

    def _open(self) -> IO[bytes]:
        try:
            return self.path.open("rb")
        except OSError as exc:
            raise IngestError(f"cannot open {self.path}: {exc.strerror or exc}") from None

    def _decoder(self) -> Callable[[str, str, Any, bytes], dict[str, Any]]:
        protobuf: dict[int, Callable[[bytes], Any]] = {}

        def decode(topic: str, encoding: str, schema: Any, data: bytes) -> dict[str, Any]:
            if encoding == "json":
                return _decode_json(topic, data)
            if encoding == "protobuf" and schema is not None:
                fn = protobuf.get(schema.id)
                if fn is None:
                    from google.protobuf.json_format import MessageToDict
                    from mcap_protobuf.decoder import DecoderFactory

                    try:
                        inner = DecoderFactory().decoder_for("protobuf", schema)
                    except Exception as exc:  # a schema that is not a FileDescriptorSet
                        raise IngestError(
                            f"cannot decode {topic}: protobuf schema {schema.name!r} unreadable ({exc})"
                        ) from None
                    if inner is None:
                        raise IngestError(f"cannot decode {topic}: protobuf schema {schema.name!r} unreadable")

                    def fn(raw: bytes, inner: Any = inner) -> Any:
                        return MessageToDict(inner(raw), preserving_proto_field_name=True)

                    protobuf[schema.id] = fn
                try:
                    return cast(dict[str, Any], fn(data))
                except Exception as exc:  # protobuf's DecodeError and friends on damaged or foreign bytes
                    raise IngestError(f"cannot decode a message on {topic} (protobuf {schema.name}): {exc}") from None
            raise IngestError(f"cannot decode {topic}: message encoding {encoding!r} is not supported")

        return decode

    def _iter(self, topics: frozenset[str] | None, *, decode: bool) -> Iterator[LogMessage]:
        decoder = self._decoder()
        if self.complete:
            yield from self._iter_indexed(topics, decoder if decode else None)
        else:
            yield from self._iter_stream(topics, decoder if decode else None)

    def _iter_indexed(
        self, topics: frozenset[str] | None, decoder: Callable[[str, str, Any, bytes], dict[str, Any]] | None
    ) -> Iterator[LogMessage]:
        # Chunk by chunk in file order through the summary's chunk index: one chunk in memory at a time.
        # (mcap's SeekingReader.iter_messages(log_time_order=False) opens every chunk before it yields.)
        from mcap.data_stream import ReadDataStream
        from mcap.reader import SeekingReader
        from mcap.records import Chunk, Message
        from mcap.stream_reader import breakup_chunk

        with self._open() as f:
            try:
                summary = SeekingReader(f).get_summary()
                if summary is None:
                    raise IngestError(_damaged_message(self.path, ValueError("the summary vanished")))
                wanted = {cid for cid, ch in summary.channels.items() if topics is None or ch.topic in topics}
                chunks = sorted(summary.chunk_indexes, key=lambda ci: ci.chunk_start_offset)
                indexed = any(ci.message_index_offsets for ci in chunks)
                for ci in chunks:
                    if indexed and topics is not None and not wanted.intersection(ci.message_index_offsets):
                        continue
                    f.seek(ci.chunk_start_offset + 1 + 8)
                    chunk = Chunk.read(ReadDataStream(f))
                    for record in breakup_chunk(chunk, validate_crc=True):
                        if not isinstance(record, Message) or record.channel_id not in wanted:
                            continue
                        channel = summary.channels[record.channel_id]
                        schema = summary.schemas.get(channel.schema_id)
                        data = decoder(channel.topic, channel.message_encoding, schema, record.data) if decoder else {}
                        yield LogMessage(channel.topic, record.log_time, data, record.publish_time)
            except IngestError:
                raise
            except self._errors as exc:
                raise IngestError(_damaged_message(self.path, exc)) from None

    def _iter_stream(
        self, topics: frozenset[str] | None, decoder: Callable[[str, str, Any, bytes], dict[str, Any]] | None
    ) -> Iterator[LogMessage]:
        from mcap.records import Channel, Message, Schema

        channels: dict[int, Any] = {}
        schemas: dict[int, Any] = {}
        for record in self._stream_records():
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels.get(record.channel_id)
                if channel is None or (topics is not None and channel.topic not in topics):
                    continue
                schema = schemas.get(channel.schema_id)
                data = decoder(channel.topic, channel.message_encoding, schema, record.data) if decoder else {}
                yield LogMessage(channel.topic, record.log_time, data, record.publish_time)

    def _stream_records(self) -> Iterator[Any]:
        """Every record front to back (chunks opened); stops quietly at a record cut off by the end of the file."""
        from mcap.stream_reader import StreamReader

        with self._open() as f:
            size = self.path.stat().st_size
            source = _StrictSource(f, size)
            reader = StreamReader(cast(IO[bytes], source), validate_crcs=True, record_size_limit=size)
            it = reader.records
            while True:
                try:
                    record = next(it)
                except (StopIteration, _TruncatedError):
                    return
                except self._errors as exc:
                    if source.position >= size:
                        return  # the end of an unfinished file
                    raise IngestError(_damaged_message(self.path, exc)) from None
                yield record

    def _read_metadata(self) -> dict[str, dict[str, str]]:
        out: dict[str, dict[str, str]] = {}
        if self.complete:
            from mcap.reader import SeekingReader

            with self._open() as f:
                try:
                    for m in SeekingReader(f).iter_metadata():
                        out.setdefault(m.name, {}).update(m.metadata)
                except self._errors as exc:
                    raise IngestError(_damaged_message(self.path, exc)) from None
            return out
        from mcap.records import Metadata

        for record in self._stream_records():
            if isinstance(record, Metadata):
                out.setdefault(record.name, {}).update(record.metadata)
        return out

    def _count_messages(self) -> dict[str, int]:
        if self.complete:
            from mcap.reader import SeekingReader

            with self._open() as f:
                try:
                    summary = SeekingReader(f).get_summary()
                except self._errors as exc:
                    raise IngestError(_damaged_message(self.path, exc)) from None
            if summary is not None and summary.statistics is not None:
                counts: dict[str, int] = {}
                for channel_id, n in summary.statistics.channel_message_counts.items():
                    channel = summary.channels.get(channel_id)
                    if channel is not None:
                        counts[channel.topic] = counts.get(channel.topic, 0) + n
                for channel in summary.channels.values():
                    counts.setdefault(channel.topic, 0)
                return counts
        counts = {}
        for msg in self._iter(None, decode=False):
            counts[msg.topic] = counts.get(msg.topic, 0) + 1
        return counts


def _check_file(path: Path) -> bool:
    """Raise IngestError unless `path` is an MCAP file; True if it is complete (footer and closing magic)."""
    if not path.exists():
        raise IngestError(f"{path}: no such file")
    if not path.is_file():
        raise IngestError(f"{path}: not a file")
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(len(MAGIC))
            tail = b""
            if size >= 2 * len(MAGIC) + _FOOTER_RECORD_SIZE:
                f.seek(size - len(MAGIC) - _FOOTER_RECORD_SIZE)
                tail = f.read(len(MAGIC) + _FOOTER_RECORD_SIZE)
    except OSError as exc:
        raise IngestError(f"cannot read {path}: {exc.strerror or exc}") from None
    if size == 0:
        raise IngestError(f"{path}: empty file (the recorder wrote nothing)")
    if head != MAGIC[: len(head)]:
        raise IngestError(f"{path}: not an MCAP file (it does not start with the MCAP magic bytes)")
    if len(head) < len(MAGIC):
        raise IngestError(_unfinished_message(path))
    return len(tail) == len(MAGIC) + _FOOTER_RECORD_SIZE and tail[0] == _OPCODE_FOOTER and tail.endswith(MAGIC)


def read(path: str | Path, *, allow_unfinished: bool = False) -> Recording:
    """Open the recording at `path`.

    Raises IngestError for a missing file, a file that is not MCAP, a damaged summary, and an
    unfinished file (no footer: the recorder was killed) unless `allow_unfinished`, which reads it
    front to back up to its last complete record instead.
    """
    p = Path(path)
    complete = _check_file(p)
    if not complete:
        if not allow_unfinished:
            raise IngestError(_unfinished_message(p))
        return Recording(p, complete=False, note=_unfinished_message(p) + " (read up to its last complete record)")
    rec = Recording(p, complete=True)
    from mcap.reader import SeekingReader

    with rec._open() as f:
        try:
            summary = SeekingReader(f).get_summary()
        except rec._errors as exc:
            raise IngestError(_damaged_message(p, exc)) from None
    if summary is None or not summary.chunk_indexes:
        # Finished without an index (another writer, or nothing recorded): read it front to back.
        rec.complete = False
        rec.note = f"{p}: no summary index; read front to back"
    return rec
