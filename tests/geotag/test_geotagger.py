"""Unit tests of `icgt.geotag.Geotagger`, constructed directly.

The telemetry is a real `TelemetryStore` fed MAVLink messages that pymavlink encoded, packed and
parsed back (what the MAVLink link hands over); the clocks are fakes with known offsets, so every
expected time, position and attitude below follows from the inputs by hand:

* device clock:    host_ns    = device_us * 1000 + 5 s
* autopilot clock: boot_us    = host_ns / 1000 - 2 s, i.e. autopilot boot_us = device_us + 3 s
* UTC:             utc_us     = device_us + UTC_OFFSET_US ("pps")

Positions are checked against `LocalFrame` (the project's WGS84 ENU, tested in tests/sim) and
against the small-angle metres-per-degree figure, so a swapped axis cannot pass; rotations are
checked by where they send the body and camera axes, worked out by hand.
"""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.clocks.device_clock import ClockNotSyncedError
from icgt.geodesy import LocalFrame
from icgt.geotag.bounds import AXIS_95, RADIAL_95
from icgt.geotag.config import GeotagConfig
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.mavlink.link import MavlinkMessage
from icgt.mavlink.telemetry import TelemetryStore
from icgt.protocol.messages import Exposure, ExposureFlags, Imu, Range, RangeFlags

MAV = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)

DEV_TO_HOST_NS = 5_000_000_000
HOST_TO_BOOT_US = 2_000_000
DEV_TO_BOOT_US = DEV_TO_HOST_NS // 1000 - HOST_TO_BOOT_US  # 3 s
UTC_OFFSET_US = 1_780_000_000_000_000

LAT_E7, LON_E7, ALT_MM = 473_977_419, 85_455_938, 488_000
ORIGIN = (LAT_E7 * 1e-7, LON_E7 * 1e-7, ALT_MM * 1e-3)  # exactly what the telemetry makes of sample A

# One exposure used throughout: trigger, then a 10 ms hot-shoe pulse 40 ms later.
TRIGGER_US = 10_000_000
START_US = 10_040_000
DURATION_US = 10_000
MID_US = START_US + DURATION_US // 2
CLOCK_S = 20_000e-9 + 300e-6  # the fake clocks' bounds: device -> host 20 us, host -> autopilot 300 us
MID_BOOT_MS = (MID_US + DEV_TO_BOOT_US) / 1000  # 13045.0


# --------------------------------------------------------------------------- fakes
class FakeDeviceClock:
    """DeviceClock: a fixed offset, a fixed bound; raises like the real filter before any exchange."""

    def __init__(self, *, synced: bool = True, uncertainty_ns: int = 20_000) -> None:
        self.synced = synced
        self.unc = uncertainty_ns

    def device_to_host_ns(self, device_us: float) -> int:
        if not self.synced:
            raise ClockNotSyncedError("no exchange yet")
        return round(device_us * 1000) + DEV_TO_HOST_NS

    def host_to_device_us(self, host_ns: int) -> float:
        if not self.synced:
            raise ClockNotSyncedError("no exchange yet")
        return (host_ns - DEV_TO_HOST_NS) / 1000

    def uncertainty_ns(self, device_us: float) -> int:
        if not self.synced:
            raise ClockNotSyncedError("no exchange yet")
        return self.unc

    @property
    def settled(self) -> bool:
        return self.synced


class FakeAutopilotClock:
    def __init__(self, *, synced: bool = True) -> None:
        self.synced = synced

    def host_to_autopilot_us(self, host_ns: int) -> float | None:
        return host_ns / 1000 - HOST_TO_BOOT_US if self.synced else None

    def method(self) -> str:
        return "timesync" if self.synced else "none"

    def uncertainty_us(self, boot_us: float) -> float | None:
        return 300.0 if self.synced else None


class FakeUtc:
    def __init__(self, *, available: bool = True) -> None:
        self.available = available

    def utc_at(self, device_us: float, host_ns: int) -> tuple[int, float, str] | None:
        return (int(device_us) + UTC_OFFSET_US, 2.5, "pps") if self.available else None


def host_ns(device_us: int) -> int:
    return device_us * 1000 + DEV_TO_HOST_NS


def wire(msg):
    """Pack and parse again, as the MAVLink link hands it over."""
    out = mavlink2.MAVLink(None).parse_buffer(msg.pack(MAV))
    assert out is not None and len(out) == 1
    return out[0]


def yaw_q(yaw_deg: float) -> tuple[float, float, float, float]:
    h = math.radians(yaw_deg) / 2
    return (math.cos(h), 0.0, 0.0, math.sin(h))


def rotate(q, v):
    """v rotated by the unit quaternion q (w, x, y, z): q v q*, written out (Rodrigues form)."""
    w, x, y, z = q
    u = np.array([x, y, z])
    v = np.asarray(v, dtype=float)
    return v + 2 * w * np.cross(u, v) + 2 * np.cross(u, np.cross(u, v))


class Rig:
    """A Geotagger with a real TelemetryStore and the fake clocks; collects what it emits."""

    def __init__(self, config: GeotagConfig | None = None, **clocks) -> None:
        self.store = TelemetryStore()
        self.frames: list[FrameRecord] = []
        self.dev = clocks.get("device_clock", FakeDeviceClock())
        self.gt = Geotagger(
            self.store,
            self.dev,
            clocks.get("autopilot_clock", FakeAutopilotClock()),
            clocks.get("utc", FakeUtc()),
            config if config is not None else GeotagConfig(origin=ORIGIN),
            self.frames.append,
        )

    def mav(self, msg) -> None:
        assert self.store.ingest(MavlinkMessage(wire(msg), 0)) is not None

    def gps(self, boot_ms: float, fix_type: int = 3) -> None:
        self.mav(
            MAV.gps_raw_int_encode(
                int(boot_ms * 1000), fix_type, LAT_E7, LON_E7, ALT_MM, 80, 120, 0, 0, 14, h_acc=900, v_acc=1500
            )
        )

    def position(self, boot_ms: int, dlat_e7: int = 0, dlon_e7: int = 0, dalt_mm: int = 0, v_ned=(0, 0, 0)) -> None:
        vn, ve, vd = (round(c * 100) for c in v_ned)
        self.mav(
            MAV.global_position_int_encode(
                boot_ms, LAT_E7 + dlat_e7, LON_E7 + dlon_e7, ALT_MM + dalt_mm, 20_000 + dalt_mm, vn, ve, vd, 0
            )
        )

    def attitude(self, boot_ms: int, q=(1.0, 0.0, 0.0, 0.0)) -> None:
        self.mav(MAV.attitude_quaternion_encode(boot_ms, *q, 0.0, 0.0, 0.0))

    def pose(self, boot_ms: int, q=(1.0, 0.0, 0.0, 0.0), **position) -> None:
        self.position(boot_ms, **position)
        self.attitude(boot_ms, q)

    def expose(self, *, start_us: int = START_US, duration_us: int = DURATION_US, index: int = 1, **kw) -> None:
        fields = {
            "image_index": index,
            "camera_id": 0,
            "trigger_t_us": start_us - (START_US - TRIGGER_US),
            "feedback_start_t_us": start_us,
            "feedback_end_t_us": start_us + duration_us if duration_us else 0,
            "duration_us": duration_us,
        }
        fields.update(kw)
        exposure = Exposure(**fields)
        self.gt.add_exposure(exposure, host_ns(start_us + duration_us) + 3_000_000)

    def poll(self, now_ns: int, *, flush: bool = False) -> list[FrameRecord]:
        before = len(self.frames)
        n = self.gt.poll(now_ns, flush=flush)
        assert n == len(self.frames) - before
        return self.frames[before:]

    def one(self) -> FrameRecord:
        """Emit the frame (all samples are in) and return it."""
        out = self.poll(host_ns(MID_US) + 1_000_000)
        assert len(out) == 1, f"expected one frame, got {len(out)} (pending {self.gt.pending})"
        return out[0]


def fix_then_bracket(rig: Rig, q=(1.0, 0.0, 0.0, 0.0), fix_type: int = 3) -> None:
    """A 3D fix, then level poses at 13000 and 13100 ms (mid-exposure 13045 ms lies between)."""
    rig.gps(12_990, fix_type)
    rig.pose(13_000, q)
    rig.pose(13_100, q)


def valid_range_at_mid(rig: Rig, cm: int = 1_000) -> None:
    """Valid LiDAR returns either side of mid-exposure, so a frame carries no range flag."""
    rig.gt.add_range(range_sample(MID_US - 2_000, cm))
    rig.gt.add_range(range_sample(MID_US + 2_000, cm))


def enu(frame: FrameRecord) -> np.ndarray:
    assert frame.east_m is not None and frame.north_m is not None and frame.up_m is not None
    return np.array([frame.east_m, frame.north_m, frame.up_m])


# --------------------------------------------------------------------------- mid-exposure
def test_mid_exposure_is_the_middle_of_the_feedback_pulse_on_all_three_clocks():
    rig = Rig()
    fix_then_bracket(rig)
    valid_range_at_mid(rig)
    rig.expose()
    f = rig.one()
    assert f.trigger_device_us == TRIGGER_US
    assert f.start_device_us == START_US
    assert f.mid_device_us == START_US + DURATION_US // 2 == 10_045_000
    assert f.duration_us == DURATION_US
    assert f.mid_host_ns == 10_045_000 * 1000 + DEV_TO_HOST_NS
    assert f.mid_host_uncertainty_ns == 20_000
    assert f.mid_utc_us == 10_045_000 + UTC_OFFSET_US
    assert f.mid_utc_uncertainty_us == 2.5
    assert f.time_source == "pps"
    assert FrameFlag.NO_FEEDBACK.value not in f.flags
    assert f.flags == []


def test_trigger_only_exposure_is_timed_at_the_trigger_and_flagged_no_feedback():
    rig = Rig()
    fix_then_bracket(rig)
    valid_range_at_mid(rig)
    # No hot-shoe line: the device sends the trigger time only. Put the trigger at the same
    # instant as the pulse middle above so the same poses bracket it.
    rig.gt.add_exposure(
        Exposure(
            image_index=4,
            camera_id=0,
            flags=int(ExposureFlags.NO_FEEDBACK_LINE),
            trigger_t_us=MID_US,
            feedback_start_t_us=0,
            feedback_end_t_us=0,
            duration_us=0,
        ),
        host_ns(MID_US) + 2_000_000,
    )
    f = rig.one()
    assert f.mid_device_us == f.start_device_us == f.trigger_device_us == MID_US
    assert f.mid_host_ns == host_ns(MID_US)
    assert f.flags == [FrameFlag.NO_FEEDBACK.value]
    assert f.device_flags == int(ExposureFlags.NO_FEEDBACK_LINE)
    assert f.blur_px is None  # no duration, no blur figure


def test_device_exposure_flags_become_frame_flags():
    rig = Rig()
    fix_then_bracket(rig)
    valid_range_at_mid(rig)
    rig.expose(flags=int(ExposureFlags.FEEDBACK_MISSING), feedback_start_t_us=0, feedback_end_t_us=0, duration_us=0)
    rig.expose(index=0, flags=int(ExposureFlags.UNSOLICITED), trigger_t_us=0)
    a, b = rig.poll(host_ns(MID_US) + 1_000_000)
    assert set(a.flags) == {FrameFlag.NO_FEEDBACK.value, FrameFlag.FEEDBACK_MISSING.value}
    assert a.mid_device_us == TRIGGER_US
    assert b.flags == [FrameFlag.UNSOLICITED.value]
    assert (b.image_index, b.trigger_device_us, b.mid_device_us) == (0, 0, MID_US)


# --------------------------------------------------------------------------- position
def test_position_is_interpolated_at_mid_exposure():
    """Two samples moving at the velocity they report: the cubic through them is the straight line."""
    rig = Rig()
    rig.gps(12_990)
    b = LocalFrame(*ORIGIN).geodetic_to_enu((LAT_E7 + 900) * 1e-7, (LON_E7 + 1_200) * 1e-7, (ALT_MM + 2_000) * 1e-3)
    v_ned = (b[1] / 0.1, b[0] / 0.1, -b[2] / 0.1)  # ~10 m north, ~9 m east, 2 m up in 100 ms
    rig.pose(13_000, v_ned=v_ned)
    rig.pose(13_100, dlat_e7=900, dlon_e7=1_200, dalt_mm=2_000, v_ned=v_ned)
    rig.expose()
    f = rig.one()
    frac = (MID_BOOT_MS - 13_000) / 100  # 0.45
    np.testing.assert_allclose(enu(f), frac * b, atol=1e-3)  # velocities are whole cm/s
    # Independent of LocalFrame: metres per degree on the WGS84 ellipsoid at 47.4 deg N.
    lat = math.radians(ORIGIN[0])
    m_per_deg_lat = 111_132.954 - 559.822 * math.cos(2 * lat) + 1.175 * math.cos(4 * lat)
    m_per_deg_lon = math.pi / 180 * 6_378_137.0 * math.cos(lat) / math.sqrt(1 - 0.00669438 * math.sin(lat) ** 2)
    assert f.north_m == pytest.approx(frac * 900e-7 * m_per_deg_lat, abs=2e-3)
    assert f.east_m == pytest.approx(frac * 1_200e-7 * m_per_deg_lon, abs=2e-3)
    assert f.up_m == pytest.approx(frac * 2.0, abs=2e-3)
    assert f.lat_deg == pytest.approx(ORIGIN[0] + frac * 900e-7, abs=1e-8)
    assert f.lon_deg == pytest.approx(ORIGIN[1] + frac * 1_200e-7, abs=1e-8)
    assert f.alt_msl_m == pytest.approx(ORIGIN[2] + frac * 2.0, abs=2e-3)
    assert f.pose_gap_before_ms == pytest.approx(45.0)
    assert f.pose_gap_after_ms == pytest.approx(55.0)
    assert (f.position_source, f.fix_type) == ("gps_3d", 3)
    assert (f.h_acc_m, f.v_acc_m, f.satellites) == (pytest.approx(0.9), pytest.approx(1.5), 14)
    # 95 %: the receiver's h_acc / v_acc, the unseen acceleration over 100 ms, the 320 us clock bound x speed
    speed_h, speed_v = math.hypot(v_ned[0], v_ned[1]), abs(v_ned[2])
    unseen = 0.1**2 * 0.45 * 0.55 / 4
    assert f.horizontal_error_bound_m == pytest.approx(RADIAL_95 * 0.9 + 1.0 * unseen + speed_h * CLOCK_S, rel=1e-3)
    assert f.vertical_error_bound_m == pytest.approx(AXIS_95 * 1.5 + 0.5 * unseen + speed_v * CLOCK_S, rel=1e-3)
    assert f.position_error_bound_m == pytest.approx(math.hypot(f.horizontal_error_bound_m, f.vertical_error_bound_m))
    assert FrameFlag.STALE_POSE.value not in f.flags  # the gap's part is under a millimetre


def test_position_follows_the_samples_velocities_between_them():
    """Starting at rest and arriving at 2 m/s over 1 s: the cubic Hermite of the two ends, not the chord."""
    rig = Rig(GeotagConfig(origin=ORIGIN))
    rig.gps(12_000)
    rig.pose(12_550)
    end = LocalFrame(*ORIGIN).geodetic_to_enu((LAT_E7 + 90) * 1e-7, *ORIGIN[1:])  # ~1 m north
    rig.pose(13_550, dlat_e7=90, v_ned=(2.0, 0.0, 0.0))
    rig.expose()
    f = rig.one()
    x = (MID_BOOT_MS - 12_550) / 1000.0  # 0.495 of the way
    h01, h11 = -2 * x**3 + 3 * x**2, x**3 - x**2
    assert f.north_m == pytest.approx(h01 * end[1] + h11 * 1.0 * 2.0, abs=1e-3)
    assert f.north_m != pytest.approx(x * end[1], abs=0.05)
    # the bend the velocities show, |dv| T u (1-u) / 2, and the unseen acceleration A T^2 u (1-u) / 4 with
    # A = 2 m/s^2 plus twice the mean acceleration no end sample explains (2 m/s over 1 s)
    shape = x * (1 - x)
    motion = 2.0 * 1.0 * shape / 2 + (2.0 + 2 * 2.0) * 1.0 * shape / 4
    assert f.horizontal_error_bound_m == pytest.approx(RADIAL_95 * 0.9 + motion, abs=1e-3)
    assert FrameFlag.STALE_POSE.value in f.flags  # the gap's part, 0.31 m, is above the 0.10 m default


def test_origin_defaults_to_the_first_fix():
    rig = Rig(GeotagConfig())
    rig.gps(12_990)
    rig.pose(13_000, dlat_e7=500)
    rig.pose(13_100, dlat_e7=500)
    rig.expose()
    f = rig.one()
    assert rig.gt.origin == ((LAT_E7 + 500) * 1e-7, LON_E7 * 1e-7, ALT_MM * 1e-3)
    np.testing.assert_allclose(enu(f), 0.0, atol=1e-6)


def test_attitude_is_slerped_at_mid_exposure():
    rig = Rig()
    rig.gps(12_990)
    rig.pose(13_000, yaw_q(0.0))
    rig.pose(13_100, yaw_q(80.0))
    rig.expose()
    f = rig.one()
    expected_yaw = 0.45 * 80.0  # slerp between rotations about one axis turns the angle linearly
    # ATTITUDE_QUATERNION carries float32: 1e-7 per component, 1e-5 deg
    assert f.yaw_deg == pytest.approx(expected_yaw, abs=1e-5)
    assert f.roll_deg == pytest.approx(0.0, abs=1e-5)
    assert f.pitch_deg == pytest.approx(0.0, abs=1e-5)
    np.testing.assert_allclose((f.body_qw, f.body_qx, f.body_qy, f.body_qz), yaw_q(expected_yaw), atol=1e-7)


def test_attitude_slerp_between_two_axes_stays_a_unit_rotation_on_the_great_arc():
    rig = Rig()
    rig.gps(12_990)
    roll90 = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)
    rig.pose(13_000, yaw_q(90.0))
    rig.pose(13_100, roll90)
    rig.expose()
    f = rig.one()
    q0, q1 = np.array(yaw_q(90.0)), np.array(roll90)
    theta = math.acos(float(q0 @ q1))
    want = (math.sin(0.55 * theta) * q0 + math.sin(0.45 * theta) * q1) / math.sin(theta)
    np.testing.assert_allclose((f.body_qw, f.body_qx, f.body_qy, f.body_qz), want, atol=1e-7)


@pytest.mark.parametrize(
    ("yaw_deg", "lever", "offset_enu"),
    [
        (0.0, (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)),  # forward, heading north: 1 m north
        (90.0, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0)),  # forward, heading east: 1 m east
        (180.0, (1.0, 0.0, 0.0), (0.0, -1.0, 0.0)),
        (90.0, (0.0, 0.5, 0.0), (0.0, -0.5, 0.0)),  # right of a vehicle heading east: south
        (90.0, (0.0, 0.0, 0.3), (0.0, 0.0, -0.3)),  # below (FRD z down): lower
    ],
)
def test_lever_arm_is_rotated_by_the_attitude(yaw_deg, lever, offset_enu):
    rig = Rig(GeotagConfig(origin=ORIGIN, lever_arm_body_m=lever))
    fix_then_bracket(rig, yaw_q(yaw_deg))
    rig.expose()
    np.testing.assert_allclose(enu(rig.one()), offset_enu, atol=1e-6)  # float32 attitude


def test_lever_arm_follows_roll():
    rig = Rig(GeotagConfig(origin=ORIGIN, lever_arm_body_m=(0.0, 0.4, 0.0)))
    roll90 = (math.sqrt(0.5), math.sqrt(0.5), 0.0, 0.0)  # right wing down
    fix_then_bracket(rig, roll90)
    rig.expose()
    np.testing.assert_allclose(enu(rig.one()), (0.0, 0.0, -0.4), atol=1e-6)


# --------------------------------------------------------------------------- camera attitude
def cam_axes(f: FrameRecord) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, down, optical axis) of the image in NED."""
    q = (f.cam_qw, f.cam_qx, f.cam_qy, f.cam_qz)
    assert None not in q
    assert math.sqrt(sum(c * c for c in q)) == pytest.approx(1.0)
    return rotate(q, (1, 0, 0)), rotate(q, (0, 1, 0)), rotate(q, (0, 0, 1))


N, E, D = np.eye(3)


@pytest.mark.parametrize(
    ("mount", "yaw_deg", "right", "down", "axis"),
    [
        ({}, 0.0, E, D, N),  # default: looks forward, image right = starboard
        ({}, 90.0, -N, D, E),  # the vehicle turned east, the camera with it
        ({"mount_pitch_deg": -90.0}, 0.0, E, -N, D),  # nadir: image top points forward
        ({"mount_yaw_deg": 90.0}, 0.0, -N, D, E),  # looks to starboard
        ({"mount_roll_deg": 90.0}, 0.0, D, -E, N),  # rolled about the optical axis
    ],
)
def test_camera_mounting_quaternion(mount, yaw_deg, right, down, axis):
    rig = Rig(GeotagConfig(origin=ORIGIN, **mount))
    fix_then_bracket(rig, yaw_q(yaw_deg))
    rig.expose()
    got = cam_axes(rig.one())
    for g, w in zip(got, (right, down, axis), strict=True):
        np.testing.assert_allclose(g, w, atol=1e-6)


def test_gimbal_stabilised_camera_turns_with_yaw_only():
    rig = Rig(GeotagConfig(origin=ORIGIN, gimbal_stabilised=True))
    # roll 20, pitch 10, yaw 90 (ZYX)
    r, p, y = (math.radians(a) / 2 for a in (20.0, 10.0, 90.0))
    q = (
        math.cos(r) * math.cos(p) * math.cos(y) + math.sin(r) * math.sin(p) * math.sin(y),
        math.sin(r) * math.cos(p) * math.cos(y) - math.cos(r) * math.sin(p) * math.sin(y),
        math.cos(r) * math.sin(p) * math.cos(y) + math.sin(r) * math.cos(p) * math.sin(y),
        math.cos(r) * math.cos(p) * math.sin(y) - math.sin(r) * math.sin(p) * math.cos(y),
    )
    fix_then_bracket(rig, q)
    rig.expose()
    f = rig.one()
    assert (f.roll_deg, f.pitch_deg, f.yaw_deg) == (pytest.approx(20.0), pytest.approx(10.0), pytest.approx(90.0))
    right, down, axis = cam_axes(f)
    np.testing.assert_allclose(axis, E, atol=1e-6)
    np.testing.assert_allclose(right, -N, atol=1e-6)
    np.testing.assert_allclose(down, D, atol=1e-6)


# --------------------------------------------------------------------------- waiting and flags
def test_frame_waits_for_the_later_position_and_attitude_samples():
    rig = Rig()
    rig.gps(12_990)
    north = LocalFrame(*ORIGIN).geodetic_to_enu((LAT_E7 + 900) * 1e-7, *ORIGIN[1:])[1]
    rig.pose(13_000, v_ned=(north / 0.1, 0, 0))
    rig.expose()
    later = host_ns(MID_US) + 200_000_000  # 200 ms after mid: within max_wait (500 ms)
    assert rig.poll(later) == [] and rig.gt.pending == 1
    rig.position(13_100, dlat_e7=900, v_ned=(north / 0.1, 0, 0))
    assert rig.poll(later) == [], "emitted before the later attitude sample arrived"
    rig.attitude(13_100)
    (f,) = rig.poll(later + 1)
    assert FrameFlag.POSE_EXTRAPOLATED.value not in f.flags
    assert f.pose_gap_after_ms == pytest.approx(55.0)
    assert f.north_m == pytest.approx(0.45 * north, abs=1e-3)
    assert f.emitted_host_ns == later + 1
    assert rig.gt.pending == 0


def test_frame_is_emitted_after_max_wait_moved_by_the_earlier_velocity_and_flagged():
    rig = Rig(GeotagConfig(origin=ORIGIN, max_wait_s=0.5))
    rig.gps(12_990)
    rig.pose(13_000, dlat_e7=300, v_ned=(0.0, 2.0, 0.0))
    rig.expose()
    mid = host_ns(MID_US)
    # A usable GPS sample 45 ms before mid: the next one may be up to max_gps_gap_s (1.5 s) away, so the
    # frame waits that long plus max_wait_s before it is moved by dead reckoning.
    assert rig.poll(mid + 500_000_000) == []
    assert rig.poll(mid + 1_999_999_999) == []
    (f,) = rig.poll(mid + 2_000_000_000)
    assert FrameFlag.POSE_EXTRAPOLATED.value in f.flags
    assert FrameFlag.STALE_POSE.value not in f.flags  # 45 ms of dead reckoning: 4 mm
    # (|a| + A) dt^2 / 2, with max_accel_m_s2 for |a| (no earlier sample shows it)
    assert f.horizontal_error_bound_m == pytest.approx(
        RADIAL_95 * 0.9 + (3.0 + 2.0) * 0.045**2 / 2 + 2.0 * CLOCK_S, rel=1e-6
    )
    assert f.vertical_error_bound_m == pytest.approx(AXIS_95 * 1.5 + (3.0 + 1.0) * 0.045**2 / 2, rel=1e-6)
    assert f.position_source == "dead_reckoned"
    assert f.pose_gap_before_ms == pytest.approx(45.0)
    assert f.pose_gap_after_ms == math.inf
    held = np.asarray(LocalFrame(*ORIGIN).geodetic_to_enu((LAT_E7 + 300) * 1e-7, *ORIGIN[1:]))
    np.testing.assert_allclose(enu(f), held + np.array([2.0 * 0.045, 0.0, 0.0]), atol=1e-6)
    assert f.emitted_host_ns == mid + 2_000_000_000


def test_long_dead_reckoning_is_flagged_stale():
    rig = Rig(GeotagConfig(origin=ORIGIN, max_wait_s=0.5))
    rig.gps(12_400)
    rig.pose(12_500)
    rig.expose()
    (f,) = rig.poll(host_ns(MID_US) + 2_000_000_000)
    assert {FrameFlag.POSE_EXTRAPOLATED.value, FrameFlag.STALE_POSE.value} <= set(f.flags)
    assert f.horizontal_error_bound_m == pytest.approx(RADIAL_95 * 0.9 + (3.0 + 2.0) * 0.545**2 / 2, rel=1e-6)


def test_no_position_beyond_the_extrapolation_horizon():
    """0.8 s after the last sample with nothing after it: (3 + 2) 0.8^2 / 2 = 1.6 m > max_extrapolation_m (1 m).
    No guess: no_pose, with the gap; the frame is placed once the later sample is there (a recompute)."""
    rig = Rig(GeotagConfig(origin=ORIGIN, max_wait_s=0.5))
    rig.gps(12_200)
    rig.pose(12_245)
    rig.expose()
    (f,) = rig.poll(host_ns(MID_US) + 2_000_000_000)
    assert FrameFlag.NO_POSE.value in f.flags and FrameFlag.NO_FIX.value not in f.flags
    assert (f.lat_deg, f.east_m, f.position_error_bound_m, f.position_source) == (None, None, None, "none")
    assert f.pose_gap_before_ms == pytest.approx(800.0)
    assert f.pose_gap_after_ms == math.inf


@pytest.mark.parametrize(
    ("before_ms", "after_ms", "dv_north", "stale", "extrapolated"),
    [
        (13_000, 13_100, 0.0, False, False),  # bound 1 mm
        (13_000, 13_100, 10.0, True, False),  # 10 m/s change of velocity in 100 ms: 0.12 m
        (12_545, 13_545, 0.0, True, False),  # 1 s apart (a 1 Hz stream): 2 m/s^2 unseen could be 0.14 m
        (12_395, 13_695, 0.0, True, False),  # 1.3 s: 0.12 m
        (12_245, 13_845, 0.0, True, False),  # 1.6 s apart: interpolated across the gap, 0.18 m
    ],
)
def test_stale_pose_flag_from_the_position_bound(before_ms, after_ms, dv_north, stale, extrapolated):
    rig = Rig(GeotagConfig(origin=ORIGIN))
    rig.gps(12_200)
    rig.pose(before_ms)
    rig.pose(after_ms, v_ned=(dv_north, 0.0, 0.0))
    rig.expose()
    (f,) = rig.poll(host_ns(MID_US) + 600_000_000)
    assert (FrameFlag.STALE_POSE.value in f.flags) is stale, f.position_error_bound_m
    assert (FrameFlag.POSE_EXTRAPOLATED.value in f.flags) is extrapolated
    assert f.pose_gap_before_ms == pytest.approx(MID_BOOT_MS - before_ms)
    if not extrapolated:
        assert f.pose_gap_after_ms == pytest.approx(after_ms - MID_BOOT_MS)


@pytest.mark.parametrize("fix_type", [0, 1, 2])
def test_no_position_before_a_3d_fix(fix_type):
    rig = Rig()
    fix_then_bracket(rig, fix_type=fix_type)
    rig.expose()
    f = rig.one()
    assert FrameFlag.NO_FIX.value in f.flags
    assert (f.lat_deg, f.lon_deg, f.alt_msl_m, f.east_m) == (None, None, None, None)
    assert f.position_source == "none"
    assert f.fix_type == fix_type
    assert f.yaw_deg == pytest.approx(0.0)  # attitude does not need a fix


def test_no_gps_message_at_all_is_no_fix():
    rig = Rig()
    rig.pose(13_000)
    rig.pose(13_100)
    rig.expose()
    f = rig.one()
    assert FrameFlag.NO_FIX.value in f.flags
    assert (f.fix_type, f.lat_deg, f.h_acc_m) == (0, None, None)


@pytest.mark.parametrize(("fix_type", "source"), [(3, "gps_3d"), (4, "gps_3d"), (5, "rtk_float"), (6, "rtk_fixed")])
def test_position_source_from_the_gps_fix_type(fix_type, source):
    rig = Rig()
    fix_then_bracket(rig, fix_type=fix_type)
    rig.expose()
    f = rig.one()
    assert (f.position_source, f.fix_type) == (source, fix_type)
    assert FrameFlag.NO_FIX.value not in f.flags


def test_fix_type_is_the_last_gps_sample_before_mid_exposure():
    rig = Rig()
    rig.gps(12_900, 6)
    fix_then_bracket(rig, fix_type=5)  # GPS at 12_990: float
    rig.gps(13_080, 6)  # after mid: fixed again, not what held at mid
    rig.expose()
    assert rig.one().position_source == "rtk_float"


# --------------------------------------------------------------------------- range
def range_sample(t_us: int, cm: int, valid: bool = True) -> Range:
    flags = int(RangeFlags.VALID) if valid else int(RangeFlags.NO_SIGNAL)
    return Range(acq_start_t_us=t_us, read_t_us=t_us + 1_000, distance_cm=cm if valid else 0, flags=flags)


def test_range_is_interpolated_at_mid_exposure():
    rig = Rig()
    fix_then_bracket(rig)
    rig.gt.add_range(range_sample(MID_US - 25_000, 900))
    rig.gt.add_range(range_sample(MID_US - 5_000, 1_000))
    rig.gt.add_range(range_sample(MID_US + 15_000, 1_400))
    rig.gt.add_range(range_sample(MID_US + 35_000, 2_000))
    rig.expose()
    f = rig.one()
    assert f.range_m == pytest.approx(11.0)  # 10 m + 4 m * 5/20
    assert f.range_age_ms == pytest.approx(5.0)
    assert f.range_valid is True
    cfg = GeotagConfig()
    assert f.scale_mm_per_px == pytest.approx(11_000 * (cfg.sensor_width_mm / cfg.image_width_px) / cfg.focal_length_mm)
    assert not {FrameFlag.RANGE_INVALID.value, FrameFlag.RANGE_OUT_OF_BAND.value} & set(f.flags)


def test_invalid_range_samples_are_skipped_in_the_interpolation():
    rig = Rig()
    fix_then_bracket(rig)
    rig.gt.add_range(range_sample(MID_US - 10_000, 1_000))
    rig.gt.add_range(range_sample(MID_US + 2_000, 0, valid=False))
    rig.gt.add_range(range_sample(MID_US + 10_000, 1_200))
    rig.expose()
    assert rig.one().range_m == pytest.approx(11.0)


@pytest.mark.parametrize("seed", range(40))
def test_range_at_mid_is_the_nearest_valid_pair(seed):
    """Random streams (valid and invalid returns, one exactly at mid sometimes): the range is interpolated
    between the last valid acquisition at or before mid and the first at or after it, within 50 ms."""
    rng = random.Random(seed)
    rig = Rig()
    fix_then_bracket(rig)
    t, samples = MID_US - 80_000, []
    at_mid = rng.random() < 0.3
    while t < MID_US + 80_000:
        step = rng.choice([2_000, 2_000, 2_000, 7_000, 23_000])
        t = MID_US if at_mid and t < MID_US < t + step else t + step
        samples.append(range_sample(t, rng.randint(100, 3_000), valid=rng.random() < 0.4))
        rig.gt.add_range(samples[-1])
    rig.expose()
    f = rig.one()
    near = [s for s in samples if abs(s.acq_start_t_us - MID_US) <= 50_000 and s.flags & int(RangeFlags.VALID)]
    before = [s for s in near if s.acq_start_t_us <= MID_US]
    after = [s for s in near if s.acq_start_t_us >= MID_US]
    if not before and not after:
        assert FrameFlag.RANGE_INVALID.value in f.flags and f.range_m is None
    elif before and after:
        a, b = before[-1], after[0]
        w = 0.0 if a is b else (MID_US - a.acq_start_t_us) / (b.acq_start_t_us - a.acq_start_t_us)
        assert f.range_m == pytest.approx((a.distance_cm + (b.distance_cm - a.distance_cm) * w) / 100.0)
    else:
        (only,) = before[-1:] or after[:1]
        assert f.range_m == pytest.approx(only.distance_cm / 100.0)


@pytest.mark.parametrize(
    "samples",
    [
        [],
        [range_sample(MID_US - 5_000, 0, valid=False), range_sample(MID_US + 5_000, 0, valid=False)],
        [range_sample(MID_US - 60_000, 1_000), range_sample(MID_US + 60_000, 1_000)],  # outside 50 ms
    ],
    ids=["none", "no_signal", "too_old"],
)
def test_range_invalid_without_a_valid_return_near_the_exposure(samples):
    rig = Rig()
    fix_then_bracket(rig)
    for s in samples:
        rig.gt.add_range(s)
    rig.expose()
    f = rig.one()
    assert FrameFlag.RANGE_INVALID.value in f.flags
    assert (f.range_m, f.range_valid, f.scale_mm_per_px, f.incidence_deg) == (None, False, None, None)


@pytest.mark.parametrize(("cm", "out"), [(30, True), (49, True), (50, False), (4_000, False), (4_100, True)])
def test_range_out_of_band(cm, out):
    rig = Rig(GeotagConfig(origin=ORIGIN, range_min_m=0.5, range_max_m=40.0))
    fix_then_bracket(rig)
    rig.gt.add_range(range_sample(MID_US - 2_000, cm))
    rig.gt.add_range(range_sample(MID_US + 2_000, cm))
    rig.expose()
    f = rig.one()
    assert (FrameFlag.RANGE_OUT_OF_BAND.value in f.flags) is out
    assert f.range_m == pytest.approx(cm / 100)
    assert f.range_valid is True


def test_incidence_and_scale_against_a_known_surface():
    # Camera looks north (level, default mount); the face's normal points 60 deg away from it.
    normal = (math.sin(math.radians(60.0)), -math.cos(math.radians(60.0)), 0.0)
    rig = Rig(GeotagConfig(origin=ORIGIN, surface_normal_enu=normal))
    fix_then_bracket(rig)
    rig.gt.add_range(range_sample(MID_US - 1_000, 1_000))
    rig.gt.add_range(range_sample(MID_US + 1_000, 1_000))
    rig.expose()
    f = rig.one()
    cfg = GeotagConfig()
    assert f.incidence_deg == pytest.approx(60.0)
    base = 10_000 * (cfg.sensor_width_mm / cfg.image_width_px) / cfg.focal_length_mm
    assert f.scale_mm_per_px == pytest.approx(base / math.cos(math.radians(60.0)))


# --------------------------------------------------------------------------- IMU: blur and calibration
def imu_sample(t_us: int, *, gyro=(0.0, 0.0, 0.0), calib: int = 0xFF, quat=(1.0, 0.0, 0.0, 0.0)) -> Imu:
    return Imu(
        read_start_t_us=t_us - 500,
        read_end_t_us=t_us + 500,
        quat_w=quat[0],
        quat_x=quat[1],
        quat_y=quat[2],
        quat_z=quat[3],
        gyro_x_rad_s=gyro[0],
        gyro_y_rad_s=gyro[1],
        gyro_z_rad_s=gyro[2],
        calib_stat=calib,
    )


def test_rotation_blur_above_the_limit_is_flagged():
    rig = Rig(GeotagConfig(origin=ORIGIN, blur_limit_px=1.0))
    fix_then_bracket(rig)
    rig.gt.add_imu(imu_sample(MID_US, gyro=(0.0, 0.03, 0.04)))  # 0.05 rad/s
    rig.expose()
    f = rig.one()
    focal_px = 35.0 / (35.9 / 7952)
    assert f.imu_gyro_rad_s == pytest.approx(0.05)
    assert f.blur_px == pytest.approx(0.05 * 0.010 * focal_px)  # ~3.9 px in 10 ms
    assert FrameFlag.MOTION_BLUR.value in f.flags


def test_still_camera_has_no_blur_and_translation_blur_uses_the_ground_sample_distance():
    rig = Rig(GeotagConfig(origin=ORIGIN, blur_limit_px=1.0))
    rig.gps(12_990)
    rig.pose(13_000, v_ned=(0.3, 0.4, 0.0))  # 0.5 m/s
    rig.pose(13_100, v_ned=(0.3, 0.4, 0.0))
    rig.gt.add_imu(imu_sample(MID_US))
    rig.expose()
    still = rig.one()
    assert still.blur_px == pytest.approx(0.0)  # no range: translation cannot be scaled
    assert FrameFlag.MOTION_BLUR.value not in still.flags

    rig.gt.add_range(range_sample(MID_US + 500_000, 500))
    rig.gt.add_range(range_sample(MID_US + 502_000, 500))
    rig.expose(start_us=START_US + 500_000, index=2)
    rig.pose(13_600, v_ned=(0.3, 0.4, 0.0))
    rig.gt.add_imu(imu_sample(MID_US + 500_000))
    moving = rig.poll(host_ns(MID_US + 500_000) + 1_000_000)[0]
    assert moving.scale_mm_per_px is not None
    # 0.5 m/s x 10 ms = 5 mm on the surface, over the mm per pixel at 5 m
    assert moving.blur_px == pytest.approx(5.0 / moving.scale_mm_per_px)
    assert FrameFlag.MOTION_BLUR.value in moving.flags


@pytest.mark.parametrize(
    ("calib", "fields", "flagged"),
    [
        (0b11_11_11_11, (3, 3, 3, 3), False),
        (0b10_11_01_00, (2, 3, 1, 0), True),
        (0b00_11_11_11, (0, 3, 3, 3), True),
        (0b11_00_00_00, (3, 0, 0, 0), False),  # only the system status decides
    ],
)
def test_imu_calibration_status(calib, fields, flagged):
    rig = Rig()
    fix_then_bracket(rig)
    rig.gt.add_imu(imu_sample(MID_US - 10_000, calib=0xFF))
    rig.gt.add_imu(imu_sample(MID_US + 2_000, calib=calib, quat=(0.0, 1.0, 0.0, 0.0)))  # the nearer one
    rig.expose()
    f = rig.one()
    assert (f.imu_calib_sys, f.imu_calib_gyr, f.imu_calib_acc, f.imu_calib_mag) == fields
    assert (FrameFlag.IMU_UNCALIBRATED.value in f.flags) is flagged
    assert (f.imu_qw, f.imu_qx) == (0.0, 1.0)
    assert f.imu_age_ms == pytest.approx(-2.0)


def test_no_imu_sample_leaves_the_imu_fields_empty():
    rig = Rig()
    fix_then_bracket(rig)
    rig.expose()
    f = rig.one()
    assert (f.imu_qw, f.imu_calib_sys, f.blur_px, f.imu_age_ms) == (None, None, None, None)
    assert FrameFlag.IMU_UNCALIBRATED.value not in f.flags


# --------------------------------------------------------------------------- clocks
def test_without_a_device_clock_mapping_the_arrival_time_is_used_and_flagged():
    rig = Rig(device_clock=FakeDeviceClock(synced=False))
    rig.expose()
    rx = host_ns(START_US + DURATION_US) + 3_000_000
    (f,) = rig.poll(rx + 1, flush=True)
    assert f.mid_host_ns == rx
    assert f.mid_host_uncertainty_ns > 1_000_000
    assert FrameFlag.CLOCK_UNSYNCED.value in f.flags


def test_a_device_clock_bound_above_the_limit_is_flagged():
    rig = Rig(
        GeotagConfig(origin=ORIGIN, max_clock_uncertainty_s=0.001),
        device_clock=FakeDeviceClock(uncertainty_ns=1_000_001),
    )
    fix_then_bracket(rig)
    valid_range_at_mid(rig)
    rig.expose()
    assert rig.one().flags == [FrameFlag.CLOCK_UNSYNCED.value]


def test_no_autopilot_clock_and_no_utc():
    rig = Rig(autopilot_clock=FakeAutopilotClock(synced=False), utc=FakeUtc(available=False))
    fix_then_bracket(rig)
    rig.expose()
    mid = host_ns(MID_US)
    assert rig.poll(mid + 100_000_000) == [], "without the autopilot clock no sample can be known to follow"
    (f,) = rig.poll(mid + 500_000_000)
    assert {FrameFlag.NO_FIX.value, FrameFlag.NO_ATTITUDE.value, FrameFlag.NO_UTC.value} <= set(f.flags)
    assert (f.mid_utc_us, f.time_source, f.lat_deg, f.body_qw, f.cam_qw) == (None, "none", None, None, None)


# --------------------------------------------------------------------------- order and flush
def test_frames_come_out_in_exposure_order_numbered_from_one_and_flush_drops_nothing():
    rig = Rig()
    for i in range(5):
        rig.expose(start_us=START_US + i * 200_000, index=10 + i)
    assert rig.gt.pending == 5
    assert rig.poll(host_ns(START_US)) == []
    # Poses for the first two only: those two come out, the third (no later sample yet) holds the rest.
    rig.gps(12_990)
    rig.pose(13_000)
    rig.pose(13_250)
    out = rig.poll(host_ns(START_US) + 300_000_000)
    assert [f.frame_seq for f in out] == [1, 2]
    out += rig.poll(host_ns(START_US), flush=True)
    assert [f.frame_seq for f in out] == [1, 2, 3, 4, 5]
    assert [f.image_index for f in out] == [10, 11, 12, 13, 14]
    assert [f.mid_device_us for f in out] == sorted(f.mid_device_us for f in out)
    assert rig.gt.pending == 0
    assert FrameFlag.POSE_EXTRAPOLATED.value in out[2].flags  # flushed before its later sample
    assert rig.poll(host_ns(START_US) + 10**12, flush=True) == []
    rig.expose(start_us=START_US + 5 * 200_000, index=15)
    (last,) = rig.poll(0, flush=True)
    assert last.frame_seq == 6


def test_a_frame_whose_telemetry_left_the_buffers_says_so() -> None:
    """Issue 27 outage accounting: no pose because the telemetry around mid-exposure had been trimmed
    (the frame came later than telemetry is kept) is `telemetry_expired`, not only `no_fix`."""
    rig = Rig()
    rig.store.retain(1.0)  # 1 s of boot clock
    fix_then_bracket(rig)
    for boot_ms in range(13_200, 15_200, 100):  # 2 s more: the samples around mid (13045 ms) expire
        rig.pose(boot_ms)
    valid_range_at_mid(rig)
    rig.expose()
    frame = rig.one()
    assert {"no_fix", "telemetry_expired"} <= set(frame.flags)
    live = Rig()
    fix_then_bracket(live)
    live.store.retain(1.0)
    valid_range_at_mid(live)
    live.expose()
    assert "telemetry_expired" not in live.one().flags


@pytest.mark.parametrize("stabilised", [False, True])
@pytest.mark.parametrize("kind", ["pier_scan", "hover"])
def test_the_simulator_and_the_geotagger_agree_on_the_camera_frame(kind, stabilised):
    """One convention across the code: the simulator's true camera (its board FRD frame, x along the optical
    axis, and its own lever arm sum) and what the geotagger makes of the same body pose agree (to 1e-6:
    ATTITUDE_QUATERNION carries float32).

    The simulator turns its camera by the mounting angles alone and looks along x; the geotagger's camera
    frame is the optical one (x right, y down, z forward): its z axis must be the simulator's x axis, its
    position the simulator's camera position."""
    import tomllib
    from pathlib import Path

    from icgt.sim.scenario import parse_scenario
    from icgt.sim.trajectory import Trajectory

    data = tomllib.loads((Path(__file__).parents[1] / "e2e" / "short_flight.toml").read_text())
    data["trajectory"] = {"kind": kind, "sway_m": 0.4, "sway_period_s": 3.0}
    mount = {"mount_roll_deg": 7.0, "mount_pitch_deg": -35.0, "mount_yaw_deg": 25.0}
    data.setdefault("camera", {}).update(stabilised=stabilised, lever_arm_m=[0.21, -0.08, 0.12], **mount)
    scenario = parse_scenario(data)
    st = Trajectory(scenario).state(np.linspace(2.0, 12.0, 7))
    frame = LocalFrame(*ORIGIN)
    config = GeotagConfig(
        origin=ORIGIN, lever_arm_body_m=tuple(scenario.camera.lever_arm_m), gimbal_stabilised=stabilised, **mount
    )
    for i in range(st.tau_s.size):
        rig = Rig(config)
        q_body = tuple(float(c) for c in st.q_body_ned[i])
        rig.gps(12_990)
        rig.pose(13_000, q_body)
        rig.pose(13_100, q_body)
        rig.expose()
        f = rig.one()
        right, down, axis = cam_axes(f)
        q_board = st.q_camera_ned[i]  # the simulator's camera: FRD, x forward along the optical axis
        np.testing.assert_allclose(axis, rotate(q_board, (1, 0, 0)), atol=1e-6)
        np.testing.assert_allclose(right, rotate(q_board, (0, 1, 0)), atol=1e-6)
        np.testing.assert_allclose(down, rotate(q_board, (0, 0, 1)), atol=1e-6)
        lever_truth = st.camera_position_enu_m[i] - st.position_enu_m[i]
        np.testing.assert_allclose(enu(f) - np.array(frame.geodetic_to_enu(*ORIGIN)), lever_truth, atol=1e-6)
        sim_axis_enu = st.optical_axis_enu[i]
        np.testing.assert_allclose([axis[1], axis[0], -axis[2]], sim_axis_enu, atol=1e-6)
