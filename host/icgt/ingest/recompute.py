"""Recompute a recording's frames offline from its raw streams, with other settings, without re-flying.

The recorder logs every input of its synchroniser (`icgt.sync.Synchroniser`) before feeding it, from
one thread: device messages, device TIME_SYNC exchanges, MAVLink TIMESYNC requests and every MAVLink
message received (raw bytes and receive time). `recompute` is an iterator over the log feeding a
fresh synchroniser the same inputs in the same order (the file's), built with the given settings
(default: the recording's own, metadata ``icgt.sync``):

* ``lookahead_s=None`` (default) polls the synchroniser where the recorder did: each ``/frames``
  record carries the host time of the poll that emitted it (``emitted_host_ns``), and the state
  then is the state live, so with the recording's own settings every frame comes out exactly as
  recorded; with another lever arm, mounting or camera they differ only by it. Exposures the
  recorder never wrote a frame for (it was killed) are emitted at the end.
* ``lookahead_s=T`` polls only T seconds of host time behind the inputs, so the clock filters and
  the pose buffers also use what came after each exposure (at most 2 s, well inside what the device
  sample buffers hold: 20 s of IMU at 100 Hz).

The autopilot telemetry is kept as long as live (`SyncConfig.telemetry_retention_s`: the device's
history horizon, `icgt.device.history`): no exposure can come back later than that, so every frame the
log's telemetry brackets is posed, in the recompute as it was live.

Logs written before ``emitted_host_ns`` existed are polled at each frame's mid-exposure plus the
geotagger's wait, which reproduces them only approximately.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import msgspec

from icgt.clocks.autopilot_clock import AutopilotClockFilter
from icgt.clocks.device_clock import DeviceClockFilter
from icgt.geotag.config import RENAMED, GeotagConfig, migrate
from icgt.geotag.record import FrameRecord
from icgt.ingest.reader import IngestError, LogMessage, Recording, read
from icgt.protocol.messages import Exposure, FrameFlags, Message
from icgt.recording import layout
from icgt.sync import SyncConfig, Synchroniser

__all__ = ["RecomputeResult", "recompute", "recording_config", "recording_sync_config"]

MAX_LOOKAHEAD_S = 2.0
_RETRANSMIT = int(FrameFlags.RETRANSMIT)
_TIMESYNC_TOPIC = layout.mavlink_topic("TIMESYNC")

M = TypeVar("M", bound=Message)


@dataclass
class RecomputeResult:
    """The recomputed frames (in emission order, frame_seq as recorded) and what the replay saw."""

    frames: list[FrameRecord]
    config: GeotagConfig
    notes: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)


def recording_sync_config(recording: Recording) -> SyncConfig:
    """The synchroniser settings the recorder used (metadata icgt.sync), ENU origin set to the recording's."""
    meta = recording.metadata.get(layout.META_SYNC)
    if meta and "json" in meta:
        try:
            cfg = SyncConfig.from_json(json.loads(meta["json"]))
        except (ValueError, TypeError) as exc:
            raise IngestError(
                f"{recording.path}: metadata {layout.META_SYNC} is not a synchroniser config: {exc}"
            ) from None
    else:
        cfg = SyncConfig(geotag=_legacy_geotag_config(recording))
    if cfg.geotag.origin is None and recording.enu_origin is not None:
        cfg = msgspec.structs.replace(cfg, geotag=msgspec.structs.replace(cfg.geotag, origin=recording.enu_origin))
    return cfg


def recording_config(recording: Recording) -> GeotagConfig:
    """The GeotagConfig the recorder used, ENU origin set to the recording's."""
    return recording_sync_config(recording).geotag


def _legacy_geotag_config(recording: Recording) -> GeotagConfig:
    """Logs without icgt.sync: the camera settings from icgt.calibration (JSON values; Python literals before)."""
    import ast

    calib = recording.metadata.get(layout.META_CALIBRATION)
    if not calib:
        raise IngestError(f"{recording.path}: no {layout.META_SYNC} or {layout.META_CALIBRATION} metadata")
    known = set(GeotagConfig.__struct_fields__) | set(RENAMED)
    values: dict[str, Any] = {}
    for key, text in calib.items():
        if key not in known:
            continue
        try:
            value = json.loads(text)
        except ValueError:
            try:
                value = ast.literal_eval(text)
            except (ValueError, SyntaxError):
                raise IngestError(f"{recording.path}: {layout.META_CALIBRATION} {key}={text!r} unreadable") from None
        values[key] = tuple(value) if isinstance(value, list) else value
    return GeotagConfig(**migrate(values))


_EXPOSURE_FIELDS = [f.name for f in dataclasses.fields(Exposure)]
ADDED_IN_V2: dict[str, frozenset[str]] = {
    Exposure.NAME: frozenset(_EXPOSURE_FIELDS[_EXPOSURE_FIELDS.index("duration_us") + 1 :]),
}
"""Fields protocol version 2 added, per message: a log of a version-1 device lacks them. They come back as 0,
which for the EXPOSURE's sensor snapshot means "holds nothing" (snapshot_flags 0)."""


def device_message(cls: type[M], data: dict[str, Any]) -> M:
    """A device message rebuilt from its log record (non-finite floats the recorder left out come back as NaN;
    the fields a version-1 device did not send, `ADDED_IN_V2`, as 0)."""
    kwargs: dict[str, Any] = {}
    added = ADDED_IN_V2.get(cls.NAME, frozenset())
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in data:
            kwargs[f.name] = data[f.name]
        elif f.name in added:
            kwargs[f.name] = 0
        elif f.type in ("float", float):
            kwargs[f.name] = math.nan  # the recorder leaves non-finite floats out
        else:
            raise IngestError(f"a {cls.NAME} message without {f.name!r}")
    return cls(**kwargs)


class _Feeder:
    """Turns log records back into the synchroniser's inputs."""

    def __init__(
        self, sync: Synchroniser, lookahead_s: float | None, max_wait_s: float, *, requests_logged: bool
    ) -> None:
        self.sync = sync
        self.requests_logged = requests_logged
        self.frames: list[FrameRecord] = []
        self.emitted: set[int] = set()
        self.lookahead_ns = None if lookahead_s is None else int(lookahead_s * 1e9)
        self.wait_ns = round(max_wait_s * 1e9)
        self.latest_ns = 0
        self.counts: dict[str, int] = {
            "frames_in_log": 0,
            "frames_emitted_as_recorded": 0,
            "frames_emitted_at_end": 0,
            "mavlink_undecodable": 0,
        }
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        self._mav = mavlink2.MAVLink(None)
        self._mav_error: type[Exception] = mavlink2.MAVError

    def _take(self, frames: list[FrameRecord]) -> None:
        for f in frames:
            self.emitted.add(f.frame_seq)
        self.frames.extend(frames)

    def feed(self, m: LogMessage) -> None:
        topic, data = m.topic, m.data
        if topic == layout.FRAMES:
            self._recorded_frame(data)
            return
        if topic.startswith(layout.DEVICE_PREFIX):
            cls = layout.DEVICE_TOPIC_TYPES.get(topic)
            if cls is None:
                return
            rx = int(data.get("host_rx_ns", 0))
            retransmitted = bool(int(data.get("frame_flags", 0)) & _RETRANSMIT)
            self.sync.on_device(device_message(cls, data), rx, retransmitted=retransmitted)
        elif topic == layout.CLOCK_DEVICE_EXCHANGES:
            rx = int(data["host_rx_ns"])
            self.sync.on_exchange(int(data["host_tx_ns"]), int(data["device_rx_us"]), int(data["device_tx_us"]), rx)
        elif topic == layout.CLOCK_AUTOPILOT_REQUESTS:
            rx = int(data["host_tx_ns"])
            self.sync.on_timesync_request(rx)
        elif topic == layout.MAVLINK_OTHER_SYSTEMS:
            self._other_systems(topic, data.get("frames") or ())
            return
        elif topic.startswith(layout.MAVLINK_PREFIX):
            if not self._mavlink(topic, data):
                return
            rx = int(data["host_rx_ns"])
        else:
            return
        self.latest_ns = max(self.latest_ns, rx)
        if self.lookahead_ns is not None:
            self._take(self.sync.poll(self.latest_ns - self.lookahead_ns))

    def _other_systems(self, topic: str, frames: Iterable[dict[str, Any]]) -> None:
        """Other systems' raw frames: counted per type without decoding them, as the recorder's synchroniser
        counted them (`Synchroniser.on_other_systems`). A frame of the autopilot's system (a recompute with
        another ``autopilot_system``) or one without its type, time or bytes goes through `_mavlink` alone."""
        counts: dict[str, int] = {}
        autopilot = self.sync.autopilot.system
        for frame in frames:
            mtype = frame.get("msg_type")
            if (
                not isinstance(mtype, str)
                or frame.get("src_system") == autopilot
                or not isinstance(frame.get("raw"), str)
                or not isinstance(frame.get("host_rx_ns"), int)
            ):
                self._mavlink(topic, frame)
                continue
            counts[mtype] = counts.get(mtype, 0) + 1
        if counts:
            self.sync.on_other_systems(counts)

    def _mavlink(self, topic: str, data: dict[str, Any]) -> bool:
        """Feed one logged MAVLink frame; False if it has no decodable raw frame."""
        raw, rx = data.get("raw"), data.get("host_rx_ns")
        if not isinstance(raw, str) or not isinstance(rx, int):
            self.counts["mavlink_undecodable"] += 1
            return False
        try:
            msg = self._mav.decode(bytearray(base64.b64decode(raw)))
        except (self._mav_error, ValueError, TypeError, IndexError, KeyError):
            self.counts["mavlink_undecodable"] += 1
            return False
        if data.get("signed") is True:
            msg._signed = True  # the recorder checked the signature with the key, which the log does not hold
        if not self.requests_logged and topic == _TIMESYNC_TOPIC and int(msg.tc1) != 0:
            # Logs from before the requests were logged: take a reply's ts1 as a request we sent.
            self.sync.on_timesync_request(int(msg.ts1))
        self.sync.on_mavlink(msg, rx)
        return True

    def _recorded_frame(self, data: dict[str, Any]) -> None:
        """The recorder wrote frame `frame_seq` here: poll as it did, at the time it did."""
        self.counts["frames_in_log"] += 1
        seq = data.get("frame_seq")
        if self.lookahead_ns is not None or not isinstance(seq, int) or seq in self.emitted:
            return
        at = data.get("emitted_host_ns")
        if not isinstance(at, int):
            mid = data.get("mid_host_ns")
            at = (mid if isinstance(mid, int) else self.latest_ns) + self.wait_ns
        before = len(self.frames)
        self._take(self.sync.poll(at))
        if seq not in self.emitted:
            self._take(self.sync.poll(at, flush=True))  # the recorder's final flush
        self.counts["frames_emitted_as_recorded"] += len(self.frames) - before

    def finish(self) -> None:
        before = len(self.frames)
        self._take(self.sync.poll(self.latest_ns, flush=True))
        self.counts["frames_emitted_at_end"] = len(self.frames) - before


def _input_topics(counts: dict[str, int]) -> set[str]:
    fixed = {layout.FRAMES, layout.CLOCK_DEVICE_EXCHANGES, layout.CLOCK_AUTOPILOT_REQUESTS}
    return fixed | {t for t in counts if t.startswith((layout.DEVICE_PREFIX, layout.MAVLINK_PREFIX))}


def recompute(
    recording: Recording | str | Path,
    config: GeotagConfig | SyncConfig | None = None,
    *,
    device_clock: DeviceClockFilter | None = None,
    autopilot_clock: AutopilotClockFilter | None = None,
    lookahead_s: float | None = None,
    autopilot_system: int | None = None,
) -> RecomputeResult:
    """Geotag every exposure of a recording again from its raw streams.

    `config`: camera, mounting, lever arm, limits as a GeotagConfig (the rest of the synchroniser's
    settings as recorded), or a whole SyncConfig (default: the recording's, `recording_sync_config`);
    an origin of None is replaced by the recording's ENU origin so east/north/up stay comparable.
    `device_clock` / `autopilot_clock`: fresh filters built with other parameters (default: the
    recorder's defaults). `lookahead_s`: see the module docstring. `autopilot_system`: the vehicle's
    MAVLink system id (default: as recorded).
    """
    rec = recording if isinstance(recording, Recording) else read(recording)
    if lookahead_s is not None and not 0.0 <= lookahead_s <= MAX_LOOKAHEAD_S:
        raise IngestError(f"lookahead_s must be between 0 and {MAX_LOOKAHEAD_S} s, not {lookahead_s}")
    recorded = recording_sync_config(rec)
    if isinstance(config, SyncConfig):
        cfg = config
    elif isinstance(config, GeotagConfig):
        cfg = msgspec.structs.replace(recorded, geotag=config)
    else:
        cfg = recorded
    if autopilot_system is not None:
        cfg = msgspec.structs.replace(cfg, autopilot_system=autopilot_system)
    if cfg.geotag.origin is None and rec.enu_origin is not None:
        cfg = msgspec.structs.replace(cfg, geotag=msgspec.structs.replace(cfg.geotag, origin=rec.enu_origin))
    counts = rec.topics()
    notes: list[str] = []
    if counts.get(layout.CLOCK_DEVICE_EXCHANGES, 0) == 0:
        notes.append(f"no {layout.CLOCK_DEVICE_EXCHANGES} in the log: device times cannot be mapped to the host clock")
    if counts.get(layout.mavlink_topic("TIMESYNC"), 0) == 0:
        notes.append("no /mavlink/timesync in the log: no autopilot clock mapping, frames will have no pose")
    if counts.get(layout.device_topic("EXPOSURE"), 0) == 0:
        notes.append("no /device/exposure in the log: nothing to geotag")
    sync = Synchroniser(cfg, device_clock=device_clock, autopilot_clock=autopilot_clock)
    offset = rec.monotonic_to_utc_offset_ns
    if offset is not None:
        sync.on_host_realtime(0, offset)
    else:
        notes.append("no icgt.time_bases metadata: frames before GPS time have no UTC")
    requests_logged = counts.get(layout.CLOCK_AUTOPILOT_REQUESTS, 0) > 0
    feeder = _Feeder(sync, lookahead_s, cfg.geotag.max_wait_s, requests_logged=requests_logged)
    for m in rec.records(_input_topics(counts)):
        feeder.feed(m)
    feeder.finish()
    if feeder.counts["mavlink_undecodable"]:
        notes.append(f"{feeder.counts['mavlink_undecodable']} MAVLink messages without a decodable raw frame skipped")
    result_counts = {**sync.counters(), **feeder.counts}
    return RecomputeResult(feeder.frames, cfg.geotag, notes, result_counts)


def iter_inputs(recording: Recording) -> Iterator[LogMessage]:
    """The records a recompute feeds, in file order (for tools that replay a log into their own synchroniser)."""
    yield from recording.records(_input_topics(recording.topics()))
