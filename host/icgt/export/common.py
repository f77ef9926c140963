"""What every export shares: the per-image item, the problem report, the record's columns.

Exports work from `(image path, FrameRecord)` pairs. `prepare_items` checks each frame once
(position, time, attitude, geometry) and records every problem per image in a `ProblemLog`; the
writers then skip, per format, what that format cannot carry, and never stop on one bad image.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from icgt.export import ExportError
from icgt.geometry import FrameSolution, GeometryError, Projector, camera_angles_deg_many
from icgt.geotag.bounds import AXIS_95, RADIAL_95
from icgt.geotag.record import FrameFlag, FrameRecord

log = logging.getLogger(__name__)

RECORD_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(FrameRecord))
"""Every FrameRecord field, in declaration order."""


def position_sigma_m(rec: FrameRecord) -> tuple[float | None, float | None]:
    """The frame's position accuracy as one standard deviation [m] (horizontal radial RMS, vertical), what
    photogrammetry weights by: its 95 % bounds scaled back (docs/error-bounds.md); a frame from a log without
    them gives the receiver's h_acc / v_acc."""
    h, v = rec.horizontal_error_bound_m, rec.vertical_error_bound_m
    if h is not None and v is not None and math.isfinite(h) and math.isfinite(v):
        return h / RADIAL_95, v / AXIS_95
    return rec.h_acc_m, rec.v_acc_m


_POSE_WARNING_FLAGS = (
    FrameFlag.STALE_POSE,
    FrameFlag.POSE_EXTRAPOLATED,
    FrameFlag.CLOCK_UNSYNCED,
)


@dataclass(frozen=True)
class Problem:
    """One input problem, tied to an image and/or a frame."""

    image: str
    """File name of the image ('' for a frame without an image)."""
    frame_seq: int | None
    severity: str
    """'error': the image is left out of the outputs named in `affects`; 'warning': exported, but distrust it."""
    code: str
    detail: str
    affects: str = ""
    """Outputs that leave the image (or the field) out, comma-separated; '' for warnings."""


PROBLEM_COLUMNS = ("image", "frame_seq", "severity", "code", "detail", "affects")


@dataclass
class ProblemLog:
    """Every problem found during one export, in the order found."""

    problems: list[Problem] = field(default_factory=list)

    def add(
        self,
        image: str,
        frame_seq: int | None,
        severity: str,
        code: str,
        detail: str,
        affects: str = "",
    ) -> None:
        self.problems.append(Problem(image, frame_seq, severity, code, detail, affects))

    def __len__(self) -> int:
        return len(self.problems)

    def __iter__(self) -> Any:
        return iter(self.problems)

    def counts(self) -> Counter[str]:
        return Counter(p.code for p in self.problems)

    def write_csv(self, path: Path) -> None:
        try:
            with path.open("w", newline="", encoding="utf-8") as f:
                w = csv.writer(f)
                w.writerow(PROBLEM_COLUMNS)
                for p in self.problems:
                    w.writerow(
                        [p.image, "" if p.frame_seq is None else p.frame_seq, p.severity, p.code, p.detail, p.affects]
                    )
        except OSError as exc:
            raise ExportError(f"cannot write {path}: {exc.strerror or exc}") from exc

    def summary(self) -> str:
        if not self.problems:
            return "no problems"
        return ", ".join(f"{code}: {n}" for code, n in sorted(self.counts().items()))


@dataclass(frozen=True)
class ExportItem:
    """One image (or a frame without one) with its record and its geometry, checked once."""

    image: Path | None
    frame: FrameRecord
    solution: FrameSolution | None = None
    position_ok: bool = False
    """The frame has a usable WGS84 position (not missing, not zero, in range)."""
    residual_s: float | None = None
    """Matching residual reported by the matcher (image time minus exposure time) [s], if any."""
    angles: tuple[float, float, float] | None = None
    """Camera (yaw, pitch, roll) [deg], gimbal convention (icgt.geometry.camera_angles_deg)."""

    @property
    def name(self) -> str:
        return self.image.name if self.image is not None else ""


def position_problem(rec: FrameRecord) -> tuple[str, str] | None:
    """(code, detail) if the frame has no usable WGS84 position, else None."""
    lat, lon, alt = rec.lat_deg, rec.lon_deg, rec.alt_msl_m
    if lat is None or lon is None or alt is None:
        why = ", ".join(rec.flags) or "no flags"
        if FrameFlag.NO_POSE.value in rec.flags:
            return (
                "no_pose",
                f"no position given: the position telemetry around the exposure has a gap of "
                f"{rec.pose_gap_before_ms / 1000.0:.2f} s before it and {rec.pose_gap_after_ms / 1000.0:.2f} s "
                f"after it, too long to bound a position (docs/error-bounds.md); icgt recompute with look-ahead "
                f"may place it ({why})",
            )
        return (
            "no_fix",
            f"no position at exposure (position source {rec.position_source}, fix type {rec.fix_type}; {why})",
        )
    if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
        return "bad_position", f"position is not finite ({lat}, {lon}, {alt})"
    if abs(lat) < 1e-7 and abs(lon) < 1e-7:
        return "zero_gps", "latitude and longitude are 0 (a GPS without a fix reports 0, 0)"
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        return "bad_position", f"latitude/longitude out of range ({lat}, {lon})"
    return None


def prepare_items(
    pairs: Iterable[tuple[Path | None, FrameRecord]] | Iterable[tuple[Path | None, FrameRecord, float | None]],
    projector: Projector | None,
    problems: ProblemLog,
) -> list[ExportItem]:
    """Check every frame once and solve its geometry (vectorised); problems go to `problems`."""
    rows: list[tuple[Path | None, FrameRecord, float | None]] = []
    for pair in pairs:
        image, frame = pair[0], pair[1]
        residual = pair[2] if len(pair) > 2 else None
        rows.append((image, frame, residual))
    solutions: Sequence[FrameSolution | GeometryError | None] = (
        projector.solve_many([r[1] for r in rows]) if projector is not None else [None] * len(rows)
    )
    angles = camera_angles_deg_many([r[1] for r in rows])
    items: list[ExportItem] = []
    for (image, rec, residual), sol, ang in zip(rows, solutions, angles, strict=True):
        name = image.name if image is not None else ""
        bad_pos = position_problem(rec)
        if bad_pos is not None:
            problems.add(name, rec.frame_seq, "error", bad_pos[0], bad_pos[1], "geo.txt,opensfm,geojson,jpeg-gps")
        flags = set(rec.flags)
        if rec.mid_utc_us is None:
            problems.add(
                name,
                rec.frame_seq,
                "warning",
                "no_utc",
                "no UTC time for this exposure: no GPS time stamp",
                "jpeg-gps-time,opensfm-capture-time",
            )
        if rec.cam_qw is None:
            problems.add(name, rec.frame_seq, "warning", "no_attitude", "no camera attitude: angles written as 0")
        risky = [f.value for f in _POSE_WARNING_FLAGS if f.value in flags]
        if risky and bad_pos is None:
            problems.add(name, rec.frame_seq, "warning", "pose_quality", f"pose flagged {', '.join(risky)}")
        if FrameFlag.FEEDBACK_MISSING.value in flags and image is not None:
            problems.add(
                name,
                rec.frame_seq,
                "warning",
                "feedback_missing",
                "the camera did not confirm this exposure, yet an image was matched to it",
            )
        solution: FrameSolution | None = None
        if isinstance(sol, GeometryError):
            if bad_pos is None or "no position" not in str(sol):
                problems.add(name, rec.frame_seq, "warning", "no_geometry", str(sol), "footprint,scale")
        elif sol is not None:
            solution = sol
            if sol.footprint is None:
                problems.add(
                    name,
                    rec.frame_seq,
                    "warning",
                    "no_footprint",
                    "part of the image does not see the surface plane (beyond its horizon)",
                    "footprint",
                )
        items.append(ExportItem(image, rec, solution, bad_pos is None, residual, ang))
    return items


def utc_iso(utc_us: int | None) -> str:
    """UTC microseconds since the epoch as ISO 8601 with microseconds and 'Z'; '' for None."""
    if utc_us is None:
        return ""
    dt = datetime.fromtimestamp(utc_us // 1_000_000, tz=UTC)
    return dt.strftime("%Y-%m-%dT%H:%M:%S") + f".{utc_us % 1_000_000:06d}Z"


def check_out_dir(out_dir: Path, images_dir: Path | None) -> None:
    """Create `out_dir`; refuse the images folder and folders inside it (the originals stay untouched)."""
    if images_dir is not None:
        out, img = out_dir.resolve(), images_dir.resolve()
        if out == img or out.is_relative_to(img):
            raise ExportError(
                f"--out {out_dir} is inside the images folder {images_dir}: choose another folder "
                "(the card's folder and its originals stay untouched)"
            )
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExportError(f"cannot create {out_dir}: {exc.strerror or exc}") from exc
