"""OpenDroneMap's image geolocation file, geo.txt.

Layout (ODM documentation, "image geolocation files"): the first line names the coordinate system,
here ``EPSG:4326``; then one line per image, fields separated by whitespace::

    image_name  geo_x  geo_y  [geo_z]  [yaw  pitch  roll]  [horz_accuracy  vert_accuracy]  [extras...]

With EPSG:4326, geo_x is the LONGITUDE and geo_y the LATITUDE [deg]; geo_z is the altitude [m]
(here above mean sea level, as in EXIF). The angles [deg] are the camera's in ODM's convention
(`icgt.export.pose_tags.odm_angles`: ODM builds its rotation from them with Baeumker's
yaw-pitch-roll matrix; yaw 0 and pitch 0 is a camera looking straight down with the top of the
image to the north, pitch 90 looks level; ODM uses geo.txt angles as they are, with no per-make
correction); ODM reads them positionally (columns 5-7 only when a line has at least 7 fields, the
accuracies only with 9), and documents 0 for angles that are not known. The
accuracies [m] are the GPS's horizontal and vertical accuracy estimates. File names must not
contain whitespace (ODM splits on it); such images are reported and left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from tqdm import tqdm

from icgt.export import ExportError
from icgt.export.common import ExportItem, ProblemLog, position_sigma_m
from icgt.export.exif_tags import item_odm_angles

GEO_TXT = "geo.txt"
PROJECTION = "EPSG:4326"


def geo_line(item: ExportItem) -> str | None:
    """The geo.txt line of one image, or None if it has no image name or no usable position."""
    rec = item.frame
    if not item.name or not item.position_ok:
        return None
    assert rec.lon_deg is not None and rec.lat_deg is not None and rec.alt_msl_m is not None
    fields = [item.name, f"{rec.lon_deg:.9f}", f"{rec.lat_deg:.9f}", f"{rec.alt_msl_m:.4f}"]
    angles = item_odm_angles(item)
    yaw, pitch, roll = angles if angles is not None else (0.0, 0.0, 0.0)
    fields += [f"{yaw:.4f}", f"{pitch:.4f}", f"{roll:.4f}"]
    h_sigma, v_sigma = position_sigma_m(rec)
    if h_sigma is not None and v_sigma is not None:
        fields += [f"{h_sigma:.3f}", f"{v_sigma:.3f}"]
    return " ".join(fields)


def write_geo_txt(path: Path, items: Sequence[ExportItem], problems: ProblemLog, *, progress: bool = False) -> int:
    """Write geo.txt; returns the number of image lines. Images it cannot describe go to `problems`."""
    lines = [PROJECTION]
    seen: set[str] = set()
    for item in tqdm(items, desc="geo.txt", unit="image", disable=not progress):
        if item.image is None or item.name in seen:
            continue
        seen.add(item.name)
        if any(ch.isspace() for ch in item.name):
            problems.add(
                item.name,
                item.frame.frame_seq,
                "error",
                "bad_file_name",
                "file name contains whitespace, which geo.txt cannot carry",
                "geo.txt",
            )
            continue
        line = geo_line(item)
        if line is not None:
            lines.append(line)
    try:
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    except OSError as exc:
        raise ExportError(f"cannot write {path}: {exc.strerror or exc}") from exc
    return len(lines) - 1
