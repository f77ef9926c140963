"""The axis conventions of ICGT and the one function that turns a body pose into a frame's camera fields.

Every module that needs a frame's camera pose (the geotagger, ``icgt regeotag``, the recorded-trajectory
source, the Foxglove views, the ROS 2 export, geometry, mapping, the simulator's renderer) takes its axes
and its camera rule from here, so that one change reaches all of them.

Frames (right-handed; quaternions Hamilton, w first; ``q_a_to_b`` turns a vector's a-axes coordinates into
b-axes coordinates, which is the attitude of frame a in frame b):

* **NED**: the autopilot's local level frame (north, east, down), in which MAVLink's ATTITUDE_QUATERNION
  gives the body's attitude (``q_frd_to_ned``).
* **ENU**: the recording's local east-north-up frame at its origin (``icgt.enu_origin``); positions of
  frames are in it (``east_m, north_m, up_m``).
* **FRD body**: the vehicle's forward, right, down axes (MAVLink, PX4, ArduPilot); the lever arm
  ``lever_arm_body_m`` is given in it.
* **FLU body**: forward, left, up: ROS's ``base_link`` (REP-103), used by the Foxglove and ROS 2 outputs.
* **Camera optical**: x right, y down, z forward along the optical axis (OpenCV, ROS ``camera_optical``).
  It is the one camera frame: the frame record's ``cam_q*`` is ``q_optical_to_ned``, the geometry's
  projections and the simulator's truth use it. With no mounting angles the camera looks along the body's
  x axis (``Q_OPTICAL_TO_FRD``), and ``mount_roll/pitch/yaw_deg`` (ZYX Euler in body axes) turn it from
  there: pitch -90 deg looks down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import numpy as np

from icgt.geodesy import (
    Q_NED_TO_ENU,
    FloatArray,
    ned_to_enu,
    q_conjugate,
    q_from_euler_zyx,
    q_multiply,
    q_multiply_tuple,
    q_rotate,
    q_to_euler_zyx,
)

__all__ = [
    "CARRIED_ATTITUDE_SOURCES",
    "Q_FRD_TO_FLU",
    "Q_NED_TO_ENU",
    "Q_OPTICAL_TO_FRD",
    "R_NED_TO_ENU",
    "CameraFields",
    "CameraMounting",
    "camera_fields",
    "camera_position_enu",
    "camera_quaternion",
    "camera_to_body_quaternion",
    "euler_deg",
    "frame_tree",
    "frd_rotation_in_optical_axes",
    "frd_to_flu",
    "lever_arm_enu",
    "optical_axis_enu",
    "q_flu_to_enu",
    "q_flu_to_enu_floats",
    "reference_position_enu",
]

Q_OPTICAL_TO_FRD: FloatArray = np.array([0.5, 0.5, 0.5, 0.5])
"""Camera optical -> body FRD with no mounting angles: optical z (forward) = body x, x (right) = body y,
y (down) = body z."""

CARRIED_ATTITUDE_SOURCES = ("gimbal", "board_imu")
"""Attitude sources that measure the camera's carrier itself (not the body): its attitude times the mount angles."""

Q_FRD_TO_FLU: FloatArray = np.array([0.0, 1.0, 0.0, 0.0])
"""Body FRD -> FLU: 180 deg about x (its own inverse)."""

R_NED_TO_ENU: FloatArray = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""NED -> ENU as a matrix (its own inverse): (e, n, u) = (n_E, n_N, -n_D); `Q_NED_TO_ENU` as a quaternion."""

_OPTICAL_Z = np.array([0.0, 0.0, 1.0])
_S = math.sqrt(0.5)


def frd_to_flu(v: Any) -> tuple[float, float, float]:
    """A body FRD vector in FLU axes."""
    return (float(v[0]), -float(v[1]), -float(v[2]))


def q_flu_to_enu(q_frd_to_ned: Any) -> FloatArray:
    """A body FRD -> NED quaternion as the body FLU -> ENU one of the same attitude (REP-103)."""
    return np.asarray(q_multiply(q_multiply(Q_NED_TO_ENU, q_frd_to_ned), Q_FRD_TO_FLU))


def q_flu_to_enu_floats(q: tuple[float, float, float, float]) -> tuple[float, float, float, float]:
    """`q_flu_to_enu` on plain floats (the numpy one costs ~40 us a call, too much at telemetry rate)."""
    return q_multiply_tuple(q_multiply_tuple((0.0, _S, _S, 0.0), q), (0.0, 1.0, 0.0, 0.0))


def frd_rotation_in_optical_axes(q_camera_frd: Any) -> FloatArray:
    """A rotation given in body-like camera axes (FRD, x along the optical axis) in optical axes.

    Returns ``conj(Q_OPTICAL_TO_FRD) * q * Q_OPTICAL_TO_FRD``: the same physical rotation expressed between
    optical frames (used for calibration files that give the camera's rotation in FRD-like axes)."""
    return np.asarray(q_multiply(q_multiply(q_conjugate(Q_OPTICAL_TO_FRD), q_camera_frd), Q_OPTICAL_TO_FRD))


def camera_to_body_quaternion(mount: CameraMounting | MountAngles) -> FloatArray:
    """Rotation camera optical -> body FRD of a mounting (ZYX Euler angles on top of `Q_OPTICAL_TO_FRD`)."""
    m = q_from_euler_zyx(
        math.radians(mount.mount_roll_deg), math.radians(mount.mount_pitch_deg), math.radians(mount.mount_yaw_deg)
    )
    return np.asarray(q_multiply(m, Q_OPTICAL_TO_FRD))


def camera_quaternion(body_q: Any, q_cam_body: Any, *, gimbal_stabilised: bool) -> FloatArray:
    """Camera -> NED: the body's attitude (or only its yaw, for a gimbal that holds roll and pitch level)
    times the mounting ``q_cam_body`` (camera -> body FRD). Vectorised over (..., 4) attitudes."""
    carrier = body_q
    if gimbal_stabilised:
        _, _, body_yaw = q_to_euler_zyx(body_q)
        carrier = q_from_euler_zyx(0.0, 0.0, body_yaw)
    return np.asarray(q_multiply(carrier, q_cam_body))


def lever_arm_enu(body_q: Any, lever_arm_body_m: Any) -> FloatArray:
    """The lever arm (body FRD [m]) in ENU axes at the attitude ``body_q`` (FRD -> NED)."""
    return ned_to_enu(q_rotate(body_q, np.asarray(lever_arm_body_m)))


def camera_position_enu(reference_enu: Any, body_q: Any | None, lever_arm_body_m: Any) -> FloatArray:
    """The camera's position [m, ENU] from the reference point's (the autopilot's) and the lever arm;
    without an attitude the reference point itself."""
    if body_q is None:
        return np.asarray(reference_enu)
    return np.asarray(reference_enu + lever_arm_enu(body_q, lever_arm_body_m))


def reference_position_enu(camera_enu: Any, body_q: Any | None, lever_arm_body_m: Any) -> FloatArray:
    """The inverse of `camera_position_enu`: the reference point from the camera's position."""
    if body_q is None:
        return np.asarray(camera_enu)
    return np.asarray(camera_enu - lever_arm_enu(body_q, lever_arm_body_m))


def frame_tree(
    camera_enu: Any, body_q: Any, cam_q: Any, q_cam_body: Any, lever_arm_body_m: Any
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A frame's transform tree for ROS and Foxglove (``enu -> base_link -> camera_mount -> camera_optical``).

    Returns (base_link's position [m, ENU], base_link FLU -> ENU, camera_mount -> camera_optical): the last is
    what a gimbal turned the camera by from its mounting (identity for a fixed mount)."""
    q_body = np.asarray(body_q, dtype=float)
    base_enu = reference_position_enu(np.asarray(camera_enu, dtype=float), q_body, lever_arm_body_m)
    nominal = q_multiply(q_body, q_cam_body)  # camera -> NED as mounted
    residual = np.asarray(q_multiply(q_conjugate(nominal), cam_q))
    return base_enu, q_flu_to_enu(q_body), residual


def optical_axis_enu(cam_q: Any) -> FloatArray:
    """The camera's optical axis (unit, ENU) for a camera optical -> NED quaternion."""
    return ned_to_enu(q_rotate(cam_q, _OPTICAL_Z))


def euler_deg(body_q: Any) -> tuple[float, float, float]:
    """Roll, pitch, yaw [deg] (ZYX, yaw in [0, 360)) of a body FRD -> NED quaternion."""
    r, p, y = q_to_euler_zyx(body_q)
    yaw = math.degrees(float(y)) % 360.0
    # a yaw a hair below 0 wraps to exactly 360.0 in floating point (-1e-18 % 360.0 == 360.0): that is north
    return math.degrees(float(r)), math.degrees(float(p)), 0.0 if yaw >= 360.0 else yaw


class MountAngles(Protocol):
    """The camera's mounting angles [deg] (as in the recorder's [camera] settings)."""

    @property
    def mount_roll_deg(self) -> float: ...
    @property
    def mount_pitch_deg(self) -> float: ...
    @property
    def mount_yaw_deg(self) -> float: ...


class _CameraSettings(MountAngles, Protocol):
    @property
    def lever_arm_body_m(self) -> tuple[float, float, float]: ...
    @property
    def gimbal_stabilised(self) -> bool: ...
    @property
    def attitude_source(self) -> str: ...
    @property
    def surface_normal_enu(self) -> tuple[float, float, float] | None: ...
    @property
    def pixel_pitch_mm(self) -> float: ...
    @property
    def focal_length_mm(self) -> float: ...


@dataclass(frozen=True)
class CameraMounting:
    """What the camera rule needs of the camera's configuration (units in the names)."""

    mount_roll_deg: float
    mount_pitch_deg: float
    mount_yaw_deg: float
    lever_arm_body_m: tuple[float, float, float]
    gimbal_stabilised: bool
    surface_normal_enu: tuple[float, float, float] | None
    pixel_pitch_mm: float
    focal_length_mm: float
    # "mount": the camera turns with the body; "gimbal": with the gimbal's reported attitude (the mount angles
    # are then the camera's on the gimbal's device frame); "board_imu": with the board's BNO055 (the angles are
    # the camera's on the board)
    attitude_source: str = "mount"

    @classmethod
    def of(cls, cfg: _CameraSettings, *, lever_arm_body_m: tuple[float, float, float] | None = None) -> CameraMounting:
        """The mounting of a camera configuration (a `GeotagConfig`), optionally with another lever arm."""
        arm = lever_arm_body_m if lever_arm_body_m is not None else cfg.lever_arm_body_m
        return cls(
            cfg.mount_roll_deg,
            cfg.mount_pitch_deg,
            cfg.mount_yaw_deg,
            (float(arm[0]), float(arm[1]), float(arm[2])),
            cfg.gimbal_stabilised,
            cfg.surface_normal_enu,
            cfg.pixel_pitch_mm,
            cfg.focal_length_mm,
            cfg.attitude_source,
        )

    @cached_property
    def q_cam_body(self) -> FloatArray:
        """Camera optical -> body FRD."""
        return camera_to_body_quaternion(self)

    @property
    def lever_arm_m(self) -> float:
        """The lever arm's length [m]."""
        return float(np.linalg.norm(np.asarray(self.lever_arm_body_m, dtype=float)))


@dataclass(frozen=True)
class CameraFields:
    """A frame's camera pose fields (the frame record's names and units)."""

    east_m: float | None
    north_m: float | None
    up_m: float | None
    body_q: FloatArray | None
    cam_q: FloatArray | None
    roll_deg: float | None
    pitch_deg: float | None
    yaw_deg: float | None
    scale_mm_per_px: float | None
    incidence_deg: float | None

    @property
    def enu(self) -> FloatArray | None:
        if self.east_m is None or self.north_m is None or self.up_m is None:
            return None
        return np.array([self.east_m, self.north_m, self.up_m])


def _incidence_and_scale(
    cam_q: FloatArray | None, range_m: float | None, mounting: CameraMounting
) -> tuple[float | None, float | None]:
    """Incidence [deg] of the optical axis on the structure's face, and the scale [mm/px] at the range.

    The scale is the range's pixel footprint, larger by 1/cos(incidence) along the tilt."""
    if range_m is None:
        return None, None
    scale = range_m * 1000.0 * mounting.pixel_pitch_mm / mounting.focal_length_mm
    if cam_q is None or mounting.surface_normal_enu is None:
        return None, scale
    n = np.asarray(mounting.surface_normal_enu, dtype=float)
    cosang = abs(float(optical_axis_enu(cam_q) @ n)) / float(np.linalg.norm(n))
    return math.degrees(math.acos(min(1.0, cosang))), scale / max(cosang, 1e-3)


def camera_fields(
    reference_enu: Any | None,
    body_q: Any | None,
    range_m: float | None,
    mounting: CameraMounting,
    gimbal_q: Any | None = None,
) -> CameraFields:
    """The camera's position, attitude, scale and incidence from a body pose and the range.

    ``reference_enu``: the autopilot's reference point [m, ENU] (None: no position); ``body_q``: FRD -> NED
    (None: no attitude; the position is then the reference point's); ``range_m``: the valid range [m];
    ``gimbal_q``: the camera's carrier -> NED at the instant (the gimbal's device frame, or the board's sensor
    axes for "board_imu"), for a mounting whose attitude source is one of `CARRIED_ATTITUDE_SOURCES` (None
    there: no camera attitude)."""
    enu = camera_position_enu(reference_enu, body_q, mounting.lever_arm_body_m) if reference_enu is not None else None
    cam_q = None
    roll = pitch = yaw = None
    if mounting.attitude_source in CARRIED_ATTITUDE_SOURCES:
        cam_q = np.asarray(q_multiply(gimbal_q, mounting.q_cam_body)) if gimbal_q is not None else None
    elif body_q is not None:
        cam_q = camera_quaternion(body_q, mounting.q_cam_body, gimbal_stabilised=mounting.gimbal_stabilised)
    if body_q is not None:
        roll, pitch, yaw = euler_deg(body_q)
    incidence, scale = _incidence_and_scale(cam_q, range_m, mounting)
    return CameraFields(
        east_m=float(enu[0]) if enu is not None else None,
        north_m=float(enu[1]) if enu is not None else None,
        up_m=float(enu[2]) if enu is not None else None,
        body_q=np.asarray(body_q) if body_q is not None else None,
        cam_q=cam_q,
        roll_deg=roll,
        pitch_deg=pitch,
        yaw_deg=yaw,
        scale_mm_per_px=scale,
        incidence_deg=incidence,
    )
