"""recompute(): the frames of the simulated flight again from its raw streams, without re-flying.

With the recording's own settings the frames come out as recorded (the flight has a USB unplug
with a backlog of exposures and an autopilot link loss, so emission order matters); another lever
arm moves every geotagged frame by exactly the lever-arm difference rotated by the vehicle attitude.
"""

from __future__ import annotations

from pathlib import Path

import msgspec
import numpy as np
import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.demo import Flight
from icgt.geodesy import q_rotate
from icgt.geotag import FrameRecord
from icgt.ingest.reader import IngestError, read
from icgt.ingest.recompute import recompute, recording_config
from icgt.recording import McapRecorder

TIME_FIELDS_NS = ("mid_host_ns", "mid_host_uncertainty_ns")
TIME_FIELDS_US = ("trigger_device_us", "start_device_us", "mid_device_us", "duration_us", "mid_utc_us")
POSITION_FIELDS_M = ("east_m", "north_m", "up_m", "alt_msl_m")


@pytest.fixture(scope="module")
def recorded(flight: Flight) -> dict[int, FrameRecord]:
    return {f.frame_seq: f for f in read(flight.mcap).frames()}


@pytest.fixture(scope="module")
def same(flight: Flight) -> dict[int, FrameRecord]:
    result = recompute(flight.mcap)
    assert result.notes == []
    assert result.counts["frames_emitted_as_recorded"] == result.counts["frames_in_log"]
    return {f.frame_seq: f for f in result.frames}


# What a frame says about the device's own sensors at exposure (the IMU and LiDAR samples it found).
SENSOR_FLAGS = {"range_invalid", "range_stale", "range_out_of_band", "imu_uncalibrated", "motion_blur"}


def _differences(
    a: FrameRecord, b: FrameRecord, *, time_ns: float, time_us: float, metres: float, sensor_flags: bool = True
) -> list[str]:
    out: list[str] = []
    ignore = set() if sensor_flags else SENSOR_FLAGS
    if set(b.flags) - ignore != set(a.flags) - ignore:
        out.append(f"flags {a.flags} != {b.flags}")
    for name in ("image_index", "camera_id", "device_flags", "time_source", "position_source", "fix_type"):
        if getattr(a, name) != getattr(b, name):
            out.append(name)
    for name in TIME_FIELDS_NS:
        if abs(getattr(b, name) - getattr(a, name)) > time_ns:
            out.append(f"{name} by {getattr(b, name) - getattr(a, name)} ns")
    for name in TIME_FIELDS_US:
        va, vb = getattr(a, name), getattr(b, name)
        if (va is None) != (vb is None) or (va is not None and abs(vb - va) > time_us):
            out.append(f"{name} {va} -> {vb}")
    for name in POSITION_FIELDS_M:
        va, vb = getattr(a, name), getattr(b, name)
        if (va is None) != (vb is None) or (va is not None and abs(vb - va) > metres):
            out.append(f"{name} {va} -> {vb}")
    if (a.lat_deg is None) != (b.lat_deg is None):
        out.append("lat_deg")
    return out


def test_own_settings_reproduce_the_recorded_frames_exactly(flight: Flight) -> None:
    """The recorder logs every input of its synchroniser before feeding it, from one thread, and each
    frame says when it was emitted: the recompute feeds a fresh synchroniser the same inputs in the same
    order and polls it at the same times, so every field of every frame comes out identical."""
    assert assert_replay_reproduces_every_frame(flight.mcap) >= 60


def test_the_flight_exercises_the_hard_cases(recorded: dict[int, FrameRecord]) -> None:
    flags = [set(f.flags) for f in recorded.values()]
    assert sum("feedback_missing" in f for f in flags) >= 3
    assert sum("unsolicited" in f for f in flags) >= 2
    # frames held through the autopilot link loss
    assert sum(bool({"pose_extrapolated", "stale_pose", "no_fix", "no_attitude"} & f) for f in flags) >= 3


def test_another_lever_arm_moves_frames_by_the_rotated_difference(flight: Flight, same: dict[int, FrameRecord]) -> None:
    rec = read(flight.mcap)
    cfg = recording_config(rec)
    other = msgspec.structs.replace(cfg, lever_arm_body_m=(0.05, -0.20, 0.35))
    moved = {f.frame_seq: f for f in recompute(rec, other).frames}
    delta = np.subtract(other.lever_arm_body_m, cfg.lever_arm_body_m)
    checked = 0
    for seq, a in same.items():
        b = moved[seq]
        assert b.flags == a.flags and b.mid_host_ns == a.mid_host_ns
        if a.east_m is None or a.body_qw is None:
            assert b.east_m is None
            continue
        q = np.array([a.body_qw, a.body_qx, a.body_qy, a.body_qz])
        ned = q_rotate(q, delta)  # body FRD -> NED
        expected = np.array([ned[1], ned[0], -ned[2]])  # NED -> ENU
        assert b.east_m is not None and b.north_m is not None and b.up_m is not None
        assert a.north_m is not None and a.up_m is not None
        got = np.array([b.east_m - a.east_m, b.north_m - a.north_m, b.up_m - a.up_m])
        assert np.abs(got - expected).max() < 1e-9, seq
        assert np.linalg.norm(got) == pytest.approx(np.linalg.norm(delta), abs=1e-9)
        checked += 1
    assert checked >= 40


def test_lookahead_uses_what_came_after_and_keeps_every_frame(recorded: dict[int, FrameRecord], flight: Flight) -> None:
    result = recompute(flight.mcap, lookahead_s=1.0)
    frames = {f.frame_seq: f for f in result.frames}
    assert frames.keys() == recorded.keys()
    for seq, a in recorded.items():
        b = frames[seq]
        assert (b.image_index, b.start_device_us) == (a.image_index, a.start_device_us)
        # the device clock line, refitted with hindsight, stays within the bounds both claim
        assert abs(b.mid_host_ns - a.mid_host_ns) <= a.mid_host_uncertainty_ns + b.mid_host_uncertainty_ns, seq
    with pytest.raises(IngestError, match="lookahead_s"):
        recompute(flight.mcap, lookahead_s=10.0)


def test_a_log_without_raw_streams_says_what_is_missing(tmp_path: Path) -> None:
    path = tmp_path / "frames_only.mcap"
    rec = McapRecorder(path, fsync=False)
    rec.add_metadata("icgt.calibration", {"focal_length_mm": "24.0", "lever_arm_body_m": "(0.1, 0.0, 0.0)"})
    rec.close()
    result = recompute(path)
    assert result.frames == []
    assert result.config.focal_length_mm == 24.0 and result.config.lever_arm_body_m == (0.1, 0.0, 0.0)
    text = " ".join(result.notes)
    assert "/clock/device/exchanges" in text and "/mavlink/timesync" in text and "/device/exposure" in text
    empty = tmp_path / "no_calibration.mcap"
    McapRecorder(empty, fsync=False).close()
    with pytest.raises(IngestError, match=r"icgt\.calibration"):
        recompute(empty)
