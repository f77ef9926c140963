"""The true flight: speeds, overlap, smoothness, attitude from thrust, and LiDAR range."""

from __future__ import annotations

import copy
import itertools
import math
from typing import Any

import numpy as np
import pytest

from icgt.geodesy import enu_to_ned, ned_to_enu, q_conjugate, q_rotate, q_to_euler_zyx
from icgt.sim.scenario import PierScan, load_scenario, parse_scenario
from icgt.sim.trajectory import GRAVITY_M_S2, Trajectory, pier_scan_plan

BASE: dict[str, Any] = {
    "name": "t",
    "duration_s": 30.0,
    "origin": {"lat_deg": 37.88, "lon_deg": 127.73, "alt_m": 76.0},
    "structure": {"point_m": [10.0, 0.0, 0.0], "normal": [-1.0, 0.0, 0.0]},
    "trajectory": {"kind": "hover", "standoff_m": 3.0, "height_m": 5.0},
}


def scenario(**changes: Any) -> Any:
    data = copy.deepcopy(BASE)
    for path, value in changes.items():
        *parents, last = path.split("__")
        node = data
        for p in parents:
            node = node.setdefault(p, {})
        node[last] = value
    return parse_scenario(data)


def test_pier_scan_passes_are_vertical_at_0_8_m_s() -> None:
    sc = load_scenario("pier_scan")
    traj = Trajectory(sc)
    st = traj.state(np.arange(0.0, sc.duration_s, 0.01))
    v = st.velocity_enu_m_s
    vertical = np.abs(v[:, 2])
    assert vertical.max() == pytest.approx(0.8, abs=1e-9)
    cruising = vertical > 0.8 - 1e-9
    assert cruising.sum() * 0.01 > 30.0  # most of the scan is at pass speed
    assert np.abs(v[cruising, :2]).max() < 1e-9  # straight up or down while cruising
    # up, down, up: bottom-right to top, top to bottom, ...
    signs = np.sign(v[cruising, 2])
    changes = np.flatnonzero(np.diff(signs))
    assert len(changes) == len(pier_scan_plan(sc).pass_offsets_m) - 1
    assert signs[0] > 0


def test_pier_scan_adjacent_passes_overlap_60_percent() -> None:
    sc = load_scenario("pier_scan")
    assert isinstance(sc.trajectory, PierScan)
    plan = pier_scan_plan(sc)
    cam = sc.camera
    # footprint from the geometry: width = standoff * sensor width / focal length
    assert plan.footprint_width_m == pytest.approx(2.5 * 35.6 / 35.0)
    traj = Trajectory(sc)
    st = traj.state(np.arange(0.0, sc.duration_s, 0.01))
    cruising = np.abs(st.velocity_enu_m_s[:, 2]) > 0.8 - 1e-9
    right = np.cross(-np.array(sc.structure.normal), [0.0, 0.0, 1.0])
    lateral = st.camera_position_enu_m[cruising] @ right
    passes = sorted({round(float(x), 6) for x in lateral}, reverse=True)
    assert len(passes) == len(plan.pass_offsets_m) >= 2
    for a, b in itertools.pairwise(passes):
        # each footprint width measured from the true range along the optical axis at that pass
        w = float(np.nanmean(st.range_m[cruising][np.isclose(lateral, a)])) * cam.sensor_width_mm / cam.focal_length_mm
        overlap = 1.0 - (a - b) / w
        assert overlap == pytest.approx(0.6, abs=1e-6)
    covered = (passes[0] - passes[-1]) + plan.footprint_width_m
    assert covered >= sc.trajectory.width_m


def test_deck_pass_reaches_10_m_s_smoothly() -> None:
    sc = load_scenario("deck_pass")
    traj = Trajectory(sc)
    tau = np.arange(0.0, sc.duration_s, 0.001)
    st = traj.state(tau)
    speed = np.linalg.norm(st.velocity_enu_m_s, axis=1)
    assert speed.max() == pytest.approx(10.0, abs=1e-9)
    assert speed[0] == 0.0 and speed[-1] == 0.0
    assert np.linalg.norm(st.accel_enu_m_s2, axis=1).max() < 6.0
    # the camera keeps the deck side in view at standoff
    assert st.range_valid.all()
    assert np.nanmax(np.abs(st.range_m - 5.0)) < 0.05


@pytest.mark.parametrize("name", ["pier_scan", "deck_pass", "hover"])
def test_motion_is_continuous_and_consistent(name: str) -> None:
    sc = load_scenario(name)
    traj = Trajectory(sc)
    dt = 0.001
    tau = np.arange(0.0, sc.duration_s, dt)
    st = traj.state(tau)
    p, v, a = st.position_enu_m, st.velocity_enu_m_s, st.accel_enu_m_s2
    # velocity is the derivative of position, acceleration of velocity (central differences)
    assert np.abs((p[2:] - p[:-2]) / (2 * dt) - v[1:-1]).max() < 1e-4
    assert np.abs((v[2:] - v[:-2]) / (2 * dt) - a[1:-1]).max() < 1e-3
    # no jumps: steps between samples are bounded by finite rates
    assert np.abs(np.diff(v, axis=0)).max() < 0.01
    assert np.abs(np.diff(a, axis=0)).max() < 0.05
    assert np.abs(st.omega_body_rad_s).max() < 1.0
    q = st.q_body_ned
    assert np.linalg.norm(q, axis=1) == pytest.approx(np.ones(len(q)))


def test_thrust_is_along_body_z_and_tilt_follows_acceleration() -> None:
    sc = load_scenario("deck_pass")
    traj = Trajectory(sc)
    st = traj.state(np.linspace(3.5, 6.5, 50))  # accelerating east, nose north
    f_ned = enu_to_ned(st.accel_enu_m_s2) - np.array([0.0, 0.0, GRAVITY_M_S2])
    f_body = q_rotate(q_conjugate(st.q_body_ned), f_ned)
    assert np.abs(f_body[:, :2]).max() < 1e-9  # a multirotor pushes along its z axis only
    roll, _, yaw = q_to_euler_zyx(st.q_body_ned)
    assert np.abs(yaw).max() < 1e-9  # heading held (facing the deck side to the north)
    assert (roll[st.accel_enu_m_s2[:, 0] > 0.1] > 0).all()  # banks right to accelerate east


def test_hover_without_sway_is_level_and_still() -> None:
    traj = Trajectory(scenario())
    st = traj.state(np.array([0.0, 5.0, 20.0]))
    assert np.abs(st.velocity_enu_m_s).max() == 0.0
    roll, pitch, yaw = q_to_euler_zyx(st.q_body_ned)
    assert np.abs(roll).max() < 1e-12 and np.abs(pitch).max() < 1e-12
    assert yaw == pytest.approx(np.full(3, math.pi / 2))  # facing the face to the east
    assert np.abs(st.omega_body_rad_s).max() < 1e-9


def test_range_is_the_analytic_ray_plane_distance() -> None:
    sc = scenario(camera__mount_pitch_deg=20.0, camera__mount_yaw_deg=-15.0, trajectory__sway_m=0.3)
    traj = Trajectory(sc)
    st = traj.state(np.linspace(0.0, 30.0, 200))
    # face x = 10 (normal -x): perpendicular distance / cosine of the angle between axis and normal
    perpendicular = 10.0 - st.camera_position_enu_m[:, 0]
    cos_incidence = st.optical_axis_enu[:, 0]
    assert st.range_valid.all()
    assert st.range_m == pytest.approx(perpendicular / cos_incidence, rel=1e-12)
    # the axis itself: 20 deg up, 15 deg left of east, in ENU
    axis_ned = enu_to_ned(st.optical_axis_enu)
    _, _, yaw_body = q_to_euler_zyx(st.q_body_ned)
    expected_yaw = yaw_body - math.radians(15.0)
    assert np.arctan2(axis_ned[:, 1], axis_ned[:, 0]) == pytest.approx(expected_yaw)
    assert np.arcsin(-axis_ned[:, 2]) == pytest.approx(np.full(200, math.radians(20.0)))
    assert ned_to_enu(axis_ned) == pytest.approx(st.optical_axis_enu)


def test_no_return_beyond_40_m_or_when_the_ray_misses() -> None:
    far = Trajectory(scenario(trajectory__standoff_m=41.0)).state(np.array([1.0]))
    assert not far.range_valid[0] and math.isnan(far.range_m[0])
    near = Trajectory(scenario(trajectory__standoff_m=39.0)).state(np.array([1.0]))
    assert near.range_valid[0] and near.range_m[0] == pytest.approx(39.0)
    parallel = Trajectory(scenario(camera__mount_yaw_deg=90.0)).state(np.array([1.0]))  # looking along the face
    assert not parallel.range_valid[0]
    away = Trajectory(scenario(camera__mount_yaw_deg=180.0)).state(np.array([1.0]))
    assert not away.range_valid[0]


def test_camera_sits_at_the_lever_arm() -> None:
    sc = scenario(camera__lever_arm_m=[0.3, 0.1, 0.2])
    st = Trajectory(sc).state(np.array([2.0]))
    offset_ned = q_rotate(st.q_body_ned[0], [0.3, 0.1, 0.2])
    assert st.camera_position_enu_m[0] - st.position_enu_m[0] == pytest.approx(ned_to_enu(offset_ned))
    assert st.range_m[0] == pytest.approx(3.0, abs=1e-9)  # the standoff is the camera's


def test_survey_turns_by_banking_as_a_coordinated_flight() -> None:
    """A VTOL survey leg: 22 m/s east, a 90 deg right turn at 35 deg of bank, 22 m/s south; in the turn the roll
    is the bank and the lateral acceleration g tan(bank); position, velocity and acceleration consistent."""
    sc = scenario(
        trajectory={"kind": "survey", "speed_m_s": 22.0, "course_deg": 90.0, "leg_s": 6.0, "legs": 1,
                    "turn_deg": 90.0, "bank_deg": 35.0, "altitude_m": 30.0},
    )  # fmt: skip
    traj = Trajectory(sc)
    st = traj.state(np.array([3.0, 9.0, 15.0]))
    np.testing.assert_allclose(st.velocity_enu_m_s[0], [22.0, 0.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(st.velocity_enu_m_s[2], [0.0, -22.0, 0.0], atol=0.05)
    roll, _, _ = q_to_euler_zyx(st.q_body_ned[1])
    assert math.degrees(float(roll)) == pytest.approx(35.0, abs=0.1)
    assert float(np.linalg.norm(st.accel_enu_m_s2[1])) == pytest.approx(
        GRAVITY_M_S2 * math.tan(math.radians(35.0)), rel=1e-3
    )
    dt = 0.001
    tau = np.arange(0.5, 18.0, dt)
    s = traj.state(tau)
    assert np.abs((s.position_enu_m[2:] - s.position_enu_m[:-2]) / (2 * dt) - s.velocity_enu_m_s[1:-1]).max() < 1e-3
    assert np.abs(np.diff(s.accel_enu_m_s2, axis=0)).max() < 0.05  # the bank rolls in and out smoothly
    with pytest.raises(Exception, match="bank_deg"):
        scenario(trajectory={"kind": "survey", "bank_deg": 80.0})
