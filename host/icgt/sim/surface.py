"""The structure's surface as the simulated camera sees it: a texture with known defects, and their truth.

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

Face coordinates (s, t) [m] are measured on the structure plane from ``structure.point_m`` along
the map axes of `icgt.geometry.plane_axes` for the structure's normal: on a vertical face seen from
the drone, s to the right and t up; on a deck (normal up) s east and t north. A face point is
point_m + s * S + t * T in the scenario's ENU frame.
"""

from __future__ import annotations

import itertools
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import shapely

from icgt.geodesy import FloatArray, LocalFrame
from icgt.geometry import plane_axes
from icgt.sim.scenario import Scenario, ScenarioError, SimError, _Reader

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
class Surface:
    texture: Literal["concrete", "checkerboard"] = "concrete"
    checker_mm: float = 100.0
    render_width_px: int = 600
    cracks: tuple[CrackSpec, ...] = ()
    spalls: tuple[SpallSpec, ...] = ()


def _points(r: _Reader, key: str, raw: Any, minimum: int) -> tuple[tuple[float, float], ...]:
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


def _items(r: _Reader, key: str) -> list[_Reader]:
    raw = r._get(key, [])
    if not isinstance(raw, list) or not all(isinstance(x, dict) for x in raw):
        r.fail(key, f"expected an array of tables ([[surface.{key}]])")
    return [_Reader(x, r.source, f"{r.prefix}{key}[{i}].") for i, x in enumerate(raw)]


def parse_surface(r: _Reader) -> Surface:
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
    r.finish()
    return Surface(texture, checker, width, tuple(cracks), tuple(spalls))  # type: ignore[arg-type]


# --- the face frame -------------------------------------------------------------------------


@dataclass(frozen=True)
class FaceFrame:
    """Face coordinates (s, t) [m] <-> the scenario's ENU frame [m] (module docstring)."""

    origin: FloatArray
    s_axis: FloatArray
    t_axis: FloatArray
    normal: FloatArray

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> FaceFrame:
        n = np.asarray(scenario.structure.normal, dtype=np.float64)
        s, t = plane_axes(n)
        return cls(np.asarray(scenario.structure.point_m, dtype=np.float64), s, t, n)

    def to_enu(self, st: Any) -> FloatArray:
        p = np.asarray(st, dtype=np.float64)
        out: FloatArray = self.origin + p[..., :1] * self.s_axis + p[..., 1:2] * self.t_axis
        return out

    def from_enu(self, enu: Any) -> FloatArray:
        d = np.asarray(enu, dtype=np.float64) - self.origin
        return np.stack([d @ self.s_axis, d @ self.t_axis], axis=-1)


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


# --- truth ----------------------------------------------------------------------------------


def _wgs84(scenario: Scenario, enu: FloatArray) -> list[list[float]]:
    o = scenario.origin
    lat, lon, h = LocalFrame(o.lat_deg, o.lon_deg, o.ellipsoid_height_m).enu_to_geodetic(enu)
    alt = np.asarray(h) - o.geoid_separation_m
    return [
        [float(a), float(b), float(c)]
        for a, b, c in zip(np.atleast_1d(lat), np.atleast_1d(lon), np.atleast_1d(alt), strict=True)
    ]


def midpoint(polyline: FloatArray) -> FloatArray:
    """The point half-way along a polyline (M, D)."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    half = cum[-1] / 2.0
    k = min(int(np.searchsorted(cum, half, side="right") - 1), len(seg) - 1)
    f = (half - cum[k]) / seg[k] if seg[k] > 0 else 0.0
    out: FloatArray = polyline[k] + (polyline[k + 1] - polyline[k]) * f
    return out


def defects_truth(scenario: Scenario, surface: Surface) -> dict[str, Any]:
    """Every defect in face, ENU and WGS84 coordinates (WGS84 as [lat, lon, alt MSL])."""
    face = FaceFrame.from_scenario(scenario)
    out: list[dict[str, Any]] = []
    for c in surface.cracks:
        st = np.asarray(c.points_m)
        enu = face.to_enu(st)
        mid = midpoint(st)
        out.append(
            {
                "id": c.id,
                "kind": "crack",
                "face_m": st.tolist(),
                "enu_m": enu.tolist(),
                "wgs84": _wgs84(scenario, enu),
                "length_mm": c.length_m * 1000.0,
                "width_mm": c.width_mm,
                "midpoint_face_m": mid.tolist(),
                "midpoint_enu_m": face.to_enu(mid).tolist(),
                "midpoint_wgs84": _wgs84(scenario, face.to_enu(mid)[None, :])[0],
            }
        )
    for sp in surface.spalls:
        st = np.asarray(sp.points_m)
        enu = face.to_enu(st)
        cen = np.asarray(shapely.Polygon(sp.points_m).centroid.coords[0])
        out.append(
            {
                "id": sp.id,
                "kind": "spalling",
                "face_m": st.tolist(),
                "enu_m": enu.tolist(),
                "wgs84": _wgs84(scenario, enu),
                "area_mm2": sp.area_m2 * 1e6,
                "midpoint_face_m": cen.tolist(),
                "midpoint_enu_m": face.to_enu(cen).tolist(),
                "midpoint_wgs84": _wgs84(scenario, face.to_enu(cen)[None, :])[0],
            }
        )
    return {
        "face_frame": {
            "origin_enu_m": face.origin.tolist(),
            "s_axis_enu": face.s_axis.tolist(),
            "t_axis_enu": face.t_axis.tolist(),
            "normal_enu": face.normal.tolist(),
            "enu_origin_wgs84": [scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.alt_m],
        },
        "units": "face_m, enu_m: metres; wgs84: [lat deg, lon deg, alt m above MSL]; length/width mm; area mm^2",
        "defects": out,
    }


def write_defects_truth(path: str | Path, scenario: Scenario, surface: Surface) -> None:
    try:
        Path(path).write_text(json.dumps(defects_truth(scenario, surface), indent=1) + "\n", encoding="utf-8")
    except OSError as exc:
        raise SimError(f"cannot write defect truth {path}: {exc.strerror}") from exc


def calibration_toml(scenario: Scenario) -> str:
    """The scenario's camera as a calibration file for `icgt map --calibration` (full resolution)."""
    c = scenario.camera
    f_px = c.focal_length_mm * c.image_width_px / c.sensor_width_mm
    return (
        f"# the simulated camera of scenario {scenario.name} (full resolution)\n[camera]\n"
        f"width_px = {c.image_width_px}\nheight_px = {c.image_height_px}\nfx = {f_px!r}\nfy = {f_px!r}\n"
        f"cx = {(c.image_width_px - 1) / 2.0!r}\ncy = {(c.image_height_px - 1) / 2.0!r}\n"
        f"[distortion]\nk1 = {c.k1!r}\nk2 = {c.k2!r}\np1 = {c.p1!r}\np2 = {c.p2!r}\nk3 = {c.k3!r}\n"
    )


def check_surface(surface: Surface, source: str) -> None:
    """Refuse defects that overlap each other (their truth would be ambiguous)."""
    shapes: list[tuple[str, Any]] = [(c.id, shapely.LineString(c.points_m)) for c in surface.cracks]
    shapes += [(s.id, shapely.Polygon(s.points_m)) for s in surface.spalls]
    for i, (a, ga) in enumerate(shapes):
        for b, gb in shapes[i + 1 :]:
            if ga.distance(gb) < 0.05:
                raise ScenarioError(f"{source}: surface: defects {a} and {b} are closer than 50 mm")
