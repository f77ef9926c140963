"""The trajectory readers and the GPS time conversion without a flight: rules, bounds and clear errors."""

from __future__ import annotations

import calendar
import math
from pathlib import Path

import numpy as np
import pytest

from icgt.clocks.autopilot_clock import GPS_EPOCH_UNIX_S
from icgt.clocks.gpstime import (
    GpsTimeError,
    leap_seconds_at_utc,
    utc_us_to_gps_week_tow_us,
    week_tow_to_utc_s,
)
from icgt.export.ppk_events import PpkEventsError, read_mrk
from icgt.geodesy import LocalFrame
from icgt.geotag.record import FrameRecord
from icgt.trajectories.rtklib_pos import PosOptions, read_pos
from icgt.trajectories.source import PoseFix, PoseMiss, TrajectoryError
from icgt.trajectories.tum import Alignment4Dof, TumOptions, read_tum

ORIGIN = (37.8813, 127.7298, 76.0)
HEADER = "% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)"
COLUMNS = "%  GPST          latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)"


def _frame(utc_us: int | None, host_ns: int = 0) -> FrameRecord:
    return FrameRecord(
        frame_seq=1, image_index=1, camera_id=0, device_flags=0, trigger_device_us=0, start_device_us=0,
        mid_device_us=0, duration_us=0, mid_host_ns=host_ns, mid_host_uncertainty_ns=0, time_source="pps",
        flags=[], position_source="gps_3d", fix_type=3, pose_gap_before_ms=0.0, pose_gap_after_ms=0.0,
        mid_utc_us=utc_us, mid_utc_uncertainty_us=0.0,
    )  # fmt: skip


def test_gps_time_leap_seconds() -> None:
    assert leap_seconds_at_utc(calendar.timegm((2026, 12, 1, 0, 0, 0))) == 18
    assert leap_seconds_at_utc(calendar.timegm((2016, 12, 31, 23, 59, 59))) == 17
    with pytest.raises(GpsTimeError):
        leap_seconds_at_utc(calendar.timegm((1990, 1, 1, 0, 0, 0)))
    # week 2404 TOW 282401.669089 s: GPS 315964800 + 2404*604800 + 282401.669089, minus 18 s
    utc = week_tow_to_utc_s(2404, 282401.669089)
    assert utc == pytest.approx(GPS_EPOCH_UNIX_S + 2404 * 604_800 + 282401.669089 - 18, abs=1e-6)
    week, tow_us = utc_us_to_gps_week_tow_us(round(utc * 1e6))
    assert (week, tow_us) == (2404, 282_401_669_089)
    # the end of a week rolls over into the next one
    end = round(week_tow_to_utc_s(2404, 604_799.5) * 1e6)
    assert utc_us_to_gps_week_tow_us(end + 1_000_000) == (2405, 500_000)


def _tum(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "t.tum"
    p.write_text(text)
    return p


def test_tum_interpolates_and_aligns(tmp_path: Path) -> None:
    # body moves 1 m along the file's x in 1 s; the file's frame is turned 90 deg (x -> north)
    p = _tum(tmp_path, "# comment\n\n100.0 0 0 0 0 0 0 1\n101.0 1 0 0 0 0 0 1\n")
    opts = TumOptions(alignment=Alignment4Dof(90.0, (10.0, 0.0, 0.0)), body_axes="flu", position_error_m=0.01,
                      max_gap_s=2.0, max_accel_m_s2=2.0)  # fmt: skip
    traj = read_tum(p, ORIGIN, opts)
    fix = traj.lookup(_frame(100_250_000))
    assert isinstance(fix, PoseFix)
    assert np.allclose(fix.enu_m, [10.0, 0.25, 0.0], atol=1e-9)
    # bound: the samples' 1 cm + 2 m/s^2 * (1 s)^2 / 8
    assert fix.error_bound_m == pytest.approx(0.01 + 0.25)
    assert fix.gap_before_ms == pytest.approx(250.0) and fix.gap_after_ms == pytest.approx(750.0)
    # identity FLU body in a frame turned 90 deg: the vehicle faces north, level -> body->NED is identity
    assert fix.q_body_ned is not None
    assert abs(abs(float(fix.q_body_ned[0])) - 1.0) < 1e-9
    lat, lon, alt = fix.geodetic()
    back = LocalFrame(*ORIGIN).geodetic_to_enu(lat, lon, alt)
    assert np.allclose(back, fix.enu_m, atol=1e-6)
    # before, after, and across a longer gap
    assert isinstance(traj.lookup(_frame(99_000_000)), PoseMiss)
    assert traj.lookup(_frame(102_000_000)).code == "after_end"  # type: ignore[union-attr]
    assert traj.lookup(_frame(None)).code == "no_time"  # type: ignore[union-attr]
    short = read_tum(p, ORIGIN, TumOptions(max_gap_s=0.5))
    assert short.lookup(_frame(100_500_000)).code == "gap"  # type: ignore[union-attr]
    # a host time base reads mid_host_ns
    host = read_tum(p, ORIGIN, TumOptions(time_base="host", time_offset_s=-50.0, max_gap_s=2.0))
    assert isinstance(host.lookup(_frame(None, host_ns=50_500_000_000)), PoseFix)


@pytest.mark.parametrize(
    ("text", "what"),
    [
        ("1.0 0 0 0 0 0 0 1 9\n", "9 columns"),
        ("1.0 0 0 zero 0 0 0 1\n", "not a number"),
        ("1.0 0 0 0 0 0 0 0\n", "quaternion"),
        ("1.0 0 0 nan 0 0 0 1\n", "not finite"),
        ("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n", "times must increase"),
        ("# only a comment\n", "no poses"),
    ],
)
def test_tum_malformed_lines_name_file_and_line(tmp_path: Path, text: str, what: str) -> None:
    p = _tum(tmp_path, text)
    with pytest.raises(TrajectoryError) as exc:
        read_tum(p, ORIGIN)
    assert what in str(exc.value) and str(p) in str(exc.value)
    if "no poses" not in what:
        assert f"{p}:" in str(exc.value)


def _pos(tmp_path: Path, lines: list[str], header: tuple[str, ...] = (HEADER, COLUMNS)) -> Path:
    p = tmp_path / "s.pos"
    p.write_text("\n".join([*header, *lines]) + "\n")
    return p


LINE_A = "2404 282401.000   37.881300000  127.729800000   100.9000   1  14   0.0100   0.0100   0.0200"
LINE_B = "2404 282401.200   37.881301000  127.729800000   100.9000   2  14   0.0300   0.0300   0.0600"


def test_pos_reads_week_tow_gpst_and_bounds(tmp_path: Path) -> None:
    p = _pos(tmp_path, [LINE_A, LINE_B])
    traj, sol = read_pos(p, ORIGIN, PosOptions(geoid_separation_m=24.9, max_accel_m_s2=0.0))
    assert (sol.time_system, sol.height, sol.time_format, sol.q_counts) == (
        "GPST",
        "ellipsoidal",
        "week_tow",
        {1: 1, 2: 1},
    )
    t0 = week_tow_to_utc_s(2404, 282401.0)
    fix = traj.at(t0)
    assert isinstance(fix, PoseFix) and fix.label == "ppk_fixed"
    assert np.allclose(fix.enu_m, [0.0, 0.0, 0.0], atol=1e-6)  # 100.9 - 24.9 = the origin's 76 m MSL
    assert fix.error_bound_m == pytest.approx(3 * math.sqrt(0.01**2 * 2 + 0.02**2))
    mid = traj.at(t0 + 0.1)
    assert isinstance(mid, PoseFix) and mid.label == "ppk_float"  # the worse of the two
    assert mid.error_bound_m == pytest.approx(3 * math.sqrt(0.03**2 * 2 + 0.06**2))
    assert mid.q_body_ned is None
    only_fixed, sol1 = read_pos(p, ORIGIN, PosOptions(geoid_separation_m=24.9, max_q=1))
    assert len(only_fixed) == 1 and sol1.left_out == 1


def test_pos_calendar_utc_geodetic_and_commas(tmp_path: Path) -> None:
    header = (
        HEADER.replace("ellipsoidal", "geodetic"),
        "%  UTC                   latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m)   sde(m)   sdu(m)",
    )
    line = "2026/12/01,12:00:00.500,37.8813,127.7298,76.0,1,12,0.01,0.01,0.02,0,0,0,0.0,9.9"
    traj, sol = read_pos(_pos(tmp_path, [line], header), ORIGIN)
    assert (sol.time_system, sol.height, sol.time_format) == ("UTC", "geodetic", "calendar")
    assert traj.t_s[0] == pytest.approx(calendar.timegm((2026, 12, 1, 12, 0, 0)) + 0.5)
    gpst = read_pos(
        _pos(tmp_path, [line.replace(",", " ", 2)], (HEADER.replace("ellipsoidal", "geodetic"), COLUMNS)), ORIGIN
    )
    assert gpst[0].t_s[0] == pytest.approx(traj.t_s[0] - 18.0)


@pytest.mark.parametrize(
    ("lines", "header", "opts", "what"),
    [
        ([LINE_A], (HEADER, COLUMNS), PosOptions(), "geoid separation"),
        ([LINE_A[:40]], (HEADER, COLUMNS), PosOptions(geoid_separation_m=0.0), "fields"),
        ([LINE_A.replace(" 1  14", " 7  14")], (HEADER, COLUMNS), PosOptions(geoid_separation_m=0.0), "Q = 7"),
        (
            [LINE_A.replace("37.881300000", "3x.88")],
            (HEADER, COLUMNS),
            PosOptions(geoid_separation_m=0.0),
            "not a number",
        ),
        ([LINE_B, LINE_A], (HEADER, COLUMNS), PosOptions(geoid_separation_m=0.0), "times must increase"),
        ([LINE_A], (HEADER,), PosOptions(geoid_separation_m=0.0), "no time system"),
        ([LINE_A], ("% (x/y/z-ecef=WGS84,Q=1:fix)", COLUMNS), PosOptions(), "ECEF"),
        (
            [LINE_A],
            (HEADER, COLUMNS.replace("latitude(deg)", "latitude(d'\")")),
            PosOptions(geoid_separation_m=0.0),
            "minutes",
        ),
        ([], (HEADER, COLUMNS), PosOptions(geoid_separation_m=0.0), "no solution lines"),
    ],
)
def test_pos_malformed_gives_clear_errors(
    tmp_path: Path, lines: list[str], header: tuple[str, ...], opts: PosOptions, what: str
) -> None:
    p = _pos(tmp_path, lines, header)
    with pytest.raises(TrajectoryError) as exc:
        read_pos(p, ORIGIN, opts)
    assert what in str(exc.value) and str(p) in str(exc.value)


def test_mrk_reader_refuses_other_lines(tmp_path: Path) -> None:
    p = tmp_path / "Timestamp.MRK"
    fields = ["1", "282401.669089", "[2404]", "   101,N", "   107,E", "   129,V", "22.77995359,Lat", "114.10089118,Lon"]
    good = "\t".join([*fields, "139.231,Ellh", "0.002967, 0.003104, 0.007622", "50,Q"])
    p.write_text(good + "\n")
    (line,) = read_mrk(p)
    assert (line.week, line.tow_s, line.offset_ned_mm, line.q) == (2404, 282401.669089, (101, 107, 129), 50)
    p.write_text(good.replace(",Lat", ",Lon") + "\n")
    with pytest.raises(PpkEventsError, match=r"Timestamp.MRK:1"):
        read_mrk(p)


def test_tum_agrees_with_evo(tmp_path: Path) -> None:
    """evo (the trajectory evaluation tool whose "tum" format SLAM systems write) as the oracle, both ways."""
    from evo.core.trajectory import PoseTrajectory3D
    from evo.tools import file_interface

    from icgt.geodesy import Q_NED_TO_ENU, q_multiply, q_normalize
    from icgt.trajectories.tum import tum_line

    rng = np.random.default_rng(3)
    n = 50
    t = 1_796_164_404.0 + np.arange(n) * 0.05
    p = rng.normal(size=(n, 3)) * 5.0
    q = np.asarray(q_normalize(rng.normal(size=(n, 4))))
    ours = tmp_path / "ours.tum"
    ours.write_text(
        "# timestamp tx ty tz qx qy qz qw\n" + "\n".join(tum_line(*row) for row in zip(t, p, q, strict=True))
    )
    back = file_interface.read_tum_trajectory_file(str(ours))
    assert np.allclose(back.timestamps, t, atol=1e-6) and np.allclose(back.positions_xyz, p, atol=1e-6)
    assert np.allclose(np.abs(np.sum(back.orientations_quat_wxyz * q, axis=1)), 1.0, atol=1e-9)
    theirs = tmp_path / "theirs.tum"
    traj = PoseTrajectory3D(positions_xyz=p, orientations_quat_wxyz=q, timestamps=t)
    file_interface.write_tum_trajectory_file(str(theirs), traj)
    got = read_tum(theirs, ORIGIN, TumOptions(body_axes="flu", max_gap_s=1.0))
    assert np.allclose(got.t_s, t, atol=1e-6) and np.allclose(got.enu_m, p, atol=1e-6)
    assert got.q_body_ned is not None
    # undo the reader's FLU -> FRD and ENU -> NED to get the file's quaternion back
    q_file = q_multiply(q_multiply(Q_NED_TO_ENU, got.q_body_ned), np.array([0.0, 1.0, 0.0, 0.0]))
    assert np.allclose(np.abs(np.sum(q_file * q, axis=1)), 1.0, atol=1e-9)
