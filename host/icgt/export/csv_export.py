"""The per-image CSV: the ICGT paper's columns first, then the whole frame record, then the geometry.

Columns 1-10 are the paper's Table 6 (``No., Filename, Time, Distance (m), Longitude, Latitude,
Altitude, Yaw, Roll, Pitch``), with these meanings here: Time is mid-exposure UTC in ISO 8601 with
microseconds (the paper's was a 1 s RTC time of day); Distance is the LiDAR range at mid-exposure
[m]; Longitude/Latitude WGS84 [deg]; Altitude above mean sea level [m]; Yaw/Roll/Pitch the camera's
attitude [deg] in the gimbal convention of `icgt.geometry.camera_angles_deg` (the paper's IMU sat on
the camera). Then every FrameRecord field under its own name (units: `icgt.geotag.record`), then
``geo_*`` columns from the camera model and ``match_residual_s``.

Cells: empty for a missing value; floats in Python's shortest round-trip form (``inf`` for an
infinite pose gap); booleans ``true``/``false``; flags joined with ``;``.
"""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from icgt.export import ExportError
from icgt.export.common import RECORD_FIELDS, ExportItem, utc_iso

PAPER_COLUMNS = ("No.", "Filename", "Time", "Distance (m)", "Longitude", "Latitude", "Altitude", "Yaw", "Roll", "Pitch")
GEOMETRY_COLUMNS = (
    "geo_surface",
    "geo_scale_mm_per_px",
    "geo_scale_u_mm_per_px",
    "geo_scale_v_mm_per_px",
    "geo_incidence_deg",
    "geo_centre_lat_deg",
    "geo_centre_lon_deg",
    "geo_centre_alt_msl_m",
    "geo_footprint_area_m2",
    "match_residual_s",
)
COLUMNS: tuple[str, ...] = (*PAPER_COLUMNS, *RECORD_FIELDS, *GEOMETRY_COLUMNS)


def cell(value: Any) -> str:
    """One CSV cell (see the module docstring)."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, list | tuple):
        return ";".join(str(v) for v in value)
    return str(value)


def row(number: int, item: ExportItem) -> list[str]:
    rec = item.frame
    angles = item.angles
    ok = item.position_ok
    paper = [
        str(number),
        item.name,
        utc_iso(rec.mid_utc_us),
        cell(rec.range_m if rec.range_valid else None),
        cell(rec.lon_deg if ok else None),
        cell(rec.lat_deg if ok else None),
        cell(rec.alt_msl_m if ok else None),
        cell(angles[0] if angles else None),
        cell(angles[2] if angles else None),
        cell(angles[1] if angles else None),
    ]
    record = [cell(getattr(rec, name)) for name in RECORD_FIELDS]
    s = item.solution
    if s is None:
        geo = [""] * (len(GEOMETRY_COLUMNS) - 1)
    else:
        c = s.centre
        geo = [
            s.surface.value,
            cell(s.scale_mm_per_px),
            cell(s.scale_u_mm_per_px),
            cell(s.scale_v_mm_per_px),
            cell(s.incidence_deg),
            cell(float(c.lat_deg[0]) if c.lat_deg is not None else None),
            cell(float(c.lon_deg[0]) if c.lon_deg is not None else None),
            cell(float(c.alt_m[0]) if c.alt_m is not None else None),
            cell(s.footprint_area_m2),
        ]
    return [*paper, *record, *geo, cell(item.residual_s)]


def write_csv(path: Path, items: Sequence[ExportItem], *, progress: bool = False) -> int:
    """Write one row per item (frames without a position too: their position cells are empty).

    Returns the number of rows written. Raises ExportError if the file cannot be written.
    """
    try:
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            for i, item in enumerate(tqdm(items, desc="csv", unit="frame", disable=not progress), 1):
                w.writerow(row(i, item))
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return len(items)
