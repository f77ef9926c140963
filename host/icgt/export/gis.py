"""GIS exports through GDAL (pyogrio): a GeoPackage (the default vector export) and KML.

``icgt.gpkg`` (OGC GeoPackage, one file, full field names and types) holds three layers:

- ``cameras``: a 3D Point per frame with a position (lon, lat, MSL altitude; EPSG:4326 + heights
  above mean sea level, as the records carry them), every FrameRecord field under its own name,
  ``mid_utc`` as a DateTime and ``mid_utc_us`` to the microsecond, the camera angles and geometry;
- ``footprints``: the image outline on the surface as a 3D Polygon (lon, lat, MSL altitude);
- ``footprints_face``: the same outline in the structure face's own 2D map coordinates (s
  horizontal along the face, t up it, metres; `icgt.geometry.plane_axes`), valid polygons even
  on a vertical pier face, where the map outline collapses to a line. No geographic CRS: it is a
  local engineering plane, shared by every frame whose surface has the same normal.

``icgt.kml`` (LIBKML driver) holds the cameras and the footprints with ``altitudeMode`` absolute:
KML's absolute heights are above mean sea level, the records' altitudes are MSL, written as they
are.

FlatGeobuf (``--formats fgb``; one layer per file: ``cameras.fgb``, ``footprints.fgb``,
``footprints_face.fgb``) carries the same layers and fields as the GeoPackage. FlatGeobuf has no
list type, so list fields (``flags``) are written as one string, comma-separated, as in the
GeoPackage (GDAL would otherwise write a Python-looking repr of the list).

Shapefile is not written: dBASE field names stop at 10 characters (most FrameRecord names are
longer, and truncated names collide) and its Date type has no time of day, so ``mid_utc`` would
lose its time. Asking for it says so and points to the GeoPackage (`shapefile_refusal`).

Every written file is read back and its feature counts checked.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icgt.export import ExportError
from icgt.export.common import RECORD_FIELDS, ExportItem

log = logging.getLogger(__name__)
logging.getLogger("pyogrio").setLevel(logging.WARNING)  # it logs every layer written at INFO

GPKG_FILE = "icgt.gpkg"
KML_FILE = "icgt.kml"
FGB_SUFFIX = ".fgb"
SHAPEFILE_NAMES = ("shp", "shapefile", "esri")
DBF_NAME_LIMIT = 10
"""Characters of a Shapefile (dBASE) field name."""
# WGS 84 + EGM96 height (EPSG:9707): latitude, longitude and a height above mean sea level, as the
# records carry it (autopilots report MSL on the EGM96 geoid).
GEO_CRS = "EPSG:9707"
# the structure face's map plane: a local engineering CRS in metres (no geographic meaning)
FACE_CRS = (
    'LOCAL_CS["icgt structure face: s along the face, t up it (icgt.geometry.plane_axes)",'
    'LOCAL_DATUM["icgt structure face",0],UNIT["metre",1],AXIS["s",EAST],AXIS["t",NORTH]]'
)
CAMERAS = "cameras"
FOOTPRINTS = "footprints"
FACE = "footprints_face"


class GisExportError(ExportError):
    """A GeoPackage or KML file cannot be written or read back."""


def _column(values: list[Any], kind: str) -> np.ndarray[Any, Any]:
    if kind == "float":
        return np.array([np.nan if v is None else float(v) for v in values], dtype=np.float64)
    if kind in ("int", "int32"):
        return np.array([0 if v is None else int(v) for v in values], dtype=np.int64 if kind == "int" else np.int32)
    if kind == "bool":
        return np.array([bool(v) for v in values], dtype=bool)
    return np.array(["" if v is None else str(v) for v in values], dtype=object)


def _record_kind(name: str, values: list[Any]) -> str:
    sample = next((v for v in values if v is not None), None)
    if isinstance(sample, bool):
        return "bool"
    if isinstance(sample, np.int32):
        return "int32"
    if isinstance(sample, int):
        return "int"
    if isinstance(sample, float):
        return "float"
    if isinstance(sample, list):
        return "list"
    return "str" if sample is not None or name in ("time_source", "position_source") else "float"


def _table(rows: list[dict[str, Any]]) -> tuple[list[str], list[np.ndarray[Any, Any]], list[Any]]:
    """(field names, columns, null masks) of a list of flat dicts with the same keys."""
    names = list(rows[0]) if rows else []
    cols: list[np.ndarray[Any, Any]] = []
    masks: list[Any] = []
    for name in names:
        values = [r[name] for r in rows]
        kind = _record_kind(name, values)
        if kind == "list":
            values = [",".join(str(x) for x in v) if v is not None else None for v in values]
            kind = "str"
        if isinstance(next((v for v in values if v is not None), None), np.datetime64):
            cols.append(np.array([v if v is not None else np.datetime64("NaT") for v in values], "datetime64[ms]"))
            masks.append(None)
            continue
        cols.append(_column(values, kind))
        null = np.array([v is None for v in values])
        masks.append(null if kind in ("int", "int32", "bool") and null.any() else None)
    return names, cols, masks


def _utc(us: int | None) -> Any:
    return np.datetime64(us, "us").astype("datetime64[ms]") if us is not None else None


def camera_row(item: ExportItem) -> dict[str, Any]:
    rec = item.frame
    row: dict[str, Any] = {"image": item.name, "mid_utc": _utc(rec.mid_utc_us)}
    for name in RECORD_FIELDS:
        row[name] = getattr(rec, name)
    yaw, pitch, roll = item.angles if item.angles is not None else (None, None, None)
    row["camera_yaw_deg"], row["camera_pitch_deg"], row["camera_roll_deg"] = yaw, pitch, roll
    s = item.solution
    row["surface"] = s.surface.value if s is not None else None
    row["geo_scale_mm_per_px"] = s.scale_mm_per_px if s is not None else None
    row["geo_incidence_deg"] = s.incidence_deg if s is not None else None
    row["match_residual_s"] = item.residual_s
    return row


def footprint_row(item: ExportItem) -> dict[str, Any]:
    s = item.solution
    assert s is not None
    rec = item.frame
    return {
        "image": item.name,
        "frame_seq": rec.frame_seq,
        "image_index": rec.image_index,
        "mid_utc": _utc(rec.mid_utc_us),
        "mid_utc_us": rec.mid_utc_us,
        "surface": s.surface.value,
        "scale_mm_per_px": s.scale_mm_per_px,
        "scale_u_mm_per_px": s.scale_u_mm_per_px,
        "scale_v_mm_per_px": s.scale_v_mm_per_px,
        "incidence_deg": s.incidence_deg,
        "area_m2": s.footprint_area_m2,
        "range_m": rec.range_m,
        "plane_normal_e": s.plane.normal[0],
        "plane_normal_n": s.plane.normal[1],
        "plane_normal_u": s.plane.normal[2],
        "flags": list(rec.flags),
    }


def _ccw(ring: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    """The ring (N, 2+) counterclockwise in its first two coordinates."""
    x, y = ring[:, 0], ring[:, 1]
    area2 = float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return ring if area2 >= 0 else ring[::-1]


def _write(path: Path, layer: str, geoms: list[Any], rows: list[dict[str, Any]], **kw: Any) -> None:
    import shapely
    from pyogrio.raw import write

    names, cols, masks = _table(rows)
    mask = masks if any(m is not None for m in masks) else None
    wkb = np.array([shapely.to_wkb(g, include_srid=False) for g in geoms], dtype=object)
    # DateTime fields are UTC: GDAL's time zone flag 100 says so, else it writes them without a zone
    tz = {n: np.full(len(c), 100, dtype=np.int32) for n, c in zip(names, cols, strict=True) if c.dtype.kind == "M"}
    try:
        write(path, wkb, cols, names, field_mask=mask, layer=layer, append=path.exists(), gdal_tz_offsets=tz, **kw)
    except Exception as exc:  # pyogrio raises DataSourceError, FieldError, ... from GDAL
        raise GisExportError(f"cannot write layer {layer} of {path}: {exc}") from exc


def _face_polygons(items: Sequence[ExportItem]) -> tuple[list[Any], list[ExportItem], int]:
    """Valid 2D face polygons; the number of outlines left out because they were not valid."""
    import shapely

    polys, kept, bad = [], [], 0
    for item in items:
        s = item.solution
        if s is None or s.footprint is None:
            continue
        st = np.asarray(s.footprint.plane_st, dtype=np.float64)
        if not np.all(np.isfinite(st)):
            bad += 1
            continue
        poly = shapely.Polygon(_ccw(st))
        if not poly.is_valid or poly.area <= 0.0:
            bad += 1
            log.warning("frame %d: its footprint on the face is not a valid polygon; left out", item.frame.frame_seq)
            continue
        polys.append(poly)
        kept.append(item)
    return polys, kept, bad


def _geo_footprints(items: Sequence[ExportItem]) -> tuple[list[Any], list[ExportItem]]:
    import shapely

    polys, kept = [], []
    for item in items:
        s = item.solution
        fp = s.footprint if s is not None else None
        if fp is None or fp.lat_deg is None or fp.lon_deg is None or fp.alt_m is None:
            continue
        ring = np.column_stack([fp.lon_deg, fp.lat_deg, fp.alt_m])
        if not np.all(np.isfinite(ring)):
            continue
        polys.append(shapely.Polygon(_ccw(ring)))
        kept.append(item)
    return polys, kept


def _cameras(items: Sequence[ExportItem]) -> tuple[list[Any], list[ExportItem]]:
    import shapely

    pts, kept = [], []
    for item in items:
        rec = item.frame
        if not item.position_ok or rec.alt_msl_m is None:
            continue
        assert rec.lon_deg is not None and rec.lat_deg is not None
        pts.append(shapely.Point(rec.lon_deg, rec.lat_deg, rec.alt_msl_m))
        kept.append(item)
    return pts, kept


def _check_counts(path: Path, expected: dict[str, int]) -> None:
    from pyogrio import list_layers, read_info

    try:
        layers = {str(name) for name, _ in list_layers(path)}
        for layer, n in expected.items():
            if n == 0:
                continue
            if layer not in layers:
                raise GisExportError(f"{path}: layer {layer} missing after writing")
            count = read_info(path, layer=layer)["features"]
            if count != n:
                raise GisExportError(f"{path}: layer {layer} reads back {count} features, {n} were written")
    except GisExportError:
        raise
    except Exception as exc:
        raise GisExportError(f"cannot read back {path}: {exc}") from exc


def write_gpkg(path: Path, items: Sequence[ExportItem]) -> dict[str, int]:
    """Write the GeoPackage (replacing an old one); returns the features written per layer."""
    path.unlink(missing_ok=True)
    cams, cam_items = _cameras(items)
    fps, fp_items = _geo_footprints(items)
    face, face_items, _ = _face_polygons(items)
    written = {CAMERAS: len(cams), FOOTPRINTS: len(fps), FACE: len(face)}
    if cams:
        rows = [camera_row(i) for i in cam_items]
        _write(path, CAMERAS, cams, rows, driver="GPKG", geometry_type="Point Z", crs=GEO_CRS)
    if fps:
        rows = [footprint_row(i) for i in fp_items]
        _write(path, FOOTPRINTS, fps, rows, driver="GPKG", geometry_type="Polygon Z", crs=GEO_CRS)
    if face:
        rows = [footprint_row(i) for i in face_items]
        _write(path, FACE, face, rows, driver="GPKG", geometry_type="Polygon", crs=FACE_CRS)
    if any(written.values()):
        _check_counts(path, written)
    return written


def write_kml(path: Path, items: Sequence[ExportItem]) -> dict[str, int]:
    """Write the KML (cameras and footprints, altitudeMode absolute = MSL); returns features per layer."""
    path.unlink(missing_ok=True)
    cams, cam_items = _cameras(items)
    fps, fp_items = _geo_footprints(items)
    written = {CAMERAS: len(cams), FOOTPRINTS: len(fps)}

    def kml_row(item: ExportItem, what: str) -> dict[str, Any]:
        rec = item.frame
        return {
            "Name": item.name or f"frame {rec.frame_seq}",
            "description": f"{what}; frame {rec.frame_seq}, mid-exposure UTC {rec.mid_utc_us} us, MSL heights",
            "altitudeMode": "absolute",
            "frame_seq": np.int32(rec.frame_seq),  # KML has no 64-bit integers: GDAL would write a string
            "mid_utc": _utc(rec.mid_utc_us),
            "alt_msl_m": rec.alt_msl_m,
        }

    if cams:
        rows = [kml_row(i, "camera at mid-exposure") for i in cam_items]
        _write(path, CAMERAS, cams, rows, driver="LIBKML", geometry_type="Point Z", crs=GEO_CRS)
    if fps:
        rows = [kml_row(i, "image footprint on the surface") for i in fp_items]
        _write(path, FOOTPRINTS, fps, rows, driver="LIBKML", geometry_type="Polygon Z", crs=GEO_CRS)
    if any(written.values()):
        _check_counts(path, written)
    return written


def write_fgb(out_dir: Path, items: Sequence[ExportItem]) -> dict[str, int]:
    """Write cameras.fgb, footprints.fgb and footprints_face.fgb (replacing old ones); features per layer."""
    cams, cam_items = _cameras(items)
    fps, fp_items = _geo_footprints(items)
    face, face_items, _ = _face_polygons(items)
    layers = [
        (CAMERAS, cams, [camera_row(i) for i in cam_items], "Point Z", GEO_CRS),
        (FOOTPRINTS, fps, [footprint_row(i) for i in fp_items], "Polygon Z", GEO_CRS),
        (FACE, face, [footprint_row(i) for i in face_items], "Polygon", FACE_CRS),
    ]
    written: dict[str, int] = {}
    for layer, geoms, rows, geometry_type, crs in layers:
        path = out_dir / f"{layer}{FGB_SUFFIX}"
        path.unlink(missing_ok=True)
        written[layer] = len(geoms)
        if geoms:
            # no spatial index: a few hundred features; the file then keeps the frames' order
            _write(path, layer, geoms, rows, driver="FlatGeobuf", geometry_type=geometry_type, crs=crs,
                   layer_options={"SPATIAL_INDEX": "NO"})  # fmt: skip
            _check_counts(path, {layer: len(geoms)})
    return written


def shapefile_refusal(asked: str) -> str:
    """Why no Shapefile is written, with the numbers, and what to use instead."""
    long_names = [n for n in RECORD_FIELDS if len(n) > DBF_NAME_LIMIT]
    return (
        f"export format {asked!r}: Shapefile is not written, it would lose data: {len(long_names)} of the "
        f"{len(RECORD_FIELDS)} frame fields have names longer than its {DBF_NAME_LIMIT} characters "
        f"(e.g. {', '.join(long_names[:3])}; truncated names collide) and its Date fields drop the time of "
        f"mid_utc. Use gpkg (GeoPackage, a default format: every field under its full name, UTC times to the "
        f"microsecond; QGIS, ArcGIS and GDAL read it) or fgb (FlatGeobuf); if a Shapefile is required, "
        f"convert the GeoPackage with ogr2ogr and choose the field names yourself"
    )
