"""Which surface the detections are placed on, and the face frame of the map.

- ``--plane E,N,U,nE,nN,nU`` (the config's structure plane, recording ENU): as given.
- otherwise the plane is fitted to the LiDAR returns of the flight (camera + range along the
  optical axis, one per frame with a valid range) by least squares (SVD). When the returns are
  nearly collinear (one straight pass: the plane's tilt about the line is not observable) the
  orientation comes from the recording's configured surface normal and only the offset is fitted.

Either way each image is then projected, as `icgt export` does, on the plane with that normal
through its own LiDAR return (`anchor="range"`, icgt.geometry), so a GPS error along the normal
does not become a scale error; `anchor="structure"` uses the one plane for every image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from icgt.geodesy import FloatArray, LocalFrame
from icgt.geometry import CameraModel, GeometryError, Plane, Projector, SurfaceSource, plane_axes
from icgt.geotag.record import FrameRecord
from icgt.mapping import MappingError

COLLINEAR_RATIO = 0.05
"""Second over first singular value of the LiDAR returns below which they count as a line."""


@dataclass(frozen=True)
class Face:
    """The map's face frame: origin and axes in the recording's ENU frame [m]."""

    plane: Plane
    s_axis: FloatArray
    t_axis: FloatArray
    how: str
    """How the plane was found (for map.json)."""
    fit_rms_m: float | None = None
    returns: int = 0

    @property
    def origin(self) -> FloatArray:
        return np.asarray(self.plane.point, dtype=np.float64)

    @property
    def normal(self) -> FloatArray:
        return np.asarray(self.plane.normal, dtype=np.float64)

    def to_face(self, enu: FloatArray) -> FloatArray:
        d = np.asarray(enu, dtype=np.float64) - self.origin
        return np.stack([d @ self.s_axis, d @ self.t_axis], axis=-1)

    def to_enu(self, st: FloatArray) -> FloatArray:
        p = np.asarray(st, dtype=np.float64)
        out: FloatArray = self.origin + p[..., :1] * self.s_axis + p[..., 1:2] * self.t_axis
        return out


def _face(plane: Plane, cameras: FloatArray, how: str, rms: float | None = None, n: int = 0) -> Face:
    normal = np.asarray(plane.normal)
    if len(cameras) and float(np.mean((cameras - np.asarray(plane.point)) @ normal)) < 0:
        normal = -normal  # towards the cameras, as the Projector orients it
    plane = Plane(plane.point, (float(normal[0]), float(normal[1]), float(normal[2])))
    s, t = plane_axes(normal)
    return Face(plane, s, t, how, rms, n)


def lidar_returns(camera: CameraModel, frames: Sequence[FrameRecord]) -> tuple[FloatArray, FloatArray]:
    """(LiDAR return points (N, 3), camera centres (N, 3)) in recording ENU [m], frames with a valid range."""
    proj = Projector(camera)  # no surface: perpendicular at range, whose plane point is the return
    pts, cams = [], []
    for sol in proj.solve_many(list(frames)):
        if isinstance(sol, GeometryError) or sol.surface is not SurfaceSource.PERPENDICULAR_AT_RANGE:
            continue
        pts.append(sol.plane.point)
        cams.append(sol.camera_enu)
    return np.asarray(pts, dtype=np.float64).reshape(-1, 3), np.asarray(cams, dtype=np.float64).reshape(-1, 3)


def find_face(
    camera: CameraModel,
    frames: Sequence[FrameRecord],
    *,
    plane: Plane | None,
    normal: tuple[float, float, float] | None,
) -> Face:
    pts, cams = lidar_returns(camera, frames)
    if plane is not None:
        return _face(plane, cams, "given (--plane)")
    if len(pts) < 3:
        raise MappingError(
            f"only {len(pts)} frames have a valid LiDAR range: cannot fit the surface; give --plane E,N,U,nE,nN,nU"
        )
    centre = pts.mean(axis=0)
    _, sv, vt = np.linalg.svd(pts - centre, full_matrices=False)
    if sv[1] < COLLINEAR_RATIO * sv[0]:
        if normal is None:
            raise MappingError(
                "the LiDAR returns lie on a line (one straight pass): the surface's tilt about it is unknown and "
                "the recording has no surface normal; give --plane"
            )
        n = np.asarray(normal, dtype=np.float64)
        n = n / np.linalg.norm(n)
        how = "offset fitted to the LiDAR returns, normal from the recording's configuration"
    else:
        n = vt[2]
        how = "fitted to the LiDAR returns (least squares)"
    rms = float(np.sqrt(np.mean(((pts - centre) @ n) ** 2)))
    p = Plane((float(centre[0]), float(centre[1]), float(centre[2])), (float(n[0]), float(n[1]), float(n[2])))
    return _face(p, cams, how, rms, len(pts))


def face_wgs84(face: Face, origin: LocalFrame) -> tuple[float, float, float]:
    lat, lon, alt = origin.enu_to_geodetic(face.origin)
    return float(lat), float(lon), float(alt)
