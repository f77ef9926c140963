"""The sensor snapshot an EXPOSURE carries (protocol version 2), in the host's units.

The device records with each exposure the LiDAR range and the BNO055 orientation and rate at mid-exposure,
from the samples it read around it (firmware/lib/core/snapshot.hpp, protocol/SPEC.md). The snapshot is kept
in the device's event history with the exposure, so it comes back through RESEND long after the samples
themselves are gone; the geotagger uses it when the samples around mid are not in its buffers.
"""

from __future__ import annotations

from dataclasses import dataclass

from icgt.geotag.record import SensorSource
from icgt.protocol.messages import Exposure, SnapshotFlags

__all__ = [
    "QUAT_PER_LSB",
    "RAD_S_PER_LSB",
    "SNAPSHOT_AGE_SATURATED_US",
    "ImuAtMid",
    "snapshot_imu",
    "snapshot_range_valid",
]

_RANGE = int(SnapshotFlags.RANGE_VALID)
_IMU = int(SnapshotFlags.IMU_VALID)
SNAPSHOT_AGE_SATURATED_US = 0xFFFF
"""EXPOSURE.range_age_us / imu_age_us at this value mean 65.535 ms or older (protocol SnapshotFlags)."""
QUAT_PER_LSB = 1.0 / 16384.0  # EXPOSURE.quat_*_q14
RAD_S_PER_LSB = 1.0 / 900.0  # EXPOSURE.gyro_*_rad900


@dataclass(frozen=True, slots=True)
class ImuAtMid:
    """The BNO055 at mid-exposure: from the nearest IMU sample held, or from the exposure's snapshot."""

    q_wxyz: tuple[float, float, float, float]
    gyro_rad_s: tuple[float, float, float]
    calib_stat: int
    age_ms: float  # mid minus the sample (signed) or the snapshot's age (>= 0)
    source: SensorSource


def snapshot_imu(e: Exposure) -> ImuAtMid | None:
    """The exposure's own BNO055 snapshot (protocol 2), or None when it holds none."""
    if not e.snapshot_flags & _IMU:
        return None
    k = QUAT_PER_LSB
    q = (e.quat_w_q14 * k, e.quat_x_q14 * k, e.quat_y_q14 * k, e.quat_z_q14 * k)
    w = (e.gyro_x_rad900 * RAD_S_PER_LSB, e.gyro_y_rad900 * RAD_S_PER_LSB, e.gyro_z_rad900 * RAD_S_PER_LSB)
    return ImuAtMid(q, w, e.imu_calib_stat, e.imu_age_us / 1000.0, SensorSource.SNAPSHOT)


def snapshot_range_valid(e: Exposure) -> bool:
    """The exposure's snapshot holds a range (range_mm, range_age_us)."""
    return bool(e.snapshot_flags & _RANGE)
