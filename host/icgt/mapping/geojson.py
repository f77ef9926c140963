"""The damage map as GeoJSON: defects.geojson (WGS84, RFC 7946) and defects_face.geojson (face metres).

defects.geojson: [lon, lat] in degrees, with a third element, the height above the WGS84 ellipsoid
[m] (RFC 7946 section 4), when the geoid separation is known (from the log's GPS_RAW_INT or
given); the height above mean sea level is always a property. A crack is a LineString along its
centreline, an area defect a Polygon (exterior counterclockwise on the map; on a vertical face a
polygon has no area in plan view, hence the face file).

defects_face.geojson: the same features in face coordinates (s, t) [m] (icgt.mapping), a local
engineering frame that GDAL/QGIS open as a plain Cartesian layer; it is GeoJSON in structure but not
RFC 7946 (whose coordinates are WGS84 only), and says so in its "icgt_face_frame" member.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from shapely.geometry.polygon import orient

from icgt.export.geojson_export import ring_signed_area
from icgt.geodesy import LocalFrame
from icgt.mapping import MappingError
from icgt.mapping.model import CRACK, Instance, midpoint
from icgt.mapping.surface import Face, face_wgs84


def _props(inst: Instance, origin: LocalFrame) -> dict[str, Any]:
    mid = midpoint(inst.enu) if inst.kind == CRACK else inst.enu.mean(axis=0)
    mid_face = midpoint(inst.face) if inst.kind == CRACK else np.asarray(shapely.Polygon(inst.face).centroid.coords[0])
    lat, lon, alt = origin.enu_to_geodetic(mid)
    return {
        "id": inst.id,
        "kind": inst.kind,
        "categories": sorted({m.det.category for m in inst.members}),
        "length_mm": None if inst.length_mm is None else round(inst.length_mm, 1),
        "width_mm": None if inst.width_mm is None else round(inst.width_mm, 2),
        "width_spread_mm": None if inst.width_spread_mm is None else round(inst.width_spread_mm, 2),
        "area_mm2": None if inst.area_mm2 is None else round(inst.area_mm2, 0),
        "position_sigma_mm": round(inst.sigma_pos_mm, 1),
        "length_sigma_mm": None if inst.sigma_len_mm is None else round(inst.sigma_len_mm, 1),
        "truncated": inst.truncated,
        "images": inst.images,
        "n_images": len(inst.images),
        "n_images_saw": inst.n_seen,
        "n_images_could_see": inst.n_could,
        "status": inst.status,
        "n_detections": len(inst.members),
        "mid_lat_deg": round(float(lat), 9),
        "mid_lon_deg": round(float(lon), 9),
        "mid_alt_msl_m": round(float(alt), 3),
        "mid_face_s_m": round(float(mid_face[0]), 4),
        "mid_face_t_m": round(float(mid_face[1]), 4),
    }


def _geometry(kind: str, coords: list[list[float]]) -> dict[str, Any]:
    if kind == CRACK:
        return {"type": "LineString", "coordinates": coords}
    return {"type": "Polygon", "coordinates": [[*coords, coords[0]]]}


def features_wgs84(
    instances: Sequence[Instance], origin: LocalFrame, geoid_separation_m: float | None
) -> dict[str, Any]:
    feats = []
    for inst in instances:
        lat, lon, alt = origin.enu_to_geodetic(inst.enu)
        pts = np.stack([np.atleast_1d(lon), np.atleast_1d(lat)], axis=1)
        coords = [[round(float(p[0]), 9), round(float(p[1]), 9)] for p in pts]
        alts = [float(a) for a in np.atleast_1d(alt)]
        if inst.kind != CRACK and ring_signed_area([*coords, coords[0]])[0] < 0:
            # the right-hand rule, judged on the written (rounded) positions: a ring on a vertical face
            # has almost no area on the map, and rounding alone could turn it the other way
            coords, alts = coords[::-1], alts[::-1]
        if geoid_separation_m is not None:
            for c, a in zip(coords, alts, strict=True):
                c.append(round(a + geoid_separation_m, 3))
        feats.append(
            {
                "type": "Feature",
                "id": inst.id,
                "geometry": _geometry(inst.kind, coords),
                "properties": _props(inst, origin),
            }
        )
    return {"type": "FeatureCollection", "features": feats}


def features_face(instances: Sequence[Instance], face: Face, origin: LocalFrame) -> dict[str, Any]:
    feats = []
    for inst in instances:
        pts = inst.face
        if inst.kind != CRACK:
            pts = np.asarray(orient(shapely.Polygon(pts), 1.0).exterior.coords)[:-1]
        coords = [[round(float(p[0]), 5), round(float(p[1]), 5)] for p in pts]
        feats.append(
            {
                "type": "Feature",
                "id": inst.id,
                "geometry": _geometry(inst.kind, coords),
                "properties": _props(inst, origin),
            }
        )
    return {"type": "FeatureCollection", "icgt_face_frame": face_frame_json(face, origin), "features": feats}


def face_frame_json(face: Face, origin: LocalFrame) -> dict[str, Any]:
    lat, lon, alt = face_wgs84(face, origin)
    return {
        "note": "face coordinates (s, t) [m] on the surface plane: point = origin + s * s_axis + t * t_axis (ENU)",
        "origin_enu_m": [round(float(v), 4) for v in face.origin],
        "origin_wgs84": {"lat_deg": lat, "lon_deg": lon, "alt_msl_m": alt},
        "s_axis_enu": [float(v) for v in face.s_axis],
        "t_axis_enu": [float(v) for v in face.t_axis],
        "normal_enu": [float(v) for v in face.normal],
        "plane": face.how,
        "plane_fit_rms_m": face.fit_rms_m,
        "lidar_returns": face.returns,
        "enu_origin_wgs84": {"lat_deg": origin.lat0_deg, "lon_deg": origin.lon0_deg, "alt_msl_m": origin.h0_m},
    }


def write_json(path: Path, obj: Any) -> None:
    try:
        path.write_text(json.dumps(obj, indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        raise MappingError(f"cannot write {path}: {exc.strerror or exc}") from exc
    try:
        json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as exc:
        raise MappingError(f"{path} does not read back: {exc}") from exc
