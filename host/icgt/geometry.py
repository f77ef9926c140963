"""Image geometry for detection and mapping: camera model, footprints, pixel -> world, crack length.

Conventions (see also geodesy.py):

- Pixels: OpenCV's. (u, v) = (column, row); integer coordinates are pixel *centres*, so the image
  covers [-0.5, W - 0.5] x [-0.5, H - 0.5] and its geometric centre is ((W - 1) / 2, (H - 1) / 2).
- Camera axes: x right, y down, z forward (the optical axis), as the frame record's cam_q* is given
  (camera -> NED). The LiDAR is taken to look along the optical axis from the projection centre.
- World: the recording's local ENU frame [m] (the frame records' east/north/up); WGS84 latitude and
  longitude [deg] and altitude above mean sea level [m], as in the records.
- Lens: Brown-Conrady on normalised coordinates (x, y) = ((u - cx) / fx, (v - cy) / fy), OpenCV's
  order k1, k2, p1, p2, k3:
  x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2),
  y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y.

The surface a pixel is projected on (`SurfaceSource`), per frame:

- ``normal_at_range`` (default when the structure's orientation is known and the LiDAR return is
  valid): the plane with the structure's normal through the LiDAR return (camera + range x optical
  axis). The range ties the plane to the camera directly, so a GPS error (metres without RTK) does
  not become a scale error; the structure's orientation gives the incidence.
- ``structure``: the structure plane as given (point and normal in the recording's ENU frame), used
  when there is no valid range or when the caller asks for it (`anchor="structure"`).
- ``perpendicular_at_range``: nothing is known about the surface: the plane perpendicular to the
  optical axis at the LiDAR range (incidence 0 by construction). This is also the paper's model.

Calibration files (`load_calibration`), by suffix:

- ``.toml`` (ours)::

      [camera]
      width_px = 6000
      height_px = 4000
      fx = 5898.876      # [px]; or focal_length_mm + sensor_width_mm (square pixels)
      fy = 5898.876
      cx = 2999.5        # [px]; default: the image centre
      cy = 1999.5
      skew = 0.0         # optional
      [distortion]       # optional, all default 0
      k1 = 0.0
      k2 = 0.0
      p1 = 0.0
      p2 = 0.0
      k3 = 0.0
      [mounting]         # optional corrections on top of the attitude the recorder already applied
      boresight_roll_deg = 0.0    # residual gimbal angles of the real camera (see CameraModel)
      boresight_pitch_deg = 0.0
      boresight_yaw_deg = 0.0
      lever_arm_camera_m = [0.0, 0.0, 0.0]   # projection centre from the recorded position, camera axes

- ``.yaml`` / ``.yml``: OpenCV FileStorage YAML (what ``cv::FileStorage`` and OpenCV's
  calibration sample write): ``image_width``, ``image_height``, ``camera_matrix`` and
  ``distortion_coefficients`` as ``!!opencv-matrix`` (rows, cols, dt, data).
- ``.json``: OpenCV FileStorage JSON (the same keys, matrices as objects with rows/cols/data) or plain
  JSON with ``camera_matrix`` as a 3x3 nested list or 9 numbers and ``distortion_coefficients`` (or
  ``dist_coeffs``) as a list; ``image_width``/``image_height`` (or ``width``/``height``).

Only the first five distortion coefficients are supported; a file with a non-zero sixth or later
coefficient (OpenCV's rational or thin-prism models) is refused rather than silently truncated.
"""

from __future__ import annotations

import enum
import json
import math
import re
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np

from icgt.errors import IcgtError
from icgt.geodesy import (
    FloatArray,
    LocalFrame,
    ecef_to_enu_matrix,
    ecef_to_geodetic,
    geodetic_to_ecef,
    q_from_euler_zyx,
    q_multiply,
    q_to_euler_zyx,
    q_to_matrix,
)
from icgt.geotag.geotagger import GeotagConfig
from icgt.geotag.record import FrameRecord

# NED components -> ENU components
_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
# optical camera axes (x right, y down, z forward) -> camera "body" axes (x forward, y right, z down):
# 120 deg about (1, 1, 1), the geotagger's base alignment
_Q_OPTICAL_TO_FRD = np.array([0.5, 0.5, 0.5, 0.5])


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

    @classmethod
    def load(cls, path: str | Path) -> CameraModel:
        return load_calibration(path)

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
        q_frd = q_from_euler_zyx(r, p, y)
        q = q_multiply(q_multiply(_conj(_Q_OPTICAL_TO_FRD), q_frd), _Q_OPTICAL_TO_FRD)
        return q_to_matrix(q)

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


def _conj(q: FloatArray) -> FloatArray:
    return np.array([q[0], -q[1], -q[2], -q[3]])


# --- calibration files ----------------------------------------------------------------------


def load_calibration(path: str | Path) -> CameraModel:
    """A CameraModel from a calibration file (formats: module docstring); raises CalibrationError."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"{p}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{p}: not a text file ({exc.reason})") from exc
    suffix = p.suffix.lower()
    if suffix == ".toml":
        return _from_toml(text, str(p))
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationError(f"{p}: not valid JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise CalibrationError(f"{p}: expected a JSON object at the top")
        return _from_opencv_mapping(data, str(p))
    if suffix in (".yaml", ".yml"):
        return _from_opencv_mapping(_parse_opencv_yaml(text, str(p)), str(p))
    raise CalibrationError(f"{p}: unknown calibration format {suffix!r}: use .toml, .yaml/.yml (OpenCV) or .json")


def _number(source: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CalibrationError(f"{source}: {key}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise CalibrationError(f"{source}: {key}: expected a finite number, got {value!r}")
    return v


def _integer(source: str, key: str, value: Any) -> int:
    v = _number(source, key, value)
    if v != int(v) or v <= 0:
        raise CalibrationError(f"{source}: {key}: expected a positive integer, got {value!r}")
    return int(v)


def _from_toml(text: str, source: str) -> CameraModel:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{source}: not valid TOML: {exc}") from exc
    cam = data.get("camera")
    if not isinstance(cam, dict):
        raise CalibrationError(f"{source}: missing the [camera] table")
    dist = data.get("distortion", {})
    mount = data.get("mounting", {})
    if not isinstance(dist, dict) or not isinstance(mount, dict):
        raise CalibrationError(f"{source}: [distortion] and [mounting] must be tables")
    known = {
        "camera": {"width_px", "height_px", "fx", "fy", "cx", "cy", "skew", "focal_length_mm", "sensor_width_mm"},
        "distortion": {"k1", "k2", "p1", "p2", "k3"},
        "mounting": {"boresight_roll_deg", "boresight_pitch_deg", "boresight_yaw_deg", "lever_arm_camera_m"},
    }
    for section, table in (("camera", cam), ("distortion", dist), ("mounting", mount)):
        unknown = sorted(set(table) - known[section])
        if unknown:
            raise CalibrationError(f"{source}: {section}.{unknown[0]}: unknown key (a typo?)")
    for top in sorted(set(data) - set(known)):
        raise CalibrationError(f"{source}: {top}: unknown table (a typo?)")
    if "width_px" not in cam or "height_px" not in cam:
        raise CalibrationError(f"{source}: camera.width_px and camera.height_px are required")
    w = _integer(source, "camera.width_px", cam["width_px"])
    h = _integer(source, "camera.height_px", cam["height_px"])
    if "fx" in cam:
        fx = _number(source, "camera.fx", cam["fx"])
        fy = _number(source, "camera.fy", cam.get("fy", cam["fx"]))
    elif "focal_length_mm" in cam and "sensor_width_mm" in cam:
        f_mm = _number(source, "camera.focal_length_mm", cam["focal_length_mm"])
        s_mm = _number(source, "camera.sensor_width_mm", cam["sensor_width_mm"])
        if s_mm <= 0:
            raise CalibrationError(f"{source}: camera.sensor_width_mm must be positive")
        fx = fy = f_mm * w / s_mm
    else:
        raise CalibrationError(f"{source}: give camera.fx (and fy) or camera.focal_length_mm and sensor_width_mm")
    lever = mount.get("lever_arm_camera_m", [0.0, 0.0, 0.0])
    if not isinstance(lever, list) or len(lever) != 3:
        raise CalibrationError(f"{source}: mounting.lever_arm_camera_m: expected [x, y, z]")
    return CameraModel(
        width_px=w,
        height_px=h,
        fx=fx,
        fy=fy,
        cx=_number(source, "camera.cx", cam.get("cx", (w - 1) / 2.0)),
        cy=_number(source, "camera.cy", cam.get("cy", (h - 1) / 2.0)),
        skew=_number(source, "camera.skew", cam.get("skew", 0.0)),
        k1=_number(source, "distortion.k1", dist.get("k1", 0.0)),
        k2=_number(source, "distortion.k2", dist.get("k2", 0.0)),
        p1=_number(source, "distortion.p1", dist.get("p1", 0.0)),
        p2=_number(source, "distortion.p2", dist.get("p2", 0.0)),
        k3=_number(source, "distortion.k3", dist.get("k3", 0.0)),
        boresight_rpy_deg=(
            _number(source, "mounting.boresight_roll_deg", mount.get("boresight_roll_deg", 0.0)),
            _number(source, "mounting.boresight_pitch_deg", mount.get("boresight_pitch_deg", 0.0)),
            _number(source, "mounting.boresight_yaw_deg", mount.get("boresight_yaw_deg", 0.0)),
        ),
        lever_arm_camera_m=(
            _number(source, "mounting.lever_arm_camera_m[0]", lever[0]),
            _number(source, "mounting.lever_arm_camera_m[1]", lever[1]),
            _number(source, "mounting.lever_arm_camera_m[2]", lever[2]),
        ),
        source=source,
    )


_YAML_KEY = re.compile(r"^(\s*)([A-Za-z_][\w-]*)\s*:\s*(.*?)\s*$")


def _yaml_scalar(text: str) -> Any:
    t = text.strip().strip('"').strip("'")
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _parse_opencv_yaml(text: str, source: str) -> dict[str, Any]:
    """The subset of OpenCV FileStorage YAML a calibration uses: scalars and !!opencv-matrix maps."""
    out: dict[str, Any] = {}
    current: dict[str, Any] | None = None
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        raw = lines[i]
        i += 1
        line = raw.split("#", 1)[0].rstrip() if not raw.lstrip().startswith("%") else ""
        if not line.strip() or line.strip() == "---":
            continue
        m = _YAML_KEY.match(line)
        if m is None:
            raise CalibrationError(f"{source}:{i}: cannot read {raw.strip()!r} (expected 'key: value')")
        indent, key, rest = m.groups()
        if not indent:
            if rest.startswith("!!opencv-matrix") or rest == "":
                current = {}
                out[key] = current
            else:
                out[key] = _yaml_scalar(rest)
                current = None
            continue
        if current is None:
            raise CalibrationError(f"{source}:{i}: {key}: indented key outside a matrix")
        if key == "data":
            chunk = rest
            while "]" not in chunk and i < len(lines):
                chunk += " " + lines[i].split("#", 1)[0]
                i += 1
            if not chunk.strip().startswith("[") or "]" not in chunk:
                raise CalibrationError(f"{source}:{i}: data: expected [ ... ]")
            body = chunk.strip()[1 : chunk.strip().index("]")]
            try:
                current["data"] = [float(x) for x in body.replace("\n", " ").split(",") if x.strip()]
            except ValueError as exc:
                raise CalibrationError(f"{source}:{i}: data: {exc}") from exc
        else:
            current[key] = _yaml_scalar(rest)
    return out


def _matrix(source: str, key: str, value: Any) -> list[float]:
    """A flat list of numbers from an OpenCV matrix object, a nested list or a flat list."""
    if isinstance(value, dict):
        data = value.get("data")
        if not isinstance(data, list):
            raise CalibrationError(f"{source}: {key}: matrix without a data list")
        rows, cols = value.get("rows"), value.get("cols")
        if isinstance(rows, int) and isinstance(cols, int) and rows * cols != len(data):
            raise CalibrationError(f"{source}: {key}: {rows}x{cols} matrix with {len(data)} values")
        value = data
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        value = [x for r in value for x in r]
    if not isinstance(value, list):
        raise CalibrationError(f"{source}: {key}: expected a matrix, got {value!r}")
    return [_number(source, key, x) for x in value]


def _first_key(data: Mapping[str, Any], *names: str) -> tuple[str, Any] | None:
    for n in names:
        if n in data:
            return n, data[n]
    return None


def _from_opencv_mapping(data: Mapping[str, Any], source: str) -> CameraModel:
    k_entry = _first_key(data, "camera_matrix", "cameraMatrix", "K")
    if k_entry is None:
        raise CalibrationError(f"{source}: no camera_matrix")
    k = _matrix(source, k_entry[0], k_entry[1])
    if len(k) != 9:
        raise CalibrationError(f"{source}: {k_entry[0]}: expected 9 values (3x3), got {len(k)}")
    if abs(k[3]) > 1e-12 or abs(k[6]) > 1e-12 or abs(k[7]) > 1e-12 or abs(k[8] - 1.0) > 1e-9:
        raise CalibrationError(f"{source}: {k_entry[0]}: not a camera matrix [[fx s cx] [0 fy cy] [0 0 1]]")
    d_entry = _first_key(data, "distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
    d = _matrix(source, d_entry[0], d_entry[1]) if d_entry is not None else []
    if any(abs(c) > 0.0 for c in d[5:]):
        raise CalibrationError(
            f"{source}: {d_entry[0] if d_entry else 'distortion'}: only k1 k2 p1 p2 k3 are supported; "
            f"coefficients 6 and later are not zero"
        )
    d = (d + [0.0] * 5)[:5]
    w_entry = _first_key(data, "image_width", "width", "imageWidth")
    h_entry = _first_key(data, "image_height", "height", "imageHeight")
    if w_entry is None or h_entry is None:
        raise CalibrationError(f"{source}: image_width and image_height are required")
    return CameraModel(
        width_px=_integer(source, w_entry[0], w_entry[1]),
        height_px=_integer(source, h_entry[0], h_entry[1]),
        fx=k[0],
        fy=k[4],
        cx=k[2],
        cy=k[5],
        skew=k[1],
        k1=d[0],
        k2=d[1],
        p1=d[2],
        p2=d[3],
        k3=d[4],
        source=source,
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


# --- per-frame geometry ---------------------------------------------------------------------


@dataclass(frozen=True)
class WorldPoints:
    """Points on the surface: ENU [m] (N, 3) and WGS84 (None when the frame has no geodetic anchor).

    Rows are NaN where the ray missed the surface (it points away from it or beyond the horizon).
    `alt_m` is above mean sea level, like the records' alt_msl_m.
    """

    enu: FloatArray
    lat_deg: FloatArray | None
    lon_deg: FloatArray | None
    alt_m: FloatArray | None
    plane_st: FloatArray
    """Map coordinates on the surface (N, 2) [m]: see plane_axes."""
    surface: SurfaceSource


@dataclass(frozen=True)
class FrameSolution:
    """Everything the exports need about one frame, computed once."""

    frame_seq: int
    surface: SurfaceSource
    plane: Plane
    camera_enu: FloatArray
    scale_mm_per_px: float
    """Surface length of one pixel at the image centre, in the steeper direction (as the record's)."""
    scale_u_mm_per_px: float
    scale_v_mm_per_px: float
    incidence_deg: float
    centre: WorldPoints
    footprint: WorldPoints | None
    """The image outline on the surface (None if part of it misses the surface)."""
    footprint_area_m2: float | None
    camera_yaw_deg: float
    camera_pitch_deg: float
    camera_roll_deg: float


@dataclass(frozen=True)
class CrackOnMap:
    """A crack polyline placed on the surface."""

    points: WorldPoints
    length_mm: float
    """Exact: the sum of the 3D segment lengths between the ray-plane intersections."""
    length_mm_paper: float | None
    """The paper's estimate (eqs 5-7 with the LiDAR distance as depth; None without a range)."""
    midpoint_enu: FloatArray
    """The point half-way along the polyline on the surface [m]."""
    midpoint_wgs84: tuple[float, float, float] | None


def camera_angles_deg(rec: FrameRecord) -> tuple[float, float, float] | None:
    """(yaw, pitch, roll) [deg] of the camera, gimbal convention; None without a camera attitude.

    yaw: compass heading of the optical axis (0 north, 90 east, in [0, 360)); pitch: elevation of
    the optical axis (0 level, -90 looking straight down, +90 up); roll: rotation of the image about
    the optical axis (positive: clockwise as seen from behind the camera). These are Euler ZYX angles
    of the camera's FRD axes (x optical axis, y image right, z image down) relative to NED, the
    convention of DJI's gimbal angles and of ODM's geo.txt.
    """
    if rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None:
        return None
    yaw, pitch, roll = _camera_angles(np.array([[rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz]]))
    return float(yaw[0]), float(pitch[0]), float(roll[0])


def camera_angles_deg_many(recs: Sequence[FrameRecord]) -> list[tuple[float, float, float] | None]:
    """camera_angles_deg for many frames at once (vectorised)."""
    q = np.array(
        [
            (r.cam_qw, r.cam_qx, r.cam_qy, r.cam_qz) if _has_attitude(r) else (np.nan, np.nan, np.nan, np.nan)
            for r in recs
        ],
        dtype=np.float64,
    ).reshape(-1, 4)
    yaw, pitch, roll = _camera_angles(q)
    return [(float(yaw[i]), float(pitch[i]), float(roll[i])) if _has_attitude(r) else None for i, r in enumerate(recs)]


def _has_attitude(rec: FrameRecord) -> bool:
    return not (rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None)


def _camera_angles(q_cam_ned: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Vectorised camera_angles_deg for camera->NED quaternions (N, 4): (yaw, pitch, roll) [deg]."""
    q = q_cam_ned / np.linalg.norm(q_cam_ned, axis=-1, keepdims=True)
    r, p, y = q_to_euler_zyx(q_multiply(q, _conj(_Q_OPTICAL_TO_FRD)))
    return np.degrees(y) % 360.0, np.degrees(p), np.degrees(r)


def _position_missing(rec: FrameRecord) -> str | None:
    if rec.east_m is None or rec.north_m is None or rec.up_m is None:
        return "no position (no fix at exposure)"
    if rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None:
        return "no camera attitude"
    return None


@dataclass
class _Batch:
    """Poses and surfaces of N frames (rows of frames that cannot be solved are NaN)."""

    recs: list[FrameRecord]
    ok: np.ndarray  # (N,) bool
    reasons: list[str | None]
    c: FloatArray  # (N, 3) camera ENU
    r: FloatArray  # (N, 3, 3) camera -> ENU
    p0: FloatArray  # (N, 3) plane point
    n: FloatArray  # (N, 3) plane normal (towards the camera)
    source: list[SurfaceSource | None]
    anchor_geo: FloatArray  # (N, 3) lat, lon, alt of the frame (NaN unknown)
    q: FloatArray  # (N, 4) camera -> NED


class Projector:
    """Projects pixels of recorded frames onto the inspected surface.

    camera: the camera model. origin: the recording's ENU origin (lat [deg], lon [deg], alt MSL [m]),
    if known; else each frame's own lat/lon/alt anchors its WGS84 output (exact to well below a
    millimetre within a few kilometres of the origin). structure: the structure plane in the
    recording's ENU frame; surface_normal: only its orientation (ENU). anchor: "range" places the
    plane through the LiDAR return when the range is valid (module docstring), "structure" uses
    the structure plane as given.
    """

    def __init__(
        self,
        camera: CameraModel,
        *,
        origin: tuple[float, float, float] | LocalFrame | None = None,
        structure: Plane | None = None,
        surface_normal: Sequence[float] | None = None,
        anchor: Literal["range", "structure"] = "range",
        footprint_points_per_edge: int | None = None,
    ) -> None:
        self.camera = camera
        if isinstance(origin, LocalFrame):
            self.origin: LocalFrame | None = origin
        elif origin is not None:
            self.origin = LocalFrame(float(origin[0]), float(origin[1]), float(origin[2]))
        else:
            self.origin = None
        self.structure = structure
        normal = structure.normal if structure is not None else surface_normal
        self.normal: FloatArray | None = None
        if normal is not None:
            nv = np.asarray(normal, dtype=np.float64)
            if nv.shape != (3,) or not np.isfinite(nv).all() or float(np.linalg.norm(nv)) < 1e-12:
                raise GeometryError(f"surface normal {normal!r} is not a direction")
            self.normal = nv / np.linalg.norm(nv)
        if anchor not in ("range", "structure"):
            raise GeometryError(f"anchor must be 'range' or 'structure', not {anchor!r}")
        if anchor == "structure" and structure is None:
            raise GeometryError("anchor='structure' needs the structure plane")
        self.anchor = anchor
        self._r_boresight = camera.boresight_matrix()
        self._lever = np.asarray(camera.lever_arm_camera_m, dtype=np.float64)
        n_edge = (
            footprint_points_per_edge if footprint_points_per_edge is not None else (8 if camera.has_distortion else 0)
        )
        self._border = camera.border_pixels(n_edge)
        cu, cv = camera.centre_px
        probe = np.array([[cu, cv], [cu - 0.5, cv], [cu + 0.5, cv], [cu, cv - 0.5], [cu, cv + 0.5]])
        self._probe_rays = camera.rays(probe[:, 0], probe[:, 1])  # (5, 3)
        self._border_rays = camera.rays(self._border[:, 0], self._border[:, 1])  # (K, 3)

    # --- batch core
    def _batch(self, recs: Sequence[FrameRecord]) -> _Batch:
        n = len(recs)
        c = np.full((n, 3), np.nan)
        q = np.full((n, 4), np.nan)
        rng = np.full(n, np.nan)
        geo = np.full((n, 3), np.nan)
        reasons: list[str | None] = []
        for i, rec in enumerate(recs):
            why = _position_missing(rec)
            reasons.append(why)
            if why is None:
                c[i] = (rec.east_m, rec.north_m, rec.up_m)
                q[i] = (rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz)
            if rec.range_valid and rec.range_m is not None and math.isfinite(rec.range_m) and rec.range_m > 0:
                rng[i] = rec.range_m
            if rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None:
                geo[i] = (rec.lat_deg, rec.lon_deg, rec.alt_msl_m)
        ok = np.array([r is None for r in reasons], dtype=bool)
        qn = q / np.linalg.norm(q, axis=-1, keepdims=True)
        r_recorded = _NED_TO_ENU @ q_to_matrix(qn)  # (N, 3, 3) recorded camera axes -> ENU
        c = c + r_recorded @ self._lever
        r = r_recorded @ self._r_boresight  # real camera axes -> ENU
        axis = r[:, :, 2]  # optical axis in ENU
        p0 = np.full((n, 3), np.nan)
        nrm = np.full((n, 3), np.nan)
        sources: list[SurfaceSource | None] = [None] * n
        has_range = np.isfinite(rng)
        hit = c + axis * np.where(has_range, rng, np.nan)[:, None]
        for i in range(n):
            if not ok[i]:
                continue
            src = self._choose(bool(has_range[i]))
            if src is None:
                reasons[i] = "no valid LiDAR range and no structure plane: the surface is unknown"
                continue
            if src is SurfaceSource.STRUCTURE:
                assert self.structure is not None
                p0[i], nrm[i] = self.structure.point, self.structure.normal
            elif not has_range[i]:
                reasons[i] = "no valid LiDAR range"
                continue
            elif src is SurfaceSource.NORMAL_AT_RANGE:
                assert self.normal is not None
                p0[i], nrm[i] = hit[i], self.normal
            else:
                p0[i], nrm[i] = hit[i], -axis[i]
            sources[i] = src
        # normals towards the camera: a consistent side for incidence and map axes
        side = np.einsum("ij,ij->i", c - p0, nrm)
        nrm = np.where((side < 0)[:, None], -nrm, nrm)
        ok = ok & np.array([s is not None for s in sources], dtype=bool)
        return _Batch(list(recs), ok, reasons, c, r, p0, nrm, sources, geo, qn)

    def _choose(self, has_range: bool) -> SurfaceSource | None:
        if self.anchor == "structure":
            return SurfaceSource.STRUCTURE
        if has_range:
            return SurfaceSource.NORMAL_AT_RANGE if self.normal is not None else SurfaceSource.PERPENDICULAR_AT_RANGE
        return SurfaceSource.STRUCTURE if self.structure is not None else None

    @staticmethod
    def _intersect(b: _Batch, rays_cam: FloatArray) -> FloatArray:
        """Ray-plane intersections (N, M, 3) for camera rays (M, 3) or (N, M, 3); NaN for misses."""
        d = np.einsum("nij,nmj->nmi", b.r, np.broadcast_to(rays_cam, (len(b.recs), *rays_cam.shape[-2:])))
        num = np.einsum("ni,ni->n", b.p0 - b.c, b.n)  # < 0: the camera is on the normal's side
        den = np.einsum("nmi,ni->nm", d, b.n)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num[:, None] / den
        t = np.where((t > 0) & np.isfinite(t), t, np.nan)
        out: FloatArray = b.c[:, None, :] + d * t[..., None]
        return out

    def _to_wgs84(self, b: _Batch, pts: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """(lat, lon, alt) arrays shaped like pts[..., 0]; None if no frame has a geodetic anchor."""
        if self.origin is not None:
            return self.origin.enu_to_geodetic(pts)
        if not np.isfinite(b.anchor_geo).any():
            return None
        # anchor each frame at its own lat/lon/alt: ECEF of the camera + the ENU offset rotated at the camera
        lat0, lon0, alt0 = b.anchor_geo[:, 0], b.anchor_geo[:, 1], b.anchor_geo[:, 2]
        cam_ecef = geodetic_to_ecef(lat0, lon0, alt0)  # (N, 3)
        rot = _enu_to_ecef_rows(lat0, lon0)  # (N, 3, 3): ENU -> ECEF
        off = pts - b.c[:, None, :]
        ecef = cam_ecef[:, None, :] + np.einsum("nij,nmj->nmi", rot, off)
        return ecef_to_geodetic(ecef)

    def _world(self, b: _Batch, pts: FloatArray, i: int | None = None) -> list[WorldPoints]:
        geo = self._to_wgs84(b, pts)
        s_axis, t_axis = plane_axes(b.n)
        st = np.stack([np.einsum("nmi,ni->nm", pts, s_axis), np.einsum("nmi,ni->nm", pts, t_axis)], axis=-1)
        out: list[WorldPoints] = []
        for k in range(len(b.recs)):
            src = b.source[k] or SurfaceSource.STRUCTURE
            if geo is None or (self.origin is None and not np.isfinite(b.anchor_geo[k]).all()):
                out.append(WorldPoints(pts[k], None, None, None, st[k], src))
            else:
                out.append(WorldPoints(pts[k], geo[0][k], geo[1][k], geo[2][k], st[k], src))
        return out

    # --- public API
    def solve_many(self, recs: Sequence[FrameRecord]) -> list[FrameSolution | GeometryError]:
        """Solve every frame at once (vectorised); a frame that cannot be solved gives its error."""
        if not recs:
            return []
        b = self._batch(recs)
        probe = self._intersect(b, self._probe_rays)  # (N, 5, 3)
        border = self._intersect(b, self._border_rays)  # (N, K, 3)
        centre_w = self._world(b, probe[:, :1, :])
        border_w = self._world(b, border)
        su = np.linalg.norm(probe[:, 2] - probe[:, 1], axis=-1) * 1000.0
        sv = np.linalg.norm(probe[:, 4] - probe[:, 3], axis=-1) * 1000.0
        axis = b.r[:, :, 2]
        cos_inc = np.abs(np.einsum("ni,ni->n", axis, b.n))
        inc = np.degrees(np.arccos(np.clip(cos_inc, 0.0, 1.0)))
        yaw, pitch, roll = _camera_angles(b.q)
        areas = _polygon_areas(border, b.n)
        out: list[FrameSolution | GeometryError] = []
        for i, rec in enumerate(recs):
            if not b.ok[i]:
                out.append(GeometryError(b.reasons[i] or "cannot be solved"))
                continue
            if not np.isfinite(probe[i, 0]).all():
                out.append(GeometryError("the optical axis does not meet the surface"))
                continue
            src = b.source[i]
            assert src is not None
            fp: WorldPoints | None = border_w[i]
            area: float | None = None
            if not np.isfinite(border[i]).all():
                fp = None
            else:
                area = float(areas[i])
            out.append(
                FrameSolution(
                    frame_seq=rec.frame_seq,
                    surface=src,
                    plane=Plane(_vec3(b.p0[i]), _vec3(b.n[i])),
                    camera_enu=b.c[i].copy(),
                    scale_mm_per_px=float(max(su[i], sv[i])),
                    scale_u_mm_per_px=float(su[i]),
                    scale_v_mm_per_px=float(sv[i]),
                    incidence_deg=float(inc[i]),
                    centre=centre_w[i],
                    footprint=fp,
                    footprint_area_m2=area,
                    camera_yaw_deg=float(yaw[i]),
                    camera_pitch_deg=float(pitch[i]),
                    camera_roll_deg=float(roll[i]),
                )
            )
        return out

    def solve(self, rec: FrameRecord) -> FrameSolution:
        """Scale, incidence, footprint and centre of one frame; raises GeometryError."""
        result = self.solve_many([rec])[0]
        if isinstance(result, GeometryError):
            raise result
        return result

    def _single(self, rec: FrameRecord) -> _Batch:
        b = self._batch([rec])
        if not b.ok[0]:
            raise GeometryError(f"frame {rec.frame_seq}: {b.reasons[0]}")
        return b

    def pixel_to_world(self, rec: FrameRecord, u: Any, v: Any) -> WorldPoints:
        """Pixels (scalars or arrays) of one frame -> points on the surface (ENU and WGS84).

        Undistorts, turns the pixel into a ray in camera axes, rotates it into ENU with the frame's
        camera attitude and intersects it with the frame's surface plane. Raises GeometryError if
        the frame has no pose or no surface; rays that miss the surface give NaN rows.
        """
        ua = np.atleast_1d(np.asarray(u, dtype=np.float64))
        va = np.atleast_1d(np.asarray(v, dtype=np.float64))
        b = self._single(rec)
        pts = self._intersect(b, self.camera.rays(ua, va))
        return self._world(b, pts)[0]

    def footprint(self, rec: FrameRecord) -> WorldPoints:
        """The image outline on the surface (clockwise on the image from the top-left corner)."""
        sol = self.solve(rec)
        if sol.footprint is None:
            raise GeometryError(f"frame {rec.frame_seq}: part of the image does not see the surface (horizon)")
        return sol.footprint

    def scale_mm_per_px(self, rec: FrameRecord) -> float:
        return self.solve(rec).scale_mm_per_px

    def incidence_deg(self, rec: FrameRecord) -> float:
        return self.solve(rec).incidence_deg

    def crack_length_mm(
        self, rec: FrameRecord, polyline_px: Any, *, method: Literal["ray_plane", "paper"] = "ray_plane"
    ) -> float:
        """Length on the surface [mm] of a crack given as a pixel polyline (M, 2).

        ``ray_plane`` (exact for a plane): every vertex is undistorted, cast as a ray and intersected
        with the frame's surface; the length is the sum of the 3D distances between consecutive
        intersections, so incidence and perspective are accounted for.

        ``paper``: the estimate of the ICGT paper. Its eq. 5 is the pinhole projection
        x ~ K [R | T] X; eq. 6 expresses each image's rotation relative to a baseline image,
        R_new = R_b^T R_i; eq. 7 inverts the projection, X = R^-1 (K^-1 x - t), which fixes the
        point only up to its depth. With the LiDAR distance D as that depth, every image point lies on
        the plane perpendicular to the optical axis at D, and a crack's length is D times its length
        in ideal normalised image coordinates: L = D * sum |(x_k+1, y_k+1) - (x_k, y_k)|. It ignores
        the incidence angle (too short by cos(incidence) along the tilt) and needs a valid range.
        """
        poly = _polyline(polyline_px)
        if method == "paper":
            if rec.range_m is None or not rec.range_valid:
                raise GeometryError(f"frame {rec.frame_seq}: the paper's method needs a valid LiDAR range")
            x, y = self.camera.pixel_to_normalized(poly[:, 0], poly[:, 1])
            return float(rec.range_m * np.sum(np.hypot(np.diff(x), np.diff(y))) * 1000.0)
        pts = self.pixel_to_world(rec, poly[:, 0], poly[:, 1]).enu
        if not np.isfinite(pts).all():
            raise GeometryError(f"frame {rec.frame_seq}: part of the crack does not project onto the surface")
        return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=-1)) * 1000.0)

    def crack_position(self, rec: FrameRecord, polyline_px: Any) -> CrackOnMap:
        """A crack polyline (M, 2) placed on the map: its points, its lengths and its midpoint."""
        poly = _polyline(polyline_px)
        b = self._single(rec)
        pts = self._intersect(b, self.camera.rays(poly[:, 0], poly[:, 1]))
        world = self._world(b, pts)[0]
        p = world.enu
        if not np.isfinite(p).all():
            raise GeometryError(f"frame {rec.frame_seq}: part of the crack does not project onto the surface")
        seg = np.linalg.norm(np.diff(p, axis=0), axis=-1)
        length = float(seg.sum())
        if length > 0:
            cum = np.concatenate([[0.0], np.cumsum(seg)])
            k = int(np.searchsorted(cum, length / 2.0, side="right") - 1)
            k = min(k, len(seg) - 1)
            f = (length / 2.0 - cum[k]) / seg[k] if seg[k] > 0 else 0.0
            mid = p[k] + (p[k + 1] - p[k]) * f
        else:
            mid = p[0]
        mid_geo = self._to_wgs84(b, mid[None, None, :])
        mid_wgs84 = None
        if mid_geo is not None and np.isfinite(mid_geo[0]).all():
            mid_wgs84 = (float(mid_geo[0][0, 0]), float(mid_geo[1][0, 0]), float(mid_geo[2][0, 0]))
        paper = None
        if rec.range_m is not None and rec.range_valid:
            paper = self.crack_length_mm(rec, poly, method="paper")
        return CrackOnMap(world, length * 1000.0, paper, mid, mid_wgs84)


def _vec3(a: FloatArray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _polyline(polyline_px: Any) -> FloatArray:
    poly = np.asarray(polyline_px, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 2 or not np.isfinite(poly).all():
        raise GeometryError("a crack polyline is a sequence of at least two (u, v) pixel points")
    return poly


def _enu_to_ecef_rows(lat_deg: FloatArray, lon_deg: FloatArray) -> FloatArray:
    """Per-frame ENU -> ECEF rotation matrices (N, 3, 3) (transposes of ecef_to_enu_matrix)."""
    lat = np.radians(lat_deg)
    lon = np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    m = np.stack(
        [
            np.stack([-so, -sl * co, cl * co], axis=-1),
            np.stack([co, -sl * so, cl * so], axis=-1),
            np.stack([z, cl, sl], axis=-1),
        ],
        axis=-2,
    )
    return m


def _polygon_areas(pts: FloatArray, normal: FloatArray) -> FloatArray:
    """Areas [m^2] of planar polygons (N, K, 3) with normals (N, 3)."""
    rel = pts - pts[:, :1, :]
    nxt = np.roll(rel, -1, axis=1)
    cross = np.cross(rel, nxt).sum(axis=1)
    out: FloatArray = np.abs(np.einsum("ni,ni->n", cross, normal)) / 2.0
    return out


def origin_from_frames(frames: Iterable[FrameRecord]) -> LocalFrame | None:
    """The recording's ENU origin recovered from a frame carrying both lat/lon/alt and east/north/up.

    For logs that do not store it (metadata icgt.enu_origin). The origin O solves
    LocalFrame(O).geodetic_to_enu(frame's lat/lon/alt) = frame's east/north/up; a few fixed-point
    steps (shift O by the residual in its own ENU frame) converge to well below a millimetre.
    """
    for rec in frames:
        if None in (rec.lat_deg, rec.lon_deg, rec.alt_msl_m, rec.east_m, rec.north_m, rec.up_m):
            continue
        assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
        enu = np.array([rec.east_m, rec.north_m, rec.up_m], dtype=np.float64)
        lat, lon, h = LocalFrame(rec.lat_deg, rec.lon_deg, rec.alt_msl_m).enu_to_geodetic(-enu)
        origin = LocalFrame(float(lat), float(lon), float(h))
        for _ in range(6):
            residual = origin.geodetic_to_enu(rec.lat_deg, rec.lon_deg, rec.alt_msl_m) - enu
            if float(np.linalg.norm(residual)) < 1e-7:
                break
            lat, lon, h = origin.enu_to_geodetic(residual)
            origin = LocalFrame(float(lat), float(lon), float(h))
        return origin
    return None


__all__ = [
    "CalibrationError",
    "CameraModel",
    "CrackOnMap",
    "FrameSolution",
    "GeometryError",
    "Plane",
    "Projector",
    "SurfaceSource",
    "WorldPoints",
    "camera_angles_deg",
    "camera_angles_deg_many",
    "ecef_to_enu_matrix",
    "load_calibration",
    "origin_from_frames",
    "plane_axes",
]
