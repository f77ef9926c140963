"""Issue 29.3 end to end, `board_imu`: the camera's attitude from the board's own BNO055 riding on the gimbal.

Flown on the simulator (the firmware core reading the simulated BNO055 over its I2C model, `icgt record` with
`[camera] attitude_source = "board_imu"`): under a deck looking up (gimbal 75 deg up, nodding +-10 deg, a 4 m/s
pass). The board sits 1.2 / -2.5 / 3.0 deg off the camera's axes (its calibrated alignment is the recorder's mount
angles) and the BNO's north is 9.5 deg off true north and drifting (IMU mode): the recorder reads its north off
the autopilot's heading. Every frame's camera attitude is scored against the simulator's truth at the true
mid-exposure; the gimbal's own reports (silent for 1.5 s) are not used.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.cli import main
from icgt.demo import Flight, fly
from icgt.geodesy import q_multiply
from icgt.pose import Q_OPTICAL_TO_FRD
from icgt.sim.evaluate import read_frames, read_truth
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("board_imu_under_deck.toml")


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return fly(load_scenario(SCENARIO), tmp_path_factory.mktemp("board_imu"))


@pytest.fixture(scope="module")
def paired(flight: Flight) -> list[tuple[dict[str, Any], dict[str, Any]]]:
    truth = {int(t["start_device_us"]): t for t in read_truth(flight.truth_exposures)}
    out = [
        (f, truth[int(f["start_device_us"])]) for f in read_frames(flight.mcap) if int(f["start_device_us"]) in truth
    ]
    assert len(out) >= 55  # 12.5 s at 5 fps
    return out


def _error_deg(f: dict[str, Any], t: dict[str, Any]) -> float:
    ours = np.array([f["cam_qw"], f["cam_qx"], f["cam_qy"], f["cam_qz"]], dtype=float)
    true = np.asarray(q_multiply(np.array(t["q_camera_ned"], dtype=float), Q_OPTICAL_TO_FRD))
    return math.degrees(2.0 * math.acos(min(1.0, abs(float(ours @ true)))))


def test_every_frame_has_the_cameras_attitude_from_the_board_within_0_2_deg(paired: list[Any]) -> None:
    errors = []
    for f, t in paired:
        assert not {"board_imu_stale", "board_imu_no_heading", "gimbal_stale"} & set(f["flags"]), f["flags"]
        errors.append(_error_deg(f, t))
    p95 = float(np.percentile(errors, 95))
    # the BNO's north 9.5 deg off and the board 3-4 deg off the camera: either left unapplied fails by degrees
    assert p95 <= 0.2, f"camera attitude error p95 {p95:.3f} deg (max {max(errors):.3f})"
    assert max(errors) <= 0.4


def test_the_frames_say_where_their_attitude_came_from(paired: list[Any]) -> None:
    for f, _ in paired:
        assert f["imu_source"] == "samples"
        assert f["body_qw"] is not None  # the body's own attitude is still recorded beside the camera's


def test_recomputing_the_board_imu_flight_reproduces_every_frame_exactly(flight: Flight) -> None:
    assert_replay_reproduces_every_frame(flight.mcap)


def test_the_calibration_flight_finds_the_boards_alignment_and_north(
    flight: Flight, capsys: pytest.CaptureFixture[str]
) -> None:
    """`icgt calibrate-board` on the same log recomputed with the gimbal's reports as the camera's attitude: the
    board's true alignment (1.2, -2.5, 3.0) deg and its north 9.5 deg (+0.6 deg/min: about 9.58 at the frames'
    mean time) come back within the gimbal's and the BNO's noise."""
    assert main(["calibrate-board", str(flight.mcap), "--attitude-source", "gimbal", "--json"]) == 0
    cal = json.loads(capsys.readouterr().out)
    assert cal["frames_used"] >= 55 and cal["pitch_span_deg"] >= 15.0
    assert cal["mount_roll_deg"] == pytest.approx(1.2, abs=0.15)
    assert cal["mount_pitch_deg"] == pytest.approx(-2.5, abs=0.15)
    assert cal["mount_yaw_deg"] == pytest.approx(3.0, abs=0.15)
    assert cal["heading_offset_deg"] == pytest.approx(9.58, abs=0.2)
    # the residual holds the gimbal's and the BNO's noise and the frames' nearest (not interpolated) BNO sample,
    # up to 5 ms from mid while the gimbal nods at up to 16 deg/s: 0.23-0.44 deg p95 idle, 0.63 once in a CI run
    # with two other test runs beside it (older samples under load). A wrong fit leaves degrees: the board's own
    # misalignment here is 1.2-3.0 deg and its north 9.5 deg, so 1 deg still tells a fit from a failed one.
    assert cal["residual_p95_deg"] <= 1.0


def test_a_log_whose_camera_attitude_came_from_the_board_is_refused_for_calibration(
    flight: Flight, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["calibrate-board", str(flight.mcap)]) == 2
    assert 'attitude_source = "board_imu"' in capsys.readouterr().err
