"""Clock maps, the sensor truth CSV of the contract, exposure ground truth and true clock offsets."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from icgt.geodesy import LocalFrame, enu_to_ned, q_conjugate, q_rotate
from icgt.sim.scenario import Scenario, SimError, load_scenario
from icgt.sim.trajectory import Trajectory
from icgt.sim.truth import (
    ClockMaps,
    exposure_truth,
    read_events,
    write_clock_offsets,
    write_exposure_truth,
    write_sensor_truth,
)

HEADER = (
    "tau_s,qw,qx,qy,qz,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,accel_x_m_s2,accel_y_m_s2,accel_z_m_s2,"
    "lin_accel_x_m_s2,lin_accel_y_m_s2,lin_accel_z_m_s2,range_cm,range_valid"
)
T0_NS = 5_000_000_000_000
UTC0_US = 1_718_000_000_123_456


def clocks_of(name: str) -> tuple[Scenario, ClockMaps]:
    sc = load_scenario(name)
    return sc, ClockMaps.from_scenario(sc, T0_NS, UTC0_US)


def test_clock_maps_follow_the_contract() -> None:
    _, clocks = clocks_of("pier_scan")
    tau = 12.5
    assert clocks.tau_to_host_ns(tau) == T0_NS + 12_500_000_000
    assert clocks.tau_to_utc_us(tau) == UTC0_US + 12_500_000
    assert clocks.tau_to_device_us(tau) == pytest.approx(7_351_224 + 12.5e6 * (1 + 42e-6))
    assert clocks.tau_to_autopilot_us(tau) == pytest.approx(412_600_000 + 12.5e6 * (1 - 17.5e-6))
    assert clocks.tau_to_camera_s(tau) == pytest.approx(UTC0_US * 1e-6 + 3.42 + 12.5 * (1 + 11e-6))
    for forward, back, tolerance_s in [
        (clocks.tau_to_device_us, clocks.device_us_to_tau, 1e-9),
        (clocks.tau_to_autopilot_us, clocks.autopilot_us_to_tau, 1e-9),
        (clocks.tau_to_camera_s, clocks.camera_s_to_tau, 1e-6),  # a float of Unix seconds: ~0.2 us steps
        (clocks.tau_to_host_ns, clocks.host_ns_to_tau, 1e-9),
        (clocks.tau_to_utc_us, clocks.utc_us_to_tau, 1e-9),
    ]:
        assert float(back(forward(tau))) == pytest.approx(tau, abs=tolerance_s)


def test_exif_time_truncates_like_a_camera() -> None:
    clocks = ClockMaps(t0_monotonic_ns=0, utc0_us=1_700_000_000_000_000, camera_offset_s=0.999, exif_resolution="10ms")
    # camera at 2023-11-14 22:13:20.999 + tau
    assert clocks.exif_time(0.0) == ("2023:11:14 22:13:20", "99")
    assert clocks.exif_time(0.0015) == ("2023:11:14 22:13:21", "00")
    one_s = ClockMaps(t0_monotonic_ns=0, utc0_us=1_700_000_000_000_000, camera_offset_s=0.999)
    assert one_s.exif_time(0.0) == ("2023:11:14 22:13:20", None)


def test_sensor_truth_csv_is_the_contract(tmp_path: Path) -> None:
    sc = load_scenario("pier_scan")
    path = tmp_path / "truth.csv"
    rows = write_sensor_truth(sc, path, margin_s=2.0)
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER
    assert len(lines) == rows + 1 == round((sc.duration_s + 2.0) / 0.005) + 2
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    assert data.shape[1] == 16
    assert data[0, 0] == 0.0
    assert np.diff(data[:, 0]) == pytest.approx(np.full(rows - 1, 0.005), abs=1e-9)
    q = data[:, 1:5]
    assert np.linalg.norm(q, axis=1) == pytest.approx(np.ones(rows), abs=1e-8)
    assert (np.sum(q[1:] * q[:-1], axis=1) > 0.99).all()  # same hemisphere row to row (device nlerps)
    # holding still at the start: gravity as an accelerometer feels it, no linear acceleration
    assert data[0, 8:11] == pytest.approx([0.0, 0.0, -9.80665], abs=1e-6)
    assert data[0, 11:14] == pytest.approx([0.0, 0.0, 0.0], abs=1e-6)
    assert set(np.unique(data[:, 15])) == {1.0}
    assert data[:, 14] == pytest.approx(np.full(rows, 250.0), abs=0.01)  # 2.5 m standoff
    assert set(lines[1].split(",")[15]) <= set("01")


def test_sensor_truth_is_specific_force_in_camera_axes(tmp_path: Path) -> None:
    sc = load_scenario("hover")  # sways, camera pitched 10 deg up on a stabilised gimbal
    path = tmp_path / "truth.csv"
    write_sensor_truth(sc, path, margin_s=0.0)
    data = np.loadtxt(path, delimiter=",", skiprows=1)[::200]
    st = Trajectory(sc).state(data[:, 0])
    q = data[:, 1:5]
    accel_ned = q_rotate(q, data[:, 8:11])
    lin_ned = q_rotate(q, data[:, 11:14])
    assert accel_ned - lin_ned == pytest.approx(np.tile([0.0, 0.0, -9.80665], (len(q), 1)), abs=1e-5)
    expected_lin = q_rotate(q_conjugate(st.q_camera_ned), enu_to_ned(st.camera_accel_enu_m_s2))
    assert data[:, 11:14] == pytest.approx(expected_lin, abs=1e-5)
    assert data[:, 5:8] == pytest.approx(st.omega_camera_rad_s, abs=1e-6)
    expected_range = np.where(st.range_valid, st.range_m * 100, 0.0)
    assert data[:, 14] == pytest.approx(expected_range, abs=0.006)


def events_for(clocks: ClockMaps, taus: list[float], exposure_us: int = 1000) -> list[dict[str, object]]:
    out: list[dict[str, object]] = []
    for i, tau in enumerate(taus, 1):
        start = round(float(clocks.tau_to_device_us(tau)))
        out.append(
            {
                "event": "exposure",
                "frame_number": i,
                "trigger_index": i,
                "trigger_t_us": start - 48_000,
                "start_t_us": start,
                "end_t_us": start + exposure_us,
                "manual": False,
            }
        )
    out.insert(1, {"event": "link", "state": "down", "tau_s": 3.0})
    return out


def test_exposure_truth_maps_mid_exposure_to_every_clock(tmp_path: Path) -> None:
    sc, clocks = clocks_of("deck_pass")
    events = events_for(clocks, [5.0, 10.0, 15.0])
    path = tmp_path / "events.jsonl"
    path.write_text("\n".join(json.dumps(e) for e in events) + "\n")
    records = exposure_truth(sc, read_events(path), clocks)
    assert [r.frame_number for r in records] == [1, 2, 3]
    traj = Trajectory(sc)
    frame = LocalFrame(37.8813, 127.7298, 76.0 + 24.9)
    for r, tau in zip(records, [5.0, 10.0, 15.0], strict=True):
        mid_tau = tau + 500e-6 / (1 + 50e-6)  # 0.5 ms of device clock (50 ppm fast) after the start
        assert r.mid_tau_s == pytest.approx(mid_tau, abs=1e-9)
        assert r.mid_device_us == r.start_device_us + 500
        assert r.mid_host_monotonic_ns == pytest.approx(T0_NS + mid_tau * 1e9, abs=1)
        assert r.mid_utc_us == pytest.approx(UTC0_US + mid_tau * 1e6, abs=1)
        st = traj.state(np.array([mid_tau]))
        assert r.position_enu_m == pytest.approx(tuple(st.camera_position_enu_m[0]), abs=1e-9)
        assert frame.geodetic_to_enu(r.lat_deg, r.lon_deg, r.alt_ellipsoid_m) == pytest.approx(
            st.camera_position_enu_m[0], abs=1e-6
        )
        assert r.alt_msl_m == pytest.approx(r.alt_ellipsoid_m - 24.9)
        assert r.range_m == pytest.approx(5.0, abs=0.05)
        assert r.q_camera_ned == pytest.approx(tuple(st.q_camera_ned[0]))
    out = tmp_path / "truth.jsonl"
    write_exposure_truth(out, records)
    back = [json.loads(line) for line in out.read_text().splitlines()]
    assert [b["event"] for b in back] == ["exposure_truth"] * 3
    assert back[1]["mid_utc_us"] == records[1].mid_utc_us


def test_bad_event_files_raise_sim_errors(tmp_path: Path) -> None:
    bad = tmp_path / "events.jsonl"
    bad.write_text('{"event": "exposure"}\nnot json\n')
    with pytest.raises(SimError, match=r"events.jsonl:2: not JSON"):
        read_events(bad)
    sc, clocks = clocks_of("hover")
    with pytest.raises(SimError, match="start_t_us"):
        exposure_truth(sc, [{"event": "exposure"}], clocks)


def test_clock_offsets_series(tmp_path: Path) -> None:
    _, clocks = clocks_of("hover")
    path = tmp_path / "offsets.csv"
    assert write_clock_offsets(path, clocks, 10.0, step_s=0.5) == 21
    with path.open() as f:
        rows = list(csv.DictReader(f))
    first, last = rows[0], rows[-1]
    assert float(last["tau_s"]) == 10.0
    # device runs 48 ppm fast: its offset to the host grows by 480 us over 10 s
    growth = float(last["device_minus_host_us"]) - float(first["device_minus_host_us"])
    assert growth == pytest.approx(480.0, abs=0.01)
    ap_growth = float(last["autopilot_minus_host_us"]) - float(first["autopilot_minus_host_us"])
    assert ap_growth == pytest.approx(95.0, abs=0.01)
    assert float(first["camera_minus_utc_s"]) == pytest.approx(32_404.1, abs=1e-5)
