"""GeoJSON (RFC 7946): a point per image at the camera, and the image's footprint on the surface.

Two FeatureCollections, so GIS tools load each as one layer:

- ``cameras.geojson``: a Point per image (the camera's position at mid-exposure) whose properties
  are the whole frame record plus the camera angles and the geometry;
- ``footprints.geojson``: a Polygon per image, the image outline projected on the surface plane
  (`icgt.geometry`), with the scale, incidence and the outline in local ENU and map coordinates.

Coordinates are [longitude, latitude] (RFC 7946 order), WGS84, with 9 decimals (0.1 mm). RFC 7946's
third coordinate is the height above the WGS84 *ellipsoid*; the records carry altitude above mean
sea level, so a third coordinate is written only when the geoid separation N is known
(ellipsoidal height = MSL altitude + N); the MSL altitudes are always in the properties. Linear
rings are closed and counterclockwise (the right-hand rule). A footprint on a vertical face
(a pier) collapses to a line on a map (its ring's area is rounding noise, oriented all the same);
such features say ``"vertical_surface": true`` and carry the outline in ENU and in map coordinates on
the face.
"""

from __future__ import annotations

import itertools
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from icgt.export import ExportError
from icgt.export.common import RECORD_FIELDS, ExportItem, utc_iso

CAMERAS_FILE = "cameras.geojson"
FOOTPRINTS_FILE = "footprints.geojson"
_M_PER_DEG = 111_320.0  # metres per degree of latitude (and of scaled longitude), near enough for a threshold
_VERTICAL_WIDTH_M = 0.01  # an outline narrower than this on a map lies on a vertical surface


def _num(value: Any, digits: int | None = None) -> Any:
    if isinstance(value, bool) or value is None:
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            return None
        return round(value, digits) if digits is not None else value
    return value


def _position(lon: float, lat: float, alt_msl: float | None, geoid_separation_m: float | None) -> list[float]:
    pos = [round(lon, 9), round(lat, 9)]
    if alt_msl is not None and geoid_separation_m is not None and math.isfinite(alt_msl):
        pos.append(round(alt_msl + geoid_separation_m, 4))
    return pos


def ring_signed_area(ring: Sequence[Sequence[float]]) -> tuple[float, float]:
    """(signed area, perimeter) of a closed lon/lat ring in a local equirectangular plane at its mean
    latitude (deg units; > 0: counterclockwise). Summed relative to the first position: in absolute
    degrees (products of ~100 degrees) the cancellation noise, ~1e-12 deg^2, is the area of a ring a
    few cm across, and the sign of a small or near-vertical footprint would be a coin toss."""
    k = math.cos(math.radians(sum(p[1] for p in ring[:-1]) / (len(ring) - 1)))
    x_ref, y_ref = ring[0][0], ring[0][1]
    area2 = 0.0
    perim = 0.0
    for a, b in itertools.pairwise(ring):
        ax, ay, bx, by = (a[0] - x_ref) * k, a[1] - y_ref, (b[0] - x_ref) * k, b[1] - y_ref
        area2 += ax * by - bx * ay
        perim += math.hypot(bx - ax, by - ay)
    return area2 / 2.0, perim


def camera_feature(item: ExportItem, geoid_separation_m: float | None) -> dict[str, Any] | None:
    rec = item.frame
    if not item.position_ok:
        return None
    assert rec.lon_deg is not None and rec.lat_deg is not None
    props: dict[str, Any] = {"image": item.name or None, "mid_utc": utc_iso(rec.mid_utc_us) or None}
    for name in RECORD_FIELDS:
        props[name] = _num(getattr(rec, name))
    if item.angles is not None:
        props["camera_yaw_deg"], props["camera_pitch_deg"], props["camera_roll_deg"] = item.angles
    s = item.solution
    if s is not None:
        props["surface"] = s.surface.value
        props["geo_scale_mm_per_px"] = _num(s.scale_mm_per_px)
        props["geo_incidence_deg"] = _num(s.incidence_deg)
    props["match_residual_s"] = _num(item.residual_s)
    return {
        "type": "Feature",
        "id": rec.frame_seq,
        "geometry": {
            "type": "Point",
            "coordinates": _position(rec.lon_deg, rec.lat_deg, rec.alt_msl_m, geoid_separation_m),
        },
        "properties": props,
    }


def footprint_feature(item: ExportItem, geoid_separation_m: float | None) -> dict[str, Any] | None:
    s = item.solution
    if s is None or s.footprint is None or s.footprint.lat_deg is None or s.footprint.lon_deg is None:
        return None
    fp = s.footprint
    assert fp.lat_deg is not None and fp.lon_deg is not None and fp.alt_m is not None
    ring = [
        _position(float(lo), float(la), float(al), geoid_separation_m)
        for lo, la, al in zip(fp.lon_deg, fp.lat_deg, fp.alt_m, strict=True)
    ]
    ring.append(list(ring[0]))
    area, perim = ring_signed_area(ring)
    # mean width of the outline on the map [m]: a vertical face leaves only rounding noise (< 1 mm)
    vertical = perim == 0.0 or 2.0 * abs(area) / perim * _M_PER_DEG < _VERTICAL_WIDTH_M
    order = list(range(len(fp.enu)))
    if area < 0:  # counterclockwise on the written coordinates, even when the area is only rounding noise
        ring.reverse()
        order.reverse()
    rec = item.frame
    props: dict[str, Any] = {
        "image": item.name or None,
        "frame_seq": rec.frame_seq,
        "image_index": rec.image_index,
        "mid_utc": utc_iso(rec.mid_utc_us) or None,
        "surface": s.surface.value,
        "scale_mm_per_px": _num(s.scale_mm_per_px),
        "scale_u_mm_per_px": _num(s.scale_u_mm_per_px),
        "scale_v_mm_per_px": _num(s.scale_v_mm_per_px),
        "incidence_deg": _num(s.incidence_deg),
        "area_m2": _num(s.footprint_area_m2),
        "range_m": _num(rec.range_m),
        "vertical_surface": vertical,
        "plane_point_enu_m": [round(c, 4) for c in s.plane.point],
        "plane_normal_enu": [round(c, 6) for c in s.plane.normal],
        "outline_alt_msl_m": [round(float(fp.alt_m[i]), 4) for i in order],
        "outline_enu_m": [[round(float(c), 4) for c in fp.enu[i]] for i in order],
        "outline_map_st_m": [[round(float(c), 4) for c in fp.plane_st[i]] for i in order],
        "flags": list(rec.flags),
    }
    return {
        "type": "Feature",
        "id": rec.frame_seq,
        "geometry": {"type": "Polygon", "coordinates": [ring]},
        "properties": props,
    }


def _collection(features: list[dict[str, Any]], geoid_separation_m: float | None, what: str) -> dict[str, Any]:
    alt = (
        f"third coordinate: height above the WGS84 ellipsoid = MSL altitude + {geoid_separation_m} m geoid separation"
        if geoid_separation_m is not None
        else "no third coordinate (geoid separation unknown); MSL altitudes are in the properties"
    )
    return {"type": "FeatureCollection", "icgt": {"content": what, "altitude": alt}, "features": features}


def write_geojson(
    out_dir: Path,
    items: Sequence[ExportItem],
    *,
    geoid_separation_m: float | None = None,
    progress: bool = False,
) -> tuple[int, int]:
    """Write cameras.geojson and footprints.geojson into out_dir; returns (points, polygons) written.

    Images without a position or without a footprint are left out (prepare_items reported why).
    """
    cams: list[dict[str, Any]] = []
    fps: list[dict[str, Any]] = []
    for item in tqdm(items, desc="geojson", unit="frame", disable=not progress):
        cam = camera_feature(item, geoid_separation_m)
        if cam is not None:
            cams.append(cam)
        fp = footprint_feature(item, geoid_separation_m)
        if fp is not None:
            fps.append(fp)
    for name, feats, what in (
        (CAMERAS_FILE, cams, "camera position at mid-exposure, one point per image"),
        (FOOTPRINTS_FILE, fps, "image footprint on the inspected surface, one polygon per image"),
    ):
        path = out_dir / name
        try:
            with path.open("w", encoding="utf-8") as f:
                json.dump(_collection(feats, geoid_separation_m, what), f, allow_nan=False, separators=(",", ":"))
        except (OSError, ValueError) as exc:
            raise ExportError(f"cannot write {path}: {exc}") from exc
    return len(cams), len(fps)
