"""The frame record in parts: each group of `FrameRecord` fields built by one small function.

The geotagger (`icgt.geotag.geotagger`) decides what a frame has (its position estimate, attitude, IMU
sample, range) and the camera rule (`icgt.pose.camera_fields`) turns the body pose into the camera's;
these functions only spell the result out as the record's flat fields (names and units as in
`icgt.geotag.record`), so the MCAP schema and every export keep one flat view.
"""

from __future__ import annotations

import math
from typing import Any

from icgt.geotag.position import PoseGap, PositionEstimate
from icgt.geotag.record import PositionSource, SensorSource
from icgt.geotag.snapshot import ImuAtMid
from icgt.mavlink.telemetry import GpsSample
from icgt.pose import CameraFields
from icgt.protocol.messages import Exposure

__all__ = [
    "attitude_fields",
    "autopilot_clock_fields",
    "exposure_fields",
    "imu_fields",
    "position_fields",
    "position_source",
    "range_fields",
    "utc_fields",
]

Fields = dict[str, Any]


def exposure_fields(frame_seq: int, e: Exposure, start_device_us: int, mid_device_us: int) -> Fields:
    """The exposure as the device reported it, on the device clock [us]."""
    return {
        "frame_seq": frame_seq,
        "image_index": e.image_index,
        "camera_id": e.camera_id,
        "device_flags": e.flags,
        "trigger_device_us": e.trigger_t_us,
        "start_device_us": start_device_us,
        "mid_device_us": mid_device_us,
        "duration_us": e.duration_us,
    }


def utc_fields(utc: tuple[int, float, str] | None) -> Fields:
    """Mid-exposure in UTC [us since the Unix epoch] and its bound [us]."""
    return {"mid_utc_us": utc[0] if utc else None, "mid_utc_uncertainty_us": utc[1] if utc else None}


def position_source(pos: PositionEstimate | None) -> PositionSource:
    """The frame's position source, named as it is: GPS (by its fix), the local position, or dead reckoning."""
    if pos is None:
        return PositionSource.NONE
    if pos.rule == "local":
        return PositionSource.LOCAL_POSITION
    if pos.rule == "dead_reckoning":
        return PositionSource.DEAD_RECKONED
    gps = pos.gps
    if gps is not None and gps.fix_type == 6:
        return PositionSource.RTK_FIXED
    if gps is not None and gps.fix_type == 5:
        return PositionSource.RTK_FLOAT
    return PositionSource.GPS_3D


def position_fields(
    placed: PositionEstimate | PoseGap | None,
    pos: PositionEstimate | None,
    gps: GpsSample | None,
    bound_h_v: tuple[float, float] | None,
    geodetic: tuple[float, float, float] | None,
    cam: CameraFields,
) -> Fields:
    """Where the camera was: its source, the GPS receiver's own figures, the gaps, the 95 % bounds, WGS84 and ENU."""
    lat, lon, alt = geodetic if geodetic is not None else (None, None, None)
    return {
        "position_source": position_source(pos).value,
        "fix_type": gps.fix_type if gps is not None else 0,
        "pose_gap_before_ms": placed.gap_before_ms if placed else math.inf,
        "pose_gap_after_ms": placed.gap_after_ms if placed else math.inf,
        "position_error_bound_m": math.hypot(*bound_h_v) if bound_h_v else None,
        "horizontal_error_bound_m": bound_h_v[0] if bound_h_v else None,
        "vertical_error_bound_m": bound_h_v[1] if bound_h_v else None,
        "lat_deg": lat,
        "lon_deg": lon,
        "alt_msl_m": alt,
        "east_m": cam.east_m,
        "north_m": cam.north_m,
        "up_m": cam.up_m,
        "h_acc_m": gps.h_acc_m if gps is not None else None,
        "v_acc_m": gps.v_acc_m if gps is not None else None,
        "satellites": gps.satellites if gps is not None else None,
    }


def attitude_fields(cam: CameraFields) -> Fields:
    """The body's attitude (FRD -> NED), its Euler angles [deg] and the camera's (optical -> NED)."""
    body, q = cam.body_q, cam.cam_q
    return {
        "body_qw": float(body[0]) if body is not None else None,
        "body_qx": float(body[1]) if body is not None else None,
        "body_qy": float(body[2]) if body is not None else None,
        "body_qz": float(body[3]) if body is not None else None,
        "roll_deg": cam.roll_deg,
        "pitch_deg": cam.pitch_deg,
        "yaw_deg": cam.yaw_deg,
        "cam_qw": float(q[0]) if q is not None else None,
        "cam_qx": float(q[1]) if q is not None else None,
        "cam_qy": float(q[2]) if q is not None else None,
        "cam_qz": float(q[3]) if q is not None else None,
    }


def imu_fields(imu: ImuAtMid | None) -> Fields:
    """The BNO055 at mid-exposure: orientation, rate magnitude [rad/s], calibration levels, age [ms]."""
    if imu is None:
        return {"imu_source": SensorSource.NONE.value}
    calib = imu.calib_stat
    return {
        "imu_qw": imu.q_wxyz[0],
        "imu_qx": imu.q_wxyz[1],
        "imu_qy": imu.q_wxyz[2],
        "imu_qz": imu.q_wxyz[3],
        "imu_gyro_rad_s": math.sqrt(sum(w * w for w in imu.gyro_rad_s)),
        "imu_calib_sys": (calib >> 6) & 3,
        "imu_calib_gyr": (calib >> 4) & 3,
        "imu_calib_acc": (calib >> 2) & 3,
        "imu_calib_mag": calib & 3,
        "imu_age_ms": imu.age_ms,
        "imu_source": imu.source.value,
    }


def range_fields(rng: tuple[float | None, float | None, SensorSource] | None, cam: CameraFields) -> Fields:
    """The LiDAR at mid-exposure [m], its age [ms], and what it gives the image: scale [mm/px], incidence [deg]."""
    return {
        "range_m": rng[0] if rng else None,
        "range_age_ms": rng[1] if rng else None,
        "range_valid": rng is not None and rng[0] is not None,
        "range_source": rng[2].value if rng else SensorSource.NONE.value,
        "scale_mm_per_px": cam.scale_mm_per_px,
        "incidence_deg": cam.incidence_deg,
    }


def autopilot_clock_fields(method: str, uncertainty_us: float | None) -> Fields:
    """How mid-exposure was put on the autopilot's clock, and the bound [us]."""
    return {"autopilot_clock": method, "autopilot_clock_uncertainty_us": uncertainty_us}
