"""The structure's surface as the simulated camera sees it: a texture with known defects (their truth: icgt.sim.face).

A scenario's optional ``[surface]`` table (absent: the camera card keeps its small tag images)::

    [surface]
    texture = "concrete"          # or "checkerboard" (squares of checker_mm, for mosaic checks)
    checker_mm = 100.0
    render_width_px = 600         # width of the rendered card images [px]; height keeps the aspect
    [[surface.cracks]]
    id = "C1"                     # optional (default C<n>)
    points_m = [[-0.4, 2.0], [-0.2, 2.3], [0.1, 2.5]]   # face coordinates [m], at least two points
    width_mm = 0.8
    [[surface.spalls]]
    id = "S1"
    points_m = [[0.5, 3.0], [0.7, 3.0], [0.7, 3.15], [0.5, 3.2]]   # polygon [m], at least three points
    [[surface.stains]]            # a look-alike, no defect: a soft-edged dark patch (water streak, shadow)
    id = "ST1"
    points_m = [[0.2, 2.4], [0.45, 2.4], [0.45, 3.1], [0.2, 3.1]]   # polygon [m]
    darkening = 0.18              # fraction of the grey level taken away inside (optional)
    [[surface.joints]]            # a look-alike, no defect: a formwork joint, a straight dark line
    id = "J1"
    points_m = [[-2.2, 4.05], [2.2, 4.05]]
    width_mm = 8.0

Stains and joints are what a crack detector mistakes for defects (icgt.sim.detector_errors); they are
no defects and are not in the truth of defects.
Face coordinates (s, t) [m] are measured on the structure plane from ``structure.point_m`` along
the map axes of `icgt.geometry.plane_axes` for the structure's normal: on a vertical face seen from
the drone, s to the right and t up; on a deck (normal up) s east and t north. A face point is
point_m + s * S + t * T in the scenario's ENU frame.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal, TypeAlias

import msgspec
import numpy as np
import shapely
from msgspec import Meta

from icgt.geodesy import FloatArray
from icgt.sim.errors import ScenarioError

TEXTURES = ("concrete", "checkerboard")
FacePoints: TypeAlias = tuple[tuple[float, float], ...]
"""Points (s, t) on the face [m] (module docstring)."""


class _Spec(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """One painted item of the [surface] table: an id and its points on the face."""


def _check_points(points: FacePoints, minimum: int) -> None:
    if len(points) < minimum:
        raise ValueError(f"points_m: expected a list of at least {minimum} [s, t] points, got {len(points)}")


def _check_polygon(points: FacePoints) -> None:
    _check_points(points, 3)
    poly = shapely.Polygon(points)
    if not poly.is_valid or poly.area <= 0.0:
        raise ValueError("points_m: not a simple polygon with an area (edges cross or points are collinear)")


class CrackSpec(_Spec, frozen=True):
    """A crack: a polyline on the face [m] and its width [mm] (constant along it)."""

    id: str
    points_m: FacePoints
    width_mm: Annotated[float, Meta(gt=0.0, le=200.0)]

    def __post_init__(self) -> None:
        _check_points(self.points_m, 2)
        if self.length_m <= 0.0:
            raise ValueError("points_m: the crack has zero length")

    @property
    def length_m(self) -> float:
        p = np.asarray(self.points_m)
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


class SpallSpec(_Spec, frozen=True):
    """A spalled area: a simple polygon on the face [m]."""

    id: str
    points_m: FacePoints

    def __post_init__(self) -> None:
        _check_polygon(self.points_m)

    @property
    def area_m2(self) -> float:
        return float(shapely.Polygon(self.points_m).area)


class StainSpec(_Spec, frozen=True):
    """A look-alike: a soft-edged dark patch (a water streak, a shadow) on the face [m]; no defect."""

    id: str
    points_m: FacePoints
    darkening: Annotated[float, Meta(ge=0.0, le=0.9)] = 0.18

    def __post_init__(self) -> None:
        _check_polygon(self.points_m)


class JointSpec(_Spec, frozen=True):
    """A look-alike: a formwork joint, a straight dark line on the face [m], width [mm]; no defect."""

    id: str
    points_m: FacePoints
    width_mm: Annotated[float, Meta(gt=0.0, le=200.0)] = 8.0

    def __post_init__(self) -> None:
        _check_points(self.points_m, 2)


class Surface(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    texture: Literal["concrete", "checkerboard"] = "concrete"
    checker_mm: Annotated[float, Meta(gt=0.0)] = 100.0
    render_width_px: Annotated[int, Meta(ge=64, le=8000)] = 600
    cracks: tuple[CrackSpec, ...] = ()
    spalls: tuple[SpallSpec, ...] = ()
    stains: tuple[StainSpec, ...] = ()
    joints: tuple[JointSpec, ...] = ()
    """A scenario's surface is checked whole by `check_surface` when it is read (a look-alike face built in code,
    icgt.sim.detector_errors, may hold items closer than that on purpose)."""


DEFAULT_ID_PREFIX = {"cracks": "C", "spalls": "S", "stains": "ST", "joints": "J"}
"""An item without an ``id`` is called prefix + its place in its list (C1, C2, ...)."""


def with_default_ids(raw: Any) -> Any:
    """The parsed [surface] table with every item's missing ``id`` filled in (anything else passed on as it is)."""
    if not isinstance(raw, Mapping):
        return raw
    out = dict(raw)
    for key, prefix in DEFAULT_ID_PREFIX.items():
        items = out.get(key)
        if isinstance(items, list):
            out[key] = [
                {"id": f"{prefix}{k}", **item} if isinstance(item, Mapping) else item for k, item in enumerate(items, 1)
            ]
    return out


def surface_problem(surface: Surface) -> str | None:
    """Why the surface's truth would be ambiguous (an id used twice, defects or look-alikes within 50 mm); None."""
    seen: set[str] = set()
    for key in ("cracks", "spalls"):
        for i, item in enumerate(getattr(surface, key)):
            if item.id in seen:
                return f"{key}[{i}].id: {item.id!r} is used twice"
            seen.add(item.id)
    shapes: list[tuple[str, Any]] = [(c.id, shapely.LineString(c.points_m)) for c in surface.cracks]
    shapes += [(s.id, shapely.Polygon(s.points_m)) for s in surface.spalls]
    for i, (a, ga) in enumerate(shapes):
        for b, gb in shapes[i + 1 :]:
            if ga.distance(gb) < 0.05:
                return f"defects {a} and {b} are closer than 50 mm"
    looks: list[tuple[str, Any]] = [(s.id, shapely.Polygon(s.points_m)) for s in surface.stains]
    looks += [(j.id, shapely.LineString(j.points_m)) for j in surface.joints]
    for a, ga in looks:
        for b, gb in shapes:
            if ga.distance(gb) < 0.05:
                return f"look-alike {a} is closer than 50 mm to defect {b}"
    return None


def check_surface(surface: Surface, source: str) -> None:
    """Refuse a surface whose truth would be ambiguous (`surface_problem`), naming `source`."""
    problem = surface_problem(surface)
    if problem is not None:
        raise ScenarioError(f"{source}: surface: {problem}")


# --- texture --------------------------------------------------------------------------------


def _segment_distance(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    ab = b - a
    denom = float(ab @ ab)
    t = np.clip(((p - a) @ ab) / denom, 0.0, 1.0) if denom > 0 else np.zeros(len(p))
    out: FloatArray = np.linalg.norm(p - (a + t[:, None] * ab), axis=1)
    return out


def polyline_distance(points: FloatArray, polyline: FloatArray) -> FloatArray:
    """Distance of each point (N, 2) to a polyline (M, 2)."""
    d = np.full(len(points), np.inf)
    for a, b in itertools.pairwise(polyline):
        d = np.minimum(d, _segment_distance(points, a, b))
    return d


def shade(surface: Surface, st: FloatArray, gsd_m: float, seed: int = 0) -> FloatArray:
    """Grey level 0..255 of face points (N, 2) [m] seen with a pixel footprint of gsd_m [m].

    Cracks thinner than a pixel darken it in proportion to the part of the pixel they cover, as a
    real sensor averages them (so a 0.3 mm crack at 1.4 mm/px is faint but there).
    """
    s, t = st[:, 0], st[:, 1]
    ok = np.isfinite(s) & np.isfinite(t)
    s0, t0 = np.where(ok, s, 0.0), np.where(ok, t, 0.0)
    if surface.texture == "checkerboard":
        q = surface.checker_mm / 1000.0
        grey = np.where((np.floor(s0 / q) + np.floor(t0 / q)) % 2 == 0, 225.0, 30.0)
    else:
        rng = np.random.default_rng(seed)
        grey = np.full(len(st), 150.0)
        for wavelength in (0.9, 0.31, 0.087, 0.023):
            phase = rng.uniform(0, 2 * math.pi, size=2)
            k = 2 * math.pi / wavelength
            grey += 7.0 * np.sin(k * s0 + phase[0]) * np.sin(k * 0.77 * t0 + phase[1])
        for stain in surface.stains:
            # soft edge: full darkening 15 mm inside the outline, none at it
            ring = shapely.Polygon(stain.points_m)
            lo, hi = np.asarray(ring.bounds[:2]), np.asarray(ring.bounds[2:])
            near = ok & (s0 >= lo[0]) & (s0 <= hi[0]) & (t0 >= lo[1]) & (t0 <= hi[1])
            if near.any():
                idx = np.flatnonzero(near)
                pts = shapely.points(s0[idx], t0[idx])
                inside = shapely.contains_xy(ring, s0[idx], t0[idx])
                depth = np.where(inside, shapely.distance(ring.exterior, pts), 0.0)
                grey[idx] *= 1.0 - stain.darkening * np.clip(depth / 0.015, 0.0, 1.0)
        for j in surface.joints:
            line = np.asarray(j.points_m)
            half_j = max(j.width_mm / 1000.0, 1.5 * gsd_m) / 2.0
            lo, hi = line.min(axis=0) - 2 * half_j, line.max(axis=0) + 2 * half_j
            near = ok & (s0 >= lo[0]) & (s0 <= hi[0]) & (t0 >= lo[1]) & (t0 <= hi[1])
            if near.any():
                idx = np.flatnonzero(near)
                d = polyline_distance(np.stack([s0[idx], t0[idx]], axis=1), line)
                cover_j = min(1.0, j.width_mm / 1000.0 / (1.5 * gsd_m))
                grey[idx] *= 1.0 - 0.35 * cover_j * np.clip(1.5 - d / half_j, 0.0, 1.0)
        for sp in surface.spalls:
            inside = shapely.contains_xy(shapely.Polygon(sp.points_m), s0, t0)
            grey = np.where(inside, 92.0 + 12.0 * np.sin(s0 * 211.0) * np.cos(t0 * 173.0), grey)
        for c in surface.cracks:
            line = np.asarray(c.points_m)
            lo, hi = line.min(axis=0) - 3 * gsd_m, line.max(axis=0) + 3 * gsd_m
            near = ok & (s0 >= lo[0]) & (s0 <= hi[0]) & (t0 >= lo[1]) & (t0 <= hi[1])
            if not near.any():
                continue
            idx = np.flatnonzero(near)
            d = polyline_distance(np.stack([s0[idx], t0[idx]], axis=1), line)
            w = c.width_mm / 1000.0
            # at least 1.5 pixels wide so that a thin crack stays a continuous line on the pixel grid
            half = max(w, 1.5 * gsd_m) / 2.0
            cover = min(1.0, w / (1.5 * gsd_m))
            dark = np.where(d <= half, cover, 0.0)
            grey[idx] = grey[idx] * (1.0 - 0.8 * dark)
    out: FloatArray = np.where(ok, np.clip(grey, 0.0, 255.0), 40.0)
    return out
