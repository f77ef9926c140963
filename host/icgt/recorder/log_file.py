"""The recorder's log file: its folder, its channels, the metadata written at start, and the writes of a worker step.

`RecorderLog` owns the `McapRecorder` of one recording (and the Foxglove live view fed from it). Log times
are host CLOCK_MONOTONIC plus one offset to UTC fixed at start (`log_time`), so the file is in log-time
order and the recompute reads the offset back from icgt.time_bases. What the worker writes in one step is
handed to the file at once (`batch`, `McapRecorder.write_many`); a write that fails (a full disk) goes to
`on_fatal`, which ends the recording.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import msgspec

from icgt.errors import IcgtError
from icgt.geotag import FrameRecord, GeotagConfig
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH
from icgt.protocol.messages import Board, ClockSource, Hello
from icgt.recorder import topics
from icgt.recorder.camera_link import CAMERA_IMAGES_SCHEMA
from icgt.recorder.config import RecorderConfig
from icgt.recording import McapRecorder, RecordingError, layout, views
from icgt.recording.writer import McapLogHandler
from icgt.sync import SyncConfig
from icgt.version import __version__

__all__ = ["RecorderLog", "board_name", "device_metadata", "output_dir", "register_channels", "start_metadata"]

log = logging.getLogger("icgt.recorder")


def output_dir(path: Path) -> Path:
    """The recordings folder, created if needed; RecordingError saying what is wrong with it otherwise."""
    if path.exists() and not path.is_dir():
        raise RecordingError(f"--out {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"--out {path}: cannot create the folder: {exc.strerror or exc}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise RecordingError(f"--out {path}: no permission to write in it")
    return path


def start_metadata(
    cfg: RecorderConfig, sync: SyncConfig, *, signing: bool, mono_to_utc_ns: int
) -> dict[str, dict[str, str]]:
    """What the log says about itself at start: the configuration, the synchroniser's settings (the
    recompute uses them), whether MAVLink signing was on (never the key) and its time bases."""
    return {
        layout.META_CONFIG: {"source": cfg.source, "config": cfg.as_text(), "host_software": f"icgt {__version__}"},
        layout.META_SYNC: {"json": json.dumps(sync.to_json())},
        layout.META_MAVLINK_SIGNING: {"enabled": "true" if signing else "false", "key": "not recorded"},
        layout.META_TIME_BASES: {
            "log_time": "host CLOCK_MONOTONIC + a fixed offset to UTC taken at start [ns since the Unix epoch], "
            "when the message was logged: the file is in log-time order",
            "publish_time": "the time of the data on the same base: receipt of an input, mid-exposure of a frame",
            "monotonic_to_utc_offset_ns": str(mono_to_utc_ns),
            "device_clock": "device microseconds since boot (DeviceClockFilter maps it to host monotonic)",
            "autopilot_clock": "autopilot boot microseconds (TIMESYNC maps it to host monotonic)",
        },
    }


def register_channels(mcap: McapRecorder) -> None:
    """Every channel the recorder writes whose schema is known before the first message."""
    for topic, cls in layout.DEVICE_TOPIC_TYPES.items():
        mcap.register_json(topic, f"icgt.device.{cls.NAME}", topics.device_schema(cls))
    mcap.register_dataclass(topics.FRAMES, FrameRecord)
    for name, kind in views.TOPICS.items():
        mcap.register_protobuf(name, kind)
    for name in (layout.CLOCK_DEVICE, layout.CLOCK_AUTOPILOT):
        mcap.register_json(name, "icgt.clock.estimate", layout.ESTIMATE_SCHEMA)
    mcap.register_json(layout.CLOCK_DEVICE_EXCHANGES, "icgt.clock.exchange", layout.EXCHANGE_SCHEMA)
    mcap.register_json(layout.CLOCK_AUTOPILOT_REQUESTS, "icgt.clock.timesync_request", layout.TIMESYNC_REQUEST_SCHEMA)
    mcap.register_json(layout.CLOCK_UTC, "icgt.clock.utc", layout.UTC_SCHEMA)
    mcap.register_json(layout.LINK_EVENTS, "icgt.link_event", layout.LINK_EVENT_SCHEMA)
    mcap.register_json(layout.COUNTERS, "icgt.counters", layout.COUNTERS_SCHEMA)
    mcap.register_json(layout.MAVLINK_OTHER_SYSTEMS, "icgt.mavlink_raw", layout.MAVLINK_RAW_SCHEMA)
    mcap.register_json(layout.CAMERA_IMAGES, "icgt.camera_image", CAMERA_IMAGES_SCHEMA)


def board_name(board: int) -> str:
    """The HELLO's board as a word ("teensy41"), or its number when this host does not know it."""
    try:
        return Board(board).name.lower()
    except ValueError:
        return str(board)


def device_metadata(hello: Hello, device_url: str, camera: GeotagConfig) -> dict[str, dict[str, str]]:
    """What the log says about the device it recorded (its HELLO, both protocol versions) and the camera."""
    try:
        clock = ClockSource(hello.clock_source).name.lower()
    except ValueError:
        clock = str(hello.clock_source)
    return {
        layout.META_DEVICE: {
            "firmware_version": hello.firmware_version,
            "protocol_version": str(hello.protocol_version),
            "host_protocol_version": str(PROTOCOL_VERSION),
            "table_hash": f"0x{hello.table_hash:08X}",
            "host_table_hash": f"0x{TABLE_HASH:08X}",
            "board": board_name(hello.board),
            "serial_number": str(hello.serial_number),
            "clock_source": clock,
            "device_url": device_url,
        },
        layout.META_CALIBRATION: {k: json.dumps(v) for k, v in msgspec.to_builtins(camera).items()},
    }


class RecorderLog:
    """One recording's MCAP file, written from the worker (batched) and from the other threads (directly)."""

    def __init__(self, mono_to_utc_ns: int, on_fatal: Callable[[IcgtError], None]) -> None:
        self.mono_to_utc_ns = mono_to_utc_ns
        self.mcap: McapRecorder | None = None
        self.live: Any = None  # icgt.recording.live.LiveView while serving
        self._on_fatal = on_fatal
        # What the worker writes in one step, handed to the file at once; None outside a step. Only the
        # thread that opened it (_batch_owner) adds to it.
        self._batch: list[tuple[str, bytes, int]] | None = None
        self._batch_owner = 0
        self._log_handler: McapLogHandler | None = None

    def open(
        self,
        path: Path,
        cfg: RecorderConfig,
        metadata: Mapping[str, Mapping[str, str]],
        live: tuple[int | None, str] = (None, "127.0.0.1"),
    ) -> McapRecorder:
        """Create the file (mode [output] file_mode), register the recorder's channels, write `metadata`;
        `live` (port, host): also serve every channel to the Foxglove app over WebSocket."""
        sinks: tuple[Any, ...] = ()
        if live[0] is not None:
            from icgt.recording.live import LiveView

            self.live = LiveView(port=live[0], host=live[1])
            sinks = (self.live,)
        # Log times from the host's monotonic clock when each message is queued: the file in log-time order.
        self.mcap = mcap = McapRecorder(
            path,
            max_chunk_interval_s=cfg.output.chunk_interval_s,
            clock=lambda: time.monotonic_ns() + self.mono_to_utc_ns,
            sinks=sinks,
        )
        os.chmod(path, cfg.output.file_mode)  # private by default ([output] file_mode)
        self._log_handler = McapLogHandler(mcap, topics.LOG)
        logging.getLogger("icgt").addHandler(self._log_handler)
        register_channels(mcap)
        for name, values in metadata.items():
            mcap.add_metadata(name, dict(values))
        return mcap

    def log_time(self, host_ns: int) -> int:
        return host_ns + self.mono_to_utc_ns

    def write(self, topic: str, message: Any, host_ns: int) -> None:
        if self.mcap is None:
            return
        try:
            batch = self._batch
            if batch is not None and self._batch_owner == threading.get_ident():
                batch.append((topic, self.mcap.encode(topic, message), self.log_time(host_ns)))
            else:
                self.mcap.write(topic, message, publish_time_ns=self.log_time(host_ns))
        except RecordingError as exc:
            self._on_fatal(exc)

    def write_encoded(self, topic: str, data: bytes, host_ns: int) -> None:
        if self.mcap is None:
            return
        batch = self._batch
        if batch is not None and self._batch_owner == threading.get_ident():
            batch.append((topic, data, self.log_time(host_ns)))
            return
        try:
            self.mcap.write_encoded(topic, data, publish_time_ns=self.log_time(host_ns))
        except RecordingError as exc:
            self._on_fatal(exc)

    def link_event(self, link: str, kind: str, detail: str, host_ns: int, count: int = 0, outage_ns: int = 0) -> None:
        """One event on /icgt/link_events (``link``: "device", "mavlink" or "sync")."""
        self.write(
            layout.LINK_EVENTS,
            {"link": link, "kind": kind, "detail": detail, "count": count, "outage_ns": outage_ns, "host_ns": host_ns},
            host_ns,
        )

    @contextlib.contextmanager
    def batch(self) -> Iterator[None]:
        """This thread's writes until the end of the block are handed to the file together at its end."""
        self._batch, self._batch_owner = [], threading.get_ident()
        try:
            yield
        finally:
            self._commit()
            self._batch = None

    def _commit(self) -> None:
        batch = self._batch
        if batch and self.mcap is not None:
            self._batch = []
            try:
                self.mcap.write_many(batch)
            except RecordingError as exc:
                self._on_fatal(exc)

    def close(self) -> RecordingError | None:
        """Close the file (its summary written and read back by McapRecorder) and the live view; the error
        that kept the file from closing cleanly, if any."""
        failure: RecordingError | None = None
        if self._log_handler is not None:
            logging.getLogger("icgt").removeHandler(self._log_handler)
        if self.mcap is not None:
            try:
                stats = self.mcap.close()
                log.info("log closed: %s", stats)
            except RecordingError as exc:
                log.error("%s", exc)
                failure = exc
        if self.live is not None:
            self.live.stop()
        return failure
