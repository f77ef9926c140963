"""Unit tests of `icgt.sync.Synchroniser` and `TimesyncPairing`: the acceptance rules, fed by hand.

Every MAVLink input is encoded by pymavlink for its sender (system, component), packed and parsed
back, as the link hands it over; host times are chosen by the test (the synchroniser does no I/O
and reads no clock), so each expectation is exact.
"""

from __future__ import annotations

import json

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.clocks.device_clock import ClockNotSyncedError
from icgt.geotag.config import GeotagConfig
from icgt.protocol.messages import Exposure, Hello, Status
from icgt.sync import SyncConfig, Synchroniser, TimesyncPairing, TimesyncReply

S = 1_000_000_000  # ns

AUTOPILOT = (1, 1)
COMPANION = (1, 191)  # an onboard computer on the vehicle: same system, another component
GCS = (255, 190)


def wire(sender: tuple[int, int], build):
    """`build(mav)` encodes a message as `sender`; returns what a receiver parses from its bytes."""
    mav = mavlink2.MAVLink(None, srcSystem=sender[0], srcComponent=sender[1])
    out = mavlink2.MAVLink(None).parse_buffer(build(mav).pack(mav))
    assert out is not None and len(out) == 1
    return out[0]


def heartbeat(sender=AUTOPILOT):
    if sender == AUTOPILOT:
        kind, autopilot = mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
    elif sender == GCS:
        kind, autopilot = mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID
    else:
        kind, autopilot = mavlink2.MAV_TYPE_ONBOARD_CONTROLLER, mavlink2.MAV_AUTOPILOT_INVALID
    return wire(sender, lambda m: m.heartbeat_encode(kind, autopilot, 0, 0, mavlink2.MAV_STATE_ACTIVE))


def timesync(tc1: int, ts1: int, sender=AUTOPILOT):
    return wire(sender, lambda m: m.timesync_encode(tc1, ts1))


def attitude(boot_ms: int, sender=AUTOPILOT):
    return wire(sender, lambda m: m.attitude_encode(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def system_time(unix_us: int, boot_ms: int, sender=AUTOPILOT):
    return wire(sender, lambda m: m.system_time_encode(unix_us, boot_ms))


# Host times of the tests below: the autopilot booted at host 20 s, the device at host 50 s.
AP_BOOT_HOST_NS = 20 * S
DEV_BOOT_HOST_NS = 50 * S


def ap_boot_ns(host_ns: int) -> int:
    return host_ns - AP_BOOT_HOST_NS


def answer(sync: Synchroniser, ts1: int, rx_ns: int, sender=AUTOPILOT) -> TimesyncReply | None:
    """The autopilot's reply to request `ts1`, stamped by it half-way, received at `rx_ns`."""
    return sync.on_mavlink(timesync(ap_boot_ns((ts1 + rx_ns) // 2), ts1, sender), rx_ns).timesync


# --------------------------------------------------------------------------- TimesyncPairing
class TestTimesyncPairing:
    def test_a_reply_is_paired_with_our_pending_request_once(self):
        p = TimesyncPairing(timeout_ns=S)
        p.request_sent(1_000)
        reply = p.reply(timesync(7_000_000, 1_000), 5_000)
        assert reply == TimesyncReply(1_000, 7_000_000, 5_000) and reply.rtt_ns == 4_000
        assert p.reply(timesync(7_000_000, 1_000), 6_000) is None  # the same answer again
        assert (p.sent, p.answered, p.foreign, p.unanswered, p.pending) == (1, 1, 1, 0, {})

    def test_replies_to_requests_we_never_sent_are_foreign(self):
        p = TimesyncPairing()
        p.request_sent(1_000)
        assert p.reply(timesync(7_000_000, 1_001), 5_000) is None
        assert p.reply(timesync(7_000_000, 999), 5_000) is None
        assert (p.answered, p.foreign, list(p.pending)) == (0, 2, [1_000])

    def test_the_autopilots_own_requests_are_not_replies(self):
        p = TimesyncPairing()
        p.request_sent(1_000)
        assert p.reply(timesync(0, 1_000), 5_000) is None
        assert (p.answered, p.foreign, list(p.pending)) == (0, 0, [1_000])

    def test_a_reply_received_before_its_request_left_is_not_taken(self):
        p = TimesyncPairing()
        p.request_sent(10_000)
        assert p.reply(timesync(7_000_000, 10_000), 9_999) is None
        assert p.foreign == 1

    def test_requests_expire_after_the_timeout_and_count_unanswered(self):
        p = TimesyncPairing(timeout_ns=S)
        p.request_sent(0)
        p.request_sent(S // 2)
        p.expire(S)  # exactly the timeout: still pending
        assert (p.unanswered, sorted(p.pending)) == (0, [0, S // 2])
        p.expire(S + 1)
        assert (p.unanswered, sorted(p.pending)) == (1, [S // 2])
        # a late answer to the expired one is not taken, the other one still is
        assert p.reply(timesync(5, 0), S + 2) is None
        assert p.reply(timesync(5, S // 2), S + 3) == TimesyncReply(S // 2, 5, S + 3)
        assert (p.answered, p.unanswered, p.foreign) == (1, 1, 1)

    def test_forget_counts_every_pending_request_unanswered(self):
        p = TimesyncPairing()
        for ts1 in (1, 2, 3):
            p.request_sent(ts1)
        p.forget()
        assert (p.pending, p.unanswered, p.sent) == ({}, 3, 3)
        assert p.reply(timesync(5, 2), 10) is None


# --------------------------------------------------------------------------- Synchroniser: TIMESYNC
def test_replies_are_taken_only_from_the_autopilot_component_learnt_from_its_heartbeat():
    sync = Synchroniser()
    t = 100 * S
    sync.on_timesync_request(t)
    assert answer(sync, t, t + 2_000_000) is None, "a reply before any HEARTBEAT: nobody is the autopilot yet"
    assert not sync.autopilot_clock.synced

    sync.on_mavlink(heartbeat(COMPANION), t + 3_000_000)  # an onboard computer: not an autopilot
    sync.on_mavlink(heartbeat(GCS), t + 3_500_000)
    assert sync.take_events() == []
    sync.on_mavlink(heartbeat(AUTOPILOT), t + 4_000_000)
    (seen,) = sync.take_events()
    assert seen.kind == "autopilot_seen" and seen.host_ns == t + 4_000_000
    assert sync.autopilot.component == 1

    ts1 = t + 10_000_000
    sync.on_timesync_request(ts1)
    assert answer(sync, ts1, ts1 + 500_000, COMPANION) is None
    assert answer(sync, ts1, ts1 + 600_000, GCS) is None
    assert not sync.autopilot_clock.synced
    reply = answer(sync, ts1, ts1 + 800_000)
    assert reply == TimesyncReply(ts1, ap_boot_ns(ts1 + 400_000), ts1 + 800_000)
    assert sync.autopilot_clock.synced
    assert sync.autopilot_clock.host_to_autopilot_us(ts1 + 400_000) == pytest.approx(ap_boot_ns(ts1 + 400_000) / 1000)
    assert answer(sync, ts1, ts1 + 900_000) is None  # each request is answered once
    c = sync.counters()
    assert (c["timesync_sent"], c["timesync_answered"], c["timesync_foreign"]) == (2, 1, 1)


def test_a_configured_autopilot_component_needs_no_heartbeat():
    sync = Synchroniser(SyncConfig(autopilot_component=1))
    t = 100 * S
    sync.on_mavlink(attitude(80_000), t)  # any message of that component: the autopilot is seen
    assert [e.kind for e in sync.take_events()] == ["autopilot_seen"]
    ts1 = t + 1_000_000
    sync.on_timesync_request(ts1)
    assert answer(sync, ts1, ts1 + 1_000_000, COMPANION) is None
    assert answer(sync, ts1, ts1 + 1_000_000) is not None


def test_unanswered_requests_expire_after_the_timeout():
    sync = Synchroniser(SyncConfig(timesync_timeout_s=1.0))
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.on_timesync_request(t)
    sync.poll(t + S)
    assert sync.counters()["timesync_unanswered"] == 0
    sync.poll(t + S + 1)
    assert sync.counters()["timesync_unanswered"] == 1
    assert answer(sync, t, t + S + 2) is None  # too late: its round trip says nothing
    assert not sync.autopilot_clock.synced
    assert sync.counters()["timesync_foreign"] == 1


def test_pending_requests_are_forgotten_when_the_autopilot_reboots():
    sync = Synchroniser()
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.on_mavlink(attitude(80_000), t + 10_000_000)
    sync.on_mavlink(attitude(80_100), t + 110_000_000)  # a later boot time: nothing happened
    sync.take_events()
    ts1 = t + 1_400_000_000
    sync.on_timesync_request(ts1)
    # boot clock back by 78.6 s after 1.3 s of silence (it was booting): rebooted
    sync.on_mavlink(attitude(1_500), ts1 + 1_000_000)
    (event,) = sync.take_events()
    assert event.kind == "autopilot_rebooted" and "80100 to 1500" in event.detail
    assert sync.counts["autopilot_reboots"] == 1
    assert sync.counters()["timesync_unanswered"] == 1
    assert answer(sync, ts1, ts1 + 2_000_000) is None  # an answer on the old boot clock
    assert not sync.autopilot_clock.synced


def test_pending_requests_are_forgotten_when_the_autopilot_comes_back_after_a_silence():
    def run(silence_ns: int) -> tuple[TimesyncReply | None, list[str]]:
        sync = Synchroniser(SyncConfig(autopilot_timeout_s=3.0))
        t = 100 * S
        sync.on_mavlink(heartbeat(), t)
        sync.take_events()
        ts1 = t + silence_ns - 200_000_000
        sync.on_timesync_request(ts1)
        sync.on_mavlink(heartbeat(), t + silence_ns)
        kinds = [e.kind for e in sync.take_events()]
        return answer(sync, ts1, t + silence_ns + 1_000_000), kinds

    reply, kinds = run(int(2.9 * S))
    assert reply is not None and kinds == []
    reply, kinds = run(int(3.1 * S))
    assert reply is None and kinds == ["autopilot_back"]


def test_timesync_unanswered_is_reported_once_after_ten_unanswered_requests():
    sync = Synchroniser(SyncConfig(timesync_timeout_s=1.0))
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.take_events()
    for k in range(9):
        sync.on_timesync_request(t + k * 100_000_000)
    sync.poll(t + 3 * S)
    assert sync.counters()["timesync_unanswered"] == 9 and sync.take_events() == []
    sync.on_timesync_request(t + 3 * S)
    sync.poll(t + 5 * S)
    (event,) = [e for e in sync.take_events() if e.presence is None]  # not the autopilot's silence (lost)
    assert event.kind == "timesync_unanswered" and event.host_ns == t + 5 * S
    assert "none of 10 TIMESYNC requests" in event.detail
    for k in range(20):
        sync.on_timesync_request(t + 6 * S + k)
    sync.poll(t + 10 * S)
    assert sync.counters()["timesync_unanswered"] == 30
    assert sync.take_events() == []


def test_no_timesync_warning_once_the_autopilot_has_answered():
    sync = Synchroniser(SyncConfig(timesync_timeout_s=1.0))
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.on_timesync_request(t)
    assert answer(sync, t, t + 1_000_000) is not None
    for k in range(12):
        sync.on_timesync_request(t + S + k)
    sync.poll(t + 5 * S)
    assert [e.kind for e in sync.take_events()] == ["autopilot_seen", "autopilot_lost"]  # silent for 5 s


# --------------------------------------------------------------------------- Synchroniser: device reboots
def sync_device_clock(sync: Synchroniser, start_ns: int, n: int = 12) -> None:
    """Exchanges with 100 us each way and a 50 us hold: the device clock is host - 50 s."""
    for k in range(n):
        tx = start_ns + k * 200_000_000
        rx_us = (tx + 100_000 - DEV_BOOT_HOST_NS) // 1000
        sync.on_exchange(tx, rx_us, rx_us + 50, tx + 250_000)


def test_a_hello_with_a_smaller_device_time_resets_the_device_clock():
    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t + 1_000)
    assert sync.device_clock.device_to_host_ns(52_000_000) == pytest.approx(102 * S, abs=100_000)
    # The host reconnected: the device says HELLO again, later on the same clock. Nothing restarts.
    sync.on_device(Hello(protocol_version=1, t_us=(t + 3 * S - DEV_BOOT_HOST_NS) // 1000), t + 3 * S)
    assert sync.counts["device_reboots"] == 0 and sync.take_events() == []
    # Rebooted: its clock starts again from zero.
    sync.on_device(Hello(protocol_version=1, t_us=250_000), t + 4 * S)
    assert sync.counts["device_reboots"] == 1
    (event,) = sync.take_events()
    assert event.kind == "device_rebooted" and event.host_ns == t + 4 * S and "250000" in event.detail
    with pytest.raises(ClockNotSyncedError):
        sync.device_clock.device_to_host_ns(300_000)
    assert sync.hello is not None and sync.hello.t_us == 250_000


def test_a_hello_earlier_than_the_device_time_already_seen_is_a_reboot():
    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=200_000), t)  # HELLO 0.2 s after boot
    sync.on_device(Status(t_us=3_600_000_000), t + 3_600 * S)  # an hour later, same boot
    # USB re-enumeration after a brown-out: the host reconnects and the device, up 1.5 s, says HELLO.
    sync.on_device(Hello(protocol_version=1, t_us=1_500_000), t + 3_610 * S)
    assert sync.counts["device_reboots"] == 1


# --------------------------------------------------------------------------- Synchroniser: telemetry sources
def test_telemetry_from_another_component_of_the_vehicle_is_not_taken():
    sync = Synchroniser()
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.on_mavlink(attitude(80_000, COMPANION), t + 1_000_000)
    assert len(sync.telemetry.attitude) == 0
    assert sync.counters()["telemetry_other_source"] == 1
    sync.on_mavlink(attitude(80_010), t + 2_000_000)
    assert len(sync.telemetry.attitude) == 1


def test_system_time_from_a_companion_computer_does_not_feed_the_utc_mapping():
    sync = Synchroniser()
    t = 100 * S
    sync.on_mavlink(heartbeat(), t)
    sync.on_mavlink(system_time(1_780_000_000_000_000, 3_000_000, COMPANION), t + 1_000_000)
    assert not sync.utc.autopilot_to_utc(3_000_000_000).valid


def test_telemetry_follows_the_configured_autopilot_component():
    sync = Synchroniser(SyncConfig(autopilot_component=2))
    t = 100 * S
    sync.on_mavlink(heartbeat((1, 2)), t)
    sync.on_mavlink(attitude(80_000, (1, 2)), t + 1_000_000)
    assert len(sync.telemetry.attitude) == 1


# --------------------------------------------------------------------------- Synchroniser: frames
def test_poll_stamps_emitted_host_ns_and_emits_each_frame_once():
    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t)
    sync.on_mavlink(heartbeat(), t)
    for k in range(5):  # TIMESYNC: 0.6 ms round trips
        ts1 = t + k * 200_000_000 + 7_000
        sync.on_timesync_request(ts1)
        assert answer(sync, ts1, ts1 + 600_000) is not None
    lat, lon, alt = 473_977_419, 85_455_938, 488_000
    sync.on_mavlink(wire(AUTOPILOT, lambda m: m.gps_raw_int_encode(84_900_000, 3, lat, lon, alt, 80, 120, 0, 0, 12)), t)
    mid_host = 105 * S  # device 55 s, autopilot 85 s
    for boot_ms, dlat in ((84_960, 0), (85_060, 1_000)):
        rx = AP_BOOT_HOST_NS + boot_ms * 1_000_000 + 5_000_000
        if boot_ms > 85_000:
            sync.on_device(
                Exposure(
                    image_index=1,
                    trigger_t_us=54_950_000,
                    feedback_start_t_us=54_995_000,
                    feedback_end_t_us=55_005_000,
                    duration_us=10_000,
                ),
                mid_host + 20_000_000,
            )
            assert sync.poll(mid_host + 30_000_000) == []  # the later sample has not arrived
            assert sync.pending_frames == 1
        sync.on_mavlink(
            wire(
                AUTOPILOT,
                # moving north at the ~111 m/s the two samples imply [cm/s]
                lambda m, b=boot_ms, d=dlat: m.global_position_int_encode(b, lat + d, lon, alt, 0, 11_120, 0, 0, 0),
            ),
            rx,
        )
        sync.on_mavlink(attitude(boot_ms), rx)
    now = AP_BOOT_HOST_NS + 85_060 * 1_000_000 + 6_000_000
    (frame,) = sync.poll(now)
    assert frame.emitted_host_ns == now
    assert frame.mid_device_us == 55_000_000
    assert frame.mid_host_ns == pytest.approx(mid_host, abs=200_000)
    assert frame.frame_seq == 1 and "no_fix" not in frame.flags and "clock_unsynced" not in frame.flags
    # 40 % of the way from the first sample to the second (~11.1 m north), within a 1 ms mapping error
    assert frame.north_m == pytest.approx(0.4 * 1_000e-7 * 111_200, abs=0.12)
    assert sync.poll(now + S) == [] and sync.poll(now + S, flush=True) == []
    assert sync.counts["frames"] == 1 and sync.counts["exposures"] == 1


def test_flush_emits_every_pending_frame_stamped_with_the_flush_time():
    sync = Synchroniser()
    for k in range(3):
        sync.on_device(Exposure(image_index=k + 1, trigger_t_us=1_000 + k), 10 * S + k)
    assert sync.poll(10 * S + 100) == []
    frames = sync.poll(10 * S + 200, flush=True)
    assert [f.image_index for f in frames] == [1, 2, 3]
    assert {f.emitted_host_ns for f in frames} == {10 * S + 200}
    assert all("clock_unsynced" in f.flags for f in frames)
    assert [f.mid_host_ns for f in frames] == [10 * S, 10 * S + 1, 10 * S + 2]  # arrival times, said so


# --------------------------------------------------------------------------- SyncConfig
def test_sync_config_round_trips_through_json():
    cfg = SyncConfig(
        geotag=GeotagConfig(
            focal_length_mm=24.0,
            mount_pitch_deg=-30.0,
            lever_arm_body_m=(0.12, -0.03, 0.08),
            gimbal_stabilised=True,
            surface_normal_enu=(0.0, -1.0, 0.0),
            origin=(47.1, 8.2, 430.5),
            max_wait_s=0.25,
        ),
        autopilot_system=3,
        autopilot_component=1,
        autopilot_timeout_s=5.0,
        timesync_timeout_s=0.5,
    )
    data = json.loads(json.dumps(cfg.to_json()))
    assert data["geotag"]["lever_arm_body_m"] == [0.12, -0.03, 0.08]
    back = SyncConfig.from_json(data)
    assert back == cfg
    assert isinstance(back.geotag.lever_arm_body_m, tuple)
    assert SyncConfig.from_json(json.loads(json.dumps(SyncConfig().to_json()))) == SyncConfig()


def test_sync_config_from_json_ignores_unknown_keys_and_defaults_missing_ones(caplog):
    back = SyncConfig.from_json({"autopilot_system": 7, "future_key": 1, "geotag": {"blur_limit_px": 2.0, "new": 0}})
    assert back == SyncConfig(autopilot_system=7, geotag=GeotagConfig(blur_limit_px=2.0))
    assert "future_key, geotag.new" in caplog.text  # ignored, but said
    assert SyncConfig.from_json({}) == SyncConfig()


def test_settings_stored_by_an_older_recorder_are_read_with_their_units_converted():
    """Logs written before issue 26 store milliseconds and microseconds under the old names, and a retired key."""
    old = {
        "autopilot_system": 2,
        "one_way_min_delay_allowance_ms": 5.0,
        "geotag": {
            "max_wait_ms": 250.0,
            "range_stale_ms": 40,
            "max_clock_uncertainty_us": 2000.0,
            "stale_pose_ms": 100,
        },
    }
    back = SyncConfig.from_json(old)
    assert back == SyncConfig(
        autopilot_system=2,
        one_way_min_delay_allowance_s=0.005,
        geotag=GeotagConfig(max_wait_s=0.25, range_stale_s=0.04, max_clock_uncertainty_s=0.002),
    )


def test_a_stored_value_out_of_its_range_is_an_error_not_a_default():
    with pytest.raises(ValueError, match="autopilot_timeout_s"):
        SyncConfig.from_json({"autopilot_timeout_s": -1.0})
    with pytest.raises(ValueError, match="max_wait_s"):  # an old name with a value that is not a number
        SyncConfig.from_json({"geotag": {"max_wait_ms": "500"}})


# --------------------------------------------------------------------------- Synchroniser: frames resent late
def test_late_resent_events_and_samples_are_taken_in_place() -> None:
    """After a gap the device resends (RESEND): exposures arrive after later ones, IMU and range samples older
    than those held, PPS edges older than the last fitted. Every exposure becomes a frame, the old samples
    are inserted (not taken for a device reboot), the old PPS edge is skipped and counted."""
    from icgt.protocol.messages import Imu, Pps, Range

    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t)
    dev0 = (t - DEV_BOOT_HOST_NS) // 1000  # device us at host t
    for k in range(50):  # live samples 5 s .. 10 s after t
        d = dev0 + 5_000_000 + k * 100_000
        sync.on_device(Imu(read_start_t_us=d, read_end_t_us=d + 1000, quat_w=1.0), t + 5 * S + k * 100_000_000)
        sync.on_device(Range(acq_start_t_us=d, read_t_us=d + 500, distance_cm=300, flags=1), t + 5 * S)
    sync.on_device(Pps(t_us=dev0 + 9_000_000, pps_count=9), t + 9 * S)
    sync.on_device(Exposure(image_index=20, trigger_t_us=dev0 + 9_500_000), t + 10 * S)
    # the gap comes back: older exposures, samples and PPS, 4-6 s older than what is held
    for k in range(5):
        d = dev0 + 1_000_000 + k * 200_000
        sync.on_device(Imu(read_start_t_us=d, read_end_t_us=d + 1000, quat_w=1.0), t + 11 * S)
        sync.on_device(Range(acq_start_t_us=d, read_t_us=d + 500, distance_cm=250, flags=1), t + 11 * S)
        sync.on_device(Exposure(image_index=10 + k, trigger_t_us=d + 10), t + 11 * S)
    sync.on_device(Pps(t_us=dev0 + 2_000_000, pps_count=2), t + 11 * S)
    assert sync.counts["late_pps_skipped"] == 1 and sync.counts["device_reboots"] == 0
    frames = sync.poll(t + 12 * S, flush=True)
    assert sorted(f.image_index for f in frames) == [10, 11, 12, 13, 14, 20]
    late = [f for f in frames if f.image_index < 20]
    assert all(f.range_m is not None and abs(f.range_m - 2.5) < 0.05 for f in late), "the resent ranges were used"
    (live,) = [f for f in frames if f.image_index == 20]
    assert live.range_m is not None and abs(live.range_m - 3.0) < 0.05, "the live ranges were kept"


def test_an_exposure_resent_minutes_late_is_posed_from_the_telemetry_that_came_on_time() -> None:
    """Issue 27: the autopilot's telemetry (50 Hz fused position) is kept for the device's history horizon,
    so an exposure that comes back through RESEND 5 minutes after it was made is posed and not `no_fix`."""
    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t)
    sync.on_mavlink(heartbeat(), t)
    for k in range(5):
        ts1 = t + k * 200_000_000 + 7_000
        sync.on_timesync_request(ts1)
        assert answer(sync, ts1, ts1 + 600_000) is not None
    lat, lon, alt = 473_977_419, 85_455_938, 488_000
    boot0_ms = (t - AP_BOOT_HOST_NS) // 1_000_000  # 80 s
    for k in range(360 * 50):  # 6 minutes of 50 Hz fused position, 5 Hz GPS, 10 Hz attitude
        boot_ms = boot0_ms + 1_000 + k * 20
        rx = AP_BOOT_HOST_NS + boot_ms * 1_000_000 + 5_000_000
        if k % 10 == 0:
            gps_us = boot_ms * 1000
            sync.on_mavlink(
                wire(AUTOPILOT, lambda m, u=gps_us: m.gps_raw_int_encode(u, 6, lat, lon, alt, 80, 120, 0, 0, 12)), rx
            )
        if k % 5 == 0:
            sync.on_mavlink(attitude(boot_ms), rx)
        fused = wire(AUTOPILOT, lambda m, b=boot_ms, d=k: m.global_position_int_encode(b, lat + d, lon, alt, *[0] * 5))
        sync.on_mavlink(fused, rx)
    # made at host t + 60 s (device 110 s), received 5 minutes later
    mid_us = (t + 60 * S - DEV_BOOT_HOST_NS) // 1000
    exposure = Exposure(
        image_index=1, trigger_t_us=mid_us - 50_000, feedback_start_t_us=mid_us - 5_000,
        feedback_end_t_us=mid_us + 5_000, duration_us=10_000,
    )  # fmt: skip
    sync.on_device(exposure, t + 361 * S)
    (frame,) = sync.poll(t + 362 * S)
    assert "no_fix" not in frame.flags and frame.position_source == "rtk_fixed"
    assert frame.lat_deg is not None
    # 59 s after the first sample at 1e-7 deg a sample: 2950 steps north, within a sample
    assert frame.lat_deg == pytest.approx((lat + 2950) * 1e-7, abs=2e-7)
    assert "no_attitude" not in frame.flags
    assert sync.telemetry.retention_s is not None and sync.telemetry.retention_s >= 10 * 60


def test_a_resent_exposure_without_its_range_samples_says_the_outage_took_them() -> None:
    """Issue 27, outage accounting: a resent frame is flagged `resent`; when none of the range samples around
    its mid-exposure came back it is `range_samples_lost` (the outage's doing), and a live frame without a
    valid return is only `range_invalid`."""
    from icgt.protocol.messages import Range

    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=1, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t)
    dev0 = (t - DEV_BOOT_HOST_NS) // 1000
    for k in range(20):  # ranges 5 s .. 7 s after t, no valid return
        d = dev0 + 5_000_000 + k * 100_000
        sync.on_device(Range(acq_start_t_us=d, read_t_us=d + 500, distance_cm=0, flags=0), t + 5 * S)
    sync.on_device(Exposure(image_index=3, trigger_t_us=dev0 + 6_000_000), t + 6 * S)
    sync.on_device(Exposure(image_index=1, trigger_t_us=dev0 + 1_000_000), t + 7 * S, retransmitted=True)
    sync.on_device(Exposure(image_index=2, trigger_t_us=dev0 + 6_500_000), t + 7 * S, retransmitted=True)
    frames = {f.image_index: f for f in sync.poll(t + 8 * S, flush=True)}
    assert "resent" not in frames[3].flags and "range_invalid" in frames[3].flags
    assert "range_samples_lost" not in frames[3].flags
    assert {"resent", "range_invalid", "range_samples_lost"} <= set(frames[1].flags)
    assert "resent" in frames[2].flags and "range_samples_lost" not in frames[2].flags  # samples, none valid


def test_a_resent_exposure_whose_samples_are_gone_is_ranged_and_oriented_from_its_own_snapshot() -> None:
    """Issue 27 part 1 (protocol 2): the range and BNO055 attitude of a frame whose samples the host no longer
    has come from the EXPOSURE's snapshot, flagged and named as the source; a frame with samples around mid
    keeps using them; a snapshot too old, or none (a version-1 log), leaves the frame unranged as before."""
    from icgt.protocol.messages import Imu, Range, SnapshotFlags

    sync = Synchroniser()
    t = 100 * S
    sync.on_device(Hello(protocol_version=2, t_us=(t - DEV_BOOT_HOST_NS) // 1000), t)
    sync_device_clock(sync, t)
    dev0 = (t - DEV_BOOT_HOST_NS) // 1000
    for k in range(200):  # valid ranges (3.00 m) and IMU samples (identity) 5 s .. 7 s after t, at 100 Hz
        d = dev0 + 5_000_000 + k * 10_000
        sync.on_device(Range(acq_start_t_us=d, read_t_us=d + 500, distance_cm=300, flags=1), t + 5 * S)
        sync.on_device(Imu(read_start_t_us=d, read_end_t_us=d + 1000, quat_w=1.0, calib_stat=0xFF), t + 5 * S)
    full = int(SnapshotFlags.RANGE_VALID | SnapshotFlags.RANGE_INTERPOLATED | SnapshotFlags.IMU_VALID)
    # A quarter turn about z, 0.5 rad/s about z, calibrated; 4.321 m, 2 ms from its nearer acquisition.
    snap = dict(
        snapshot_flags=full, range_mm=4321, range_age_us=2000, imu_age_us=3000, imu_calib_stat=0xFF,
        quat_w_q14=11585, quat_z_q14=11585, gyro_z_rad900=450,
    )  # fmt: skip
    sync.on_device(Exposure(image_index=1, trigger_t_us=dev0 + 1_000_000, **snap), t + 7 * S, retransmitted=True)
    sync.on_device(Exposure(image_index=2, trigger_t_us=dev0 + 6_000_000, **snap), t + 7 * S)
    stale = dict(snap, range_age_us=0xFFFF)
    sync.on_device(Exposure(image_index=3, trigger_t_us=dev0 + 1_500_000, **stale), t + 7 * S, retransmitted=True)
    sync.on_device(Exposure(image_index=4, trigger_t_us=dev0 + 2_000_000), t + 7 * S, retransmitted=True)
    frames = {f.image_index: f for f in sync.poll(t + 8 * S, flush=True)}

    gone = frames[1]
    assert gone.range_m == pytest.approx(4.321) and gone.range_age_ms == pytest.approx(2.0) and gone.range_valid
    assert gone.range_source == "snapshot" and "range_from_snapshot" in gone.flags
    assert not {"range_invalid", "range_samples_lost"} & set(gone.flags)
    assert gone.imu_source == "snapshot" and "imu_from_snapshot" in gone.flags
    assert (gone.imu_qw, gone.imu_qz) == (pytest.approx(0.70709, abs=1e-4), pytest.approx(0.70709, abs=1e-4))
    assert gone.imu_gyro_rad_s == pytest.approx(0.5) and gone.imu_age_ms == pytest.approx(3.0)
    assert gone.imu_calib_sys == 3 and "imu_uncalibrated" not in gone.flags

    live = frames[2]  # samples at mid: they win over the snapshot
    assert live.range_m == pytest.approx(3.0) and live.range_source == "samples" and live.imu_source == "samples"
    assert live.imu_qw == pytest.approx(1.0)
    assert not {"range_from_snapshot", "imu_from_snapshot"} & set(live.flags)

    for too_old_or_none in (frames[3], frames[4]):
        assert too_old_or_none.range_m is None and too_old_or_none.range_source == "none"
        assert {"resent", "range_invalid", "range_samples_lost"} <= set(too_old_or_none.flags)
    assert frames[3].imu_source == "snapshot" and frames[4].imu_source == "samples"  # v1: the nearest sample held


def test_each_outage_and_reboot_is_one_presence_change_with_its_outage():
    """The one autopilot state machine: lost once per silence longer than autopilot_timeout_s (at a poll), back (or
    rebooted) once at its next message, each with the silence it ended; a reboot without a loss has no outage."""
    from icgt.mavlink.autopilot_rules import AutopilotState, PresenceChange

    sync = Synchroniser(SyncConfig(autopilot_timeout_s=2.0))
    assert sync.autopilot.state is AutopilotState.WAITING
    t = 100 * S
    sync.on_mavlink(attitude(80_000), t)
    sync.on_mavlink(heartbeat(), t)
    for k in range(1, 31):  # polled every 100 ms through 3 s of silence
        sync.poll(t + k * 100_000_000)
    assert sync.autopilot.state is AutopilotState.LOST
    sync.on_mavlink(attitude(83_500), t + 3_500_000_000)  # back after 3.5 s
    sync.poll(t + 3_600_000_000)
    sync.on_mavlink(attitude(1_500), t + 5_100_000_000)  # rebooted after 1.6 s: no loss
    sync.poll(t + 5_200_000_000)
    events = sync.take_events()
    assert [e.presence for e in events] == [
        PresenceChange.SEEN,
        PresenceChange.LOST,
        PresenceChange.BACK,
        PresenceChange.REBOOTED,
    ]
    seen, lost, back, rebooted = events
    assert lost.kind == "autopilot_lost" and lost.host_ns == t + 2_100_000_000 and lost.outage_ns == 2_100_000_000
    assert back.outage_ns == 3_500_000_000 and rebooted.outage_ns == 0 and seen.outage_ns == 0
    assert sync.autopilot.state is AutopilotState.UP
    assert sync.counts["autopilot_outages"] == 1 and sync.counts["autopilot_reboots"] == 1
    # a reboot that ends a loss closes that outage
    sync.on_mavlink(attitude(3_500), t + 7_100_000_000)  # the rebooted autopilot's clock runs on
    for k in range(1, 31):
        sync.poll(t + 7_100_000_000 + k * 100_000_000)
    sync.on_mavlink(attitude(200), t + 10_600_000_000)
    lost, rebooted = sync.take_events()
    assert lost.presence is PresenceChange.LOST and rebooted.presence is PresenceChange.REBOOTED
    assert rebooted.outage_ns == 3_500_000_000
