"""The camera's attitude from its gimbal (`[camera] attitude_source = "gimbal"`, issue 29.3).

GIMBAL_DEVICE_ATTITUDE_STATUS (MAVLink Gimbal Protocol v2) packed and parsed by pymavlink, fed to the real
`Synchroniser` (its stamping onto the autopilot's clock) and to a real `Geotagger` (its use at mid-exposure).
Every expected direction is worked out by hand from the angles: the optical axis of a camera whose gimbal
points it at pitch p (positive up) and yaw y is (cos p cos y, cos p sin y, -sin p) in NED.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.geodesy import q_from_euler_zyx, q_rotate
from icgt.geotag.config import GeotagConfig
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.mavlink.gimbal import GimbalSample, gimbal_sample
from icgt.mavlink.link import MavlinkMessage
from icgt.mavlink.telemetry import TelemetryStore
from icgt.protocol.messages import Exposure
from icgt.sync import Synchroniser

AP = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
GIMBAL = mavlink2.MAVLink(None, srcSystem=1, srcComponent=mavlink2.MAV_COMP_ID_GIMBAL)
VEHICLE = mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME | mavlink2.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
EARTH = mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME | mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK

S = 1_000_000_000
DEV_TO_HOST_NS = 5 * S  # host_ns = device_us * 1000 + 5 s
HOST_TO_BOOT_US = 2_000_000  # autopilot boot_us = host_ns / 1000 - 2 s
MID_DEVICE_US = 10_045_000
MID_BOOT_US = MID_DEVICE_US + DEV_TO_HOST_NS // 1000 - HOST_TO_BOOT_US  # 13 045 000


def wire(codec: mavlink2.MAVLink, msg: mavlink2.MAVLink_message) -> mavlink2.MAVLink_message:
    out = mavlink2.MAVLink(None).parse_buffer(msg.pack(codec))
    assert out is not None and len(out) == 1
    return out[0]


def report(pitch_deg: float, yaw_deg: float, flags: int, boot_ms: int = 0) -> mavlink2.MAVLink_message:
    q = [float(c) for c in q_from_euler_zyx(0.0, math.radians(pitch_deg), math.radians(yaw_deg))]
    return wire(GIMBAL, GIMBAL.gimbal_device_attitude_status_encode(0, 0, boot_ms, flags, q, 0.0, 0.0, 0.0, 0))


def axis_ned(pitch_deg: float, yaw_deg: float) -> np.ndarray:
    p, y = math.radians(pitch_deg), math.radians(yaw_deg)
    return np.array([math.cos(p) * math.cos(y), math.cos(p) * math.sin(y), -math.sin(p)])


class FixedClocks:
    """Fixed offsets (device -> host 5 s, host -> autopilot -2 s) with small bounds; UTC unknown."""

    settled = True

    def device_to_host_ns(self, device_us: float) -> int:
        return round(device_us * 1000) + DEV_TO_HOST_NS

    def host_to_device_us(self, host_ns: int) -> float:
        return (host_ns - DEV_TO_HOST_NS) / 1000

    def uncertainty_ns(self, device_us: float) -> int:
        return 20_000

    def host_to_autopilot_us(self, host_ns: int) -> float:
        return host_ns / 1000 - HOST_TO_BOOT_US

    def method(self) -> str:
        return "timesync"

    def uncertainty_us(self, boot_us: float) -> float:
        return 300.0

    def utc_at(self, device_us: float, host_ns: int) -> None:
        return None


def frame_with(gimbal: list[tuple[int, mavlink2.MAVLink_message]], body_yaw_deg: float = 90.0) -> FrameRecord:
    """One exposure at mid boot 13.045 s, level body at ``body_yaw_deg``, the gimbal reports given (boot us)."""
    store = TelemetryStore()
    out: list[FrameRecord] = []
    clocks = FixedClocks()
    cfg = GeotagConfig(origin=(47.4, 8.5, 500.0), attitude_source="gimbal")
    gt = Geotagger(store, clocks, clocks, clocks, cfg, out.append)
    q_body = [float(c) for c in q_from_euler_zyx(0.0, 0.0, math.radians(body_yaw_deg))]
    fix = AP.gps_raw_int_encode(12_990_000, 3, 474_000_000, 85_000_000, 500_000, 80, 120, 0, 0, 14)
    store.ingest(MavlinkMessage(wire(AP, fix), 0))
    for boot_ms in (13_000, 13_100):
        store.ingest(MavlinkMessage(wire(AP, AP.attitude_quaternion_encode(boot_ms, *q_body, 0.0, 0.0, 0.0)), 0))
        store.ingest(
            MavlinkMessage(
                wire(AP, AP.global_position_int_encode(boot_ms, 474_000_000, 85_000_000, 500_000, 0, 0, 0, 0, 0)), 0
            )
        )
    for boot_us, msg in gimbal:
        sample = gimbal_sample(msg, boot_us, 0)
        assert sample is not None
        store.gimbal.push(sample)
    return expose_at_mid(gt, out)


def expose_at_mid(gt: Geotagger, out: list[FrameRecord]) -> FrameRecord:
    """One 10 ms exposure centred on MID_DEVICE_US, received 3 ms after its end, flushed: its frame record."""
    e = Exposure(
        image_index=1,
        camera_id=0,
        trigger_t_us=MID_DEVICE_US - 45_000,
        feedback_start_t_us=MID_DEVICE_US - 5_000,
        feedback_end_t_us=MID_DEVICE_US + 5_000,
        duration_us=10_000,
    )
    gt.add_exposure(e, (MID_DEVICE_US + 5_000) * 1000 + DEV_TO_HOST_NS + 3_000_000)
    gt.poll((MID_DEVICE_US + 5_000) * 1000 + DEV_TO_HOST_NS + 10 * S, flush=True)
    assert len(out) == 1
    return out[0]


def optical_axis(f: FrameRecord) -> np.ndarray:
    assert f.cam_qw is not None and f.cam_qx is not None and f.cam_qy is not None and f.cam_qz is not None
    return np.asarray(q_rotate(np.array([f.cam_qw, f.cam_qx, f.cam_qy, f.cam_qz]), np.array([0.0, 0.0, 1.0])))


def test_a_vehicle_frame_report_is_turned_by_the_body_yaw() -> None:
    """Body heading east (90 deg), gimbal pitched 30 deg up and yawed 0 from the nose: the camera looks east, up."""
    f = frame_with([(13_000_000, report(30.0, 0.0, VEHICLE)), (13_100_000, report(30.0, 0.0, VEHICLE))])
    assert FrameFlag.GIMBAL_STALE.value not in f.flags
    np.testing.assert_allclose(optical_axis(f), axis_ned(30.0, 90.0), atol=1e-9)
    assert f.yaw_deg is not None and abs(f.yaw_deg - 90.0) < 1e-6  # the body's own angles stay the body's


def test_an_earth_frame_report_is_taken_as_it_is() -> None:
    """Body heading east, gimbal locked on north and pitched 45 deg down: the camera looks north, down."""
    f = frame_with([(13_000_000, report(-45.0, 0.0, EARTH)), (13_100_000, report(-45.0, 0.0, EARTH))])
    np.testing.assert_allclose(optical_axis(f), axis_ned(-45.0, 0.0), atol=1e-9)


def test_the_gimbal_is_interpolated_at_mid_exposure() -> None:
    """Yaw 0 at 13.000 s, 20 deg at 13.100 s (earth frame): at mid (13.045 s) 9 deg."""
    f = frame_with([(13_000_000, report(0.0, 0.0, EARTH)), (13_100_000, report(0.0, 20.0, EARTH))])
    np.testing.assert_allclose(optical_axis(f), axis_ned(0.0, 9.0), atol=1e-9)


def test_a_silent_gimbal_stream_leaves_the_frame_without_camera_attitude() -> None:
    """The last report 1 s before mid and nothing after: flagged, no camera attitude, never the body's instead."""
    f = frame_with([(12_000_000, report(30.0, 0.0, VEHICLE))])
    assert FrameFlag.GIMBAL_STALE.value in f.flags
    assert f.cam_qw is None and f.incidence_deg is None
    assert f.body_qw is not None  # the body's attitude is there: it was not used for the camera
    assert f.lat_deg is not None  # the position does not depend on the gimbal


def test_reports_too_far_apart_are_stale_and_one_close_to_mid_is_held() -> None:
    far = frame_with([(12_700_000, report(0.0, 0.0, EARTH)), (13_400_000, report(0.0, 40.0, EARTH))])
    assert FrameFlag.GIMBAL_STALE.value in far.flags and far.cam_qw is None  # 0.7 s apart > 0.5 s
    held = frame_with([(13_020_000, report(0.0, 10.0, EARTH))])  # 25 ms before mid, nothing after
    assert FrameFlag.GIMBAL_STALE.value not in held.flags
    np.testing.assert_allclose(optical_axis(held), axis_ned(0.0, 10.0), atol=1e-9)


def test_a_report_without_a_rotation_is_not_a_sample() -> None:
    nan = wire(GIMBAL, GIMBAL.gimbal_device_attitude_status_encode(0, 0, 0, VEHICLE, [math.nan] * 4, 0, 0, 0, 0))
    assert gimbal_sample(nan, 0, 0) is None
    legacy = report(0.0, 0.0, mavlink2.GIMBAL_DEVICE_FLAGS_YAW_LOCK)  # neither frame flag: yaw lock = earth
    sample = gimbal_sample(legacy, 0, 0)
    assert isinstance(sample, GimbalSample) and sample.yaw_in_earth_frame


def test_the_synchroniser_stamps_a_gimbal_device_by_arrival_and_the_autopilots_mount_by_its_clock() -> None:
    sync = Synchroniser()
    boot_host_ns = 20 * S  # the autopilot booted at host 20 s
    sync.on_mavlink(wire(AP, AP.heartbeat_encode(2, 3, 0, 0, 4)), boot_host_ns)
    # the gimbal device booted 3 s before the autopilot: its clock reads 3 s more
    sync.on_mavlink(report(0.0, 0.0, VEHICLE, boot_ms=3_001), boot_host_ns + 2_000_000)  # no autopilot clock yet
    assert sync.counters()["gimbal_unstamped"] == 1
    for k in range(200):  # 20 s of ATTITUDE at 10 Hz, 1-4 ms late: the arrival clock maps the autopilot
        boot = 1_000 + 100 * k
        msg = wire(AP, AP.attitude_encode(boot, 0, 0, 0, 0, 0, 0))
        sync.on_mavlink(msg, boot_host_ns + int((boot + 1.0 + k % 4) * 1e6))
    # the gimbal device's own boot clock is not the autopilot's: mapped through its arrivals' lower envelope (a
    # report 40 ms late in a queue is placed when it was sent) and the autopilot clock
    for k in range(10):
        sent_ms = 14_000 + 100 * k
        late_ms = 40 if k == 9 else 1
        sync.on_mavlink(
            report(0.0, 0.0, VEHICLE, boot_ms=sent_ms + 3_000), boot_host_ns + (sent_ms + late_ms) * 1_000_000
        )
    # the autopilot's mount driver (its own component) reports on the autopilot's clock
    mount = AP.gimbal_device_attitude_status_encode(0, 0, 16_000, EARTH, [1.0, 0.0, 0.0, 0.0], 0, 0, 0, 0)
    sync.on_mavlink(wire(AP, mount), boot_host_ns + 17 * S)
    samples = sync.telemetry.gimbal.samples()
    assert [s.component for s in samples] == [mavlink2.MAV_COMP_ID_GIMBAL] * 10 + [1]
    assert abs(samples[-2].boot_us - 14_900_000) <= 5_000  # the late one: the arrival clock's floor, not +40 ms
    assert samples[-1].boot_us == 16_000_500  # the mount driver: the centre of its millisecond
    assert sync.counters()["gimbal_samples"] == 11
