"""OpenSfM's exif_overrides.json: per image, values that replace what OpenSfM reads from the EXIF.

OpenSfM's extract_metadata step reads each image's EXIF into a dictionary and updates it with the
image's entry of ``exif_overrides.json`` in the dataset folder (the entry's keys replace the EXIF
ones whole). The keys written here:

- ``gps``: ``latitude`` and ``longitude`` [deg, WGS84], ``altitude`` [m, above mean sea level, as
  EXIF], ``dop``: OpenSfM uses this as the position's standard deviation in metres (its name comes
  from the EXIF GPSDOP tag); the GPS horizontal accuracy is written;
- ``capture_time``: mid-exposure UTC [s since the Unix epoch, float] (EXIF only has the camera's
  clock to the second or the 1/100 s);

Images without a usable position get no entry (their EXIF stays as it is); an image without a UTC
time gets ``gps`` only.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from icgt.export import ExportError
from icgt.export.common import ExportItem, position_sigma_m

EXIF_OVERRIDES = "exif_overrides.json"


def override(item: ExportItem) -> dict[str, Any] | None:
    rec = item.frame
    if not item.name or not item.position_ok:
        return None
    gps: dict[str, Any] = {"latitude": rec.lat_deg, "longitude": rec.lon_deg, "altitude": rec.alt_msl_m}
    h_sigma, _ = position_sigma_m(rec)
    if h_sigma is not None:
        gps["dop"] = h_sigma
    entry: dict[str, Any] = {"gps": gps}
    if rec.mid_utc_us is not None:
        entry["capture_time"] = rec.mid_utc_us / 1e6
    return entry


def write_exif_overrides(path: Path, items: Sequence[ExportItem]) -> int:
    """Write exif_overrides.json; returns the number of images in it."""
    out: dict[str, Any] = {}
    for item in items:
        entry = override(item)
        if entry is not None and item.name not in out:
            out[item.name] = entry
    try:
        with path.open("w", encoding="utf-8") as f:
            json.dump(out, f, indent=1, allow_nan=False)
    except (OSError, ValueError) as exc:
        raise ExportError(f"cannot write {path}: {exc}") from exc
    return len(out)
