"""The gimbal's attitude at mid-exposure, from its GIMBAL_DEVICE_ATTITUDE_STATUS reports (`icgt.mavlink.gimbal`).

Interpolated like the body's attitude (a slerp between the reports on either side of mid), with its own
freshness rule: the two reports at most ``max_gap_s`` apart, else the nearest one if it is within
``max_hold_s`` of mid. A vehicle-frame report (yaw from the vehicle's heading) is turned by the body's yaw at
mid. Outside the rule there is no gimbal attitude: the caller flags the frame (`gimbal_stale`) and gives it no
camera attitude, never the body's in its place (a gimbal that points up under a deck is 90 deg from it).
"""

from __future__ import annotations

import numpy as np

from icgt.geodesy import q_slerp
from icgt.mavlink.gimbal import GimbalSample, earth_quaternion
from icgt.mavlink.telemetry_buffer import TelemetryBuffer

__all__ = ["gimbal_at"]


def gimbal_at(
    reports: TelemetryBuffer[GimbalSample],
    mid_boot_us: float,
    body_yaw_rad: float | None,
    max_gap_s: float,
    max_hold_s: float,
) -> np.ndarray | None:
    """Device frame -> NED (w, x, y, z) at ``mid_boot_us`` (autopilot boot clock [us]); None by the rule above."""
    before, after = reports.bracket(int(mid_boot_us))
    q_report: object = None
    if (
        before is not None
        and after is not None
        and after.boot_us - before.boot_us <= max_gap_s * 1e6
        and before.yaw_in_earth_frame == after.yaw_in_earth_frame
    ):
        span = after.boot_us - before.boot_us
        f = 0.0 if span == 0 else (mid_boot_us - before.boot_us) / span
        q_report, earth = q_slerp(before.q_wxyz, after.q_wxyz, f), before.yaw_in_earth_frame
    else:
        near = [s for s in (before, after) if s is not None and abs(s.boot_us - mid_boot_us) <= max_hold_s * 1e6]
        if not near:
            return None
        nearest = min(near, key=lambda s: abs(s.boot_us - mid_boot_us))
        q_report, earth = nearest.q_wxyz, nearest.yaw_in_earth_frame
    q = earth_quaternion(q_report, earth, body_yaw_rad)
    return None if q is None else np.asarray(q, dtype=float)
