"""The scenario's structure face: face coordinates (s, t) <-> ENU, the defects' truth, the camera's calibration.

Face coordinates (s, t) [m] are measured on the structure plane from ``structure.point_m`` along the map
axes of `icgt.geometry.plane_axes` for the structure's normal (`icgt.sim.surface`'s docstring). The truth
file lists every defect of the scenario's `Surface` in face, ENU and WGS84 coordinates.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from icgt.geodesy import FloatArray, LocalFrame
from icgt.geometry import plane_axes
from icgt.sim.scenario import Scenario, SimError
from icgt.sim.surface import Surface

__all__ = ["FaceFrame", "calibration_toml", "defects_truth", "midpoint", "write_defects_truth"]


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
