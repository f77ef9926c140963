"""SimAutopilot end to end over real UDP on 127.0.0.1 (ephemeral ports), read with pymavlink."""

from __future__ import annotations

import copy
import itertools
import math
import socket
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import LocalFrame, enu_to_ned, q_to_euler_zyx
from icgt.sim.autopilot import SimAutopilot
from icgt.sim.scenario import Scenario, parse_scenario
from icgt.sim.trajectory import Trajectory
from icgt.sim.truth import ClockMaps

TAU_AT_START_S = 10.0  # the run starts in the cruise of the deck pass (10 m/s)
FIX_AT_S = 11.0
AP_OFFSET_US = 123_456_789
AP_DRIFT_PPM = 300.0  # 3 ms after 10 s: 3 cm at 10 m/s, far beyond the tolerances below

SCENARIO: dict[str, Any] = {
    "name": "autopilot-test",
    "duration_s": 60.0,
    "seed": 5,
    "origin": {"lat_deg": 37.8813, "lon_deg": 127.7298, "alt_m": 76.0, "geoid_separation_m": 24.9},
    "structure": {"point_m": [0.0, 20.0, 17.0], "normal": [0.0, -1.0, 0.0]},
    "trajectory": {"kind": "deck_pass", "standoff_m": 5.0, "speed_m_s": 10.0, "length_m": 200.0, "ramp_s": 4.0},
    "gps": {
        "fix_type": 6,
        "fix_acquired_after_s": FIX_AT_S,
        "noise_horizontal_m": 0.0,
        "noise_vertical_m": 0.0,
        "fused_noise_horizontal_m": 0.0,
        "fused_noise_vertical_m": 0.0,
    },
    "autopilot": {"mavlink1_messages": ["HEARTBEAT"], "rates_hz": {"system_time": 5.0}},
    "clocks": {"autopilot": {"offset_s": AP_OFFSET_US / 1e6, "drift_ppm": AP_DRIFT_PPM}},
}


class Peer:
    """A pymavlink peer on its own UDP socket that records (receive ns, first byte, message)."""

    def __init__(self, remote: tuple[str, int] | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.port = self.sock.getsockname()[1]
        self.remote = remote
        self.parser = mavlink2.MAVLink(None)
        self.parser.robust_parsing = True
        self.log: list[tuple[int, int, Any]] = []
        self.lock = threading.Lock()
        self.running = True
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while self.running:
            try:
                data, addr = self.sock.recvfrom(65536)
            except (TimeoutError, OSError):
                continue
            now = time.monotonic_ns()
            if self.remote is None:
                self.remote = addr
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    with self.lock:
                        self.log.append((now, data[0], msg))

    def send(self, msg: Any, sysid: int = 255, compid: int = 190) -> None:
        assert self.remote is not None
        self.sock.sendto(msg.pack(mavlink2.MAVLink(None, sysid, compid)), self.remote)

    def received(self, mtype: str | None = None, after_ns: int = 0) -> list[tuple[int, int, Any]]:
        with self.lock:
            return [e for e in self.log if e[0] >= after_ns and (mtype is None or e[2].get_type() == mtype)]

    def wait_for(self, pred: Callable[[Any], bool], after_ns: int, timeout_s: float = 2.0) -> Any:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for _, _, msg in self.received(after_ns=after_ns):
                if pred(msg):
                    return msg
            time.sleep(0.005)
        return None

    def close(self) -> None:
        self.running = False
        self.thread.join()
        self.sock.close()


def make_scenario(**extra: Any) -> Scenario:
    data = copy.deepcopy(SCENARIO)
    for section, values in extra.items():
        data.setdefault(section, {}).update(values)
    return parse_scenario(data, "test")


def wait_tau(clocks: ClockMaps, tau_s: float) -> None:
    while clocks.host_ns_to_tau(time.monotonic_ns()) < tau_s:
        time.sleep(0.01)


class Rig:
    def __init__(self, scenario: Scenario, tau_at_start_s: float) -> None:
        self.scenario = scenario
        self.clocks = ClockMaps.from_scenario(
            scenario, time.monotonic_ns() - round(tau_at_start_s * 1e9), time.time_ns() // 1000
        )
        self.companion = Peer()
        self.ap = SimAutopilot(scenario, self.clocks, f"udpout:127.0.0.1:{self.companion.port}", "udpin:127.0.0.1:0")
        self.ap.start()
        gcs_address = self.ap.gcs_address
        assert gcs_address is not None
        self.gcs = Peer(remote=("127.0.0.1", gcs_address[1]))

    def close(self) -> None:
        self.ap.stop()
        self.companion.close()
        self.gcs.close()

    def command(self, peer: Peer, command: int, *params: float, target: tuple[int, int] = (1, 1)) -> Any:
        """Send COMMAND_LONG and return the COMMAND_ACK for it (or None)."""
        p = [*params] + [0.0] * (7 - len(params))
        before = time.monotonic_ns()
        peer.send(mavlink2.MAVLink_command_long_message(target[0], target[1], command, 0, *p))
        return peer.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == command, before)


@pytest.fixture(scope="module")
def rig() -> Iterator[Rig]:
    r = Rig(make_scenario(), TAU_AT_START_S)
    yield r
    r.close()
    assert r.ap.errors == []


def stamp_tau(clocks: ClockMaps, stamp_us: float) -> float:
    return float(clocks.autopilot_us_to_tau(stamp_us))


def test_streams_arrive_stamped_on_the_boot_clock(rig: Rig) -> None:
    wait_tau(rig.clocks, FIX_AT_S + 0.8)
    log = rig.companion.received()
    types = {m.get_type() for _, _, m in log}
    assert types >= {
        "HEARTBEAT",
        "GPS_RAW_INT",
        "GLOBAL_POSITION_INT",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "LOCAL_POSITION_NED",
        "SYSTEM_TIME",
    }
    traj = Trajectory(rig.scenario)
    frame = LocalFrame(37.8813, 127.7298, 76.0 + 24.9)
    checked = 0
    delays_ms: dict[str, list[float]] = {}
    for recv_ns, _, m in log:
        if not hasattr(m, "time_boot_ms") and m.get_type() != "GPS_RAW_INT":
            continue
        stamp_us = m.time_usec if m.get_type() == "GPS_RAW_INT" else m.time_boot_ms * 1000
        ap_at_receipt_us = float(rig.clocks.tau_to_autopilot_us(rig.clocks.host_ns_to_tau(recv_ns)))
        delay_ms = (ap_at_receipt_us - stamp_us) / 1000.0
        assert delay_ms >= 1.4, (m.get_type(), delay_ms)  # sent ~2 ms after its stamp, never before
        delays_ms.setdefault(m.get_type(), []).append(delay_ms)
        tau = stamp_tau(rig.clocks, stamp_us)
        st = traj.state(np.array([tau]))
        ned = enu_to_ned(st.position_enu_m[0])
        if m.get_type() == "LOCAL_POSITION_NED":
            assert (m.x, m.y, m.z) == pytest.approx(tuple(ned), abs=2e-3)
            assert m.vy == pytest.approx(10.0, abs=1e-3)  # east at cruise speed
            assert m.time_boot_ms % 100 == 0  # the 10 Hz grid of the boot clock
            checked += 1
        elif m.get_type() == "ATTITUDE":
            roll, pitch, yaw = (float(a[0]) for a in q_to_euler_zyx(st.q_body_ned))
            assert (m.roll, m.pitch, m.yaw) == pytest.approx((roll, pitch, yaw), abs=1e-5)
        elif m.get_type() == "ATTITUDE_QUATERNION":
            assert (m.q1, m.q2, m.q3, m.q4) == pytest.approx(tuple(st.q_body_ned[0]), abs=1e-6)
        elif m.get_type() in ("GLOBAL_POSITION_INT", "GPS_RAW_INT") and tau >= FIX_AT_S:
            lat, lon, h = frame.enu_to_geodetic(st.position_enu_m[0])
            assert m.lat == pytest.approx(float(lat) * 1e7, abs=1.5)
            assert m.lon == pytest.approx(float(lon) * 1e7, abs=1.5)
            assert m.alt == pytest.approx((float(h) - 24.9) * 1000, abs=1.5)
            checked += 1
    assert checked >= 20
    # Upper bound on the typical delay only: a receiver the shared machine descheduled for a
    # moment gets some messages late, which says nothing about the autopilot's stamps.
    for kind, delays in delays_ms.items():
        assert float(np.median(delays)) <= 50.0, (kind, sorted(delays))


def test_no_fix_until_acquired_then_gps_time(rig: Rig) -> None:
    wait_tau(rig.clocks, FIX_AT_S + 0.8)
    gps = [m for _, _, m in rig.companion.received("GPS_RAW_INT")]
    before = [m for m in gps if stamp_tau(rig.clocks, m.time_usec) < FIX_AT_S]
    after = [m for m in gps if stamp_tau(rig.clocks, m.time_usec) >= FIX_AT_S]
    assert before and after
    assert all(m.fix_type < 3 and m.lat == 0 and m.lon == 0 for m in before)
    assert all(m.fix_type == 6 for m in after)
    times = [m for _, _, m in rig.companion.received("SYSTEM_TIME")]
    early = [m for m in times if stamp_tau(rig.clocks, m.time_boot_ms * 1000) < FIX_AT_S]
    late = [m for m in times if stamp_tau(rig.clocks, m.time_boot_ms * 1000) >= FIX_AT_S]
    assert early and late
    assert all(m.time_unix_usec == 0 for m in early)
    for m in late:
        utc = rig.clocks.tau_to_utc_us(stamp_tau(rig.clocks, m.time_boot_ms * 1000))
        assert m.time_unix_usec == pytest.approx(utc, abs=2)


def test_heartbeat_is_a_mavlink1_frame_among_mavlink2(rig: Rig) -> None:
    wait_tau(rig.clocks, TAU_AT_START_S + 1.2)
    beats = rig.companion.received("HEARTBEAT")
    assert len(beats) >= 1
    for _, first_byte, m in beats:
        assert first_byte == 0xFE
        assert m.get_srcSystem() == 1 and m.get_srcComponent() == 1
        assert m.type == mavlink2.MAV_TYPE_QUADROTOR and m.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert m.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    others = rig.companion.received("ATTITUDE")
    assert others and all(first == 0xFD for first, _ in ((e[1], e[2]) for e in others))


def test_timesync_answered_with_boot_time(rig: Rig) -> None:
    errors = []
    for _ in range(5):
        ts1 = time.monotonic_ns()
        rig.companion.send(mavlink2.MAVLink_timesync_message(0, ts1))
        reply = rig.companion.wait_for(lambda m, sent=ts1: m.get_type() == "TIMESYNC" and m.ts1 == sent, ts1)
        assert reply is not None
        now = max(e[0] for e in rig.companion.received("TIMESYNC") if e[2].ts1 == ts1)
        assert reply.tc1 % 1000 == 0  # microsecond granularity, as ArduPilot
        estimate_ns = ((reply.ts1 + now) - 2 * reply.tc1) / 2  # host minus autopilot
        true_ns = now - float(rig.clocks.tau_to_autopilot_us(rig.clocks.host_ns_to_tau(now))) * 1000
        # the two-way estimate is off by at most half the round trip (the path's asymmetry), plus tc1's 1 us
        errors.append(abs(estimate_ns - true_ns) - (now - ts1) / 2)
    # every answer within its own bound: under load the error comes with a long round trip, not a wrong stamp
    assert max(errors) <= 2_000, errors


def test_set_message_interval_changes_the_rate(rig: Rig) -> None:
    att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
    ack = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, att, 20_000)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    assert (ack.target_system, ack.target_component) == (255, 190)
    time.sleep(0.05)
    start = time.monotonic_ns()
    time.sleep(0.5)
    fast = [m for _, _, m in rig.companion.received("ATTITUDE", start)]
    assert 20 <= len(fast) <= 30
    assert {b.time_boot_ms - a.time_boot_ms for a, b in itertools.pairwise(fast)} == {20}
    ack = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, att, -1)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    time.sleep(0.05)
    start = time.monotonic_ns()
    time.sleep(0.3)
    assert rig.companion.received("ATTITUDE", start) == []
    ack = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, att, 0)  # back to the default
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    start = time.monotonic_ns()
    time.sleep(0.35)
    default = [m for _, _, m in rig.companion.received("ATTITUDE", start)]
    assert 2 <= len(default) <= 5 and all(m.time_boot_ms % 100 == 0 for m in default)
    denied = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, 263, 100_000)
    assert denied.result == mavlink2.MAV_RESULT_DENIED


def test_request_message_sends_it_once_with_an_ack(rig: Rig) -> None:
    before = time.monotonic_ns()
    ack = rig.command(rig.companion, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    version = rig.companion.wait_for(lambda m: m.get_type() == "AUTOPILOT_VERSION", before)
    assert version is not None and version.capabilities & mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME, -1)
    time.sleep(0.05)
    before = time.monotonic_ns()
    ack = rig.command(rig.companion, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME)
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    assert rig.companion.wait_for(lambda m: m.get_type() == "SYSTEM_TIME", before) is not None
    time.sleep(0.3)
    assert len(rig.companion.received("SYSTEM_TIME", before)) == 1  # once, the stream is off
    rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME, 0)
    assert rig.command(rig.companion, mavlink2.MAV_CMD_REQUEST_MESSAGE, 9999).result == mavlink2.MAV_RESULT_DENIED
    unsupported = rig.command(rig.companion, mavlink2.MAV_CMD_DO_SET_ROI_NONE)
    assert unsupported.result == mavlink2.MAV_RESULT_UNSUPPORTED


def test_routing_between_gcs_and_camera_component(rig: Rig) -> None:
    gcs, companion = rig.gcs, rig.companion
    start = time.monotonic_ns()
    gcs.send(mavlink2.MAVLink_heartbeat_message(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    # the ground station now hears the autopilot
    assert gcs.wait_for(lambda m: m.get_type() == "ATTITUDE_QUATERNION", start) is not None
    # GCS -> camera (1, 100): forwarded to the companion link with the GCS's ids
    gcs.send(
        mavlink2.MAVLink_command_long_message(1, 100, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0.2, 0, 0, 0, 0, 0)
    )
    cmd = companion.wait_for(lambda m: m.get_type() == "COMMAND_LONG", start)
    assert cmd is not None and cmd.command == mavlink2.MAV_CMD_IMAGE_START_CAPTURE
    assert (cmd.get_srcSystem(), cmd.get_srcComponent(), cmd.target_component) == (255, 190, 100)
    # camera component on the companion link -> GCS
    companion.send(
        mavlink2.MAVLink_heartbeat_message(
            mavlink2.MAV_TYPE_CAMERA, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE, 3
        ),
        1,
        100,
    )
    companion.send(
        mavlink2.MAVLink_command_ack_message(mavlink2.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 255, 190), 1, 100
    )
    companion.send(
        mavlink2.MAVLink_camera_image_captured_message(1000, 0, 1, 0, 0, 0, 0, [1, 0, 0, 0], 0, 1, b""), 1, 100
    )
    for mtype in ("HEARTBEAT", "COMMAND_ACK", "CAMERA_IMAGE_CAPTURED"):
        got = gcs.wait_for(lambda m, t=mtype: m.get_type() == t and m.get_srcComponent() == 100, start)
        assert got is not None, mtype
        assert got.get_srcSystem() == 1
    # the autopilot answers the GCS itself, and does not pass on what is addressed to it alone
    ack = rig.command(gcs, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME)
    assert ack is not None and ack.get_srcComponent() == 1 and ack.result == mavlink2.MAV_RESULT_ACCEPTED
    time.sleep(0.1)
    forwarded = [m for _, _, m in companion.received("COMMAND_LONG", start)]
    assert [m.command for m in forwarded] == [mavlink2.MAV_CMD_IMAGE_START_CAPTURE]


def test_link_drop_silences_the_companion_link_and_stop_cleans_up() -> None:
    threads_before = {t.ident for t in threading.enumerate()}
    sc = make_scenario(faults={"autopilot_link_drops_s": [[5.4, 5.8]]}, gps={"fix_acquired_after_s": 0.0})
    rig = Rig(sc, 5.0)
    try:
        rig.gcs.send(
            mavlink2.MAVLink_heartbeat_message(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3)
        )
        wait_tau(rig.clocks, 5.55)
        ts1 = time.monotonic_ns()
        rig.companion.send(mavlink2.MAVLink_timesync_message(0, ts1))  # ignored during the drop
        wait_tau(rig.clocks, 6.1)
        taus = [rig.clocks.host_ns_to_tau(ns) for ns, _, _ in rig.companion.received()]
        assert any(t < 5.4 for t in taus) and any(t > 5.8 for t in taus)
        assert not any(5.41 < t < 5.79 for t in taus)
        assert rig.companion.received("TIMESYNC") == []
        gcs_taus = [rig.clocks.host_ns_to_tau(ns) for ns, _, _ in rig.gcs.received("ATTITUDE")]
        assert sum(1 for t in gcs_taus if 5.41 < t < 5.79) >= 3  # the GCS link kept going
        sock = rig.ap._companion.conn.port if rig.ap._companion else None
    finally:
        rig.close()
    assert rig.ap.errors == []
    assert sock is not None and sock.fileno() == -1  # socket closed
    assert rig.ap.companion_address is None and rig.ap.gcs_address is None
    leaked = [t.name for t in threading.enumerate() if t.ident not in threads_before]
    assert leaked == []
    rig.ap.stop()  # a second stop is harmless
    assert not math.isnan(rig.clocks.host_ns_to_tau(0))


def test_stream_reset_undoes_rates_accepted_before_it_as_ardupilots_boot() -> None:
    sc = make_scenario(autopilot={"stream_reset_s": 5.6})
    rig = Rig(sc, 5.0)
    try:
        assert rig.companion.wait_for(lambda m: True, 0) is not None  # the companion link is up
        att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
        ack = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, att, 20_000)
        assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED  # ACCEPTED, then undone
        wait_tau(rig.clocks, 5.65)
        start = time.monotonic_ns()
        time.sleep(0.5)
        default = [m for _, _, m in rig.companion.received("ATTITUDE", start)]
        assert 3 <= len(default) <= 7 and all(m.time_boot_ms % 100 == 0 for m in default)  # the 10 Hz default
        assert rig.ap.stream_resets == 1
        ack = rig.command(rig.companion, mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, att, 20_000)  # asked again
        time.sleep(0.05)
        start = time.monotonic_ns()
        time.sleep(0.5)
        assert len(rig.companion.received("ATTITUDE", start)) >= 20
    finally:
        rig.close()
    assert rig.ap.errors == []
