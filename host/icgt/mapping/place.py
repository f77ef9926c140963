"""Placing detections on the surface: face coordinates, lengths, widths, areas and their uncertainty.

Every point of a detection is scaled from the image file's pixels to the calibration's, cast with
`Projector.pixel_to_world` onto the frame's surface plane, and expressed in the map's face frame.

Uncertainty (1 sigma, in the surface plane), from the pose and the range, per detection:

    sigma_pos^2 = sigma_position^2 + (D * sigma_attitude / cos(incidence))^2 + (sigma_range * tan(off_axis))^2

with D the distance from the camera to the point and off_axis the angle of its ray from the
optical axis (a range error moves an off-axis point along the surface by that much). A length L
seen at distance D scales with the range: sigma_L^2 = (L * sigma_range / D)^2 + 2 (sigma_px * gsd)^2
(the two end points located to sigma_px pixels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import shapely

from icgt.geometry import FrameSolution, GeometryError, Projector
from icgt.geotag.record import FrameRecord
from icgt.mapping import MappingError
from icgt.mapping.args import ATTITUDE_SIGMA_DEG, POSITION_SIGMA_M, RANGE_SIGMA_M
from icgt.mapping.model import CRACK, Detection, Placed
from icgt.mapping.surface import Face


@dataclass(frozen=True)
class Errors:
    """1-sigma errors of the inputs."""

    position_m: float = POSITION_SIGMA_M
    """Recorded camera positions (the autopilot's fused estimate; ~0.01 m with RTK)."""
    attitude_deg: float = ATTITUDE_SIGMA_DEG
    range_m: float = RANGE_SIGMA_M
    """LIDAR-Lite v3: +-2.5 cm."""
    pixel_px: float = 1.0
    """A detector's localisation of a point, in image-file pixels."""


def place(
    det: Detection,
    rec: FrameRecord,
    sol: FrameSolution,
    image_size: tuple[int, int],
    projector: Projector,
    face: Face,
    errors: Errors,
) -> Placed:
    """One detection on the surface; raises MappingError (naming it) if it cannot be placed."""
    cam = projector.camera
    w, h = image_size
    f = cam.width_px / w
    if abs(cam.height_px / f - h) > 1.0:
        raise MappingError(
            f"{det.image}: the image is {w}x{h}, the calibration {cam.width_px}x{cam.height_px}: "
            "not the same aspect ratio"
        )
    pts = (det.points_px + 0.5) * f - 0.5
    try:
        world = projector.pixel_to_world(rec, pts[:, 0], pts[:, 1])
    except GeometryError as exc:
        raise MappingError(f"{det.source}: {det.image}: cannot place it: {exc}") from exc
    enu = world.enu
    if not np.isfinite(enu).all():
        raise MappingError(f"{det.source}: {det.image}: part of the detection does not meet the surface")
    st = face.to_face(enu)
    cam_c = sol.camera_enu
    dist = np.linalg.norm(enu - cam_c, axis=1)
    axis_dir = (np.asarray(sol.centre.enu[0]) - cam_c) / max(float(np.linalg.norm(sol.centre.enu[0] - cam_c)), 1e-9)
    cos_off = np.clip(((enu - cam_c) @ axis_dir) / dist, -1.0, 1.0)
    tan_off = float(np.max(np.tan(np.arccos(cos_off))))
    cos_inc = max(math.cos(math.radians(sol.incidence_deg)), 0.1)
    d_mean = float(dist.mean())
    sigma_pos = math.sqrt(
        errors.position_m**2
        + (d_mean * math.radians(errors.attitude_deg) / cos_inc) ** 2
        + (errors.range_m * tan_off) ** 2
    )
    gsd_mm = sol.scale_mm_per_px * (d_mean / max(float(np.linalg.norm(sol.centre.enu[0] - cam_c)), 1e-9)) * f
    length = width = area = sigma_len = None
    if det.kind == CRACK:
        length = float(np.sum(np.linalg.norm(np.diff(enu, axis=0), axis=1)) * 1000.0)
        if det.width_px is not None:
            width = det.width_px * gsd_mm
        sigma_len = math.sqrt((length * errors.range_m / d_mean) ** 2 + 2.0 * (errors.pixel_px * gsd_mm) ** 2)
    else:
        poly = shapely.Polygon(st)
        area = float(abs(poly.area)) * 1e6 if poly.is_valid else float(abs(shapely.make_valid(poly).area)) * 1e6
    margin = 1.5
    px = det.points_px
    at_border = (
        (px[:, 0] < margin - 0.5)
        | (px[:, 1] < margin - 0.5)
        | (px[:, 0] > w - 0.5 - margin)
        | (px[:, 1] > h - 0.5 - margin)
    )
    cut_ends = (bool(at_border[0]), bool(at_border[-1]))
    truncated = bool(at_border.any())
    return Placed(
        det, rec.frame_seq, st, enu, length, width, area, sigma_pos * 1000.0, sigma_len, d_mean, truncated, cut_ends
    )
