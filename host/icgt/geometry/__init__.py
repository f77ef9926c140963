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

from icgt.geodesy import ecef_to_enu_matrix
from icgt.geometry.calibration import load_calibration
from icgt.geometry.camera import CalibrationError, CameraModel, GeometryError, SurfaceSource
from icgt.geometry.planes import Plane, plane_axes
from icgt.geometry.projector import (
    CrackOnMap,
    FrameSolution,
    Projector,
    WorldPoints,
    camera_angles_deg,
    camera_angles_deg_many,
    origin_from_frames,
)

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
