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
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import shapely

from icgt.geodesy import FloatArray
from icgt.sim.scenario_reader import ScenarioError, TableReader

TEXTURES = ("concrete", "checkerboard")


@dataclass(frozen=True)
class CrackSpec:
    """A crack: a polyline on the face [m] and its width [mm] (constant along it)."""

    id: str
    points_m: tuple[tuple[float, float], ...]
    width_mm: float

    @property
    def length_m(self) -> float:
        p = np.asarray(self.points_m)
        return float(np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)))


@dataclass(frozen=True)
class SpallSpec:
    """A spalled area: a simple polygon on the face [m]."""

    id: str
    points_m: tuple[tuple[float, float], ...]

    @property
    def area_m2(self) -> float:
        return float(shapely.Polygon(self.points_m).area)


@dataclass(frozen=True)
class StainSpec:
    """A look-alike: a soft-edged dark patch (a water streak, a shadow) on the face [m]; no defect."""

    id: str
    points_m: tuple[tuple[float, float], ...]
    darkening: float = 0.18


@dataclass(frozen=True)
class JointSpec:
    """A look-alike: a formwork joint, a straight dark line on the face [m], width [mm]; no defect."""

    id: str
    points_m: tuple[tuple[float, float], ...]
    width_mm: float = 8.0


@dataclass(frozen=True)
class Surface:
    texture: Literal["concrete", "checkerboard"] = "concrete"
    checker_mm: float = 100.0
    render_width_px: int = 600
    cracks: tuple[CrackSpec, ...] = ()
    spalls: tuple[SpallSpec, ...] = ()
    stains: tuple[StainSpec, ...] = ()
    joints: tuple[JointSpec, ...] = ()


def _points(r: TableReader, key: str, raw: Any, minimum: int) -> tuple[tuple[float, float], ...]:
    if not isinstance(raw, list) or len(raw) < minimum:
        r.fail(key, f"expected a list of at least {minimum} [s, t] points, got {raw!r}")
    out: list[tuple[float, float]] = []
    for i, p in enumerate(raw):
        if not isinstance(p, list) or len(p) != 2:
            r.fail(f"{key}[{i}]", f"expected [s, t], got {p!r}")
        s = r._check_number(f"{key}[{i}]", p[0], None, None, False)
        t = r._check_number(f"{key}[{i}]", p[1], None, None, False)
        out.append((s, t))
    return tuple(out)


def _items(r: TableReader, key: str) -> list[TableReader]:
    raw = r._get(key, [])
    if not isinstance(raw, list) or not all(isinstance(x, dict) for x in raw):
        r.fail(key, f"expected an array of tables ([[surface.{key}]])")
    return [TableReader(x, r.source, f"{r.prefix}{key}[{i}].") for i, x in enumerate(raw)]


def parse_surface(r: TableReader) -> Surface:
    """The [surface] table (module docstring); errors name the file and the key."""
    texture = r.string("texture", "concrete", choices=TEXTURES)
    checker = r.number("checker_mm", 100.0, positive=True)
    width = r.integer("render_width_px", 600, min_value=64, max_value=8000)
    cracks: list[CrackSpec] = []
    ids: set[str] = set()
    for k, c in enumerate(_items(r, "cracks"), 1):
        cid = c.string("id", f"C{k}")
        pts = _points(c, "points_m", c._get("points_m", None), 2)
        cracks.append(CrackSpec(cid, pts, c.number("width_mm", positive=True, max_value=200.0)))
        if cracks[-1].length_m <= 0.0:
            c.fail("points_m", "the crack has zero length")
        c.finish()
        if cid in ids:
            c.fail("id", f"{cid!r} is used twice")
        ids.add(cid)
    spalls: list[SpallSpec] = []
    for k, s in enumerate(_items(r, "spalls"), 1):
        sid = s.string("id", f"S{k}")
        pts = _points(s, "points_m", s._get("points_m", None), 3)
        poly = shapely.Polygon(pts)
        if not poly.is_valid or poly.area <= 0.0:
            s.fail("points_m", "not a simple polygon with an area (edges cross or points are collinear)")
        s.finish()
        if sid in ids:
            s.fail("id", f"{sid!r} is used twice")
        ids.add(sid)
        spalls.append(SpallSpec(sid, pts))
    stains: list[StainSpec] = []
    for k, s in enumerate(_items(r, "stains"), 1):
        sid = s.string("id", f"ST{k}")
        pts = _points(s, "points_m", s._get("points_m", None), 3)
        poly = shapely.Polygon(pts)
        if not poly.is_valid or poly.area <= 0.0:
            s.fail("points_m", "not a simple polygon with an area")
        stains.append(StainSpec(sid, pts, s.number("darkening", 0.18, min_value=0.0, max_value=0.9)))
        s.finish()
    joints: list[JointSpec] = []
    for k, j in enumerate(_items(r, "joints"), 1):
        jid = j.string("id", f"J{k}")
        pts = _points(j, "points_m", j._get("points_m", None), 2)
        joints.append(JointSpec(jid, pts, j.number("width_mm", 8.0, positive=True, max_value=200.0)))
        j.finish()
    r.finish()
    tex: Any = texture
    return Surface(tex, checker, width, tuple(cracks), tuple(spalls), tuple(stains), tuple(joints))


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


def check_surface(surface: Surface, source: str) -> None:
    """Refuse defects that overlap each other (their truth would be ambiguous)."""
    shapes: list[tuple[str, Any]] = [(c.id, shapely.LineString(c.points_m)) for c in surface.cracks]
    shapes += [(s.id, shapely.Polygon(s.points_m)) for s in surface.spalls]
    for i, (a, ga) in enumerate(shapes):
        for b, gb in shapes[i + 1 :]:
            if ga.distance(gb) < 0.05:
                raise ScenarioError(f"{source}: surface: defects {a} and {b} are closer than 50 mm")
    looks: list[tuple[str, Any]] = [(s.id, shapely.Polygon(s.points_m)) for s in surface.stains]
    looks += [(j.id, shapely.LineString(j.points_m)) for j in surface.joints]
    for a, ga in looks:
        for b, gb in shapes:
            if ga.distance(gb) < 0.05:
                raise ScenarioError(f"{source}: surface: look-alike {a} is closer than 50 mm to defect {b}")
