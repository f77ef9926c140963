"""A GeoJSON checker written from RFC 7946 (independent of icgt.export), for the export tests.

Checked: the object structure (FeatureCollection, Feature, Point, Polygon, ...); positions are 2 or 3
numbers, longitude first (|lon| <= 180, |lat| <= 90); no "crs" member (removed by RFC 7946);
linear rings have at least four positions and are closed; exterior rings are counterclockwise and
holes clockwise (the right-hand rule, section 3.1.6), judged in a local plane, except rings with no
area on the map (e.g. the outline of a vertical wall), which are returned separately.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

GEOMETRY_TYPES = {
    "Point",
    "MultiPoint",
    "LineString",
    "MultiLineString",
    "Polygon",
    "MultiPolygon",
    "GeometryCollection",
}


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def _position(p: Any, where: str, errors: list[str]) -> None:
    if not isinstance(p, list) or len(p) not in (2, 3) or not all(_is_number(c) for c in p):
        errors.append(f"{where}: a position is [lon, lat] or [lon, lat, alt] numbers, got {p!r}")
        return
    if not -180.0 <= p[0] <= 180.0:
        errors.append(f"{where}: longitude {p[0]} out of range (longitude must come first)")
    if not -90.0 <= p[1] <= 90.0:
        errors.append(f"{where}: latitude {p[1]} out of range (coordinate order?)")


def signed_area(ring: list[list[float]]) -> tuple[float, float]:
    """(signed area, perimeter^2) of a closed ring in an equirectangular plane at its mean latitude,
    relative to its first position (absolute degrees would leave only cancellation noise for small rings)."""
    k = math.cos(math.radians(sum(p[1] for p in ring[:-1]) / (len(ring) - 1)))
    x_ref, y_ref = ring[0][0], ring[0][1]
    pts = [((p[0] - x_ref) * k, p[1] - y_ref) for p in ring]
    a2 = 0.0
    perim = 0.0
    for (x0, y0), (x1, y1) in itertools.pairwise(pts):
        a2 += x0 * y1 - x1 * y0
        perim += math.hypot(x1 - x0, y1 - y0)
    return a2 / 2.0, perim * perim


def _ring(ring: Any, where: str, exterior: bool, errors: list[str], degenerate: list[str]) -> None:
    if not isinstance(ring, list) or len(ring) < 4:
        errors.append(f"{where}: a linear ring needs at least 4 positions")
        return
    for i, p in enumerate(ring):
        _position(p, f"{where}[{i}]", errors)
    if ring[0] != ring[-1]:
        errors.append(f"{where}: linear ring is not closed (first {ring[0]} != last {ring[-1]})")
        return
    area, perim2 = signed_area(ring)
    if perim2 == 0.0 or abs(area) / perim2 < 1e-7:
        degenerate.append(where)
        return
    if exterior and area < 0:
        errors.append(f"{where}: exterior ring is clockwise (RFC 7946 right-hand rule: counterclockwise)")
    if not exterior and area > 0:
        errors.append(f"{where}: hole is counterclockwise (RFC 7946 right-hand rule: clockwise)")


def _geometry(g: Any, where: str, errors: list[str], degenerate: list[str]) -> None:
    if g is None:
        return
    if not isinstance(g, dict) or g.get("type") not in GEOMETRY_TYPES:
        errors.append(f"{where}: not a geometry object: {g!r:.80}")
        return
    t = g["type"]
    if t == "GeometryCollection":
        for i, sub in enumerate(g.get("geometries", [])):
            _geometry(sub, f"{where}.geometries[{i}]", errors, degenerate)
        return
    c = g.get("coordinates")
    if t == "Point":
        _position(c, where, errors)
    elif t in ("MultiPoint", "LineString"):
        if not isinstance(c, list) or (t == "LineString" and len(c) < 2):
            errors.append(f"{where}: bad {t} coordinates")
        else:
            for i, p in enumerate(c):
                _position(p, f"{where}[{i}]", errors)
    elif t == "Polygon":
        if not isinstance(c, list) or not c:
            errors.append(f"{where}: a Polygon is a non-empty list of linear rings")
            return
        for i, ring in enumerate(c):
            _ring(ring, f"{where}.rings[{i}]", i == 0, errors, degenerate)
    elif t == "MultiPolygon":
        for j, poly in enumerate(c if isinstance(c, list) else []):
            for i, ring in enumerate(poly):
                _ring(ring, f"{where}[{j}].rings[{i}]", i == 0, errors, degenerate)


def check(obj: Any) -> tuple[list[str], list[str]]:
    """(errors, rings without area on the map) of a GeoJSON object."""
    errors: list[str] = []
    degenerate: list[str] = []
    if not isinstance(obj, dict):
        return ["top level is not a JSON object"], degenerate
    if "crs" in obj:
        errors.append("'crs' member (not part of RFC 7946: coordinates are always WGS84 lon/lat)")
    if obj.get("type") == "FeatureCollection":
        feats = obj.get("features")
        if not isinstance(feats, list):
            return [*errors, "FeatureCollection without a features array"], degenerate
    elif obj.get("type") == "Feature":
        feats = [obj]
    else:
        return [*errors, f"unexpected top-level type {obj.get('type')!r}"], degenerate
    for k, f in enumerate(feats):
        where = f"features[{k}]"
        if not isinstance(f, dict) or f.get("type") != "Feature":
            errors.append(f"{where}: not a Feature")
            continue
        if "geometry" not in f or "properties" not in f:
            errors.append(f"{where}: a Feature has 'geometry' and 'properties' members")
        if f.get("properties") is not None and not isinstance(f["properties"], dict):
            errors.append(f"{where}: properties must be an object or null")
        if "id" in f and not (isinstance(f["id"], str) or _is_number(f["id"])):
            errors.append(f"{where}: id must be a string or a number")
        _geometry(f.get("geometry"), f"{where}.geometry", errors, degenerate)
    return errors, degenerate
