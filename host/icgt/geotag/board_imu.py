"""The camera's attitude from the board's own BNO055, when the board rides on the gimbal with the camera.

``[camera] attitude_source = "board_imu"``. The BNO055's fusion output is its sensor axes -> its own world
frame: level by gravity (roll and pitch are absolute), its north the magnetometer's (NDOF mode) or wherever it
pointed at power-on (IMU mode, drifting with the gyro). Two rotations turn it into the camera's attitude:

    q_camera_ned = Rz(heading_offset) * q_bno * q_cam_board

* ``q_cam_board``: the camera's optical axes on the board, which the ``[camera]`` mount angles give in this mode
  (found from a calibration flight by `icgt.geotag.board_calibration`; docs/board-imu.md).
* ``heading_offset`` [rad]: true north minus the BNO's north, about NED's down axis.
  - ``board_imu_heading = "magnetic"``: a fixed ``board_imu_heading_offset_deg`` (the declination and the
    sensor's own heading error, both from the calibration flight). Steel under a bridge deck bends the field.
  - ``"autopilot"``: read off the autopilot's heading before each frame. A gimbal in follow mode turns the
    camera with the vehicle's yaw: once the vehicle's yaw rate is small the follow has settled, and the camera's
    right axis (horizontal on a gimbal that holds roll level, at any pitch) points at the vehicle's heading
    + 90 deg. Each instant of the window before mid gives one reading of the offset; their circular mean is the
    frame's. Its error is the gimbal's yaw-follow error plus the autopilot's own heading error; it follows an
    IMU-mode drift over the window's length.

Pure functions over the geotagger's buffers: the live recorder and the recompute get the same answer.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from icgt.geodesy import q_from_euler_zyx, q_multiply, q_rotate, q_slerp, q_to_euler_zyx
from icgt.mavlink.telemetry import AttitudeSample
from icgt.mavlink.telemetry_buffer import TelemetryBuffer
from icgt.protocol.messages import Imu

__all__ = ["HeadingWindow", "board_at", "board_in_ned", "heading_offset_rad", "right_axis_heading_rad"]

_MAX_ATTITUDE_GAP_US = 250_000  # autopilot attitude samples farther apart are not read for the heading


@dataclass(frozen=True)
class HeadingWindow:
    """How the autopilot's heading is read (``[camera] board_imu_*``): over ``window_s`` before mid, at
    ``points`` instants, each used when the vehicle's yaw rate there is at most ``max_yaw_rate_rad_s``; at least
    ``min_points`` of them, else no heading (the frame has no camera attitude)."""

    window_s: float
    points: int
    max_yaw_rate_rad_s: float
    min_points: int


def board_at(imu: TelemetryBuffer[Any], t_device_us: float, max_gap_us: float) -> np.ndarray | None:
    """The BNO055's quaternion (sensor -> its world, w x y z) at ``t_device_us``: a slerp between the IMU samples
    on either side, at most ``max_gap_us`` apart; None without two such samples (never a held sample: at a
    gimbal's nod rates a sample 10 ms old is tenths of a degree off)."""
    before, after = imu.bracket(int(t_device_us))
    if before is None or after is None:
        return None
    a, b = before.msg, after.msg
    if not isinstance(a, Imu) or not isinstance(b, Imu) or after.boot_us - before.boot_us > max_gap_us:
        return None
    qa = (a.quat_w, a.quat_x, a.quat_y, a.quat_z)
    qb = (b.quat_w, b.quat_x, b.quat_y, b.quat_z)
    if not (_unit(qa) and _unit(qb)):
        return None  # the BNO055 reports zeros before its fusion starts
    span = after.boot_us - before.boot_us
    f = 0.0 if span == 0 else (t_device_us - before.boot_us) / span
    return np.asarray(q_slerp(qa, qb, f), dtype=float)


def _unit(q: tuple[float, float, float, float]) -> bool:
    return abs(math.sqrt(sum(c * c for c in q)) - 1.0) < 0.05


def board_in_ned(q_bno: Any, heading_offset: float) -> np.ndarray:
    """The board's sensor axes -> NED: the BNO's attitude turned by ``heading_offset`` [rad] about down."""
    return np.asarray(q_multiply(q_from_euler_zyx(0.0, 0.0, heading_offset), q_bno), dtype=float)


def right_axis_heading_rad(q_sensor_world: Any, q_cam_board: Any) -> float:
    """The heading [rad, from north towards east] of the camera's right axis (optical x) at a board attitude."""
    right = q_rotate(q_multiply(q_sensor_world, q_cam_board), np.array([1.0, 0.0, 0.0]))
    return math.atan2(float(right[1]), float(right[0]))


def heading_offset_rad(
    imu: TelemetryBuffer[Any],
    attitude: TelemetryBuffer[AttitudeSample],
    mid_device_us: int,
    device_to_boot_us: Callable[[float], float | None],
    q_cam_board: Any,
    window: HeadingWindow,
    max_imu_gap_us: float,
) -> float | None:
    """True north minus the BNO's north [rad] from the autopilot's heading over the window before mid (module
    docstring), or None with fewer than ``window.min_points`` usable instants."""
    step_us = window.window_s * 1e6 / window.points
    sin_sum = cos_sum = 0.0
    used = 0
    for k in range(window.points):
        t_dev = mid_device_us - k * step_us
        q_bno = board_at(imu, t_dev, max_imu_gap_us)
        boot = device_to_boot_us(t_dev) if q_bno is not None else None
        yaw = _settled_yaw(attitude, boot, window.max_yaw_rate_rad_s) if boot is not None else None
        if q_bno is None or yaw is None:
            continue
        d = yaw + math.pi / 2.0 - right_axis_heading_rad(q_bno, q_cam_board)
        sin_sum += math.sin(d)
        cos_sum += math.cos(d)
        used += 1
    if used < window.min_points:
        return None
    return math.atan2(sin_sum, cos_sum)


def _settled_yaw(attitude: TelemetryBuffer[AttitudeSample], boot_us: float, max_rate: float) -> float | None:
    """The vehicle's heading [rad] at ``boot_us`` (slerp of its attitude samples), if it turns at most
    ``max_rate`` there (the body z rate at both samples: near level flight, the heading's rate)."""
    before, after = attitude.bracket(int(boot_us))
    if before is None or after is None or after.boot_us - before.boot_us > _MAX_ATTITUDE_GAP_US:
        return None
    if max(abs(before.yawspeed_rps), abs(after.yawspeed_rps)) > max_rate:
        return None
    span = after.boot_us - before.boot_us
    f = 0.0 if span == 0 else (boot_us - before.boot_us) / span
    return float(q_to_euler_zyx(q_slerp(before.q_wxyz, after.q_wxyz, f))[2])
