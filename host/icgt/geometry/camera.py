"""The camera model: pinhole intrinsics, Brown-Conrady distortion, mounting corrections; the package's errors.

Conventions (pixels, camera axes, the lens model): `icgt.geometry`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from icgt.errors import IcgtError
from icgt.geodesy import (
    FloatArray,
    q_from_euler_zyx,
    q_to_matrix,
)
from icgt.geotag.config import GeotagConfig
from icgt.pose import frd_rotation_in_optical_axes


class GeometryError(IcgtError):
    """A frame or an input the geometry cannot use (no pose, no range, a ray that misses the surface)."""


class CalibrationError(GeometryError):
    """A calibration file that cannot be read or does not describe a supported camera model."""


class SurfaceSource(enum.StrEnum):
    """Which plane the image was projected on (module docstring)."""

    NORMAL_AT_RANGE = "normal_at_range"
    STRUCTURE = "structure"
    PERPENDICULAR_AT_RANGE = "perpendicular_at_range"


# --- camera model ---------------------------------------------------------------------------


@dataclass(frozen=True)
class CameraModel:
    """Pinhole camera with Brown-Conrady distortion, plus optional mounting corrections.

    Intrinsics in pixels (OpenCV convention, module docstring). `boresight_rpy_deg` is a residual
    rotation of the real camera relative to the camera attitude in the records (roll about the
    optical axis z, pitch about x, yaw about y, i.e. the gimbal angles of the camera applied as
    yaw, then pitch, then roll); `lever_arm_camera_m` moves the projection centre from the recorded
    position, in the recorded camera axes (x right, y down, z forward). Both default to zero: the
    recorder already applies the configured mounting and lever arm, so these are for a later, better
    calibration only.
    """

    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    skew: float = 0.0
    boresight_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 0.0)
    lever_arm_camera_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    source: str = field(default="", compare=False)

    def __post_init__(self) -> None:
        name = self.source or "camera"
        if self.width_px <= 0 or self.height_px <= 0:
            raise CalibrationError(f"{name}: image size must be positive, got {self.width_px} x {self.height_px}")
        for key in ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3", "skew"):
            value = getattr(self, key)
            if not math.isfinite(value):
                raise CalibrationError(f"{name}: {key} is not a finite number ({value})")
        if self.fx <= 0 or self.fy <= 0:
            raise CalibrationError(f"{name}: focal lengths must be positive, got fx {self.fx}, fy {self.fy}")

    # --- constructors
    @classmethod
    def from_sensor(
        cls, focal_length_mm: float, sensor_width_mm: float, width_px: int, height_px: int, *, source: str = ""
    ) -> CameraModel:
        """An ideal camera (square pixels, principal point at the image centre, no distortion)."""
        if focal_length_mm <= 0 or sensor_width_mm <= 0:
            raise CalibrationError(f"{source or 'camera'}: focal length and sensor width must be positive")
        f_px = focal_length_mm * width_px / sensor_width_mm
        return cls(width_px, height_px, f_px, f_px, (width_px - 1) / 2.0, (height_px - 1) / 2.0, source=source)

    @classmethod
    def from_geotag_config(cls, cfg: GeotagConfig) -> CameraModel:
        """The ideal camera the recorder used for the records' scale_mm_per_px."""
        return cls.from_sensor(
            cfg.focal_length_mm, cfg.sensor_width_mm, cfg.image_width_px, cfg.image_height_px, source="GeotagConfig"
        )

    # --- properties
    @property
    def has_distortion(self) -> bool:
        return any(c != 0.0 for c in (self.k1, self.k2, self.p1, self.p2, self.k3))

    @property
    def centre_px(self) -> tuple[float, float]:
        """The geometric centre of the image (not the principal point)."""
        return ((self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0)

    @property
    def matrix(self) -> FloatArray:
        """K (3, 3)."""
        return np.array([[self.fx, self.skew, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def boresight_matrix(self) -> FloatArray:
        """Rotation real camera axes -> recorded camera axes (identity without a boresight)."""
        r, p, y = (math.radians(a) for a in self.boresight_rpy_deg)
        if r == p == y == 0.0:
            return np.eye(3)
        # gimbal angles act on the camera's FRD axes; conjugate them into the optical axes
        return q_to_matrix(frd_rotation_in_optical_axes(q_from_euler_zyx(r, p, y)))

    # --- lens
    def distort(self, x: FloatArray, y: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Ideal normalised coordinates -> distorted normalised coordinates."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def undistort(self, xd: FloatArray, yd: FloatArray, *, iterations: int = 30) -> tuple[FloatArray, FloatArray]:
        """Distorted -> ideal normalised coordinates (Newton's method on the Brown-Conrady model).

        Converges to ~1e-14 within a few iterations for any lens a calibration produces in its image
        area; points where the model folds over (far outside the calibrated field) come back NaN.
        """
        xd = np.asarray(xd, dtype=np.float64)
        yd = np.asarray(yd, dtype=np.float64)
        if not self.has_distortion:
            return xd.copy(), yd.copy()
        x, y = xd.copy(), yd.copy()
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
            d_radial = self.k1 + r2 * (2.0 * self.k2 + 3.0 * self.k3 * r2)
            fx = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x) - xd
            fy = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y - yd
            j11 = radial + 2.0 * x * x * d_radial + 2.0 * self.p1 * y + 6.0 * self.p2 * x
            j12 = 2.0 * x * y * d_radial + 2.0 * self.p1 * x + 2.0 * self.p2 * y
            j22 = radial + 2.0 * y * y * d_radial + 6.0 * self.p1 * y + 2.0 * self.p2 * x
            det = j11 * j22 - j12 * j12
            with np.errstate(divide="ignore", invalid="ignore"):
                dx = (j22 * fx - j12 * fy) / det
                dy = (j11 * fy - j12 * fx) / det
            x = x - dx
            y = y - dy
            if float(np.nanmax(np.abs(dx), initial=0.0)) < 1e-15 and float(np.nanmax(np.abs(dy), initial=0.0)) < 1e-15:
                break
        bad = ~(np.isfinite(x) & np.isfinite(y))
        if bad.any():
            x = np.where(bad, np.nan, x)
            y = np.where(bad, np.nan, y)
        return x, y

    def pixel_to_normalized(self, u: Any, v: Any) -> tuple[FloatArray, FloatArray]:
        """Pixels -> ideal (undistorted) normalised coordinates x = X/Z, y = Y/Z."""
        ua = np.asarray(u, dtype=np.float64)
        va = np.asarray(v, dtype=np.float64)
        yd = (va - self.cy) / self.fy
        xd = (ua - self.cx - self.skew * yd) / self.fx
        return self.undistort(xd, yd)

    def normalized_to_pixel(self, x: Any, y: Any) -> tuple[FloatArray, FloatArray]:
        """Ideal normalised coordinates -> pixels (applies the distortion)."""
        xd, yd = self.distort(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return self.fx * xd + self.skew * yd + self.cx, self.fy * yd + self.cy

    def project(self, points_cam: Any) -> FloatArray:
        """Points in camera axes (..., 3) -> pixels (..., 2); NaN for points behind the camera."""
        p = np.asarray(points_cam, dtype=np.float64)
        z = np.where(p[..., 2] > 0.0, p[..., 2], np.nan)
        u, v = self.normalized_to_pixel(p[..., 0] / z, p[..., 1] / z)
        return np.stack([u, v], axis=-1)

    def rays(self, u: Any, v: Any) -> FloatArray:
        """Ray directions (..., 3) in camera axes with z = 1 (so a ray parameter is the depth)."""
        x, y = self.pixel_to_normalized(u, v)
        return np.stack([x, y, np.ones_like(x)], axis=-1)

    def border_pixels(self, points_per_edge: int = 0) -> FloatArray:
        """The image outline (K, 2), clockwise on the image from the top-left corner (K = 4 (n + 1)).

        `points_per_edge` extra points per edge follow a distorted border's curve on the surface.
        """
        u0, v0 = -0.5, -0.5
        u1, v1 = self.width_px - 0.5, self.height_px - 0.5
        corners = [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
        out: list[tuple[float, float]] = []
        n = max(0, int(points_per_edge))
        for i in range(4):
            a, b = corners[i], corners[(i + 1) % 4]
            for k in range(n + 1):
                f = k / (n + 1)
                out.append((a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f))
        return np.asarray(out, dtype=np.float64)
