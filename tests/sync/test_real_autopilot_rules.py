"""Real-autopilot rules of the synchroniser, fed real-looking sequences by hand (issue 9):

* no TIMESYNC answers: the autopilot clock comes from arrival times, frames say `arrival`;
* an EKF local-origin reset (ArduPilot: LOCAL_POSITION_NED jumps, GPS_GLOBAL_ORIGIN changes) starts a new
  local epoch, and no position is anchored across it;
* UTC: a SITL clock in year 2908 is refused; a switch from the host clock to GPS time is logged with its jump.
"""

from __future__ import annotations

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.sync import Synchroniser

S = 1_000_000_000
AP_BOOT_HOST_NS = 20 * S
AUTOPILOT = (1, 1)


def wire(build, sender=AUTOPILOT):
    mav = mavlink2.MAVLink(None, srcSystem=sender[0], srcComponent=sender[1])
    out = mavlink2.MAVLink(None).parse_buffer(build(mav).pack(mav))
    assert out is not None and len(out) == 1
    return out[0]


def heartbeat():
    return wire(lambda m: m.heartbeat_encode(2, 3, 0, 0, 4))


def local(boot_ms: int, x: float, vx: float = 0.0):
    return wire(lambda m: m.local_position_ned_encode(boot_ms, x, 0.0, -5.0, vx, 0.0, 0.0))


def rx_of(boot_ms: int, delay_ms: float = 1.0) -> int:
    return AP_BOOT_HOST_NS + int((boot_ms + delay_ms) * 1e6)


def test_without_timesync_the_arrival_clock_maps_the_autopilot() -> None:
    sync = Synchroniser()
    sync.on_mavlink(heartbeat(), rx_of(0))
    for k in range(200):  # 20 s of ATTITUDE at 10 Hz, 1-4 ms late
        boot = 1_000 + 100 * k
        sync.on_mavlink(wire(lambda m, b=boot: m.attitude_encode(b, 0, 0, 0, 0, 0, 0)), rx_of(boot, 1.0 + (k % 4)))
    assert sync.autopilot_time.method().value == "arrival"
    boot_us = sync.autopilot_time.host_to_autopilot_us(AP_BOOT_HOST_NS + 15 * S)
    assert abs(boot_us - 15_000_000) <= 2_000  # the 1 ms floor and the stamp's truncation


def test_a_local_origin_reset_starts_a_new_epoch() -> None:
    sync = Synchroniser()
    sync.on_mavlink(heartbeat(), rx_of(0))
    for k in range(10):  # 2 m/s along x at 10 Hz
        sync.on_mavlink(local(1_000 + 100 * k, 0.2 * k, 2.0), rx_of(1_000 + 100 * k))
    sync.on_mavlink(local(2_000, 483.0, 2.0), rx_of(2_000))  # the EKF reset its origin: 483 m in 0.1 s
    sync.on_mavlink(local(2_100, 483.2, 2.0), rx_of(2_100))
    samples = sync.telemetry.local_position.samples()
    assert [s.epoch for s in samples] == [0] * 10 + [1, 1]
    origin = wire(lambda m: m.gps_global_origin_encode(473_977_419, 85_455_938, 488_000, 0))
    sync.on_mavlink(origin, rx_of(2_150))
    sync.on_mavlink(origin, rx_of(2_160))  # the same origin again: nothing new
    moved = wire(lambda m: m.gps_global_origin_encode(473_977_500, 85_455_938, 488_000, 0))
    sync.on_mavlink(moved, rx_of(2_170))
    sync.on_mavlink(local(2_200, 1.0, 2.0), rx_of(2_200))
    assert sync.telemetry.local_position.latest().epoch == 2
    assert sync.counters()["telemetry_local_origin_resets"] == 2


def test_fast_flight_is_not_an_origin_reset() -> None:
    sync = Synchroniser()
    sync.on_mavlink(heartbeat(), rx_of(0))
    for k in range(20):  # 25 m/s at 4 Hz: 6.25 m between samples, as the velocity says
        sync.on_mavlink(local(1_000 + 250 * k, 6.25 * k, 25.0), rx_of(1_000 + 250 * k))
    assert {s.epoch for s in sync.telemetry.local_position.samples()} == {0}


def test_a_clock_in_the_year_2908_is_refused_and_counted() -> None:
    sync = Synchroniser()
    sync.on_host_realtime(0, 1_780_000_000 * S)
    sync.on_mavlink(heartbeat(), rx_of(0))
    year_2908 = 29_590_000_000 * 1_000_000
    for k in range(5):
        sync.on_mavlink(wire(lambda m, k=k: m.system_time_encode(year_2908 + k * 500_000, 1_000 + 500 * k)), rx_of(0))
    assert sync.counters()["utc_ignored_implausible"] == 5
    assert sync.utc.host_to_utc(AP_BOOT_HOST_NS).source.value == "host_realtime"


def test_the_switch_from_the_host_clock_to_gps_time_is_logged_with_its_jump() -> None:
    sync = Synchroniser()
    host_utc_ns = 1_780_000_000 * S
    sync.on_host_realtime(0, host_utc_ns - AP_BOOT_HOST_NS)  # host clock: UTC 1_780_000_000 s at the autopilot's boot
    sync.on_mavlink(heartbeat(), rx_of(0))
    sync.poll(rx_of(10))
    assert sync.take_events()[-1].kind == "autopilot_seen"
    for k in range(40):  # the autopilot's GPS time is 2.5 s ahead of this host's clock
        boot = 1_000 + 100 * k
        sync.on_mavlink(wire(lambda m, b=boot: m.attitude_encode(b, 0, 0, 0, 0, 0, 0)), rx_of(boot))
        utc_us = (host_utc_ns + boot * 1_000_000 + 2_500_000_000) // 1000
        sync.on_mavlink(wire(lambda m, u=utc_us, b=boot: m.system_time_encode(u, b)), rx_of(boot))
    sync.poll(rx_of(5_000))
    (event,) = [e for e in sync.take_events() if e.kind == "utc_source_changed"]
    assert "system_time" in event.detail and "host_realtime" in event.detail
    jump_s = float(event.detail.split(": ")[1].split(" s ")[0])
    assert jump_s == pytest.approx(2.5, abs=0.002)  # seconds from the host clock
