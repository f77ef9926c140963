"""`icgt calibrate-board LOG`: the board IMU's ``[camera]`` settings from a calibration flight (docs/board-imu.md).

The flight is recorded with the camera's attitude from its gimbal (``attitude_source = "gimbal"``), nodding the
gimbal through at least 10 deg of pitch; every frame then holds the gimbal's camera attitude beside the board's
BNO055 quaternion, and `icgt.geotag.board_calibration` fits the board's alignment and its north to them. A log
recorded with another source is recomputed first with ``--attitude-source gimbal`` (the camera square on its
gimbal: mount angles 0).
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict
from pathlib import Path

import msgspec

from icgt.geotag.board_calibration import BoardCalibrationError, calibrate_board
from icgt.ingest.reader import IngestError, read
from icgt.ingest.recompute import recompute, recording_sync_config

__all__ = ["add_calibrate_board_arguments", "cmd_calibrate_board"]


def add_calibrate_board_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="the calibration flight's MCAP log")
    p.add_argument(
        "--attitude-source",
        choices=("gimbal", "mount"),
        help="recompute the frames with this camera attitude source first (mount angles 0) instead of as recorded",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of [camera] lines")


def cmd_calibrate_board(args: argparse.Namespace) -> int:
    try:
        rec = read(args.log)
        geotag = recording_sync_config(rec).geotag
        if args.attitude_source is not None:
            cfg = msgspec.structs.replace(
                geotag, attitude_source=args.attitude_source, mount_roll_deg=0.0, mount_pitch_deg=0.0, mount_yaw_deg=0.0
            )
            frames = recompute(rec, cfg).frames
        elif geotag.attitude_source == "board_imu":
            raise BoardCalibrationError(
                f'{args.log}: its camera attitude came from the board itself (attitude_source = "board_imu"); '
                "give --attitude-source gimbal to recompute it from the gimbal's reports"
            )
        else:
            frames = list(rec.frames())
        cal = calibrate_board(frames)
    except (IngestError, BoardCalibrationError) as exc:
        print(f"icgt calibrate-board: {exc}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(asdict(cal), indent=2))
    else:
        print(
            f"# {cal.frames_used} frames, pitch span {cal.pitch_span_deg:.1f} deg, residual p50 / p95 "
            f"{cal.residual_p50_deg:.3f} / {cal.residual_p95_deg:.3f} deg"
        )
        print("[camera]")
        print(cal.toml(), end="")
    return 0
