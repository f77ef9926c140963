"""World -> pixel for a recorded frame: the inverse of `Projector.pixel_to_world`, same conventions.

The Projector casts pixels onto the surface; the mosaic needs the other direction (which image
pixel sees this face point). The camera centre and rotation are built exactly as the Projector
builds them (recorded camera attitude camera -> NED, the calibration's boresight and lever arm),
and tests/mapping check that world_to_pixel(pixel_to_world(u, v)) gives (u, v) back.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icgt.geodesy import FloatArray, q_to_matrix
from icgt.geometry import CameraModel, GeometryError
from icgt.geotag.record import FrameRecord
from icgt.pose import R_NED_TO_ENU


def camera_pose(camera: CameraModel, rec: FrameRecord) -> tuple[FloatArray, FloatArray]:
    """(projection centre (3,) ENU [m], rotation camera axes -> ENU (3, 3)) of a frame."""
    if None in (rec.east_m, rec.north_m, rec.up_m, rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz):
        raise GeometryError(f"frame {rec.frame_seq}: no position or no camera attitude")
    q = np.array([rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz], dtype=np.float64)
    r_rec = R_NED_TO_ENU @ q_to_matrix(q / np.linalg.norm(q))
    c = np.array([rec.east_m, rec.north_m, rec.up_m], dtype=np.float64) + r_rec @ np.asarray(camera.lever_arm_camera_m)
    return c, r_rec @ camera.boresight_matrix()


def world_to_pixel(camera: CameraModel, rec: FrameRecord, enu: Any) -> FloatArray:
    """ENU points (..., 3) -> pixels (..., 2) of the frame (NaN behind the camera)."""
    c, r = camera_pose(camera, rec)
    p_cam = (np.asarray(enu, dtype=np.float64) - c) @ r
    return camera.project(p_cam)


def face_grid_to_pixel(
    camera: CameraModel,
    rec: FrameRecord,
    origin: FloatArray,
    s_axis: FloatArray,
    t_axis: FloatArray,
    s: FloatArray,
    t: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Pixels (u, v), each (len(t), len(s)), of the face grid points origin + s_j S + t_i T.

    The same projection as world_to_pixel; on a plane the camera coordinates are affine in (s, t),
    so the grid is built from three vectors instead of rotating every point.
    """
    c, r = camera_pose(camera, rec)
    a = (np.asarray(origin) - c) @ r
    b = np.asarray(s_axis) @ r
    d = np.asarray(t_axis) @ r
    cam = a + np.asarray(t)[:, None, None] * d + np.asarray(s)[None, :, None] * b
    z = np.where(cam[..., 2] > 0.0, cam[..., 2], np.nan)
    u, v = camera.normalized_to_pixel(cam[..., 0] / z, cam[..., 1] / z)
    return u, v
