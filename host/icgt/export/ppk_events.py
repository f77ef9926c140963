"""The exposure events in GPS time, for PPK tools: ``events_gpst.csv`` and a DJI-style ``Timestamp.MRK``.

PPK software computes the antenna's trajectory from the rover's and a base's raw GNSS logs, then
needs the instant of every photo on GPS time. Two files are written (`icgt export --formats ppk`):

``events_gpst.csv`` (every frame with a UTC time): ``mrk_index`` (its line in the MRK, empty if it
has none), ``frame_seq``, ``image_index``, ``camera_id``, ``gps_week``, ``gps_tow_s`` (6 decimals,
mid-exposure), ``utc_iso``, ``mid_utc_uncertainty_us``, ``position_source``, ``flags`` (``;``-joined).
GPS time = UTC + the leap seconds (18 s since 2017, `icgt.clocks.gpstime`).

``Timestamp.MRK``, the event file DJI's RTK drones write beside their photos and that Emlid Studio
(its DJI drone workflow), Qinertia, Skycatch and others read. Its rules, as DJI's user manuals
(Matrice 4 series, image log file) and readers of the files describe them: one line per photo, in
photo order, fields separated by tabs:

1. the photo's sequence number (1, 2, ... in the order of the photos);
2. GPS time of week [s] of the exposure, 6 decimals;
3. the GPS week in square brackets, ``[2404]``;
4-6. the camera's offset from the GNSS antenna phase centre in mm, integers right-aligned in 6
   characters, suffixed ``,N`` (north positive), ``,E`` (east positive), ``,V`` (down positive);
7-9. the camera's latitude ``,Lat`` and longitude ``,Lon`` [deg, 8 decimals] and ellipsoidal height
   ``,Ellh`` [m, 3 decimals] (the position after the offset);
10. the standard deviations north, east, vertical [m, 6 decimals] in one field, separated by ``, ``;
11. the RTK status ``,Q``: 0 no position, 16 single point, 34 RTK float, 50 RTK fixed.

Here: the offset is the lever arm (camera from the antenna, body FRD; the recording's
``lever_arm_body_m`` unless another is given) rotated to NED by the frame's attitude, 0 without
attitude; the position is the frame's camera position with its MSL altitude + the geoid separation
N (so N must be known); the deviations are the autopilot receiver's h_acc (north and east) and
v_acc, 0 when unknown; Q from ``position_source`` (rtk_fixed/ppk_fixed 50, rtk_float/ppk_float 34,
any other placed position 16, none 0). A frame flagged ``feedback_missing`` (the camera did not
confirm it: there may be no photo) has no MRK line, so the lines keep pairing with the photos in
order; it stays in the CSV. Frames without UTC appear in neither and are listed.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from icgt.clocks.gpstime import utc_us_to_gps_week_tow_us
from icgt.errors import IcgtError
from icgt.geodesy import q_rotate
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.ingest.recompute import recording_config

__all__ = [
    "EVENTS_COLUMNS",
    "EVENTS_CSV",
    "MRK_FILE",
    "MrkLine",
    "PpkEventsResult",
    "dji_rtk_flag",
    "export_ppk",
    "read_mrk",
    "write_ppk_events",
]

EVENTS_CSV = "events_gpst.csv"
MRK_FILE = "Timestamp.MRK"
EVENTS_COLUMNS = (
    "mrk_index",
    "frame_seq",
    "image_index",
    "camera_id",
    "gps_week",
    "gps_tow_s",
    "utc_iso",
    "mid_utc_uncertainty_us",
    "position_source",
    "flags",
)


class PpkEventsError(IcgtError):
    """The event files cannot be written or read back."""


@dataclass(frozen=True)
class MrkLine:
    index: int
    tow_s: float
    week: int
    offset_ned_mm: tuple[int, int, int]
    lat_deg: float
    lon_deg: float
    ellh_m: float
    std_ned_m: tuple[float, float, float]
    q: int


@dataclass
class PpkEventsResult:
    events: int
    mrk_lines: int
    skipped: list[tuple[int, str]] = field(default_factory=list)
    """(frame_seq, why) of frames left out of one or both files."""


def dji_rtk_flag(position_source: str, has_position: bool) -> int:
    """DJI's RTK status code for a frame's position source."""
    if not has_position or position_source == "none":
        return 0
    if position_source in ("rtk_fixed", "ppk_fixed"):
        return 50
    if position_source in ("rtk_float", "ppk_float"):
        return 34
    return 16


def _utc_iso(utc_us: int) -> str:
    dt = datetime.fromtimestamp(utc_us // 1_000_000, tz=UTC)
    return dt.strftime("%Y-%m-%dT%H:%M:%S") + f".{utc_us % 1_000_000:06d}Z"


def _tow_text(tow_us: int) -> str:
    return f"{tow_us // 1_000_000}.{tow_us % 1_000_000:06d}"


def _mrk_line(
    index: int, frame: FrameRecord, week: int, tow_us: int, lever_arm: np.ndarray, geoid_separation_m: float
) -> str:
    q_parts = (frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz)
    if None in q_parts:
        off = (0, 0, 0)
    else:
        ned = q_rotate(np.array(q_parts, dtype=float), lever_arm)
        off = (round(float(ned[0]) * 1000.0), round(float(ned[1]) * 1000.0), round(float(ned[2]) * 1000.0))
    has_pos = frame.lat_deg is not None and frame.lon_deg is not None and frame.alt_msl_m is not None
    lat = frame.lat_deg if has_pos and frame.lat_deg is not None else 0.0
    lon = frame.lon_deg if has_pos and frame.lon_deg is not None else 0.0
    ellh = frame.alt_msl_m + geoid_separation_m if has_pos and frame.alt_msl_m is not None else 0.0
    sh = frame.h_acc_m if frame.h_acc_m is not None and math.isfinite(frame.h_acc_m) else 0.0
    sv = frame.v_acc_m if frame.v_acc_m is not None and math.isfinite(frame.v_acc_m) else 0.0
    q = dji_rtk_flag(frame.position_source, has_pos)
    return "\t".join(
        [
            str(index),
            _tow_text(tow_us),
            f"[{week}]",
            f"{off[0]:6d},N",
            f"{off[1]:6d},E",
            f"{off[2]:6d},V",
            f"{lat:.8f},Lat",
            f"{lon:.8f},Lon",
            f"{ellh:.3f},Ellh",
            f"{sh:.6f}, {sh:.6f}, {sv:.6f}",
            f"{q},Q",
        ]
    )


def write_ppk_events(
    out_dir: Path,
    frames: Sequence[FrameRecord],
    *,
    lever_arm_body_m: tuple[float, float, float],
    geoid_separation_m: float | None,
) -> PpkEventsResult:
    """Write events_gpst.csv and Timestamp.MRK into out_dir, read both back, and say what was left out."""
    if geoid_separation_m is None:
        raise PpkEventsError(
            "Timestamp.MRK carries ellipsoidal heights: the geoid separation N is unknown "
            "(the log has no GPS_RAW_INT.alt_ellipsoid): give --geoid-separation METRES"
        )
    lever = np.asarray(lever_arm_body_m, dtype=float)
    result = PpkEventsResult(0, 0)
    csv_rows: list[list[str]] = []
    mrk: list[str] = []
    expected_tow: list[tuple[int, int]] = []
    for f in sorted(frames, key=lambda fr: fr.frame_seq):
        if f.mid_utc_us is None:
            result.skipped.append((f.frame_seq, "no UTC time at mid-exposure: no GPS time; in neither file"))
            continue
        week, tow_us = utc_us_to_gps_week_tow_us(f.mid_utc_us)
        index = ""
        if FrameFlag.FEEDBACK_MISSING.value in f.flags:
            result.skipped.append((f.frame_seq, "feedback_missing: the camera may not have taken it; not in the MRK"))
        else:
            index = str(len(mrk) + 1)
            mrk.append(_mrk_line(len(mrk) + 1, f, week, tow_us, lever, geoid_separation_m))
            expected_tow.append((week, tow_us))
        unc = f.mid_utc_uncertainty_us
        csv_rows.append(
            [
                index,
                str(f.frame_seq),
                str(f.image_index),
                str(f.camera_id),
                str(week),
                _tow_text(tow_us),
                _utc_iso(f.mid_utc_us),
                "" if unc is None else repr(float(unc)),
                f.position_source,
                ";".join(f.flags),
            ]
        )
    csv_path, mrk_path = out_dir / EVENTS_CSV, out_dir / MRK_FILE
    try:
        with csv_path.open("w", newline="", encoding="utf-8") as fh:
            w = csv.writer(fh)
            w.writerow(EVENTS_COLUMNS)
            w.writerows(csv_rows)
        mrk_path.write_text("".join(line + "\n" for line in mrk), encoding="utf-8")
    except OSError as exc:
        raise PpkEventsError(f"cannot write the PPK event files in {out_dir}: {exc.strerror or exc}") from exc
    # read both back: the counts and every MRK time must be what was meant
    with csv_path.open(newline="", encoding="utf-8") as fh:
        back_rows = list(csv.DictReader(fh))
    back = read_mrk(mrk_path)
    if len(back_rows) != len(csv_rows) or len(back) != len(mrk):
        raise PpkEventsError(f"{out_dir}: the event files read back with other line counts than written")
    for line, (week, tow_us) in zip(back, expected_tow, strict=True):
        if line.week != week or round(line.tow_s * 1e6) != tow_us:
            raise PpkEventsError(f"{mrk_path}: line {line.index} reads back as another time")
    result.events, result.mrk_lines = len(csv_rows), len(mrk)
    return result


def read_mrk(path: Path) -> list[MrkLine]:
    """Parse a Timestamp.MRK (the layout of the module docstring); errors name the file and line."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise PpkEventsError(f"cannot read {path}: {exc}") from None
    out: list[MrkLine] = []
    for number, raw in enumerate(lines, 1):
        if not raw.strip():
            continue
        f = [x.strip() for x in raw.split("\t")]
        try:
            if len(f) != 11 or not (f[2].startswith("[") and f[2].endswith("]")):
                raise ValueError("not 11 tab-separated fields with the week in brackets")
            tags = [(f[i].rsplit(",", 1)) for i in (3, 4, 5, 6, 7, 8, 10)]
            if [t[1] for t in tags] != ["N", "E", "V", "Lat", "Lon", "Ellh", "Q"]:
                raise ValueError("field tags are not N, E, V, Lat, Lon, Ellh, Q")
            std = [float(s) for s in f[9].split(",")]
            if len(std) != 3:
                raise ValueError("three standard deviations expected")
            out.append(
                MrkLine(
                    index=int(f[0]),
                    tow_s=float(f[1]),
                    week=int(f[2][1:-1]),
                    offset_ned_mm=(int(tags[0][0]), int(tags[1][0]), int(tags[2][0])),
                    lat_deg=float(tags[3][0]),
                    lon_deg=float(tags[4][0]),
                    ellh_m=float(tags[5][0]),
                    std_ned_m=(std[0], std[1], std[2]),
                    q=int(tags[6][0]),
                )
            )
        except (ValueError, IndexError) as exc:
            raise PpkEventsError(f"{path}:{number}: not an MRK line ({exc}): {raw[:80]!r}") from None
    return out


def export_ppk(
    recording: Any, frames: Sequence[FrameRecord], out_dir: Path, problems: Any, *, geoid_separation_m: float | None
) -> dict[str, int]:
    """The `icgt export --formats ppk` step: events_gpst.csv and Timestamp.MRK; skipped frames become problems."""
    try:
        lever = recording_config(recording).lever_arm_body_m
    except IcgtError:
        lever = (0.0, 0.0, 0.0)
        problems.add("", None, "warning", "no_lever_arm", "no mounting in the log: MRK offsets written as 0")
    result = write_ppk_events(out_dir, frames, lever_arm_body_m=lever, geoid_separation_m=geoid_separation_m)
    for seq, why in result.skipped:
        affects = "events_gpst.csv,Timestamp.MRK" if why.startswith("no UTC") else "Timestamp.MRK"
        problems.add("", seq, "warning", "ppk_event_skipped", why, affects)
    return {"ppk events": result.events, "mrk lines": result.mrk_lines}
