"""The geotagged frame record: everything the inspection pipeline needs about one exposure.

One record per exposure. Times are
given on the three clocks with their uncertainty; the pose is interpolated to mid-exposure;
quality flags say what to distrust. Written to MCAP on /frames (JSON, schema derived from this
class) and read back by the ingest tools.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Annotated

from icgt.field_doc import Doc


class PositionSource(enum.StrEnum):
    """Where the position came from, best first."""

    RTK_FIXED = "rtk_fixed"
    RTK_FLOAT = "rtk_float"
    GPS_3D = "gps_3d"  # the autopilot's fused estimate while GPS has a 3D fix
    LOCAL_POSITION = "local_position"  # LOCAL_POSITION_NED moved from the last GPS fix (GPS denied, or a gap)
    DEAD_RECKONED = "dead_reckoned"  # the last GPS sample moved by its own velocity (no later sample yet)
    VIO = "vio"  # a visual-odometry source; never written by this version (logs before 0.2 wrote it for local)
    NONE = "none"


class SensorSource(enum.StrEnum):
    """Where a frame's range or BNO055 attitude came from (FrameRecord.range_source, imu_source)."""

    SAMPLES = "samples"  # the RANGE / IMU samples the host holds around mid-exposure
    SNAPSHOT = "snapshot"  # the device's own snapshot in the EXPOSURE (protocol 2): the samples were gone
    NONE = "none"


class FrameFlag(enum.StrEnum):
    """Quality flags; a frame can carry several."""

    NO_FIX = "no_fix"  # no usable 3D position at exposure
    STALE_POSE = "stale_pose"  # what the samples do not show (gap, extrapolation) exceeds max_position_error_m
    POSE_EXTRAPOLATED = "pose_extrapolated"  # the later sample never came: held from the earlier one
    NO_ATTITUDE = "no_attitude"
    CLOCK_UNSYNCED = "clock_unsynced"  # device->host mapping unknown or its bound above the limit (1 ms)
    NO_UTC = "no_utc"
    RANGE_INVALID = "range_invalid"  # no LiDAR return near the exposure
    RANGE_OUT_OF_BAND = "range_out_of_band"  # outside the configured working distance
    RANGE_STALE = "range_stale"
    MOTION_BLUR = "motion_blur"  # predicted blur above the limit
    NO_FEEDBACK = "no_feedback"  # trigger time only (no hot-shoe line or the camera did not confirm)
    FEEDBACK_MISSING = "feedback_missing"  # the camera did not confirm this trigger: it may not exist
    UNSOLICITED = "unsolicited"  # an exposure nobody triggered (manual shot)
    IMU_UNCALIBRATED = "imu_uncalibrated"
    NO_POSE = "no_pose"  # the samples around it are too far apart to bound a position: none given (see the gaps)
    # Outages (issue 27): what a frame lacks because the device link was down when it was made.
    RESENT = "resent"  # the exposure came back through RESEND (the device resent it after an outage)
    RANGE_SAMPLES_LOST = "range_samples_lost"  # resent, and no range sample near mid came back: none to range it
    TELEMETRY_EXPIRED = "telemetry_expired"  # no pose: the telemetry around mid had left the host's buffers
    # The device's snapshot in the EXPOSURE stood in for samples the host no longer had (issue 27, protocol 2).
    RANGE_FROM_SNAPSHOT = "range_from_snapshot"  # no valid range sample near mid: the exposure's own snapshot
    IMU_FROM_SNAPSHOT = "imu_from_snapshot"  # the snapshot is nearer mid than any IMU sample held
    # [camera] attitude_source = "gimbal": no gimbal attitude around mid (its stream silent or too sparse), or a
    # vehicle-frame report without the body's yaw: the frame has no camera attitude (never the body's instead)
    GIMBAL_STALE = "gimbal_stale"
    # attitude_source = "board_imu": no two BNO055 samples around mid (board_imu_max_gap_s), or no heading for
    # it (the autopilot's heading not settled long enough in the window before mid): no camera attitude
    BOARD_IMU_STALE = "board_imu_stale"
    BOARD_IMU_NO_HEADING = "board_imu_no_heading"


POOR_POSE_FLAGS = (
    FrameFlag.NO_FIX,
    FrameFlag.NO_POSE,
    FrameFlag.TELEMETRY_EXPIRED,
    FrameFlag.STALE_POSE,
    FrameFlag.POSE_EXTRAPOLATED,
    FrameFlag.NO_ATTITUDE,
)
"""Flags of a frame whose pose is missing or not to be trusted: no position goes to a ground station
(CAMERA_IMAGE_CAPTURED) and the damage map does not place detections from it (unless asked)."""

OUTAGE_NO_POSE = FrameFlag.TELEMETRY_EXPIRED
"""The flag of a frame without a pose because of an outage (it came back later than telemetry is kept)."""
OUTAGE_NO_RANGE = FrameFlag.RANGE_SAMPLES_LOST
"""The flag of a frame without a range because of an outage (the device no longer held its range samples)."""


@dataclass(frozen=True, slots=True)
class FrameRecord:
    """One exposure, geotagged at mid-exposure."""

    frame_seq: Annotated[int, Doc("recorder's running count of frames in this log, from 1")]
    image_index: Annotated[int, Doc("device's trigger index (0 for an unsolicited exposure)")]
    camera_id: Annotated[int, Doc("camera port")]
    device_flags: Annotated[int, Doc("EXPOSURE.flags bitmask as the device sent it (protocol ExposureFlags)")]
    # --- time
    trigger_device_us: Annotated[int, Doc("shutter line asserted, device clock (0 if unsolicited)", unit="us")]
    start_device_us: Annotated[int, Doc("exposure start (hot-shoe edge, else trigger), device clock", unit="us")]
    mid_device_us: Annotated[int, Doc("mid-exposure, device clock", unit="us")]
    duration_us: Annotated[int, Doc("exposure duration from the feedback pulse (0 unknown)", unit="us")]
    mid_host_ns: Annotated[int, Doc("mid-exposure, host CLOCK_MONOTONIC", unit="ns")]
    mid_host_uncertainty_ns: Annotated[int, Doc("bound on the device->host mapping error at mid", unit="ns")]
    time_source: Annotated[str, Doc("what mid_utc is derived from: pps, autopilot_gps, host_realtime")]
    flags: Annotated[list[str], Doc("quality flags (FrameFlag values)")]
    position_source: Annotated[str, Doc("PositionSource value")]
    fix_type: Annotated[int, Doc("GPS_RAW_INT.fix_type of the last GPS sample before mid (0-1 none, 3 3D, 6 RTK)")]
    pose_gap_before_ms: Annotated[float, Doc("mid minus the earlier bracketing position sample", unit="ms")]
    pose_gap_after_ms: Annotated[float, Doc("later bracketing position sample minus mid", unit="ms")]
    mid_utc_us: Annotated[int | None, Doc("mid-exposure, UTC since the Unix epoch", unit="us")] = None
    mid_utc_uncertainty_us: Annotated[float | None, Doc("bound on the UTC error at mid", unit="us")] = None
    # --- position (WGS84, MSL altitude) and local ENU (origin in the log's metadata)
    lat_deg: Annotated[float | None, Doc("latitude WGS84", unit="deg")] = None
    lon_deg: Annotated[float | None, Doc("longitude WGS84", unit="deg")] = None
    alt_msl_m: Annotated[float | None, Doc("altitude above mean sea level", unit="m")] = None
    east_m: Annotated[float | None, Doc("camera position east of the ENU origin", unit="m")] = None
    north_m: Annotated[float | None, Doc("camera position north of the ENU origin", unit="m")] = None
    up_m: Annotated[float | None, Doc("camera position above the ENU origin", unit="m")] = None
    h_acc_m: Annotated[float | None, Doc("GPS horizontal accuracy", unit="m")] = None
    v_acc_m: Annotated[float | None, Doc("GPS vertical accuracy", unit="m")] = None
    satellites: Annotated[int | None, Doc("satellites visible")] = None
    # --- attitude (vehicle body -> NED, and the camera after the mounting rotation)
    body_qw: Annotated[float | None, Doc("vehicle attitude quaternion w (body->NED)")] = None
    body_qx: Annotated[float | None, Doc("vehicle attitude quaternion x")] = None
    body_qy: Annotated[float | None, Doc("vehicle attitude quaternion y")] = None
    body_qz: Annotated[float | None, Doc("vehicle attitude quaternion z")] = None
    roll_deg: Annotated[float | None, Doc("vehicle roll", unit="deg")] = None
    pitch_deg: Annotated[float | None, Doc("vehicle pitch", unit="deg")] = None
    yaw_deg: Annotated[float | None, Doc("vehicle yaw, clockwise from north", unit="deg")] = None
    cam_qw: Annotated[
        float | None, Doc("camera attitude quaternion w (camera->NED; camera x right, y down, z forward)")
    ] = None
    cam_qx: Annotated[float | None, Doc("camera attitude quaternion x")] = None
    cam_qy: Annotated[float | None, Doc("camera attitude quaternion y")] = None
    cam_qz: Annotated[float | None, Doc("camera attitude quaternion z")] = None
    # --- BNO055 at exposure
    imu_qw: Annotated[float | None, Doc("BNO055 orientation quaternion w (its fusion frame)")] = None
    imu_qx: Annotated[float | None, Doc("BNO055 quaternion x")] = None
    imu_qy: Annotated[float | None, Doc("BNO055 quaternion y")] = None
    imu_qz: Annotated[float | None, Doc("BNO055 quaternion z")] = None
    imu_gyro_rad_s: Annotated[float | None, Doc("BNO055 angular rate magnitude at exposure", unit="rad/s")] = None
    imu_calib_sys: Annotated[int | None, Doc("BNO055 system calibration 0..3")] = None
    imu_calib_gyr: Annotated[int | None, Doc("BNO055 gyroscope calibration 0..3")] = None
    imu_calib_acc: Annotated[int | None, Doc("BNO055 accelerometer calibration 0..3")] = None
    imu_calib_mag: Annotated[int | None, Doc("BNO055 magnetometer calibration 0..3")] = None
    imu_age_ms: Annotated[
        float | None, Doc("mid minus the nearest IMU sample time (from the snapshot: its age, >= 0)", unit="ms")
    ] = None
    imu_source: Annotated[str, Doc("SensorSource of the BNO055 fields: samples, snapshot or none")] = "none"
    # --- LiDAR at exposure
    range_m: Annotated[float | None, Doc("LiDAR distance at mid-exposure (interpolated)", unit="m")] = None
    range_age_ms: Annotated[float | None, Doc("mid minus the nearest valid range acquisition", unit="ms")] = None
    range_valid: Annotated[bool, Doc("a valid LiDAR return bracketed the exposure")] = False
    range_source: Annotated[str, Doc("SensorSource of range_m: samples, snapshot or none")] = "none"
    # --- derived
    scale_mm_per_px: Annotated[float | None, Doc("ground sample distance at the image centre", unit="mm/px")] = None
    incidence_deg: Annotated[float | None, Doc("angle between optical axis and surface normal", unit="deg")] = None
    blur_px: Annotated[float | None, Doc("predicted motion blur (rotation and translation)", unit="px")] = None
    position_error_bound_m: Annotated[
        float | None,
        Doc("95 % bound on the camera position error, 3D: hypot of the horizontal and vertical bounds", unit="m"),
    ] = None
    horizontal_error_bound_m: Annotated[
        float | None,
        Doc("95 % bound on the horizontal error: source accuracy, gap, clock, lever arm", unit="m"),
    ] = None
    vertical_error_bound_m: Annotated[float | None, Doc("95 % bound on the vertical error", unit="m")] = None
    attitude_error_bound_deg: Annotated[float | None, Doc("95 % bound on the attitude error", unit="deg")] = None
    # --- provenance
    autopilot_clock: Annotated[
        str, Doc("how mid-exposure was put on the autopilot's clock: timesync, arrival (one-way) or none")
    ] = "none"
    autopilot_clock_uncertainty_us: Annotated[
        float | None, Doc("bound on the host->autopilot clock mapping error at mid", unit="us")
    ] = None
    emitted_host_ns: Annotated[
        int | None, Doc("host CLOCK_MONOTONIC when the synchroniser emitted the frame (its poll)", unit="ns")
    ] = None
