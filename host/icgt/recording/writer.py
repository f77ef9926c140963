"""Crash-safe MCAP recording: a thread-safe recorder over the chunk writer of `icgt.recording.mcap_file`.

Times: every `log_time_ns` / `publish_time_ns` is nanoseconds since the Unix epoch (UTC), as Foxglove
expects; wall-clock intervals (`max_chunk_interval_s`) are seconds of `time.monotonic()`.

Log-time order. A message written without a log time gets one from the recorder's `clock` when it is
queued, under the queue lock: log time is then when the message was handed to the log, and because the
writer thread keeps queue order, the file's messages are in log-time order (what `mcap doctor
--strict-message-order` asks for), whichever threads write. The data's own time (a receipt, a
mid-exposure) is the message's publish time. A caller that passes log times itself keeps that order.

Sinks. Every registered topic and every message written is also handed to each `sink` (a
`RecordingSink`, e.g. the live WebSocket view), in the writing thread, as the bytes that go to the file.

Crash safety. Messages are collected in memory into one chunk; the chunk is compressed and written
(chunk record + its message indexes in one write call) when it is `max_chunk_interval_s` old or
`max_chunk_bytes` large, whichever comes first, even if no further message arrives, and then fsync'd.
Schemas, channels, metadata and attachments go to disk between chunks as soon as they are
registered. So after kill -9 or a power cut the file is an MCAP prefix that ends at a record boundary
and holds everything up to the last closed chunk, and `icgt recover` (recover.py) turns it into a
complete, indexed file.

The loss bound (`KILL9_LOSS_BOUND_S`, 0.5 s) follows from that: a message is on disk (the page cache,
which survives kill -9) at most `max_chunk_interval_s` (default `CHUNK_INTERVAL_S`, 0.25 s) after it was
queued, plus what is in flight when the deadline passes: the writer thread's wake-up on a loaded machine,
the compression and write of that chunk, and the fsync of the one before if it is still running
(`WRITE_ALLOWANCE_S`, 0.25 s; the worst age measured was 0.250 s with a busy loop on each core and
0.258 s with six on two cores (load 5), i.e. under 10 ms in flight: `benchmarks/kill9_loss.py`).
Messages are stamped (log time) when queued, so a kill loses log times newer than kill - 0.5 s; what the
kernel still held for the recorder (serial and UDP buffers) is lost too, and the device's part of it comes
back by RESEND. Smaller chunks cost some compression: against 1 s chunks, +3 % file size at 1000 small
messages/s, +14 % at 200/s (zstd; `benchmarks/kill9_loss.py` prints it); the files stay plain MCAP.

Write errors (disk full, quota, I/O error) stop the recording: the file is cut back to the last complete
record, the summary is written if it fits, and a RecordingError says how far the file is readable.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import math
import os
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from itertools import count
from pathlib import Path
from typing import IO, Any, Protocol

import msgspec
from google.protobuf.message import Message as ProtobufMessage
from mcap_protobuf.schema import build_file_descriptor_set

from icgt.recording.log_handler import McapLogHandler
from icgt.recording.mcap_file import (
    LIBRARY,
    MAGIC,
    ChunkTail,
    Compression,
    McapFileWriter,
    RecordingError,
    _describe_oserror,
    iso_utc,
    message_record,
)
from icgt.recording.schemas import json_encoder, json_schema_bytes, schema_name

__all__ = [
    "CHUNK_INTERVAL_S",
    "KILL9_LOSS_BOUND_S",
    "LIBRARY",
    "MAGIC",
    "WRITE_ALLOWANCE_S",
    "ChunkTail",
    "McapFileWriter",
    "McapLogHandler",
    "McapRecorder",
    "RecordingError",
    "RecordingSink",
    "RecordingStats",
    "iso_utc",
    "message_record",
]

logger = logging.getLogger(__name__)

CHUNK_INTERVAL_S = 0.25
"""Default age [s] at which the open chunk goes to disk."""
WRITE_ALLOWANCE_S = 0.25
"""What may be in flight past a chunk's deadline [s]: the writer's wake-up under load, compress, write, an fsync."""
KILL9_LOSS_BOUND_S = CHUNK_INTERVAL_S + WRITE_ALLOWANCE_S
"""At most this much [s] of log time before a kill -9 is missing from the file (default interval)."""


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


class RecordingSink(Protocol):
    """Something fed every channel and message of a recording besides the file (the live view)."""

    def add_channel(
        self, topic: str, message_encoding: str, schema: tuple[str, str, bytes], metadata: Mapping[str, str]
    ) -> None:
        """A new topic: schema is (name, encoding, data) as in the file."""

    def message(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        """One message as encoded for the file; must not block (it runs in the writer's caller)."""


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
        max_chunk_interval_s: float = CHUNK_INTERVAL_S,
        max_chunk_bytes: int = 4 * 1024 * 1024,
        compression: Compression = "zstd",
        fsync: bool = True,
        queue_size: int = 50_000,
        put_timeout_s: float = 5.0,
        opener: Callable[[Path], IO[bytes]] | None = None,
        clock: Callable[[], int] = time.time_ns,
        sinks: tuple[RecordingSink, ...] = (),
    ) -> None:
        """Creates `path` (never overwriting) and starts the writer thread.

        `clock` gives the log time [ns since the Unix epoch] of messages written without one (taken
        when queued, so the file stays in log-time order); it must never go backwards (the recorder
        passes host CLOCK_MONOTONIC plus a fixed offset). `sinks` are fed every channel and message too.

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
        self._clock = clock
        self._sinks = tuple(sinks)
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
            return McapFileWriter(
                stream,
                profile=profile,
                compression=compression,
                max_chunk_bytes=max_chunk_bytes,
                spill_dir=self.path.parent,  # the chunk index waits next to the log, on the disk meant for it
            )
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
        for sink in self._sinks:
            _feed_sink(sink.add_channel, topic, message_encoding, schema, meta)
        return entry

    # --- writing ----------------------------------------------------------------------------------

    def write(
        self, topic: str, message: Any, log_time_ns: int | None = None, publish_time_ns: int | None = None
    ) -> None:
        """Records one message; thread-safe, returns once queued (not yet on disk).

        `message`: a protobuf message, a dataclass instance, or a mapping for a `register_json` topic.
        `log_time_ns`: when it was logged, ns since the Unix epoch; None (the recorder's way): the
        `clock` when queued, which keeps the file in log-time order. `publish_time_ns`: the time of the
        data (its receipt, its mid-exposure), same epoch; defaults to the log time. Raises
        RecordingError after a write error, after close(), or for a message that does not fit its topic.
        """
        entry, data = self._encode(topic, message)
        self._write_data(topic, entry, data, log_time_ns, publish_time_ns)

    def encode(self, topic: str, message: Any) -> bytes:
        """`message` encoded as `topic` records it (registering a protobuf or dataclass topic on first use),
        for `write_many`; raises RecordingError as `write` does."""
        return self._encode(topic, message)[1]

    def _encode(self, topic: str, message: Any) -> tuple[_Topic, bytes]:
        entry = self._topics.get(topic)
        if entry is None:
            entry = self._auto_register(topic, message)
        elif entry.kind is not None and type(message) is not entry.kind:
            raise RecordingError(f"topic {topic} records {entry.kind.__name__}, not {type(message).__name__}")
        try:
            return entry, entry.encode(message)
        except (TypeError, ValueError) as exc:
            raise RecordingError(f"cannot encode a message for {topic}: {exc}") from exc

    def write_many(self, messages: Sequence[tuple[str, bytes, int]]) -> None:
        """Encoded messages (topic, data, publish time [ns since the Unix epoch]) queued together, in order,
        each with its log time: the `clock` when queued, read for each message as `write` does (readers and
        live clients may tell messages apart by it). What a recorder's worker wrote in one step goes here at
        its end: one lock and one hand-off instead of one each per message (about half of the cost of a small
        message). Topics must be registered; raises RecordingError as `write` does.
        """
        if not messages:
            return
        topics = self._topics
        entries = []
        for topic, _, _ in messages:
            entry = topics.get(topic)
            if entry is None:
                raise RecordingError(f"topic {topic}: register it before writing encoded messages")
            entries.append(entry)
        stamps: list[int] = []

        def make() -> list[_Item]:
            clock, item = self._clock, self._message_item
            stamps.extend(clock() for _ in messages)
            return [
                item(entry, now, publish, data)
                for entry, now, (_, data, publish) in zip(entries, stamps, messages, strict=True)
            ]

        self._enqueue(make, len(messages))
        if not stamps:  # not queued (see _enqueue): the sinks still see each message, stamped now
            stamps.extend(self._clock() for _ in messages)
        for sink in self._sinks:
            for (topic, data, publish), log_time in zip(messages, stamps, strict=True):
                _feed_sink(sink.message, topic, data, log_time, publish)

    def write_encoded(
        self, topic: str, data: bytes, log_time_ns: int | None = None, publish_time_ns: int | None = None
    ) -> None:
        """Records one message already encoded in its topic's encoding (the caller keeps it valid: a fast path
        for a hot topic, e.g. JSON built without a mapping); otherwise as `write`. The topic must be registered."""
        entry = self._topics.get(topic)
        if entry is None:
            raise RecordingError(f"topic {topic}: register it before writing encoded messages")
        self._write_data(topic, entry, data, log_time_ns, publish_time_ns)

    def _write_data(
        self, topic: str, entry: _Topic, data: bytes, log_time_ns: int | None, publish_time_ns: int | None
    ) -> None:
        if log_time_ns is not None:
            self._enqueue(self._message_item(entry, log_time_ns, publish_time_ns, data))
            log_time = log_time_ns
        else:
            stamped: list[int] = []

            def make() -> _Item:
                stamped.append(self._clock())
                return self._message_item(entry, stamped[-1], publish_time_ns, data)

            self._enqueue(make)
            log_time = stamped[-1] if stamped else self._clock()  # not queued: see _enqueue
        for sink in self._sinks:
            _feed_sink(sink.message, topic, data, log_time, log_time if publish_time_ns is None else publish_time_ns)

    @staticmethod
    def _message_item(entry: _Topic, log_time_ns: int, publish_time_ns: int | None, data: bytes) -> _Item:
        publish = log_time_ns if publish_time_ns is None else publish_time_ns
        try:
            record = message_record(entry.channel_id, next(entry.sequence) & 0xFFFFFFFF, log_time_ns, publish, data)
        except struct.error:
            raise RecordingError(
                f"times must be integers in [0, 2**64) ns since the Unix epoch, got {log_time_ns!r}, {publish!r}"
            ) from None
        return (entry.channel_id, log_time_ns, record, time.monotonic())

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

    def _enqueue(self, item: _Item | Callable[[], _Item] | Callable[[], list[_Item]], n_items: int = 0) -> None:
        """Queues an item; a callable is called under the lock to make it (a message stamped with the clock);
        `n_items` > 0: the callable makes that many message items, queued in order."""
        deadline = None
        while True:
            with self._lock:
                self._raise_if_failed()
                if self._closing:
                    raise RecordingError(f"{self.path} is closed")
                if len(self._pending) + max(0, n_items - 1) < self._max_pending:
                    made = item() if callable(item) else item
                    if isinstance(made, list):
                        self._pending.extend(made)
                        is_message = True
                    else:
                        self._pending.append(made)
                        is_message = isinstance(made, tuple)
                    # Read after the append: the writer sets _writer_idle before its last look at the
                    # queue, so either it sees this item or we see the flag (see _wait_for_work).
                    if self._writer_idle or not is_message or len(self._pending) >= self._drain_at:
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


_sink_failures = [0]


def _feed_sink(call: Callable[..., None], *args: Any) -> None:
    """A sink's failure is counted and the first one logged, never raised: the file comes first."""
    try:
        call(*args)
    except Exception:
        _sink_failures[0] += 1
        if _sink_failures[0] == 1:  # once: the log itself goes through the sinks
            logger.exception("a recording sink failed (the file is not affected; later failures are counted)")


def sink_failures() -> int:
    """How many times a sink raised in this process."""
    return _sink_failures[0]


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
