"""Planes in the local ENU frame and their map axes."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from icgt.geodesy import (
    FloatArray,
    LocalFrame,
)
from icgt.geometry.camera import (
    GeometryError,
)

# --- planes ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Plane:
    """A plane in the recording's ENU frame: a point on it [m] and its unit normal."""

    point: tuple[float, float, float]
    normal: tuple[float, float, float]

    def __post_init__(self) -> None:
        nx, ny, nz = (float(c) for c in self.normal)
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        if not math.isfinite(norm) or norm < 1e-12:
            raise GeometryError(f"plane normal {self.normal} is not a direction")
        object.__setattr__(self, "normal", (nx / norm, ny / norm, nz / norm))
        object.__setattr__(self, "point", tuple(float(c) for c in self.point))

    def transfer(self, src: LocalFrame, dst: LocalFrame) -> Plane:
        """The same plane expressed in another local frame (e.g. a scenario's ENU -> the recording's)."""
        lat, lon, h = src.enu_to_geodetic(np.asarray(self.point))
        p = dst.geodetic_to_enu(lat, lon, h)
        n_ecef = src.r_ecef_to_enu.T @ np.asarray(self.normal)
        n = dst.r_ecef_to_enu @ n_ecef
        return Plane((float(p[0]), float(p[1]), float(p[2])), (float(n[0]), float(n[1]), float(n[2])))


def plane_axes(normal: Any) -> tuple[FloatArray, FloatArray]:
    """In-plane map axes (s, t) for a plane with `normal` (..., 3): s horizontal, t = normal x s.

    For a vertical face seen from the side the normal points to, s runs to the right and t up; for
    a horizontal surface s is east and t north (normal up) or south (normal down). (s, t, normal)
    is right-handed. Map coordinates are p . s and p . t in the ENU frame, so every frame that
    shares the normal shares the map.
    """
    n = np.asarray(normal, dtype=np.float64)
    up = np.array([0.0, 0.0, 1.0])
    s = np.cross(up, n)
    norm = np.linalg.norm(s, axis=-1, keepdims=True)
    east = np.broadcast_to(np.array([1.0, 0.0, 0.0]), n.shape)
    horizontal = norm[..., 0] < 1e-6
    with np.errstate(invalid="ignore", divide="ignore"):
        s = np.where(horizontal[..., None], east, s / np.where(norm > 0, norm, 1.0))
    t = np.cross(n, s)
    return s, t
