"""`icgt export --formats ppk` on a simulated flight: events_gpst.csv and Timestamp.MRK read back, their GPS
times equal the frames' UTC + the leap seconds, and the MRK offsets are the lever arm turned by the attitude."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

import icgt
from icgt.cli import main
from icgt.clocks.autopilot_clock import GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_S
from icgt.export.ppk_events import EVENTS_CSV, MRK_FILE, read_mrk
from icgt.geodesy import q_rotate
from icgt.ingest.recompute import recording_config

from .conftest import Truth


def _gps_us(utc_us: int) -> int:
    return utc_us + (GPS_UTC_LEAP_S - GPS_EPOCH_UNIX_S) * 1_000_000


def test_ppk_export_reads_back_in_gps_time(truth: Truth, tmp_path: Path, capsys: object) -> None:
    out = tmp_path / "export"
    code = main(["export", str(truth.flight.mcap), "--out", str(out), "--formats", "ppk", "--no-progress",
                 "--geoid-separation", str(truth.geoid_m)])  # fmt: skip
    # exit 1: problems.csv has warnings (frames whose pose is flagged); none of them may be an export error but
    # the frames withheld in the flight's telemetry outage (no_pose: no position rather than a guess)
    with (out / "problems.csv").open(newline="") as fh:
        problems = list(csv.DictReader(fh))
    assert code == (1 if any(p["severity"] in ("error", "warning") for p in problems) else 0)
    assert not [p for p in problems if p["severity"] == "error" and p["code"] not in ("ppk_event_skipped", "no_pose")]
    frames = {f.frame_seq: f for f in icgt.read(truth.flight.mcap).frames()}
    with (out / EVENTS_CSV).open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    with_utc = [f for f in frames.values() if f.mid_utc_us is not None]
    assert len(rows) == len(with_utc) >= 5
    for r in rows:
        f = frames[int(r["frame_seq"])]
        assert f.mid_utc_us is not None
        whole, frac = r["gps_tow_s"].split(".")
        assert len(frac) == 6
        gps_us = int(r["gps_week"]) * 604_800_000_000 + int(whole) * 1_000_000 + int(frac)
        assert gps_us == _gps_us(f.mid_utc_us)
    mrk = read_mrk(out / MRK_FILE)
    by_index = {int(r["mrk_index"]): frames[int(r["frame_seq"])] for r in rows if r["mrk_index"]}
    assert [m.index for m in mrk] == list(range(1, len(mrk) + 1)) == sorted(by_index)
    missing = [f for f in with_utc if "feedback_missing" in f.flags]
    assert len(mrk) == len(with_utc) - len(missing)
    lever = np.asarray(recording_config(icgt.read(truth.flight.mcap)).lever_arm_body_m)
    for m in mrk:
        f = by_index[m.index]
        assert f.mid_utc_us is not None
        assert m.week * 604_800_000_000 + round(m.tow_s * 1e6) == _gps_us(f.mid_utc_us)
        if f.lat_deg is not None and f.alt_msl_m is not None:
            assert abs(m.lat_deg - f.lat_deg) < 1e-8 and abs(m.ellh_m - (f.alt_msl_m + truth.geoid_m)) < 1e-3
            assert m.q == 16  # a 3D GPS fix in this flight
        else:
            assert m.q == 0
        if f.body_qw is not None:
            ned = q_rotate(np.array([f.body_qw, f.body_qx, f.body_qy, f.body_qz]), lever) * 1000.0
            assert np.max(np.abs(np.array(m.offset_ned_mm) - ned)) <= 0.5
            assert m.offset_ned_mm[2] > 0  # the camera hangs below the autopilot (lever z +0.12 m, FRD z down)
            assert abs(np.linalg.norm(m.offset_ned_mm) - np.linalg.norm(lever) * 1000.0) <= 1.0
    problems = (out / "problems.csv").read_text()
    assert problems.count("ppk_event_skipped") == len(frames) - len(rows) + len(missing)


def test_ppk_export_without_geoid_says_so(truth: Truth, tmp_path: Path, capsys: object) -> None:
    code = main(["export", str(truth.flight.mcap), "--out", str(tmp_path / "e"), "--formats", "ppk",
                 "--no-progress", "--geoid-separation", "none"])  # fmt: skip
    assert code == 1
    assert "geoid separation" in capsys.readouterr().err  # type: ignore[attr-defined]
