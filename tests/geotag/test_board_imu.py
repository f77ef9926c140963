"""The camera's attitude from the board's own BNO055 on the gimbal (`[camera] attitude_source = "board_imu"`).

A real `Geotagger` fed IMU samples (the protocol's IMU message) and ATTITUDE_QUATERNION packed and parsed by
pymavlink. The board's true attitude is built from the camera's by hand: the camera looks at pitch p (positive up)
and yaw y, so its optical axis is (cos p cos y, cos p sin y, -sin p) in NED; the board sits at the mount angles
on the camera's axes, and its BNO055 reports it in a world frame whose north is ``BNO_OFF_DEG`` from true north.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from test_gimbal import DEV_TO_HOST_NS, HOST_TO_BOOT_US, MID_DEVICE_US, FixedClocks, expose_at_mid, optical_axis

from icgt.geodesy import q_conjugate, q_from_euler_zyx, q_multiply
from icgt.geotag.board_imu import right_axis_heading_rad
from icgt.geotag.config import GeotagConfig
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.mavlink.link import MavlinkMessage
from icgt.mavlink.telemetry import TelemetryStore
from icgt.pose import Q_OPTICAL_TO_FRD, camera_to_body_quaternion
from icgt.protocol.messages import Imu

AP = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
DEVICE_TO_BOOT_US = DEV_TO_HOST_NS // 1000 - HOST_TO_BOOT_US  # 3 s
BNO_OFF_DEG = 20.0  # true north minus the BNO's north
MOUNT = {"mount_roll_deg": 2.0, "mount_pitch_deg": -1.0, "mount_yaw_deg": 4.0}  # the camera on the board
BODY_YAW_DEG = 90.0  # the vehicle heads east; the gimbal follows it


def wire(msg: Any) -> Any:
    out = mavlink2.MAVLink(None).parse_buffer(msg.pack(AP))
    assert out is not None and len(out) == 1
    return out[0]


def camera_frd(pitch_deg: float, yaw_deg: float) -> np.ndarray:
    return np.asarray(q_from_euler_zyx(0.0, math.radians(pitch_deg), math.radians(yaw_deg)))


def bno_report(pitch_deg: float, yaw_deg: float, bno_off_deg: float = BNO_OFF_DEG) -> np.ndarray:
    """What the BNO055 reports for a camera looking at (pitch, yaw): the board's attitude in its own world."""
    q_cam_board = q_from_euler_zyx(
        *(math.radians(MOUNT[k]) for k in ("mount_roll_deg", "mount_pitch_deg", "mount_yaw_deg"))
    )
    q_board = q_multiply(camera_frd(pitch_deg, yaw_deg), q_conjugate(q_cam_board))
    return np.asarray(q_multiply(q_from_euler_zyx(0.0, 0.0, -math.radians(bno_off_deg)), q_board))


def axis_ned(pitch_deg: float, yaw_deg: float) -> np.ndarray:
    p, y = math.radians(pitch_deg), math.radians(yaw_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)])


def frame_with(bno: Callable[[int], np.ndarray | None], *, yawspeed_rps: float = 0.0, **config: Any) -> FrameRecord:
    """One exposure at mid device 10.045 s; IMU samples at 100 Hz from device 0 to 10.2 s where ``bno`` gives a
    quaternion; a level body heading east at 20 Hz over the same span."""
    store = TelemetryStore()
    out: list[FrameRecord] = []
    clocks = FixedClocks()
    cfg = GeotagConfig(origin=(47.4, 8.5, 500.0), attitude_source="board_imu", **MOUNT, **config)
    gt = Geotagger(store, clocks, clocks, clocks, cfg, out.append)
    q_body = [float(c) for c in q_from_euler_zyx(0.0, 0.0, math.radians(BODY_YAW_DEG))]
    for k in range(0, 205):
        boot_ms = DEVICE_TO_BOOT_US // 1000 + 50 * k
        fix = AP.gps_raw_int_encode(boot_ms * 1000, 3, 474_000_000, 85_000_000, 500_000, 80, 120, 0, 0, 14)
        store.ingest(MavlinkMessage(wire(fix), 0))
        store.ingest(MavlinkMessage(wire(AP.attitude_quaternion_encode(boot_ms, *q_body, 0.0, 0.0, yawspeed_rps)), 0))
        pos = AP.global_position_int_encode(boot_ms, 474_000_000, 85_000_000, 500_000, 0, 0, 0, 0, 0)
        store.ingest(MavlinkMessage(wire(pos), 0))
    for t_us in range(0, 10_200_001, 10_000):
        q = bno(t_us)
        if q is not None:
            w, x, y, z = (float(c) for c in q)
            gt.add_imu(
                Imu(
                    read_start_t_us=t_us - 200,
                    read_end_t_us=t_us + 200,
                    quat_w=w,
                    quat_x=x,
                    quat_y=y,
                    quat_z=z,
                    calib_stat=0xFF,
                )
            )
    return expose_at_mid(gt, out)


def steady(pitch_deg: float) -> Callable[[int], np.ndarray]:
    """A gimbal following the vehicle's heading (east), the camera pitched up, the board as mounted."""
    return lambda _t: bno_report(pitch_deg, BODY_YAW_DEG)


@pytest.mark.parametrize("pitch_deg", [0.0, 45.0, 75.0, 89.0])
def test_the_camera_looks_where_the_board_says_with_its_north_read_off_the_autopilot(pitch_deg: float) -> None:
    f = frame_with(steady(pitch_deg))
    assert not {FrameFlag.BOARD_IMU_STALE.value, FrameFlag.BOARD_IMU_NO_HEADING.value} & set(f.flags)
    np.testing.assert_allclose(optical_axis(f), axis_ned(pitch_deg, BODY_YAW_DEG), atol=1e-6)


def test_the_board_is_interpolated_at_mid_exposure() -> None:
    """The camera nods at 20 deg/s: mid is 4.5 ms after a sample, a held sample would be 0.09 deg off."""
    f = frame_with(lambda t: bno_report(60.0 + 20.0 * (t - MID_DEVICE_US) / 1e6, BODY_YAW_DEG))
    np.testing.assert_allclose(optical_axis(f), axis_ned(60.0, BODY_YAW_DEG), atol=1e-5)


def test_a_magnetic_north_takes_the_configured_offset_and_not_the_autopilot() -> None:
    f = frame_with(steady(30.0), board_imu_heading="magnetic", board_imu_heading_offset_deg=BNO_OFF_DEG)
    np.testing.assert_allclose(optical_axis(f), axis_ned(30.0, BODY_YAW_DEG), atol=1e-6)
    off = frame_with(steady(30.0), board_imu_heading="magnetic", board_imu_heading_offset_deg=0.0)
    np.testing.assert_allclose(optical_axis(off), axis_ned(30.0, BODY_YAW_DEG - BNO_OFF_DEG), atol=1e-6)


def test_without_board_samples_around_mid_the_frame_has_no_camera_attitude() -> None:
    f = frame_with(lambda t: None if t > MID_DEVICE_US - 60_000 else bno_report(30.0, BODY_YAW_DEG))
    assert FrameFlag.BOARD_IMU_STALE.value in f.flags
    assert f.cam_qw is None and f.incidence_deg is None  # never the body's attitude in its place
    assert f.body_qw is not None and f.lat_deg is not None  # the rest of the pose is there


def test_while_the_vehicle_turns_the_whole_window_there_is_no_north_for_the_board() -> None:
    """A yaw rate above board_imu_max_yaw_rate_deg_s everywhere: the gimbal's follow has not settled anywhere."""
    f = frame_with(steady(30.0), yawspeed_rps=math.radians(10.0))
    assert FrameFlag.BOARD_IMU_NO_HEADING.value in f.flags
    assert f.cam_qw is None


def test_the_right_axis_heading_holds_at_any_pitch_of_a_roll_level_camera() -> None:
    q_cam_board = camera_to_body_quaternion(
        type("M", (), {"mount_roll_deg": 0.0, "mount_pitch_deg": 0.0, "mount_yaw_deg": 0.0})()
    )
    assert np.allclose(q_cam_board, Q_OPTICAL_TO_FRD)
    for pitch in (-80.0, 0.0, 60.0, 89.9):
        got = right_axis_heading_rad(camera_frd(pitch, 30.0), q_cam_board)
        assert math.degrees(got) == pytest.approx(120.0, abs=1e-6)
