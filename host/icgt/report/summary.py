"""What a flight report says, gathered once from a recording (`icgt.read`) and its camera card.

`gather(recording)` reads the frames, the vehicle track, the clock estimates, the link events and
the device's STATUS counters into a `FlightData`; `summarize` reduces it to the figures that
`icgt info` prints and the report's first table shows. Times are seconds from the recording's
first message on the host clock (the log time's base); positions are metres in the recording's
ENU frame (metadata icgt.enu_origin).
"""

from __future__ import annotations

import itertools
import logging
import math
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from icgt.errors import IcgtError
from icgt.geotag.record import OUTAGE_NO_POSE, OUTAGE_NO_RANGE, FrameFlag, FrameRecord
from icgt.recording import layout

_TRACK = layout.mavlink_topic("GLOBAL_POSITION_INT")
PLAUSIBLE_RADIUS_M = 20_000.0
"""A track sample farther than this from the recording's ENU origin is not the flight (a glitch, a stale or
foreign position) and is not drawn [m]: an inspection flight stays within a few km of its start."""
NO_FIX = "no fix (latitude/longitude 0)"
OUTSIDE = f"over {PLAUSIBLE_RADIUS_M / 1000:.0f} km from the ENU origin"
_STATUS = layout.device_topic("STATUS")

log = logging.getLogger(__name__)


class ReportError(IcgtError):
    """A report cannot be made (unreadable recording, output not writable)."""


@dataclass(frozen=True)
class Outage:
    link: str
    """'device' or 'mavlink'."""
    start_s: float
    end_s: float
    detail: str


@dataclass(frozen=True)
class Loss:
    link: str
    t_s: float
    kind: str
    """'sequence_gap' (messages missing, asked again), 'frames_rejected' (corrupt frames skipped) or
    'history_lost' (what the device could no longer send: exposures + PPS + samples)."""
    count: int


@dataclass
class FlightData:
    """Everything the report draws, read from one recording."""

    path: Path
    t0_host_ns: int
    """Host CLOCK_MONOTONIC of the recording's first message [ns]: time zero of every time axis."""
    duration_s: float
    frames: list[FrameRecord]
    track_t_s: np.ndarray[Any, Any]
    track_enu_m: np.ndarray[Any, Any]
    """Vehicle track from GLOBAL_POSITION_INT, (N, 3) ENU [m]: only samples with a fix, inside the plausible area."""
    device_clock: list[tuple[float, float | None]]
    """(t [s], device->host mapping bound [us], None while not valid) per /clock/device estimate."""
    utc_clock: list[tuple[float, float | None, str]]
    """(t [s], UTC bound [us] or None, source) per /clock/utc estimate."""
    outages: list[Outage]
    losses: list[Loss]
    status: dict[str, int]
    """The device's last STATUS counters."""
    metadata: dict[str, dict[str, str]]
    topics: dict[str, int]
    images: dict[int, str] = field(default_factory=dict)
    """frame_seq -> matched image name (with --images)."""
    unmatched_images: list[str] = field(default_factory=list)
    footprints: dict[int, np.ndarray[Any, Any]] = field(default_factory=dict)
    """frame_seq -> footprint outline in the structure face's map coordinates (s, t) [m], (N, 2)."""
    footprint_note: str = ""
    note: str | None = None
    track_left_out: dict[str, int] = field(default_factory=dict)
    """Track samples not drawn, by reason (NO_FIX, OUTSIDE)."""
    sync_counters: dict[str, int] = field(default_factory=dict)
    """The synchroniser's last counters (/icgt/counters)."""
    mavlink_counters: dict[str, int] = field(default_factory=dict)
    """The MAVLink link's last counters (/icgt/counters: kernel drops, the UDP receive buffer granted)."""
    device_stopped_itself: str | None = None
    """The device stopped the capture by itself, its host silent for the host timeout (the recorder's account of
    the DEVICE_STATE that said so when the link came back)."""
    unreachable_at_end: tuple[int, str] | None = None
    """The recording ended with capture running on an unreachable device: (exposures it was known to be taking,
    interval x outage, 0 if the rate is unknown; the recorder's account)."""

    def t_s(self, host_ns: int) -> float:
        return (host_ns - self.t0_host_ns) / 1e9


def _host_ns(log_time_ns: int, offset_ns: int | None) -> int:
    return log_time_ns - offset_ns if offset_ns is not None else log_time_ns


def gather(recording: Any, images: Path | None = None) -> FlightData:
    """Read what the report needs; images (a camera card folder) adds the matching per frame."""
    from icgt.geodesy import LocalFrame

    offset = recording.monotonic_to_utc_offset_ns
    frames: list[FrameRecord] = list(recording.frames())
    topics = recording.topics()
    wanted = [
        t
        for t in (_TRACK, layout.CLOCK_DEVICE, layout.CLOCK_UTC, layout.LINK_EVENTS, _STATUS, layout.COUNTERS)
        if t in topics
    ]
    t0: int | None = None
    track: list[tuple[int, float, float, float]] = []
    dev_clock: list[tuple[int, float | None]] = []
    utc_clock: list[tuple[int, float | None, str]] = []
    events: list[dict[str, Any]] = []
    status: dict[str, int] = {}
    sync_counters: dict[str, int] = {}
    mavlink_counters: dict[str, int] = {}
    first = next(iter(recording.records()), None)
    if first is not None:
        t0 = _host_ns(first.time_ns, offset)
    for msg in recording.records(wanted):
        host = _host_ns(msg.time_ns, offset)
        d = msg.data
        if msg.topic == _TRACK:
            if isinstance(d.get("lat"), int) and isinstance(d.get("lon"), int) and isinstance(d.get("alt"), int):
                track.append((host, d["lat"] / 1e7, d["lon"] / 1e7, d["alt"] / 1000.0))
        elif msg.topic == layout.CLOCK_DEVICE:
            dev_clock.append((host, d["uncertainty_ns"] / 1000.0 if d.get("valid") else None))
        elif msg.topic == layout.CLOCK_UTC:
            bound = d.get("uncertainty_us")
            utc_clock.append(
                (host, float(bound) if d.get("valid") and bound is not None else None, d.get("source", ""))
            )
        elif msg.topic == layout.LINK_EVENTS:
            events.append({**d, "_host": d.get("host_ns", host)})
        elif msg.topic == _STATUS:
            status = {k: int(v) for k, v in d.items() if isinstance(v, int)}
        elif msg.topic == layout.COUNTERS and isinstance(d.get("sync"), dict):
            sync_counters = {k: int(v) for k, v in d["sync"].items() if isinstance(v, int)}
            if isinstance(d.get("mavlink"), dict):
                mavlink_counters = {k: int(v) for k, v in d["mavlink"].items() if isinstance(v, int)}
    if t0 is None:
        raise ReportError(f"{recording.path}: the recording is empty")
    last = t0
    for f in frames:
        last = max(last, f.mid_host_ns)
    for h, *_ in track:
        last = max(last, h)
    duration = (max([last] + [h for h, _ in dev_clock]) - t0) / 1e9

    # Autopilots send GLOBAL_POSITION_INT before their first fix with latitude and longitude 0: those
    # samples (and any far outside the flight) would stretch the plots over thousands of kilometres.
    left_out: Counter[str] = Counter()
    fixed = [row for row in track if row[1] != 0 or row[2] != 0]
    left_out[NO_FIX] = len(track) - len(fixed)
    origin = recording.enu_origin
    if origin is None and fixed:
        origin = fixed[0][1:]
    enu = np.zeros((0, 3))
    track = fixed
    if track and origin is not None:
        lf = LocalFrame(*origin)
        arr = np.array([row[1:] for row in track])
        enu = lf.geodetic_to_enu(arr[:, 0], arr[:, 1], arr[:, 2])
        inside = np.linalg.norm(enu, axis=1) <= PLAUSIBLE_RADIUS_M
        left_out[OUTSIDE] = int((~inside).sum())
        enu = enu[inside]
        track = [row for row, ok in zip(track, inside.tolist(), strict=True) if ok]
    data = FlightData(
        path=Path(recording.path),
        t0_host_ns=t0,
        duration_s=duration,
        frames=frames,
        track_t_s=np.array([(h - t0) / 1e9 for h, *_ in track]),
        track_enu_m=enu,
        device_clock=[((h - t0) / 1e9, b) for h, b in dev_clock],
        utc_clock=[((h - t0) / 1e9, b, s) for h, b, s in utc_clock],
        outages=[],
        losses=[],
        status=status,
        metadata=recording.metadata,
        topics=topics,
        note=getattr(recording, "note", None),
        sync_counters=sync_counters,
        mavlink_counters=mavlink_counters,
        track_left_out={k: v for k, v in left_out.items() if v},
    )
    _events(data, events)
    _footprints(data, recording)
    if images is not None:
        _match(data, images)
    return data


def _events(data: FlightData, events: list[dict[str, Any]]) -> None:
    open_since: dict[str, tuple[float, str]] = {}
    for e in events:
        t = data.t_s(int(e["_host"]))
        link, kind = str(e.get("link", "?")), str(e.get("kind", "?"))
        outage = int(e.get("outage_ns") or 0)
        if kind == "unreachable_at_end":
            data.unreachable_at_end = (int(e.get("count") or 0), str(e.get("detail", kind)))
        elif kind == "device_stopped_itself":
            data.device_stopped_itself = str(e.get("detail", kind))
        elif kind in ("sequence_gap", "frames_rejected", "history_lost"):
            data.losses.append(Loss(link, t, kind, int(e.get("count") or 0)))
        elif kind in ("disconnected", "autopilot_lost"):
            # autopilot_lost comes after its silence timeout: its outage_ns is the time since the last message
            open_since.setdefault(link, (t - outage / 1e9, str(e.get("detail", kind))))
        elif outage > 0:
            start, detail = open_since.pop(link, (t - outage / 1e9, str(e.get("detail", kind))))
            data.outages.append(Outage(link, start, t, detail))
    for link, (start, detail) in open_since.items():
        data.outages.append(Outage(link, start, data.duration_s, detail + " (not back by the end)"))


def _footprints(data: FlightData, recording: Any) -> None:
    """The frames' footprints on the structure face (s, t) [m], through the export's geometry."""
    from icgt.export.cli import camera_from_metadata, surface_normal_from_metadata
    from icgt.geometry import GeometryError, Projector

    camera = camera_from_metadata(data.metadata)
    if camera is None:
        data.footprint_note = "no camera calibration in the recording: no footprints"
        return
    normal = surface_normal_from_metadata(data.metadata)
    try:
        projector = Projector(camera, origin=recording.enu_origin, surface_normal=normal, anchor="range")
        solutions = projector.solve_many(data.frames)
    except GeometryError as exc:
        data.footprint_note = f"no footprints: {exc}"
        return
    missing = 0
    for rec, sol in zip(data.frames, solutions, strict=True):
        if isinstance(sol, GeometryError) or sol is None or sol.footprint is None:
            missing += 1
            continue
        st = np.asarray(sol.footprint.plane_st, dtype=float)
        if np.all(np.isfinite(st)):
            data.footprints[rec.frame_seq] = st
        else:
            missing += 1
    if missing:
        data.footprint_note = f"{missing} frames without a footprint (no range, pose or surface)"


def _match(data: FlightData, images: Path) -> None:
    from icgt.ingest.match import match_images

    result = match_images(data.frames, images)
    for p in result.pairs:
        data.images[p.frame.frame_seq] = p.image.name
    data.unmatched_images = sorted(
        [u.image.name for u in result.unmatched_images] + [a.image.name for a in result.ambiguous]
    )


# --- the summary ------------------------------------------------------------------------------


def _stats(values: list[float]) -> tuple[float, float, float] | None:
    """(median, 95th percentile, max) of the finite values, None if there are none."""
    v = np.array([x for x in values if x is not None and math.isfinite(x)])
    if v.size == 0:
        return None
    return float(np.median(v)), float(np.percentile(v, 95)), float(v.max())


def coverage(data: FlightData) -> dict[str, float] | None:
    """Face area covered [m^2], the sum of footprint areas, mean overlap of consecutive frames [%]."""
    if not data.footprints:
        return None
    import shapely

    polys = [shapely.Polygon(st).buffer(0) for st in data.footprints.values()]
    union = shapely.union_all(polys)
    overlaps = []
    for a, b in itertools.pairwise(polys):
        if a.area > 0:
            overlaps.append(100.0 * a.intersection(b).area / a.area)
    return {
        "covered_m2": float(union.area),
        "footprints_m2": float(sum(p.area for p in polys)),
        "mean_overlap_pct": float(np.mean(overlaps)) if overlaps else 0.0,
        "min_overlap_pct": float(np.min(overlaps)) if overlaps else 0.0,
    }


POSE_GAP_REPORTED_S = 1.0
"""Position samples farther apart than this around a frame make a telemetry gap worth reporting [s]."""


def pose_gaps(frames: list[FrameRecord]) -> list[tuple[float, float, int]]:
    """The position telemetry's gaps the frames fell in: (start, end) on the host clock [s], frames without a
    position in it (no_pose). From each frame's gaps to the samples before and after its mid-exposure."""
    spans: list[tuple[float, float, int]] = []
    for r in frames:
        before, after = r.pose_gap_before_ms, r.pose_gap_after_ms
        withheld = FrameFlag.NO_POSE.value in r.flags
        if not (
            withheld or (math.isfinite(before) and math.isfinite(after) and before + after > POSE_GAP_REPORTED_S * 1e3)
        ):
            continue
        mid_s = r.mid_host_ns / 1e9
        end = mid_s + after / 1e3 if math.isfinite(after) else mid_s
        start = mid_s - before / 1e3 if math.isfinite(before) else mid_s
        spans.append((start, end, int(withheld)))
    merged: list[tuple[float, float, int]] = []
    for start, end, n in sorted(spans):
        if merged and start <= merged[-1][1] + 1e-3:
            a, b, k = merged[-1]
            merged[-1] = (a, max(b, end), k + n)
        else:
            merged.append((start, end, n))
    return merged


def _pose_gaps_text(frames: list[FrameRecord]) -> str:
    gaps = pose_gaps(frames)
    if not gaps:
        return "none"
    longest = max(b - a for a, b, _ in gaps)
    withheld = sum(n for _, _, n in gaps)
    return (
        f"{len(gaps)} longer than {POSE_GAP_REPORTED_S:g} s (longest {longest:.2f} s); "
        f"{withheld} frames without a position in them (no_pose)"
    )


def summarize(data: FlightData) -> list[tuple[str, str]]:
    """The summary as (label, value) rows, each value with its unit."""
    frames = data.frames
    flags: Counter[str] = Counter(f for rec in frames for f in rec.flags)
    rows: list[tuple[str, str]] = [
        ("recording", str(data.path)),
        ("duration", f"{data.duration_s:.1f} s"),
        ("frames", f"{len(frames)}"),
    ]
    device = data.metadata.get("icgt.device", {})
    if device:
        rows.append(("device", f"{device.get('board', '?')} firmware {device.get('firmware_version', '?')}"))
    if data.images or data.unmatched_images:
        rows.append(("images matched", f"{len(data.images)} of {len(frames)} frames"))
        rows.append(("images not matched", f"{len(data.unmatched_images)}"))
    with_pos = [r for r in frames if r.lat_deg is not None]
    rows.append(("frames with a position", f"{len(with_pos)}"))
    rows.append(("position sources", _counts(Counter(r.position_source for r in frames))))
    rows.append(("UTC sources", _counts(Counter(r.time_source for r in frames))))
    rows.append(("flags", _counts(flags) if flags else "none"))
    rows.append(("position telemetry gaps", _pose_gaps_text(frames)))
    resent = flags.get(FrameFlag.RESENT.value, 0)
    if resent:
        rows.append(
            (
                "frames resent after an outage",
                f"{resent}; because of the outage {flags.get(OUTAGE_NO_POSE.value, 0)} without a pose, "
                f"{flags.get(OUTAGE_NO_RANGE.value, 0)} without a range; "
                f"{flags.get(FrameFlag.RANGE_FROM_SNAPSHOT.value, 0)} ranged from the device's snapshot",
            )
        )
    for label, values, unit in (
        ("horizontal accuracy", [r.h_acc_m for r in frames if r.h_acc_m is not None], "m"),
        ("vertical accuracy", [r.v_acc_m for r in frames if r.v_acc_m is not None], "m"),
        ("device->host clock bound", [r.mid_host_uncertainty_ns / 1000.0 for r in frames], "us"),
        ("UTC bound", [r.mid_utc_uncertainty_us for r in frames if r.mid_utc_uncertainty_us is not None], "us"),
        ("pose gap before", [r.pose_gap_before_ms for r in frames], "ms"),
        ("horizontal bound (95 %)", [r.horizontal_error_bound_m for r in frames if r.horizontal_error_bound_m], "m"),
        ("vertical bound (95 %)", [r.vertical_error_bound_m for r in frames if r.vertical_error_bound_m], "m"),
        ("range", [r.range_m for r in frames if r.range_m is not None], "m"),
        ("GSD", [r.scale_mm_per_px for r in frames if r.scale_mm_per_px is not None], "mm/px"),
        ("predicted blur", [r.blur_px for r in frames if r.blur_px is not None], "px"),
    ):
        s = _stats(values)
        if s is not None:
            rows.append((label, f"median {s[0]:.3g}, 95% {s[1]:.3g}, max {s[2]:.3g} {unit}"))
    cov = coverage(data)
    if cov is not None:
        rows.append(
            (
                "face coverage",
                f"{cov['covered_m2']:.2f} m^2 covered ({len(data.footprints)} footprints, "
                f"{cov['footprints_m2']:.2f} m^2 in all); consecutive overlap mean {cov['mean_overlap_pct']:.0f} %, "
                f"min {cov['min_overlap_pct']:.0f} %",
            )
        )
    if data.footprint_note:
        rows.append(("footprints", data.footprint_note))
    total_out = sum(o.end_s - o.start_s for o in data.outages)
    rows.append(("link outages", f"{len(data.outages)} ({total_out:.2f} s in all)" if data.outages else "none"))
    second = data.sync_counters.get("autopilot_second_sender_messages", 0)
    unsigned = data.sync_counters.get("autopilot_unsigned_messages", 0)
    if second or unsigned:
        rows.append(
            (
                "messages with the autopilot's id not believed",
                f"{second} from a second sender, {unsigned} without a valid signature (kept out of clocks and poses)",
            )
        )
    kernel_row = kernel_drops_row(data.mavlink_counters)
    if kernel_row is not None:
        rows.append(kernel_row)
    lost = sum(x.count for x in data.losses if x.kind == "sequence_gap")
    rejected = sum(x.count for x in data.losses if x.kind == "frames_rejected")
    rows.append(("device messages missing / corrupt frames", f"{lost} / {rejected}"))
    link = data.metadata.get("icgt.device_link", {})
    if data.device_stopped_itself is not None:
        rows.append(("capture stopped by the device", data.device_stopped_itself.removeprefix("the device ")))
    recovered = data.metadata.get(layout.META_FLIGHT, {})
    if recovered.get("kind") == "recovered":
        rows.append(("recovered from the device", recovered.get("note", "")))
    if data.unreachable_at_end is not None:
        taken, _ = data.unreachable_at_end
        rows.append(
            (
                "exposures lost at the end",
                "unknown, device unreachable at the end"
                + (f": it was taking about {taken} (capture interval x outage)" if taken else "")
                + "; the capture stop was not delivered",
            )
        )
    if "resend_recovered" in link:
        rows.append(
            (
                "device frames recovered (RESEND) / lost",
                f"{link.get('resend_recovered')} recovered; lost: {link.get('lost_exposures')} exposures"
                f"{' + unknown (device unreachable at the end)' if data.unreachable_at_end else ''}, "
                f"{link.get('lost_pps')} PPS, {link.get('lost_samples')} samples, {link.get('lost_other')} "
                f"status/replies/logs, {link.get('lost_unknown')} unknown",
            )
        )
    history_lost = [x for x in data.losses if x.kind == "history_lost"]
    if history_lost and "resend_recovered" not in link:
        rows.append(("device frames lost (exposures + PPS + samples)", str(sum(x.count for x in history_lost))))
    st = data.status
    if st:
        rows.append(
            (
                "device STATUS (last)",
                f"triggers {st.get('triggers_fired', 0)}, confirmed {st.get('exposures_confirmed', 0)}, "
                f"feedback missing {st.get('feedback_missing', 0)}, unsolicited {st.get('feedback_unsolicited', 0)}, "
                f"dropped imu/range/log/event {st.get('dropped_imu', 0)}/{st.get('dropped_range', 0)}/"
                f"{st.get('dropped_log', 0)}/{st.get('dropped_event', 0)}, I2C errors {st.get('i2c_errors', 0)}",
            )
        )
    if data.note:
        rows.append(("note", data.note))
    return rows


def kernel_drops_row(counters: dict[str, int]) -> tuple[str, str] | None:
    """MAVLink datagrams the kernel dropped before the recorder read them, with the receive buffer it granted
    (None for a log without the count: not UDP, or an older recorder)."""
    granted = counters.get("udp_receive_buffer_bytes", 0)
    if "kernel_drops" not in counters or not granted:
        return None
    drops = counters["kernel_drops"]
    asked = counters.get("udp_receive_buffer_asked_bytes", 0)
    buffer = f"UDP receive buffer {granted} bytes granted" + (
        f" of {asked} asked (capped by net.core.rmem_max)" if asked > granted else ""
    )
    if not drops:
        return ("MAVLink datagrams dropped by the kernel", f"0 ({buffer})")
    return ("MAVLink datagrams dropped by the kernel", f"{drops}: the buffer was full ({buffer}), not read in time")


def _counts(c: Counter[str]) -> str:
    return ", ".join(f"{k} {n}" for k, n in c.most_common())


def format_text(rows: list[tuple[str, str]]) -> str:
    width = max(len(k) for k, _ in rows)
    return "\n".join(f"{k:<{width}}  {v}" for k, v in rows)
