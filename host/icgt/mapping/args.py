"""The arguments of `icgt map` and `icgt tiles` (cheap to import: the `icgt` parser is built at every call)."""

from __future__ import annotations

import argparse
from pathlib import Path

POSITION_SIGMA_M = 0.03
"""1-sigma error of the recorded camera positions (the autopilot's fused estimate; ~0.01 m with RTK)."""
ATTITUDE_SIGMA_DEG = 0.3
RANGE_SIGMA_M = 0.025
"""LIDAR-Lite v3: +-2.5 cm."""


def add_map_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="the recording (.mcap)")
    p.add_argument("--images", type=Path, required=True, help="folder of the camera card's JPEGs (only read)")
    p.add_argument("--detections", type=Path, action="append", required=True,
                   help="COCO JSON, icgt-detections JSON or a folder of YOLO segment txt (repeatable)")  # fmt: skip
    p.add_argument("--out", type=Path, required=True, help="output folder")
    p.add_argument(
        "--calibration", type=Path, help="camera calibration (.toml, OpenCV .yaml/.json); default: the log's"
    )
    p.add_argument(
        "--plane", help="structure plane E,N,U,nE,nN,nU (recording ENU); default: fitted to the LiDAR ranges"
    )
    p.add_argument("--anchor", choices=("range", "structure"), default="range",
                   help="range: each image's plane through its LiDAR return (default); structure: one")  # fmt: skip
    p.add_argument("--classes", help="YOLO class names, comma-separated in class order")
    p.add_argument(
        "--tiles", type=Path, help="tiles.json of `icgt tiles`: detections on tiles map back to their images"
    )
    p.add_argument("--mm-per-px", type=float, default=2.0, help="mosaic resolution [mm/px] (default 2)")
    p.add_argument("--no-mosaic", action="store_true", help="skip the mosaic")
    p.add_argument("--mosaic-format", choices=("png", "tif"), default="png",
                   help="png (+ .pgw world file) or tif (tiled GeoTIFF); both in face metres")  # fmt: skip
    p.add_argument("--extent", help="mosaic extent s0,t0,s1,t1 [face m] (default: every footprint)")
    p.add_argument("--position-sigma-m", type=float, default=POSITION_SIGMA_M, help="1-sigma camera position error [m]")
    p.add_argument("--attitude-sigma-deg", type=float, default=ATTITUDE_SIGMA_DEG, help="1-sigma attitude error [deg]")
    p.add_argument("--range-sigma-m", type=float, default=RANGE_SIGMA_M, help="1-sigma LiDAR range error [m]")
    p.add_argument("--detector-recall", type=float, default=0.85,
                   help="the detector's per-image recall, for the multi-view consensus (default 0.85)")  # fmt: skip
    p.add_argument("--lookalike-rate", type=float, default=0.25,
                   help="how often it reports a look-alike (joint, stain) in a view (default 0.25)")  # fmt: skip
    p.add_argument("--min-tolerance-mm", type=float, default=10.0, help="smallest merge distance [mm]")
    p.add_argument("--cache-mb", type=float, default=512.0, help="decoded-image cache of the mosaic [MB]")
    p.add_argument("--recompute-lookahead-s", type=float, metavar="S",
                   help="geotag the frames again from the raw streams with S s of look-ahead (<= 2)")  # fmt: skip
    p.add_argument("--trust-flagged-poses", action="store_true",
                   help="use frames flagged stale_pose/pose_extrapolated too (default: reported, unused)")  # fmt: skip


def add_tiles_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("log", type=Path, help="the recording (.mcap): places every tile on the face")
    p.add_argument("--images", type=Path, required=True, help="folder of the camera card's JPEGs (only read)")
    p.add_argument("--out", type=Path, required=True, help="output folder for the tiles and tiles.json")
    p.add_argument("--size", type=int, default=512, help="tile size [px] (default 512, the paper's)")
    p.add_argument("--overlap", type=int, default=0, help="overlap of neighbouring tiles [px]")
    p.add_argument("--calibration", type=Path)
    p.add_argument("--plane")
    p.add_argument("--anchor", choices=("range", "structure"), default="range")
    p.add_argument("--recompute-lookahead-s", type=float, metavar="S", help="as for icgt map")
