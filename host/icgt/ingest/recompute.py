"""Recompute a recording's frames offline from its raw streams, with other settings, without re-flying.

The recorder keeps everything the geotagger used: every TIME_SYNC exchange with the device
(/clock/device/exchanges), every raw device message (/device/exposure, /device/imu,
/device/range, /device/pps, /device/hello) and every raw MAVLink frame with its host receive
time (/mavlink/<msg>: telemetry, SYSTEM_TIME and the autopilot's TIMESYNC replies). `recompute`
replays them, in the order the file holds them (the order the recorder wrote them), into fresh
clock filters, a fresh TelemetryStore and a Geotagger built with the given GeotagConfig (default:
the recording's own, metadata icgt.calibration):

* ``lookahead_s=None`` (default) emits each frame at the point of the file where the recorder
  wrote it, so the filters hold what they held live: with the recording's own settings the
  frames come out as recorded; with another lever arm, mounting or camera they differ only by it.
  Exposures the recorder never wrote a frame for (it was killed) are emitted at the end.
* ``lookahead_s=T`` hands each exposure to the geotagger only T seconds after it arrived, so
  the clock filters and the pose buffers also use what came after it (at most 2 s: the geotagger's
  IMU buffer holds about 5 s at 100 Hz).

What cannot be replayed bit for bit: the host's CLOCK_REALTIME sample the UTC fallback uses is
taken from metadata icgt.time_bases (the same instant to within a few hundred nanoseconds), and
the live threads' interleaving is known only to the order of the file (an exchange or a MAVLink
message that arrived in the microseconds between the recorder's processing and its write can
land on the other side of a frame).
"""

from __future__ import annotations

import ast
import base64
import dataclasses
import math
import tomllib
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from icgt.clocks.autopilot_clock import AutopilotClockFilter, UtcMapper
from icgt.clocks.device_clock import DeviceClockFilter, PpsUtcMapper
from icgt.errors import IcgtError
from icgt.geotag.clock_views import AutopilotClockView, UtcView, add_pps_edge
from icgt.geotag.geotagger import GeotagConfig, Geotagger
from icgt.geotag.record import FrameRecord
from icgt.ingest.reader import FRAMES_TOPIC, IngestError, LogMessage, Recording, read
from icgt.mavlink.link import Received
from icgt.mavlink.telemetry import TELEMETRY_TYPES, TelemetryStore
from icgt.protocol.messages import Exposure, Hello, Imu, Message, Pps, Range

__all__ = ["RecomputeResult", "recompute", "recording_config"]

EXCHANGES_TOPIC = "/clock/device/exchanges"
DEVICE_TOPICS: dict[str, type[Message]] = {
    "/device/exposure": Exposure,
    "/device/imu": Imu,
    "/device/range": Range,
    "/device/pps": Pps,
    "/device/hello": Hello,
}
LINK_EVENTS_TOPIC = "/icgt/link_events"
_MAVLINK_TYPES = frozenset(TELEMETRY_TYPES | {"TIMESYNC", "HEARTBEAT"})
_AUTOPILOT_FRESH_EVENTS = frozenset({"autopilot_seen", "autopilot_back", "autopilot_rebooted"})
_TIMESYNC_TIMEOUT_NS = 1_000_000_000  # icgt.mavlink.link.LinkConfig.timesync_timeout_s
MAX_LOOKAHEAD_S = 2.0

M = TypeVar("M", bound=Message)


@dataclass
class RecomputeResult:
    """The recomputed frames (in emission order, frame_seq as recorded) and what the replay saw."""

    frames: list[FrameRecord]
    config: GeotagConfig
    notes: list[str] = field(default_factory=list)
    counts: dict[str, int] = field(default_factory=dict)


def recording_config(recording: Recording) -> GeotagConfig:
    """The GeotagConfig the recorder used (metadata icgt.calibration), ENU origin set to the recording's."""
    calib = recording.metadata.get("icgt.calibration")
    if not calib:
        raise IngestError(f"{recording.path}: no icgt.calibration metadata: pass a GeotagConfig")
    known = {f.name: f for f in dataclasses.fields(GeotagConfig)}
    kwargs: dict[str, Any] = {}
    for key, text in calib.items():
        if key not in known:
            continue
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            raise IngestError(f"{recording.path}: icgt.calibration {key}={text!r} is not a literal") from None
        if isinstance(value, list):
            value = tuple(value)
        kwargs[key] = value
    cfg = GeotagConfig(**kwargs)
    if cfg.origin is None and recording.enu_origin is not None:
        cfg = dataclasses.replace(cfg, origin=recording.enu_origin)
    return cfg


def _autopilot_system(recording: Recording) -> int:
    text = recording.metadata.get("icgt.config", {}).get("config", "")
    try:
        value = tomllib.loads(text).get("mavlink", {}).get("system_id", 1)
    except tomllib.TOMLDecodeError:
        return 1
    return int(value) if isinstance(value, int) else 1


def _device_message(cls: type[M], data: dict[str, Any]) -> M:
    kwargs: dict[str, Any] = {}
    for f in dataclasses.fields(cls):  # type: ignore[arg-type]
        if f.name in data:
            kwargs[f.name] = data[f.name]
        elif f.type in ("float", float):
            kwargs[f.name] = math.nan  # the recorder leaves non-finite floats out
        else:
            raise IngestError(f"a {cls.NAME} message without {f.name!r}")
    return cls(**kwargs)


class _StopEmitting(Exception):  # noqa: N818 - a control-flow signal, not an error
    """Raised by the emit callback to end Geotagger.poll after the frame the log says was written here."""


@dataclass
class _Exp:
    seq: int
    exposure: Exposure
    rx_ns: int


class _Replay:
    def __init__(
        self,
        recording: Recording,
        config: GeotagConfig,
        device_clock: DeviceClockFilter,
        autopilot_clock: AutopilotClockFilter,
        autopilot_system: int,
        lookahead_s: float | None,
    ) -> None:
        self.rec = recording
        self.cfg = config
        self.dev = device_clock
        self.ap = autopilot_clock
        self.ap_system = autopilot_system
        self.utc = UtcMapper(self.ap)
        self.pps = PpsUtcMapper()
        self.tm = TelemetryStore(autopilot_system=autopilot_system)
        self.frames: list[FrameRecord] = []
        self.geotagger = Geotagger(
            self.tm, self.dev, AutopilotClockView(self.ap), UtcView(self.pps, self.utc), config, self._emit
        )
        self.lookahead_ns = None if lookahead_s is None else int(lookahead_s * 1e9)
        self.pending: dict[int, _Exp] = {}  # handed to the geotagger, not emitted yet
        self.deferred: deque[_Exp] = deque()  # lookahead: not handed over yet
        self.seq = 0
        self.stop_after: int | None = None  # as recorded: the frame whose /frames record is being replayed
        self.hello_t_us: int | None = None
        self.timesync_seen: set[int] = set()
        self.ap_component: int | None = None  # from the autopilot's first HEARTBEAT, as the link does
        self.fresh_ns = 0  # the link forgets its unanswered TIMESYNC requests when the autopilot (re)appears
        self.counts: dict[str, int] = {
            "exposures": 0,
            "exchanges": 0,
            "timesync_used": 0,
            "mavlink_messages": 0,
            "mavlink_undecodable": 0,
            "frames_in_log": 0,
            "frames_emitted_as_recorded": 0,
            "frames_emitted_at_end": 0,
            "device_clock_resets": 0,
        }
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        self._mav = mavlink2.MAVLink(None)
        self._mav_error: type[Exception] = mavlink2.MAVError

    # --- output -----------------------------------------------------------------------------------
    def _emit(self, record: FrameRecord) -> None:
        self.pending.pop(record.frame_seq, None)
        self.frames.append(record)
        if self.stop_after is not None and record.frame_seq >= self.stop_after:
            # The recorder emitted the frames ready at one poll one by one, with other threads'
            # messages in between (which the file shows): the next one is emitted at its own record.
            raise _StopEmitting

    def _mid_host_ns(self, e: _Exp) -> int:
        x = e.exposure
        if x.feedback_start_t_us and x.feedback_end_t_us:
            mid = x.feedback_start_t_us + (x.feedback_end_t_us - x.feedback_start_t_us) // 2
        else:
            mid = x.feedback_start_t_us or x.trigger_t_us
        try:
            return self.dev.device_to_host_ns(mid)
        except IcgtError:
            return e.rx_ns

    def _emit_recorded(self, data: dict[str, Any]) -> None:
        """The recorder wrote frame `frame_seq` here: emit it (and those before it) now."""
        self.counts["frames_in_log"] += 1
        seq = data.get("frame_seq")
        if not isinstance(seq, int) or self.lookahead_ns is not None:
            return
        target = self.pending.get(seq)
        if target is None:
            return
        if target.exposure.image_index != data.get("image_index"):
            return  # not the exposure this replay numbered so (the log lost one): let the geotagger decide
        wait_ns = int(self.cfg.max_wait_ms * 1e6)
        now = max(self._mid_host_ns(e) for s, e in self.pending.items() if s <= seq) + wait_ns
        before = len(self.frames)
        self.stop_after = seq
        try:
            self.geotagger.poll(now)
        except _StopEmitting:
            pass
        finally:
            self.stop_after = None
        self.counts["frames_emitted_as_recorded"] += len(self.frames) - before

    # --- inputs -----------------------------------------------------------------------------------
    def _release(self, now_ns: int) -> None:
        assert self.lookahead_ns is not None
        while self.deferred and self.deferred[0].rx_ns + self.lookahead_ns <= now_ns:
            e = self.deferred.popleft()
            self.geotagger.add_exposure(e.exposure, e.rx_ns)
            self.pending[e.seq] = e
        self.geotagger.poll(now_ns)

    def _device(self, topic: str, data: dict[str, Any]) -> None:
        msg: Message = _device_message(DEVICE_TOPICS[topic], data)
        rx = int(data.get("host_rx_ns", 0))
        if isinstance(msg, Exposure):
            self.seq += 1
            self.counts["exposures"] += 1
            e = _Exp(self.seq, msg, rx)
            if self.lookahead_ns is None:
                self.geotagger.add_exposure(msg, rx)
                self.pending[e.seq] = e
            else:
                self.deferred.append(e)
        elif isinstance(msg, Imu):
            self.geotagger.add_imu(msg)
        elif isinstance(msg, Range):
            self.geotagger.add_range(msg)
        elif isinstance(msg, Pps):
            add_pps_edge(self.pps, self.utc, self.dev, msg.t_us, msg.pps_count)
        elif isinstance(msg, Hello):
            if self.hello_t_us is None:
                self.hello_t_us = msg.t_us
            elif msg.t_us < self.hello_t_us:
                self.dev.reset()  # the device rebooted: its clock restarted (as the recorder does)
                self.counts["device_clock_resets"] += 1
                self.hello_t_us = msg.t_us

    def _exchange(self, data: dict[str, Any]) -> None:
        self.counts["exchanges"] += 1
        self.dev.add_exchange(
            int(data["host_tx_ns"]), int(data["device_rx_us"]), int(data["device_tx_us"]), int(data["host_rx_ns"])
        )

    def _mavlink(self, data: dict[str, Any]) -> None:
        self.counts["mavlink_messages"] += 1
        raw = data.get("raw")
        rx = data.get("host_rx_ns")
        if not isinstance(raw, str) or not isinstance(rx, int):
            self.counts["mavlink_undecodable"] += 1
            return
        try:
            msg: Any = self._mav.decode(bytearray(base64.b64decode(raw)))
        except (self._mav_error, ValueError, TypeError, IndexError, KeyError):
            self.counts["mavlink_undecodable"] += 1
            return
        mtype = str(msg.get_type())
        if mtype == "TIMESYNC":
            self._timesync(msg, rx)
            return
        if mtype == "HEARTBEAT":
            if self.ap_component is None and self._is_autopilot_heartbeat(msg):
                self.ap_component = int(msg.get_srcComponent())
            return
        self.tm.ingest(Received(msg, rx))
        if mtype == "SYSTEM_TIME" and int(msg.get_srcSystem()) == self.ap_system:
            self.utc.add_system_time(int(msg.time_unix_usec), int(msg.time_boot_ms))

    def _is_autopilot_heartbeat(self, msg: Any) -> bool:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        return (
            int(msg.get_srcSystem()) == self.ap_system
            and int(msg.autopilot) != mavlink2.MAV_AUTOPILOT_INVALID
            and int(msg.type)
            not in (
                mavlink2.MAV_TYPE_GCS,
                mavlink2.MAV_TYPE_CAMERA,
                mavlink2.MAV_TYPE_GIMBAL,
                mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
            )
        )

    def _link_event(self, data: dict[str, Any]) -> None:
        if data.get("link") == "mavlink" and data.get("kind") in _AUTOPILOT_FRESH_EVENTS:
            host_ns = data.get("host_ns")
            if isinstance(host_ns, int):
                self.fresh_ns = max(self.fresh_ns, host_ns)

    def _timesync(self, msg: Any, rx_ns: int) -> None:
        # The link (icgt.mavlink.link) feeds the filter only replies to its own requests from the
        # autopilot component it has seen a HEARTBEAT from: tc1 set, ts1 one of its send times (its
        # monotonic clock), answered within the timeout, each once, and sent after the autopilot last
        # (re)appeared (it forgets pending requests then).
        tc1, ts1 = int(msg.tc1), int(msg.ts1)
        if int(msg.get_srcSystem()) != self.ap_system or int(msg.get_srcComponent()) != self.ap_component:
            return
        if tc1 == 0 or ts1 in self.timesync_seen or ts1 < self.fresh_ns:
            return
        if not 0 < rx_ns - ts1 <= _TIMESYNC_TIMEOUT_NS:
            return
        self.timesync_seen.add(ts1)
        self.counts["timesync_used"] += 1
        self.ap.add_timesync(ts1, tc1, rx_ns)

    def run(self, messages: Iterator[LogMessage]) -> None:
        for m in messages:
            topic, data = m.topic, m.data
            if topic == FRAMES_TOPIC:
                self._emit_recorded(data)
                continue
            if topic == LINK_EVENTS_TOPIC:
                self._link_event(data)
                continue
            if topic == EXCHANGES_TOPIC:
                self._exchange(data)
            elif topic in DEVICE_TOPICS:
                self._device(topic, data)
            else:
                self._mavlink(data)
            if self.lookahead_ns is not None:
                now = data.get("host_rx_ns")
                if isinstance(now, int):
                    self._release(now)
        while self.deferred:
            e = self.deferred.popleft()
            self.geotagger.add_exposure(e.exposure, e.rx_ns)
            self.pending[e.seq] = e
        before = len(self.frames)
        self.geotagger.poll(0, flush=True)
        self.counts["frames_emitted_at_end"] = len(self.frames) - before


def recompute(
    recording: Recording | str | Path,
    config: GeotagConfig | None = None,
    *,
    device_clock: DeviceClockFilter | None = None,
    autopilot_clock: AutopilotClockFilter | None = None,
    lookahead_s: float | None = None,
    autopilot_system: int | None = None,
) -> RecomputeResult:
    """Geotag every exposure of a recording again from its raw streams.

    `config`: camera, mounting, lever arm, limits (default: the recording's, `recording_config`); an
    origin of None is replaced by the recording's ENU origin so east/north/up stay comparable.
    `device_clock` / `autopilot_clock`: fresh filters built with other parameters (default: the
    recorder's defaults). `lookahead_s`: see the module docstring. `autopilot_system`: the vehicle's
    MAVLink system id (default: the recorder's configuration in metadata icgt.config).
    """
    rec = recording if isinstance(recording, Recording) else read(recording)
    if lookahead_s is not None and not 0.0 <= lookahead_s <= MAX_LOOKAHEAD_S:
        raise IngestError(f"lookahead_s must be between 0 and {MAX_LOOKAHEAD_S} s, not {lookahead_s}")
    cfg = config if config is not None else recording_config(rec)
    if cfg.origin is None and rec.enu_origin is not None:
        cfg = dataclasses.replace(cfg, origin=rec.enu_origin)
    counts = rec.topics()
    notes: list[str] = []
    if counts.get(EXCHANGES_TOPIC, 0) == 0:
        notes.append(f"no {EXCHANGES_TOPIC} in the log: device times cannot be mapped to the host clock")
    if counts.get("/mavlink/timesync", 0) == 0:
        notes.append("no /mavlink/timesync in the log: no autopilot clock mapping, frames will have no pose")
    if counts.get("/device/exposure", 0) == 0:
        notes.append("no /device/exposure in the log: nothing to geotag")
    offset = rec.monotonic_to_utc_offset_ns
    replay = _Replay(
        rec,
        cfg,
        device_clock or DeviceClockFilter(),
        autopilot_clock or AutopilotClockFilter(),
        autopilot_system if autopilot_system is not None else _autopilot_system(rec),
        lookahead_s,
    )
    if offset is not None:
        replay.utc.add_host_realtime(0, offset)
    else:
        notes.append("no icgt.time_bases metadata: frames before GPS time have no UTC")
    mavlink_topics = {
        t for t in counts if t.startswith("/mavlink/") and t[len("/mavlink/") :].upper() in _MAVLINK_TYPES
    }
    topics = {FRAMES_TOPIC, EXCHANGES_TOPIC, LINK_EVENTS_TOPIC, *DEVICE_TOPICS, *mavlink_topics}
    replay.run(rec.records(topics))
    if replay.counts["mavlink_undecodable"]:
        notes.append(f"{replay.counts['mavlink_undecodable']} MAVLink messages without a decodable raw frame skipped")
    return RecomputeResult(replay.frames, cfg, notes, replay.counts)
