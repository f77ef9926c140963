"""The geotagger's settings: camera, mounting and quality limits (the recorder's config file, [camera]).

Declared once, with msgspec, like the rest of the recorder's configuration (`icgt.recorder.config`): each
field's unit is in its name, every time is in seconds (`_s`), and the allowed ranges are declared with the
field (checked when a configuration is read; a value built in code is taken as it is).

Settings renamed since a log or a config file was written are listed in `RENAMED`, with the factor that
converts the old value: a log's stored settings are converted when it is read (`migrate`), a config file
that still uses an old name is refused with a message naming the new one (`renamed_message`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

__all__ = ["RENAMED", "RETIRED", "GeotagConfig", "migrate", "renamed_message"]

_Angle = Annotated[float, Meta(ge=-360.0, le=360.0)]
_Metres = Annotated[float, Meta(ge=-10.0, le=10.0)]  # a camera within 10 m of the autopilot
_Lat = Annotated[float, Meta(ge=-90.0, le=90.0)]
_Lon = Annotated[float, Meta(ge=-180.0, le=180.0)]


class GeotagConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Camera, mounting and quality limits (the recorder's config file, [camera])."""

    focal_length_mm: Annotated[float, Meta(gt=0.0, le=2000.0)] = 35.0
    sensor_width_mm: Annotated[float, Meta(gt=0.0, le=200.0)] = 35.9
    image_width_px: Annotated[int, Meta(ge=1, le=100_000)] = 7952
    image_height_px: Annotated[int, Meta(ge=1, le=100_000)] = 5304
    mount_roll_deg: _Angle = 0.0  # camera relative to the body, applied after "camera looks forward"
    mount_pitch_deg: _Angle = 0.0
    mount_yaw_deg: _Angle = 0.0
    lever_arm_body_m: tuple[_Metres, _Metres, _Metres] = (0.0, 0.0, 0.0)  # camera from the autopilot (FRD)
    gimbal_stabilised: bool = False  # a gimbal holds the camera level: only the body's yaw turns it
    # Where the camera's attitude comes from: "mount" (the body's attitude times the mount angles above), or
    # "gimbal" (the gimbal's own report, MAVLink Gimbal Protocol v2 GIMBAL_DEVICE_ATTITUDE_STATUS, interpolated at
    # mid-exposure; the mount angles are then the camera's on the gimbal, usually 0). A frame without gimbal
    # samples around mid has no camera attitude (flag gimbal_stale): never the body's in its place.
    # "board_imu": the board's BNO055, riding on the gimbal with the camera (icgt.geotag.board_imu; the mount
    # angles are then the camera's on the board, from the calibration flight of docs/board-imu.md).
    attitude_source: Literal["mount", "gimbal", "board_imu"] = "mount"
    gimbal_max_gap_s: Annotated[float, Meta(gt=0.0, le=10.0)] = 0.5  # gimbal samples farther apart: gimbal_stale
    gimbal_max_hold_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.05  # beyond the last gimbal sample at most
    # board_imu: its north. "autopilot": read off the vehicle's heading while the gimbal follows it (settled:
    # the vehicle's yaw rate at most board_imu_max_yaw_rate_deg_s) over the board_imu_heading_window_s before
    # mid; "magnetic": the BNO's own north plus board_imu_heading_offset_deg (true minus magnetic).
    board_imu_heading: Literal["autopilot", "magnetic"] = "autopilot"
    board_imu_heading_offset_deg: _Angle = 0.0
    board_imu_heading_window_s: Annotated[float, Meta(gt=0.0, le=20.0)] = 10.0  # the IMU buffer holds 20 s
    board_imu_max_yaw_rate_deg_s: Annotated[float, Meta(gt=0.0, le=180.0)] = 2.0
    board_imu_max_gap_s: Annotated[float, Meta(gt=0.0, le=1.0)] = 0.05  # IMU samples farther apart around mid
    range_min_m: Annotated[float, Meta(ge=0.0, le=1000.0)] = 0.5
    range_max_m: Annotated[float, Meta(gt=0.0, le=1000.0)] = 40.0
    range_stale_s: Annotated[float, Meta(gt=0.0, le=10.0)] = 0.05  # a range sample farther from mid: not used
    max_position_error_m: Annotated[float, Meta(gt=0.0)] = 0.10  # a larger gap part of the bound: stale_pose
    max_gps_gap_s: Annotated[float, Meta(gt=0.0, le=60.0)] = 1.5  # a frame is held this long for the next fix
    max_accel_m_s2: Annotated[float, Meta(ge=0.0, le=100.0)] = 3.0  # acceleration when no sample shows it
    local_drift_m_per_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.05  # local frame drift since the anchor
    # The error model (icgt.geotag.bounds, docs/error-bounds.md): every bound is a 95 % bound.
    max_interpolation_gap_s: Annotated[float, Meta(gt=0.0, le=600.0)] = 10.0  # farther apart: not interpolated
    max_extrapolation_m: Annotated[float, Meta(ge=0.0, le=1000.0)] = 1.0  # a larger guess: no position (no_pose)
    unseen_accel_h_m_s2: Annotated[float, Meta(ge=0.0, le=100.0)] = 2.0  # acceleration change hidden in a gap
    unseen_accel_v_m_s2: Annotated[float, Meta(ge=0.0, le=100.0)] = 1.0
    unseen_rate_rad_s2: Annotated[float, Meta(ge=0.0, le=100.0)] = 0.5  # body-rate change hidden in a gap
    attitude_accuracy_deg: Annotated[float, Meta(ge=0.0, le=90.0)] = 1.0  # the autopilot's attitude, 95 %
    max_wait_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.5  # a frame waits this long for its later sample
    max_clock_uncertainty_s: Annotated[float, Meta(gt=0.0, le=1.0)] = 0.001  # a worse device->host bound flags it
    blur_limit_px: Annotated[float, Meta(gt=0.0)] = 1.0
    surface_normal_enu: tuple[float, float, float] | None = None  # the structure's face, if known
    origin: tuple[_Lat, _Lon, float] | None = None  # ENU origin lat, lon, alt MSL; else the first fix

    def __post_init__(self) -> None:
        if self.range_min_m >= self.range_max_m:
            raise ValueError(f"range_min_m ({self.range_min_m}) must be below range_max_m ({self.range_max_m})")
        if self.surface_normal_enu is not None and math.hypot(*self.surface_normal_enu) < 1e-6:
            raise ValueError("surface_normal_enu must not be the zero vector")

    @property
    def pixel_pitch_mm(self) -> float:
        return self.sensor_width_mm / self.image_width_px

    @property
    def focal_length_px(self) -> float:
        return self.focal_length_mm / self.pixel_pitch_mm


RENAMED: dict[str, tuple[str, float]] = {
    "range_stale_ms": ("range_stale_s", 1e-3),
    "max_wait_ms": ("max_wait_s", 1e-3),
    "max_clock_uncertainty_us": ("max_clock_uncertainty_s", 1e-6),
}
"""Old name -> (new name, factor: new value = old value x factor). Logs before issue 26 hold the old names."""

RETIRED: frozenset[str] = frozenset({"stale_pose_ms"})
"""Settings nothing reads any more (the error bound decides `stale_pose`): dropped from old logs."""


def migrate(data: Mapping[str, Any], renamed: Mapping[str, tuple[str, float]] = RENAMED) -> dict[str, Any]:
    """`data` with old names converted to the new ones (value times the factor) and retired settings left out.

    A value stored under both names (never written by a recorder) keeps the new one. A value that is not a
    number is passed on unconverted under the new name, so that reading it fails naming the setting rather
    than the setting falling back to its default."""
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key in RETIRED:
            continue
        if key in renamed:
            new, factor = renamed[key]
            if new not in data:
                numeric = isinstance(value, int | float) and not isinstance(value, bool)
                out[new] = value * factor if numeric else value
            continue
        out[key] = value
    return out


def renamed_message(key: str, value: Any, renamed: Mapping[str, tuple[str, float]] = RENAMED) -> str | None:
    """For a config file: what an old name is called now, with its value converted; None if `key` is current."""
    if key in RETIRED:
        return f"{key} is no longer used (the position error bound decides stale_pose): remove it"
    if key not in renamed:
        return None
    new, factor = renamed[key]
    shown = f" = {value * factor:.12g}" if isinstance(value, int | float) and not isinstance(value, bool) else ""
    return f"{key} was renamed {new} (seconds): write {new}{shown}"
