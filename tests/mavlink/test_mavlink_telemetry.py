"""Telemetry conversions (units, unknown values, the 3D-fix rule), TelemetryBuffer.bracket, and mixed
MAVLink 1 / MAVLink 2 input on one real link."""

from __future__ import annotations

import math
import random
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from mavlink_peers import AutopilotPeer, free_udp_port, pack_v1, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.link import LinkConfig, MavlinkLink, MavlinkMessage
from icgt.mavlink.telemetry import (
    TELEMETRY_TYPES,
    SystemTimeSample,
    TelemetryBuffer,
    TelemetryStore,
    attitude_sample,
    euler_to_quaternion,
    fused_position_sample,
    gps_sample,
    local_position_sample,
    quaternion_to_euler,
    system_time_sample,
)

MAV = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)


def wire(msg, *, v1: bool = False):
    """Pack and parse again, as the link would see it (MAVLink 1 frames drop the v2 extensions)."""
    parser = mavlink2.MAVLink(None)
    out = parser.parse_buffer(pack_v1(msg, MAV) if v1 else msg.pack(MAV))
    assert out is not None and len(out) == 1
    return out[0]


def rotate(q, v):
    """Rotate vector v by unit quaternion q (w, x, y, z): q v q*."""
    w, x, y, z = q
    vx, vy, vz = v
    # t = 2 * cross(q.xyz, v); v' = v + w t + cross(q.xyz, t)
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return (
        vx + w * tx + (y * tz - z * ty),
        vy + w * ty + (z * tx - x * tz),
        vz + w * tz + (x * ty - y * tx),
    )


# --------------------------------------------------------------------------- GPS_RAW_INT
def test_gps_3d_fix_units():
    msg = wire(
        MAV.gps_raw_int_encode(
            123_456_789,
            3,
            473_977_419,
            85_455_938,
            488_123,
            120,
            250,
            1234,
            9000,
            14,
            alt_ellipsoid=535_000,
            h_acc=1500,
            v_acc=2500,
            vel_acc=300,
            hdg_acc=0,
            yaw=36000,
        )
    )
    s = gps_sample(msg, host_rx_ns=42)
    assert s.usable and s.fix_type == 3
    assert s.boot_us == 123_456_789 and s.host_rx_ns == 42
    assert s.lat_deg == pytest.approx(47.3977419, abs=1e-9)
    assert s.lon_deg == pytest.approx(8.5455938, abs=1e-9)
    assert s.alt_msl_m == pytest.approx(488.123)
    assert s.alt_ellipsoid_m == pytest.approx(535.0)
    assert s.h_acc_m == pytest.approx(1.5) and s.v_acc_m == pytest.approx(2.5)
    assert s.vel_acc_mps == pytest.approx(0.3)
    assert s.eph == pytest.approx(1.2) and s.epv == pytest.approx(2.5)
    assert s.vel_mps == pytest.approx(12.34) and s.cog_deg == pytest.approx(90.0)
    assert s.satellites == 14
    assert s.yaw_deg == pytest.approx(0.0)  # 36000 = north


def test_gps_fix_type_1_with_position_is_not_usable():
    msg = wire(MAV.gps_raw_int_encode(1_000_000, 1, 473_977_419, 85_455_938, 488_123, 9999, 9999, 0, 0, 3))
    s = gps_sample(msg, 0)
    assert not s.usable
    assert s.lat_deg is None and s.lon_deg is None and s.alt_msl_m is None and s.alt_ellipsoid_m is None
    assert (s.raw_lat_e7, s.raw_lon_e7, s.raw_alt_mm) == (473_977_419, 85_455_938, 488_123)


@pytest.mark.parametrize("fix", [0, 1, 2])
def test_gps_below_3d_never_yields_a_position(fix):
    s = gps_sample(wire(MAV.gps_raw_int_encode(1, fix, 10, 20, 30, 100, 100, 0, 0, 8)), 0)
    assert not s.usable and s.lat_deg is None


def test_gps_3d_fix_at_zero_zero_is_not_usable():
    assert not gps_sample(wire(MAV.gps_raw_int_encode(1, 3, 0, 0, 0, 100, 100, 0, 0, 8)), 0).usable


def test_gps_unknown_values_are_none():
    msg = wire(MAV.gps_raw_int_encode(5, 6, 1, 1, 0, 65535, 65535, 65535, 65535, 255, yaw=65535))
    s = gps_sample(msg, 0)
    assert s.usable  # RTK fixed
    assert s.eph is None and s.epv is None and s.vel_mps is None and s.cog_deg is None
    assert s.satellites is None and s.yaw_deg is None and s.h_acc_m is None


def test_gps_mavlink1_frame_has_no_extensions():
    msg = wire(MAV.gps_raw_int_encode(7, 3, 100, 200, 300, 80, 90, 10, 0, 9, alt_ellipsoid=5, h_acc=700), v1=True)
    s = gps_sample(msg, 0)
    assert s.usable and s.h_acc_m is None and s.alt_ellipsoid_m is None and s.alt_msl_m == pytest.approx(0.3)


# --------------------------------------------------------------------------- GLOBAL_POSITION_INT
def test_fused_position_units_and_fix_rule():
    msg = wire(MAV.global_position_int_encode(123_456, 473_977_419, 85_455_938, 488_123, 12_345, 150, -250, 35, 27_000))
    s = fused_position_sample(msg, 9, gps_fix_ok=True)
    assert s.usable and s.boot_us == 123_456_000 and s.host_rx_ns == 9
    assert s.lat_deg == pytest.approx(47.3977419, abs=1e-9) and s.lon_deg == pytest.approx(8.5455938, abs=1e-9)
    assert s.alt_msl_m == pytest.approx(488.123) and s.relative_alt_m == pytest.approx(12.345)
    assert (s.vn_mps, s.ve_mps, s.vd_mps) == pytest.approx((1.5, -2.5, 0.35))
    assert s.heading_deg == pytest.approx(270.0)
    no_fix = fused_position_sample(msg, 9, gps_fix_ok=False)
    assert not no_fix.usable and no_fix.lat_deg is None and no_fix.alt_msl_m is None
    assert no_fix.raw_lat_e7 == 473_977_419 and no_fix.relative_alt_m == pytest.approx(12.345)
    unknown_hdg = wire(MAV.global_position_int_encode(1, 1, 1, 0, 0, 0, 0, 0, 65535))
    assert fused_position_sample(unknown_hdg, 0, True).heading_deg is None


# --------------------------------------------------------------------------- attitude
def test_attitude_euler_to_quaternion_body_to_ned():
    yaw90 = attitude_sample(wire(MAV.attitude_encode(2_000, 0.0, 0.0, math.pi / 2, 0.01, -0.02, 0.03)), 5)
    assert yaw90 is not None
    assert yaw90.boot_us == 2_000_000 and yaw90.source == "ATTITUDE"
    assert yaw90.q_wxyz == pytest.approx((math.sqrt(0.5), 0, 0, math.sqrt(0.5)), abs=1e-7)
    # the body x axis (nose) points east in NED when yawed 90 degrees
    assert rotate(yaw90.q_wxyz, (1, 0, 0)) == pytest.approx((0, 1, 0), abs=1e-6)
    assert (yaw90.rollspeed_rps, yaw90.pitchspeed_rps, yaw90.yawspeed_rps) == pytest.approx((0.01, -0.02, 0.03))
    pitch_up = attitude_sample(wire(MAV.attitude_encode(1, 0.0, 0.3, 0.0, 0, 0, 0)), 0)
    assert pitch_up is not None
    nose = rotate(pitch_up.q_wxyz, (1, 0, 0))
    assert nose == pytest.approx((math.cos(0.3), 0, -math.sin(0.3)), abs=1e-6)  # up is -z in NED


def test_attitude_quaternion_matches_euler_and_is_normalised():
    roll, pitch, yaw = 0.2, -0.4, 2.5
    q = euler_to_quaternion(roll, pitch, yaw)
    scaled = [c * 1.01 for c in q]
    qs = attitude_sample(wire(MAV.attitude_quaternion_encode(3_000, *scaled, 0.1, 0.2, 0.3)), 0)
    es = attitude_sample(wire(MAV.attitude_encode(3_000, roll, pitch, yaw, 0.1, 0.2, 0.3)), 0)
    assert qs is not None and es is not None
    assert qs.source == "ATTITUDE_QUATERNION"
    assert qs.q_wxyz == pytest.approx(es.q_wxyz, abs=1e-6)
    assert math.fsum(c * c for c in qs.q_wxyz) == pytest.approx(1.0)
    assert (qs.roll_rad, qs.pitch_rad, qs.yaw_rad) == pytest.approx((roll, pitch, yaw), abs=1e-6)


def test_attitude_invalid_values_give_none():
    assert attitude_sample(wire(MAV.attitude_encode(1, math.nan, 0, 0, 0, 0, 0)), 0) is None
    assert attitude_sample(wire(MAV.attitude_quaternion_encode(1, 0, 0, 0, 0, 0, 0, 0)), 0) is None


@settings(max_examples=200, deadline=None)
@given(st.floats(-3.1, 3.1), st.floats(-1.5, 1.5), st.floats(-3.1, 3.1))
def test_euler_quaternion_round_trip(roll, pitch, yaw):
    assert quaternion_to_euler(euler_to_quaternion(roll, pitch, yaw)) == pytest.approx((roll, pitch, yaw), abs=1e-6)


# --------------------------------------------------------------------------- local position, system time
def test_local_position_units():
    s = local_position_sample(wire(MAV.local_position_ned_encode(4_500, 1.0, -2.0, -3.5, 0.5, 0.25, -0.125)), 1)
    assert s is not None and s.boot_us == 4_500_000
    assert (s.x_m, s.y_m, s.z_m, s.vx_mps, s.vy_mps, s.vz_mps) == pytest.approx((1, -2, -3.5, 0.5, 0.25, -0.125))


def test_system_time_zero_means_no_utc():
    s0 = system_time_sample(wire(MAV.system_time_encode(0, 1_234)), 3)
    assert s0.unix_us is None and s0.boot_ms == 1_234 and s0.boot_us == 1_234_000
    s1 = system_time_sample(wire(MAV.system_time_encode(1_700_000_000_123_456, 5_000)), 3)
    assert s1.unix_us == 1_700_000_000_123_456


# --------------------------------------------------------------------------- TelemetryStore
def rec(msg, rx_ns=0, sysid=1, compid=1):
    m = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
    parsed = mavlink2.MAVLink(None).parse_buffer(msg.pack(m))
    return MavlinkMessage(parsed[0], rx_ns)


def test_store_applies_the_fix_rule_to_fused_position():
    store = TelemetryStore()
    gpi = MAV.global_position_int_encode(10_000, 473_977_419, 85_455_938, 500_000, 10_000, 0, 0, 0, 0)
    assert not store.ingest(rec(gpi)).usable  # no GPS_RAW_INT seen yet
    store.ingest(rec(MAV.gps_raw_int_encode(9_900_000, 2, 473_977_419, 85_455_938, 500_000, 100, 100, 0, 0, 6)))
    assert not store.ingest(rec(gpi)).usable  # 2D fix
    store.ingest(rec(MAV.gps_raw_int_encode(9_950_000, 3, 473_977_419, 85_455_938, 500_000, 100, 100, 0, 0, 9)))
    good = store.ingest(rec(gpi))
    assert good.usable and good.lat_deg == pytest.approx(47.3977419)
    late = MAV.global_position_int_encode(13_000, 473_977_419, 85_455_938, 500_000, 10_000, 0, 0, 0, 0)
    assert not store.ingest(rec(late)).usable  # fix older than 2 s on the boot clock
    assert len(store.fused) == 2  # 10 000 ms stored twice -> replaced
    assert store.counts()["fused_unusable"] == 3 and store.counts()["gps_no_fix"] == 1


def test_store_ignores_other_sources_and_system_time_zero():
    store = TelemetryStore()
    assert store.ingest(rec(MAV.system_time_encode(0, 100))) is None
    assert isinstance(store.ingest(rec(MAV.system_time_encode(1_700_000_000_000_000, 200))), SystemTimeSample)
    assert store.ingest(rec(MAV.attitude_encode(1, 0, 0, 0, 0, 0, 0), sysid=2)) is None
    assert store.ingest(rec(MAV.attitude_encode(1, 0, 0, 0, 0, 0, 0), compid=100)) is None
    assert len(store.system_time) == 1 and len(store.attitude) == 0
    assert store.counts()["system_time_without_utc"] == 1 and store.counts()["other_source"] == 2


# --------------------------------------------------------------------------- TelemetryBuffer
class S:
    __slots__ = ("boot_us", "tag")

    def __init__(self, boot_us, tag=None):
        self.boot_us = boot_us
        self.tag = tag


def test_bracket_basics():
    buf: TelemetryBuffer[S] = TelemetryBuffer(16)
    assert buf.bracket(5) == (None, None)
    for t in (10, 20, 30):
        buf.push(S(t))
    b, a = buf.bracket(25)
    assert (b.boot_us, a.boot_us) == (20, 30)
    b, a = buf.bracket(20)
    assert b is a and b.boot_us == 20  # exact hit: the same sample on both sides
    assert buf.bracket(5)[0] is None and buf.bracket(5)[1].boot_us == 10
    assert buf.bracket(35)[0].boot_us == 30 and buf.bracket(35)[1] is None
    assert [s.boot_us for s in buf.between(15, 30)] == [20, 30]


def test_bracket_late_duplicate_capacity_and_reboot():
    buf: TelemetryBuffer[S] = TelemetryBuffer(4, reboot_backstep_us=1_000_000)
    for t in (100, 200, 400):
        buf.push(S(t))
    buf.push(S(300))  # late (UDP reordering)
    assert [s.boot_us for s in buf.samples()] == [100, 200, 300, 400] and buf.late == 1
    buf.push(S(400, "again"))
    assert buf.latest().tag == "again" and buf.replaced == 1
    buf.push(S(500))
    assert [s.boot_us for s in buf.samples()] == [200, 300, 400, 500]  # bounded
    buf.push(S(50))  # older than everything in a full buffer: dropped
    assert len(buf) == 4 and buf.oldest().boot_us == 200
    buf.push(S(10))  # 490 ms back is still "late"; a reboot needs > 1 s back
    buf.push(S(2_000_000))
    buf.push(S(5))  # boot clock restarted
    assert buf.resets == 1 and [s.boot_us for s in buf.samples()] == [5]


def test_bracket_matches_brute_force_over_many_pushes():
    rng = random.Random(7)
    buf: TelemetryBuffer[S] = TelemetryBuffer(500)
    kept: list[int] = []
    t = 0
    for _ in range(5_000):
        t += rng.randint(1, 30_000)
        buf.push(S(t))
        kept.append(t)
    kept = kept[-500:]
    assert [s.boot_us for s in buf.samples()] == kept
    for _ in range(2_000):
        q = rng.randint(kept[0] - 50_000, kept[-1] + 50_000)
        before = max((k for k in kept if k <= q), default=None)
        after = min((k for k in kept if k >= q), default=None)
        b, a = buf.bracket(q)
        assert (b.boot_us if b else None, a.boot_us if a else None) == (before, after)


def test_bracket_is_logarithmic():
    buf: TelemetryBuffer[S] = TelemetryBuffer(100_000)
    for t in range(100_000):
        buf.push(S(t * 20_000))
    t0 = time.perf_counter()
    for q in range(0, 2_000_000_000, 200_000):
        buf.bracket(q)
    per_call = (time.perf_counter() - t0) / 10_000
    assert per_call < 50e-6  # a linear scan of 100 000 entries would take milliseconds


# --------------------------------------------------------------------------- mixed MAVLink 1 / 2 on one link
def test_mixed_mavlink1_and_mavlink2_on_one_link():
    port = free_udp_port()
    link = MavlinkLink(LinkConfig(f"udpin:127.0.0.1:{port}", request_rates=False, timesync=False))
    store = TelemetryStore()
    inbox = link.subscribe_queue(TELEMETRY_TYPES)  # handed over to this thread, as the recorder's worker does

    def drained() -> TelemetryStore:
        while not inbox.empty():
            store.ingest(inbox.get_nowait())
        return store

    link.start()
    ap = AutopilotPeer(port)
    try:
        t_start = time.monotonic_ns()
        ap.heartbeat()
        ap.send(
            ap.mav.gps_raw_int_encode(8_000_000, 3, 473_977_419, 85_455_938, 488_000, 90, 120, 500, 18000, 12), v1=True
        )
        ap.send(ap.mav.global_position_int_encode(8_010, 473_977_420, 85_455_940, 488_100, 20_000, 100, 0, -10, 9000))
        ap.send_raw(b"\x00\x01garbage\xfe\x05\x00")  # noise, then a truncated v1 start
        ap.send(ap.mav.attitude_encode(8_020, 0.0, 0.0, 0.5, 0, 0, 0), v1=True)
        ap.send(ap.mav.attitude_quaternion_encode(8_030, 1, 0, 0, 0, 0, 0, 0))
        ap.send(ap.mav.local_position_ned_encode(8_040, 1, 2, -3, 0, 0, 0), v1=True)
        ap.send(ap.mav.system_time_encode(0, 8_050), v1=True)
        ap.send(ap.mav.system_time_encode(1_700_000_000_000_000, 8_060))
        assert wait_until(lambda: drained().counts()["samples"] >= 6 and store.counts()["system_time_without_utc"] == 1)
        gps = store.gps.latest()
        assert gps.usable and gps.lat_deg == pytest.approx(47.3977419) and gps.h_acc_m is None  # v1: no extensions
        fused = store.fused.latest()
        assert fused.usable and fused.boot_us == 8_010_000 and fused.heading_deg == pytest.approx(90.0)
        assert store.attitude.latest().yaw_rad == pytest.approx(0.5)
        assert store.attitude_quaternion.latest().q_wxyz == (1.0, 0.0, 0.0, 0.0)
        assert store.local_position.latest().z_m == pytest.approx(-3.0)
        assert [s.unix_us for s in store.system_time.samples()] == [1_700_000_000_000_000]
        for sample in (gps, fused):
            assert t_start <= sample.host_rx_ns <= time.monotonic_ns()
        stats = link.stats()
        assert stats.v1_frames >= 4 and stats.v2_frames >= 3 and stats.bad_frames >= 1
        assert stats.messages_by_type["GPS_RAW_INT"] == 1 and stats.messages_by_type["SYSTEM_TIME"] == 2
    finally:
        ap.close()
        link.stop()


def test_a_buffer_with_a_retention_keeps_samples_by_time_and_counts_what_expires() -> None:
    buf: TelemetryBuffer[S] = TelemetryBuffer(1000, retain_us=1_000_000)
    for k in range(50):  # 5 s at 10 Hz
        buf.push(S(k * 100_000, float(k)))
    kept = buf.samples()
    assert kept[0].boot_us == 3_900_000 and kept[-1].boot_us == 4_900_000 and len(kept) == 11
    assert buf.expired == 39
    buf.push(S(3_000_000, -1.0))  # a late sample older than the retention: not taken, counted
    assert buf.expired == 40 and len(buf) == 11
    buf.push(S(4_450_000, -2.0))  # a late one within it is inserted
    before, after = buf.bracket(4_450_000)
    assert before is after and before is not None and before.tag == -2.0


def test_a_store_keeps_a_50_hz_stream_for_its_retention() -> None:
    from icgt.mavlink.telemetry import SAMPLE_BYTES, FusedPositionSample

    store = TelemetryStore(retention_s=700.0)
    assert store.fused.capacity >= 700 * 100 and store.fused.retain_us == 700_000_000
    for k in range(720 * 50):  # 12 min at 50 Hz
        store.fused.push(
            FusedPositionSample(k * 20_000, k, True, 47.0, 8.0, 500.0, 30.0, 0, 0, 0, float(k), 0.0, 0.0, None)
        )
    oldest = store.fused.oldest()
    assert oldest is not None and oldest.boot_us == 719_980_000 - 700_000_000  # the newest minus 700 s
    assert store.memory_bytes() == store.fused.held * SAMPLE_BYTES
    assert store.fused.held <= 700 * 50 * 1.25 + 1
