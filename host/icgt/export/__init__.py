"""Exports of a recording for photogrammetry, GIS and the crack detector.

`icgt export` (icgt.export.cli) matches the camera card's JPEGs to the log and writes:

- frames.csv: the ICGT paper's columns, then the whole frame record and the geometry (csv_export);
- cameras.geojson / footprints.geojson: camera points and image footprints (geojson_export);
- icgt.gpkg (GeoPackage, the default vector export), icgt.kml (absolute MSL heights) and with
  ``--formats fgb`` cameras/footprints/footprints_face.fgb (FlatGeobuf), through GDAL (gis); no
  Shapefile (its 10-character field names and dates without time would lose data: refused, said why);
- geo.txt: OpenDroneMap's image geolocation file (odm);
- exif_overrides.json: OpenSfM's per-image overrides (opensfm);
- images/: geotagged copies of the JPEGs written by ExifTool (geotag_writer; tags in exif_tags,
  pose conventions in pose_tags), every other tag and the pixels untouched, each read back and
  checked; XMP sidecars for RAW files shot with a JPEG (card: hidden files, RAW, HEIC, damage);
- problems.csv: every input problem, per image.

The writers take `ExportItem`s made by `prepare_items` from `(image path, FrameRecord)` pairs.
Importing this package is cheap (the command line builds its parser from it); the names below
load their modules (numpy, Pillow) on first use.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from icgt.errors import IcgtError


class ExportError(IcgtError):
    """An export cannot be made at all (output folder unusable, no frames); per-image problems are not errors."""


if TYPE_CHECKING:
    from icgt.export.common import (
        RECORD_FIELDS,
        ExportItem,
        Problem,
        ProblemLog,
        position_problem,
        prepare_items,
    )

_LAZY = {"RECORD_FIELDS", "ExportItem", "Problem", "ProblemLog", "position_problem", "prepare_items"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from icgt.export import common

        return getattr(common, name)
    raise AttributeError(f"module 'icgt.export' has no attribute {name!r}")


__all__ = [
    "RECORD_FIELDS",
    "ExportError",
    "ExportItem",
    "Problem",
    "ProblemLog",
    "position_problem",
    "prepare_items",
]
