"""The gimbal's attitude as MAVLink Gimbal Protocol v2 reports it (GIMBAL_DEVICE_ATTITUDE_STATUS, id 285).

A gimbal device (its own component, MAV_COMP_ID_GIMBAL = 154, or the autopilot's mount driver on the
autopilot's component) broadcasts its attitude at a low regular rate. The quaternion rotates the gimbal's
device frame (x along the camera's pointing direction, y right, z down) into a frame whose roll and pitch are
always those of the horizon; its yaw is relative to north (earth frame) or to the vehicle's heading (vehicle
frame) as the flags say: GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME / _YAW_IN_VEHICLE_FRAME, and for older
devices that set neither, YAW_LOCK means earth frame (the message's definition in common.xml).

`gimbal_sample` turns a message into a `GimbalSample` stamped on the autopilot's boot clock: a device's own
``time_boot_ms`` is its own clock, not the autopilot's, so the synchroniser maps it onto the host's clock by the
lower envelope of its arrivals (`icgt.clocks.one_way`) and from there onto the autopilot's, unless the autopilot's
own component sent it. `earth_quaternion` gives the
device frame -> NED rotation, with the vehicle's yaw for a vehicle-frame report.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import q_from_euler_zyx, q_multiply

__all__ = ["GIMBAL_MESSAGE", "GimbalSample", "earth_quaternion", "gimbal_sample", "yaw_in_earth_frame"]

GIMBAL_MESSAGE = "GIMBAL_DEVICE_ATTITUDE_STATUS"
_EARTH = int(mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)
_VEHICLE = int(mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
_YAW_LOCK = int(mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK)


@dataclasses.dataclass(frozen=True, slots=True)
class GimbalSample:
    """One gimbal attitude: device frame -> horizon frame (yaw from north or from the vehicle's heading)."""

    boot_us: int  # on the autopilot's boot clock (see the module docstring)
    host_rx_ns: int
    q_wxyz: tuple[float, float, float, float]
    yaw_in_earth_frame: bool
    flags: int
    failure_flags: int
    component: int


def yaw_in_earth_frame(flags: int) -> bool:
    """Whether a report's yaw is from north (True) or from the vehicle's heading, by its flags."""
    if flags & _EARTH:
        return True
    if flags & _VEHICLE:
        return False
    return bool(flags & _YAW_LOCK)  # neither: the older rule (yaw lock = earth frame)


def gimbal_sample(msg: Any, boot_us: int, host_rx_ns: int) -> GimbalSample | None:
    """A GIMBAL_DEVICE_ATTITUDE_STATUS as a sample stamped ``boot_us``; None if its quaternion is not a rotation
    (NaN: a device that does not know its attitude)."""
    raw = tuple(float(c) for c in msg.q)
    if len(raw) != 4 or not all(math.isfinite(c) for c in raw):
        return None
    norm = math.sqrt(sum(c * c for c in raw))
    if not 0.5 < norm < 1.5:
        return None
    q = tuple(c / norm for c in raw)
    if q[0] < 0:  # one hemisphere, so neighbouring samples interpolate the short way
        q = tuple(-c for c in q)
    flags = int(msg.flags)
    return GimbalSample(
        boot_us,
        host_rx_ns,
        (q[0], q[1], q[2], q[3]),
        yaw_in_earth_frame(flags),
        flags,
        int(msg.failure_flags),
        int(msg.get_srcComponent()),
    )


def earth_quaternion(q_wxyz: Any, yaw_in_earth_frame: bool, vehicle_yaw_rad: float | None) -> Any | None:
    """Device frame -> NED: the report itself (earth frame), or the vehicle's yaw times it (vehicle frame:
    q_earth = q(yaw) q_vehicle, as common.xml gives it). None: a vehicle-frame report without the vehicle's yaw."""
    if yaw_in_earth_frame:
        return q_wxyz
    if vehicle_yaw_rad is None:
        return None
    return q_multiply(q_from_euler_zyx(0.0, 0.0, vehicle_yaw_rad), q_wxyz)
