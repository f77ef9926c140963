"""Autopilot profiles (icgt.sim.profiles): the scenario keys they default, and what the autopilot then sends.

Each rig runs a SimAutopilot over real UDP for a couple of seconds of the 10 m/s deck pass of
test_sim_autopilot and reads its messages with pymavlink.
"""

from __future__ import annotations

import copy
import itertools
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from test_sim_autopilot import FIX_AT_S, SCENARIO, TAU_AT_START_S, Rig, wait_tau

from icgt.geodesy import LocalFrame, enu_to_ned
from icgt.sim.profiles import PROFILES
from icgt.sim.scenario import Scenario, ScenarioError, parse_scenario
from icgt.sim.trajectory import Trajectory


def scenario(**autopilot: Any) -> Scenario:
    data = copy.deepcopy(SCENARIO)
    data["autopilot"] = autopilot
    return parse_scenario(data, "test")


# --- scenario keys ---------------------------------------------------------------------------


def test_the_default_profile_is_the_ideal_autopilot_of_before() -> None:
    ap = scenario().autopilot
    assert ap.profile == "ideal"
    assert ap.rates_hz["global_position_int"] == 10.0 and ap.rates_hz["gps_raw_int"] == 5.0
    assert ap.latency_s == 0.002 and ap.answer_timesync and ap.honour_message_interval
    assert ap.stamp_jitter_s == 0.0 and ap.local_position_lag_s == 0.0 and ap.system_id == 1


@pytest.mark.parametrize("profile", ["ardupilot", "px4"])
def test_a_profile_sets_the_defaults_and_the_scenario_overrides_them(profile: str) -> None:
    ap = scenario(profile=profile).autopilot
    base = PROFILES[profile]
    assert dict(ap.rates_hz) == dict(base["rates_hz"])
    assert ap.firmware == base["firmware"] and ap.latency_s == base["latency_s"]
    assert ap.local_position_lag_s == base["local_position_lag_s"]
    changed = scenario(profile=profile, latency_s=0.007, rates_hz={"global_position_int": 2.0}).autopilot
    assert changed.latency_s == 0.007 and changed.rates_hz["global_position_int"] == 2.0
    assert changed.rates_hz["attitude"] == base["rates_hz"]["attitude"]


def test_profile_facts() -> None:
    px4 = scenario(profile="px4").autopilot
    assert px4.rates_hz["global_position_int"] == 50.0 and px4.rates_hz["local_position_ned"] == 30.0
    assert px4.own_timesync_hz == 10.0 and px4.rates_hz["gps_global_origin"] == 1.0
    ardu = scenario(profile="ardupilot").autopilot
    assert ardu.rates_hz["global_position_int"] == 4.0 and ardu.rates_hz["attitude_quaternion"] == 0.0
    assert ardu.local_position_lag_s == 0.02 and ardu.gps_fix_rate_hz == 5.0 and ardu.origin_on_change
    assert ardu.param_burst_stream_divisor == 4


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("profile", "inav", "profile: must be one of"),
        ("system_id", 0, "system_id: must be >= 1"),
        ("gcs_heartbeat_systems", [245, 300], "gcs_heartbeat_systems[1]: must be <= 255"),
        ("origin_reset_shift_m", [1.0, 2.0], "origin_reset_shift_m: expected an array of 3 values"),
        ("param_burst_count", 0, "param_burst_count: must be >= 1"),
        ("local_position_lagms", 3.0, "local_position_lagms: unknown key"),
    ],
)
def test_mistakes_are_named(key: str, value: Any, message: str) -> None:
    with pytest.raises(ScenarioError, match=message.replace("[", r"\[").replace("]", r"\]")):
        scenario(**{key: value})


# --- on the wire -----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ardupilot() -> Iterator[Rig]:
    sc = scenario(
        profile="ardupilot",
        system_id=42,
        rates_hz={"global_position_int": 10.0, "local_position_ned": 10.0, "gps_raw_int": 10.0},
        gcs_heartbeat_systems=[245, 250, 255],
        foreign_camera=True,
        origin_resets_s=[TAU_AT_START_S + 1.5],
        param_bursts_s=[TAU_AT_START_S + 0.5],
        param_burst_count=300,
        param_burst_duration_s=0.3,
    )
    r = Rig(sc, TAU_AT_START_S)
    # the GCS link is udpin: the autopilot learns where the ground station is from its first message
    r.gcs.send(mavlink2.MAVLink_heartbeat_message(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
    wait_tau(r.clocks, TAU_AT_START_S + 2.6)
    yield r
    r.close()
    assert r.ap.errors == []


def test_ardupilot_stamps_local_position_after_the_global_one(ardupilot: Rig) -> None:
    gpi = [m.time_boot_ms for _, _, m in ardupilot.companion.received("GLOBAL_POSITION_INT")]
    lpn = [m.time_boot_ms for _, _, m in ardupilot.companion.received("LOCAL_POSITION_NED")]
    assert len(gpi) >= 10 and len(lpn) >= 10
    grid = 100  # ms, the 10 Hz stream on the boot clock
    gpi_offsets = [t % grid for t in gpi]
    lpn_offsets = [t % grid for t in lpn]
    assert max(gpi_offsets) <= 3  # the 2.5 ms main-loop jitter, whole ms
    assert max(lpn_offsets) > 5 and max(lpn_offsets) <= 23  # up to 20 ms later as well
    assert all(b > a for a, b in itertools.pairwise(lpn))


def test_ardupilot_gps_raw_carries_the_receivers_last_fix(ardupilot: Rig) -> None:
    stamps = [m.time_usec for _, _, m in ardupilot.companion.received("GPS_RAW_INT")]
    assert len(stamps) >= 10
    assert all(s % 200_000 == 0 for s in stamps)  # the 5 Hz receiver grid, not the 10 Hz send grid
    assert len(set(stamps)) < len(stamps)  # a 10 Hz stream sends each 5 Hz fix twice


def test_the_vehicle_system_id_is_the_scenarios(ardupilot: Rig) -> None:
    own = [m for _, _, m in ardupilot.companion.received() if m.get_srcComponent() == 1]
    assert own and {m.get_srcSystem() for m in own} == {42}
    ack = ardupilot.command(
        ardupilot.companion, mavlink2.MAV_CMD_REQUEST_MESSAGE, mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION, target=(42, 1)
    )
    assert ack is not None and ack.result == mavlink2.MAV_RESULT_ACCEPTED


def test_ground_stations_and_a_foreign_camera_are_heard_on_the_companion_link(ardupilot: Rig) -> None:
    beats = [m for _, _, m in ardupilot.companion.received("HEARTBEAT")]
    gcs = {m.get_srcSystem() for m in beats if m.type == mavlink2.MAV_TYPE_GCS}
    assert gcs == {245, 250, 255}
    assert all(m.get_srcComponent() == 190 for m in beats if m.type == mavlink2.MAV_TYPE_GCS)
    cams = [m for m in beats if m.type == mavlink2.MAV_TYPE_CAMERA]
    assert cams and {(m.get_srcSystem(), m.get_srcComponent()) for m in cams} == {(42, 100)}
    assert all(m.autopilot == mavlink2.MAV_AUTOPILOT_INVALID for m in cams)
    gcs_side = [m for _, _, m in ardupilot.gcs.received("HEARTBEAT") if m.type == mavlink2.MAV_TYPE_CAMERA]
    assert gcs_side  # the camera is routed to the ground station too
    assert not [m for _, _, m in ardupilot.gcs.received("HEARTBEAT") if m.type == mavlink2.MAV_TYPE_GCS]


def test_a_parameter_burst_arrives_whole_and_slows_the_streams(ardupilot: Rig) -> None:
    params = [m for _, _, m in ardupilot.companion.received("PARAM_VALUE")]
    assert sorted(m.param_index for m in params) == list(range(300))
    assert all(m.param_count == 300 for m in params)
    assert ardupilot.ap.skipped_in_param_bursts > 0
    t0 = float(ardupilot.clocks.tau_to_autopilot_us(TAU_AT_START_S + 0.5)) / 1000
    during = [m for _, _, m in ardupilot.companion.received("GLOBAL_POSITION_INT") if t0 <= m.time_boot_ms < t0 + 300]
    assert len(during) <= 1  # 10 Hz / 4 over 0.3 s


def test_an_origin_reset_moves_the_local_position_and_is_announced(ardupilot: Rig) -> None:
    sc, clocks = ardupilot.scenario, ardupilot.clocks
    reset_tau = sc.autopilot.origin_resets_s[0]
    traj = Trajectory(sc)
    shift = np.asarray(sc.autopilot.origin_reset_shift_m)
    for _, _, m in ardupilot.companion.received("LOCAL_POSITION_NED"):
        tau = float(clocks.autopilot_us_to_tau(m.time_boot_ms * 1000))
        want = enu_to_ned(traj.state(np.array([tau])).position_enu_m[0] - (shift if tau >= reset_tau else 0.0))
        assert (m.x, m.y, m.z) == pytest.approx(tuple(want), abs=0.3)  # fused noise 3 cm / 5 cm
    origins = [m for _, _, m in ardupilot.companion.received("GPS_GLOBAL_ORIGIN")]
    assert origins  # sent at the reset (the first one went before the peer listened)
    frame = LocalFrame(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.ellipsoid_height_m)
    lat, lon, _ = frame.enu_to_geodetic(shift)
    assert origins[-1].latitude == round(float(lat) * 1e7) and origins[-1].longitude == round(float(lon) * 1e7)


@pytest.fixture(scope="module")
def px4() -> Iterator[Rig]:
    r = Rig(scenario(profile="px4", rates_hz={"attitude": 20.0}), FIX_AT_S + 0.5)
    wait_tau(r.clocks, FIX_AT_S + 3.0)
    yield r
    r.close()
    assert r.ap.errors == []


def test_px4_says_px4_sends_its_own_timesync_requests_and_streams_the_origin(px4: Rig) -> None:
    beats = [m for _, _, m in px4.companion.received("HEARTBEAT") if m.get_srcComponent() == 1]
    assert beats and all(m.autopilot == mavlink2.MAV_AUTOPILOT_PX4 for m in beats)
    requests = [m for _, _, m in px4.companion.received("TIMESYNC") if m.tc1 == 0]
    # the autopilot's clock after the messages were read: none of them can be stamped later
    now_ns = float(px4.clocks.tau_to_autopilot_us(px4.clocks.host_ns_to_tau(time.monotonic_ns()))) * 1000
    assert len(requests) >= 10  # 10 Hz over 2.5 s
    assert all(0 < m.ts1 <= now_ns for m in requests)  # its boot clock in ns
    assert len(px4.companion.received("GPS_GLOBAL_ORIGIN")) >= 1
    gpi = px4.companion.received("GLOBAL_POSITION_INT")
    assert len(gpi) >= 60  # 50 Hz over 2.5 s
