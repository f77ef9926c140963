"""Rendered camera images: the scenario's face, textured with its defects, seen from the true pose.

Each output pixel's centre is mapped to the full-resolution sensor (the scenario camera's
intrinsics, principal point at the image centre, its lens distortion), undistorted into a ray,
rotated with the exposure's true camera attitude and intersected with the structure plane; the
face texture (icgt.sim.surface.shade) at that point is the pixel's grey level. The images are
rendered at `surface.render_width_px` wide (the same field of view as the full sensor), so a
detector's pixel coordinates on them scale to the sensor by full width / rendered width.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from icgt.geodesy import FloatArray, q_to_matrix
from icgt.geometry import CameraModel
from icgt.pose import R_NED_TO_ENU
from icgt.sim.face import FaceFrame
from icgt.sim.scenario import Scenario
from icgt.sim.surface import Surface, shade
from icgt.sim.truth import ExposureTruth


def scenario_camera(scenario: Scenario) -> CameraModel:
    """The scenario's camera at full resolution with its distortion."""
    c = scenario.camera
    ideal = CameraModel.from_sensor(c.focal_length_mm, c.sensor_width_mm, c.image_width_px, c.image_height_px)
    return CameraModel(
        ideal.width_px, ideal.height_px, ideal.fx, ideal.fy, ideal.cx, ideal.cy, c.k1, c.k2, c.p1, c.p2, c.k3
    )


def render_size(scenario: Scenario, surface: Surface) -> tuple[int, int]:
    c = scenario.camera
    w = surface.render_width_px
    return w, max(1, round(w * c.image_height_px / c.image_width_px))


def camera_to_enu(q_optical_ned: tuple[float, float, float, float]) -> FloatArray:
    """Rotation camera optical axes -> ENU for a true camera optical -> NED attitude (`icgt.pose`)."""
    out: FloatArray = R_NED_TO_ENU @ q_to_matrix(np.asarray(q_optical_ned, dtype=np.float64))
    return out


def face_points(scenario: Scenario, surface: Surface, e: ExposureTruth) -> tuple[FloatArray, float, int, int]:
    """Face coordinates (H*W, 2) [m] of every rendered pixel centre, the centre GSD [m/px], W, H."""
    cam = scenario_camera(scenario)
    w, h = render_size(scenario, surface)
    f = cam.width_px / w
    uu, vv = np.meshgrid((np.arange(w) + 0.5) * f - 0.5, (np.arange(h) + 0.5) * f - 0.5)
    rays = cam.rays(uu.ravel(), vv.ravel())
    r = camera_to_enu(e.q_optical_ned)
    d = rays @ r.T
    face = FaceFrame.from_scenario(scenario)
    c = np.asarray(e.position_enu_m)
    num = float((face.origin - c) @ face.normal)
    den = d @ face.normal
    with np.errstate(divide="ignore", invalid="ignore"):
        t = num / den
    t = np.where((t > 0) & np.isfinite(t), t, np.nan)
    st = face.from_enu(c + d * t[:, None])
    depth = float(np.nanmedian(t)) if np.isfinite(t).any() else 1.0
    gsd = depth * f / cam.fx
    return st, gsd, w, h


def render(scenario: Scenario, surface: Surface, e: ExposureTruth) -> Image.Image:
    """The grey image of the face one exposure saw (RGB, rendered size)."""
    st, gsd, w, h = face_points(scenario, surface, e)
    grey = shade(surface, st, gsd, seed=scenario.seed).reshape(h, w)
    g8 = np.round(grey).astype(np.uint8)
    return Image.fromarray(np.stack([g8, g8, g8], axis=-1), mode="RGB")


TAG_BOX_PX = (0, 0, 72, 40)
"""Where icgt.sim.camera_card writes the frame number over a rendered image (x0, y0, x1, y1) [px]:
no part of the face, for a detector to leave alone."""
