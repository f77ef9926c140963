"""Re-geotagging a simulated flight from trajectories written from its truth with noise and a time offset.

Each trajectory is the true vehicle reference point (and attitude, for TUM) sampled on a regular
grid, moved by at most NOISE_M (a 3-D Gaussian of 1 cm per axis, clipped to 2 cm), stamped with a
wrong clock (TIME_OFFSET_S) that the reader is told to take back. Every placed frame's camera
position must be within NOISE_M + the interpolation allowance (the truth's largest acceleration
times T^2 / 8 for samples T apart) + the timing allowance (the true speed times that frame's UTC or
host-time error against the true mid-exposure) + for position-only sources, the lever arm turned by
the recorded attitude's error, + 1 mm. And within the bound the frame reports.
"""

from __future__ import annotations

import dataclasses
import math
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import pytest

import icgt
from icgt.clocks.autopilot_clock import GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_S
from icgt.geodesy import Q_NED_TO_ENU, q_conjugate, q_from_euler_zyx, q_multiply, q_rotate
from icgt.geotag.record import FrameRecord
from icgt.ingest.recompute import recording_config
from icgt.trajectories.regeotag import RegeotagConfig, regeotag, regeotag_detailed
from icgt.trajectories.rtklib_pos import PosOptions, read_pos
from icgt.trajectories.tum import Alignment4Dof, TumOptions, read_tum, tum_line

from .conftest import Truth

NOISE_M = 0.02
TIME_OFFSET_S = -2.5  # the file's clock runs 2.5 s behind: the reader adds +2.5 s
YAW_DEG = 37.0
TRANSLATION = (4.0, -7.5, 1.25)
_Q_X_180 = np.array([0.0, 1.0, 0.0, 0.0])


def _noise(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    d = rng.normal(scale=0.01, size=(n, 3))
    norm = np.linalg.norm(d, axis=1, keepdims=True)
    return np.where(norm > NOISE_M, d * (NOISE_M / norm), d)


def _grid(truth: Truth, rate_hz: float) -> np.ndarray:
    sc = truth.flight.scenario
    return np.arange(round((sc.duration_s + 2.0) * rate_hz)) / rate_hz  # k / rate: exact at whole seconds


def _interp_allowance(truth: Truth, tau: np.ndarray) -> float:
    _, _, _, acc = truth.state_in_log(_grid(truth, 100.0))  # the largest true acceleration, finely sampled
    span = float(tau[1] - tau[0])
    return float(np.max(np.linalg.norm(acc, axis=1))) * span**2 / 8.0


def _speed(truth: Truth, tau: float) -> float:
    return float(np.linalg.norm(truth.trajectory.state(np.array([tau])).velocity_enu_m_s[0]))


def _timing_allowance(truth: Truth, frame: FrameRecord, time_base: str) -> float:
    t = truth.exposures[frame.start_device_us]
    if time_base == "utc":
        assert frame.mid_utc_us is not None
        dt_s = abs(frame.mid_utc_us - t["mid_utc_us"]) / 1e6
    else:
        dt_s = abs(frame.mid_host_ns - t["mid_host_monotonic_ns"]) / 1e9
    return _speed(truth, t["mid_tau_s"]) * dt_s + 1e-4


def _attitude_allowance(truth: Truth, frame: FrameRecord, lever: np.ndarray) -> float:
    t = truth.exposures[frame.start_device_us]
    q_true = np.array(t["q_body_ned"])
    q_rec = np.array([frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz])
    return float(np.linalg.norm(q_rotate(q_rec, lever) - q_rotate(q_true, lever)))


def _frames(truth: Truth) -> list[FrameRecord]:
    return list(icgt.read(truth.flight.mcap).frames())


def _matched(frames: list[FrameRecord], truth: Truth) -> list[FrameRecord]:
    return [f for f in frames if f.start_device_us in truth.exposures]


def write_tum(truth: Truth, path: Path, time_base: str, rate_hz: float = 20.0) -> np.ndarray:
    tau = _grid(truth, rate_hz)
    enu, _, q_ned, _ = truth.state_in_log(tau)
    enu = enu + _noise(len(tau), 5)
    q_yaw_inv = q_conjugate(q_from_euler_zyx(0.0, 0.0, math.radians(YAW_DEG)))
    p_file = q_rotate(q_yaw_inv, enu - np.array(TRANSLATION))
    q_flu_enu = q_multiply(q_multiply(Q_NED_TO_ENU, q_ned), _Q_X_180)
    q_file = q_multiply(q_yaw_inv, q_flu_enu)
    if time_base == "utc":
        t_true = (truth.utc0_us + tau * 1e6) / 1e6
    else:
        t_true = (truth.host0_ns + tau * 1e9) / 1e9
    lines = ["# timestamp tx ty tz qx qy qz qw  (written from simulator truth)"]
    lines += [tum_line(t + TIME_OFFSET_S, p, q) for t, p, q in zip(t_true, p_file, q_file, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return tau


@pytest.mark.parametrize("time_base", ["utc", "host"])
def test_tum_regeotag_within_noise(truth: Truth, tmp_path: Path, time_base: str) -> None:
    path = tmp_path / "vio.tum"
    tau = write_tum(truth, path, time_base)
    rec = icgt.read(truth.flight.mcap)
    config = RegeotagConfig.from_recording(rec)
    options = TumOptions(
        time_base=time_base,  # type: ignore[arg-type]
        time_offset_s=-TIME_OFFSET_S,
        alignment=Alignment4Dof(YAW_DEG, TRANSLATION),
        position_error_m=NOISE_M,
    )
    source = read_tum(path, config.origin, options)
    frames = list(rec.frames())
    result = regeotag_detailed(frames, source, config)
    interp = _interp_allowance(truth, tau)
    errors, margins = [], []
    for f in _matched(result.frames, truth):
        if f.frame_seq not in result.placed:
            continue
        assert f.position_source == "slam"
        err = truth.camera_error_m(f)
        allowed = NOISE_M + interp + _timing_allowance(truth, f, time_base) + 1e-3
        errors.append(err)
        margins.append(allowed - err)
        assert err <= allowed, f"frame {f.frame_seq}: {err * 100:.2f} cm > {allowed * 100:.2f} cm"
        assert f.position_error_bound_m is not None and err <= f.position_error_bound_m + 1e-3
        # the attitude came from the file: body quaternion equals the truth's up to the sign
        t = truth.exposures[f.start_device_us]
        dot = abs(float(np.dot([f.body_qw, f.body_qx, f.body_qy, f.body_qz], t["q_body_ned"])))
        assert dot > math.cos(math.radians(0.5) / 2), f"frame {f.frame_seq}: attitude off by > 0.5 deg"
        assert "no_attitude" not in f.flags
    # every frame with a time on the base inside the trajectory was placed
    with_time = [f for f in frames if (f.mid_utc_us is not None) or time_base == "host"]
    assert len(result.placed) == len(with_time)
    assert len(errors) >= 5  # a loaded machine can start the capture late
    print(
        f"TUM/{time_base}: {len(errors)} frames, camera error p50 {np.median(errors) * 100:.2f} cm, "
        f"max {max(errors) * 100:.2f} cm (interpolation allowance {interp * 1000:.2f} mm)"
    )
    # the same file without the time offset taken back places the frames 2.5 s wrong: far off
    wrong = read_tum(path, config.origin, dataclasses.replace(options, time_offset_s=0.0))
    off = regeotag(frames, wrong, config)
    far = [truth.camera_error_m(f) for f in _matched(off, truth) if f.position_source == "slam"]
    assert far and max(far) > 0.1


def _pos_text(truth: Truth, tau: np.ndarray, llh: np.ndarray, q: list[int], week_tow: bool) -> str:
    head = [
        "% program   : icgt test (written from simulator truth)",
        "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)",
        "%  GPST"
        + (" " * 10 if week_tow else " " * 18)
        + "latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)  sdne(m)  sdeu(m)  sdun(m)"
        + " age(s)  ratio",
    ]
    rows = []
    for k, (ta, (la, lo, h)) in enumerate(zip(tau, llh, strict=True)):
        gps_unix = (truth.utc0_us + ta * 1e6) / 1e6 + GPS_UTC_LEAP_S + TIME_OFFSET_S
        if week_tow:
            week, tow = divmod(gps_unix - GPS_EPOCH_UNIX_S, 604_800.0)
            t = f"{int(week):4d} {tow:10.3f}"
        else:
            dt = datetime.fromtimestamp(round(gps_unix, 3), tz=UTC)
            t = dt.strftime("%Y/%m/%d %H:%M:%S.") + f"{dt.microsecond // 1000:03d}"
        rows.append(
            f"{t}  {la:14.9f} {lo:14.9f} {h:10.4f} {q[k]:3d} {14:3d} {0.008:8.4f} {0.008:8.4f} {0.012:8.4f}"
            f" {0.001:8.4f} {-0.002:8.4f} {0.001:8.4f} {0.0:6.2f} {12.3:6.1f}"
        )
    return "\n".join(head + rows) + "\n"


@pytest.mark.parametrize("week_tow", [False, True], ids=["calendar", "week_tow"])
def test_pos_regeotag_within_noise(truth: Truth, tmp_path: Path, week_tow: bool) -> None:
    rate = 5.0
    tau = _grid(truth, rate)
    gap = (tau > 6.0) & (tau < 8.0)  # a 2 s outage in the solution: frames inside it are not placed
    tau = tau[~gap]
    enu, _, _, _ = truth.state_in_log(tau)
    enu = enu + _noise(len(tau), 9)
    lat, lon, msl = truth.log_frame.enu_to_geodetic(enu)
    llh = np.stack([lat, lon, msl + truth.geoid_m], axis=-1)
    q = [2 if 12.0 <= t < 13.0 else 1 for t in tau]
    path = tmp_path / "rover.pos"
    path.write_text(_pos_text(truth, tau, llh, q, week_tow))
    rec = icgt.read(truth.flight.mcap)
    config = RegeotagConfig.from_recording(rec)
    source, sol = read_pos(
        path, config.origin, PosOptions(geoid_separation_m=truth.geoid_m, time_offset_s=-TIME_OFFSET_S)
    )
    assert sol.time_system == "GPST" and sol.height == "ellipsoidal"
    assert sol.time_format == ("week_tow" if week_tow else "calendar")
    assert sol.q_counts[2] == sum(1 for x in q if x == 2)
    frames = list(rec.frames())
    result = regeotag_detailed(frames, source, config)
    lever = np.asarray(recording_config(rec).lever_arm_body_m)
    interp = _interp_allowance(truth, _grid(truth, rate))
    errors, fresh = [], []
    gap_misses = {seq for seq, m in result.unplaced if m.code == "gap"}
    for f in _matched(result.frames, truth):
        t = truth.exposures[f.start_device_us]
        if 6.01 < t["mid_tau_s"] < 7.99 and f.mid_utc_us is not None:
            assert f.frame_seq in gap_misses, f"frame {f.frame_seq} in the solution's gap was placed"
        if f.frame_seq not in result.placed:
            continue
        # a frame between a float sample (Q 2, tau 12.0-12.8 s) and any other is placed "float"
        tau_f = t["mid_tau_s"]
        if abs(tau_f - 11.8) > 0.005 and abs(tau_f - 13.0) > 0.005:
            assert f.position_source == ("ppk_float" if 11.8 < tau_f < 13.0 else "ppk_fixed"), f.frame_seq
        if f.body_qw is None:
            continue  # no attitude: the reference point, and a bound that says so (checked below)
        err = truth.camera_error_m(f)
        allowed = NOISE_M + interp + _timing_allowance(truth, f, "utc") + _attitude_allowance(truth, f, lever) + 1e-3
        errors.append(err)
        before = next(b for b in frames if b.frame_seq == f.frame_seq)
        if "pose_extrapolated" not in before.flags:
            fresh.append(err)  # the recorded attitude was not held across the telemetry gap
        assert err <= allowed, f"frame {f.frame_seq}: {err * 100:.2f} cm > {allowed * 100:.2f} cm"
        assert f.position_error_bound_m is not None and err <= f.position_error_bound_m + 1e-3
    for f in result.frames:
        if f.frame_seq in result.placed and f.body_qw is None:
            assert f.position_error_bound_m is not None and f.position_error_bound_m >= float(np.linalg.norm(lever))
    assert len(errors) >= 5
    with_utc = [f for f in frames if f.mid_utc_us is not None]
    assert len(result.placed) + len(gap_misses) == len(with_utc)
    print(
        f".pos/{'week_tow' if week_tow else 'calendar'}: {len(errors)} frames, camera error p50 "
        f"{np.median(errors) * 100:.2f} cm, max {max(errors) * 100:.2f} cm (max {max(fresh, default=0) * 100:.2f} cm "
        f"over {len(fresh)} with a fresh recorded attitude); {len(gap_misses)} in the gap"
    )


def test_cli_regeotag_writes_and_reports(truth: Truth, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from icgt.cli import main
    from icgt.ingest.reader import decode_frame

    path = tmp_path / "vio.tum"
    write_tum(truth, path, "utc")
    out = tmp_path / "frames.json"
    code = main(["regeotag", str(truth.flight.mcap), "--trajectory", str(path), "--format", "tum",
                 "--time-offset-s", str(-TIME_OFFSET_S), "--yaw-deg", str(YAW_DEG),
                 "--translation", ",".join(str(v) for v in TRANSLATION), "--out", str(out)])  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    frames = _frames(truth)
    placed = [f for f in frames if f.mid_utc_us is not None]
    assert f"placed {len(placed)} of {len(frames)} frames (slam {len(placed)})" in text
    import json

    back = [decode_frame(r) for r in json.loads(out.read_text())]
    assert [f.frame_seq for f in back] == [f.frame_seq for f in frames]
    assert all(truth.camera_error_m(f) < 0.05 for f in _matched(back, truth) if f.position_source == "slam")
    csv_out = tmp_path / "frames.csv"
    assert main(["regeotag", str(truth.flight.mcap), "--trajectory", str(path), "--format", "tum",
                 "--out", str(csv_out)]) == 0  # fmt: skip
    assert csv_out.read_text().count("\n") == len(frames) + 1
    bad = tmp_path / "bad.tum"
    bad.write_text("1.0 2.0 3.0\n")
    assert main(["regeotag", str(truth.flight.mcap), "--trajectory", str(bad), "--format", "tum",
                 "--out", str(csv_out)]) == 1  # fmt: skip
    assert f"{bad}:1: 3 columns" in capsys.readouterr().err


def test_recorded_telemetry_source_gives_back_the_recorded_frames(truth: Truth) -> None:
    """The autopilot's telemetry behind the same interface: the lever arm and attitude rules match the geotagger's."""
    from icgt.trajectories.recorded import RecordedTelemetry

    rec = icgt.read(truth.flight.mcap)
    config = RegeotagConfig.from_recording(rec)
    frames = list(rec.frames())
    source = RecordedTelemetry(config.origin, recording_config(rec).lever_arm_body_m)
    result = regeotag_detailed(frames, source, config)
    assert {seq for seq, m in result.unplaced if m.code == "no_fix"} == {
        f.frame_seq for f in frames if f.lat_deg is None
    }
    compared = 0
    for before, after in zip(frames, result.frames, strict=True):
        if before.lat_deg is None or before.body_qw is None:
            continue
        compared += 1
        assert after.position_source == before.position_source and after.flags == before.flags
        assert after.position_error_bound_m == before.position_error_bound_m
        d = truth.log_frame.geodetic_to_enu(
            after.lat_deg, after.lon_deg, after.alt_msl_m
        ) - truth.log_frame.geodetic_to_enu(before.lat_deg, before.lon_deg, before.alt_msl_m)
        assert float(np.linalg.norm(d)) < 1e-6
        assert np.allclose(
            [after.cam_qw, after.cam_qx, after.cam_qy, after.cam_qz],
            [before.cam_qw, before.cam_qx, before.cam_qy, before.cam_qz],
            atol=1e-9,
        )
        if before.incidence_deg is not None:
            assert after.incidence_deg == pytest.approx(before.incidence_deg, abs=1e-6)
    assert compared >= 5


def test_cli_regeotag_rtklib(truth: Truth, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from icgt.cli import main

    tau = _grid(truth, 5.0)
    _, llh, _, _ = truth.state_in_log(tau)
    path = tmp_path / "rover.pos"
    path.write_text(_pos_text(truth, tau, llh, [1] * len(tau), week_tow=True))
    out = tmp_path / "frames.json"
    args = ["regeotag", str(truth.flight.mcap), "--trajectory", str(path), "--format", "rtklib", "--out", str(out)]
    assert main([*args, "--time-offset-s", str(-TIME_OFFSET_S), "--geoid-separation", str(truth.geoid_m)]) == 0
    text = capsys.readouterr().out
    frames = _frames(truth)
    n = sum(1 for f in frames if f.mid_utc_us is not None)
    assert "(GPST, week_tow times, ellipsoidal heights; Q1: " in text
    assert f"placed {n} of {len(frames)} frames (ppk_fixed {n})" in text
    assert main([*args, "--time-base", "host"]) == 1
    assert "--time-base host does not apply" in capsys.readouterr().err
