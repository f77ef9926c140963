"""`icgt regeotag`: re-geotag a recording's frames from a TUM (SLAM/VIO) or RTKLIB .pos (PPK) trajectory.

    icgt regeotag FLIGHT.mcap --trajectory FILE --format tum|rtklib --out FRAMES.csv|FRAMES.json
                  [--time-base utc|host] [--time-offset-s X] [--geoid-separation auto|METRES]
                  [--lever-arm X,Y,Z] [--position-error-m M] [--yaw-deg D] [--translation E,N,U]
                  [--body-axes flu|frd] [--max-gap-s S]

Writes every frame (the placed ones replaced, the others as recorded) as the export's frames.csv
columns (.csv) or as a JSON array of frame records (.json, non-finite numbers as null), reads the
file back, and prints how many frames were placed, per position source, and every frame that was
not, with the reason.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from icgt.geotag.record import FrameRecord
from icgt.trajectories.regeotag import RegeotagConfig, RegeotagResult, regeotag_detailed
from icgt.trajectories.source import TrajectoryError

__all__ = ["add_regeotag_arguments", "cmd_regeotag", "run_regeotag", "write_frames"]


def _triple(text: str, what: str) -> tuple[float, float, float]:
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise TrajectoryError(f"{what} wants three numbers X,Y,Z, got {text!r}")
    return (v[0], v[1], v[2])


def _geoid(text: str, recording: Any) -> float | None:
    if text == "auto":
        from icgt.export.cli import geoid_separation_from_log

        return geoid_separation_from_log(recording)
    try:
        return float(text)
    except ValueError:
        raise TrajectoryError(f"--geoid-separation wants auto or metres, got {text!r}") from None


def _json_value(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


def write_frames(path: Path, frames: Sequence[FrameRecord]) -> int:
    """Write frames as CSV (the export's frames.csv columns) or JSON by the suffix; read back, return the count."""
    suffix = path.suffix.lower()
    if suffix == ".csv":
        import csv

        from icgt.export.common import ProblemLog, prepare_items
        from icgt.export.csv_export import write_csv

        n = write_csv(path, prepare_items([(None, f) for f in frames], None, ProblemLog()))
        with path.open(newline="", encoding="utf-8") as fh:
            back = sum(1 for _ in csv.DictReader(fh))
    elif suffix == ".json":
        from icgt.ingest.reader import decode_frame

        rows = [{k: _json_value(v) for k, v in dataclasses.asdict(f).items()} for f in frames]
        try:
            path.write_text(json.dumps(rows, allow_nan=False, indent=1) + "\n", encoding="utf-8")
            back = len([decode_frame(r) for r in json.loads(path.read_text(encoding="utf-8"))])
        except OSError as exc:
            raise TrajectoryError(f"cannot write {path}: {exc.strerror or exc}") from exc
        n = len(rows)
    else:
        raise TrajectoryError(f"--out {path}: choose a .csv or .json file")
    if back != n:
        raise TrajectoryError(f"{path}: read back {back} frames, wrote {n}")
    return n


def run_regeotag(args: argparse.Namespace) -> tuple[RegeotagResult, str]:
    """Build the source from the arguments, re-geotag, write --out; returns the result and a description."""
    from icgt.ingest import read
    from icgt.trajectories.rtklib_pos import PosOptions, read_pos
    from icgt.trajectories.tum import Alignment4Dof, TumOptions, read_tum

    recording = read(args.log)
    lever = _triple(args.lever_arm, "--lever-arm") if args.lever_arm else None
    config = RegeotagConfig.from_recording(recording, lever_arm_body_m=lever)
    extra = ""
    if args.format == "tum":
        translation = _triple(args.translation, "--translation") if args.translation else (0.0, 0.0, 0.0)
        options = TumOptions(
            time_base=args.time_base,
            time_offset_s=args.time_offset_s,
            alignment=Alignment4Dof(args.yaw_deg, translation),
            body_axes=args.body_axes,
            position_error_m=args.position_error_m,
            max_gap_s=args.max_gap_s if args.max_gap_s is not None else 0.5,
            use_attitude=not args.no_attitude,
        )
        source = read_tum(args.trajectory, config.origin, options)
    else:
        if args.time_base != "utc":
            raise TrajectoryError("an RTKLIB .pos solution is on GPS time or UTC: --time-base host does not apply")
        pos_opts = PosOptions(
            geoid_separation_m=_geoid(args.geoid_separation, recording),
            time_offset_s=args.time_offset_s,
            max_gap_s=args.max_gap_s if args.max_gap_s is not None else 1.5,
        )
        source, sol = read_pos(args.trajectory, config.origin, pos_opts)
        q = ", ".join(f"Q{k}: {v}" for k, v in sorted(sol.q_counts.items()))
        extra = f" ({sol.time_system}, {sol.time_format} times, {sol.height} heights; {q})"
    result = regeotag_detailed(list(recording.frames()), source, config)
    n = write_frames(Path(args.out), result.frames)
    by_label = ", ".join(f"{k} {v}" for k, v in sorted(result.labels.items())) or "none"
    lines = [
        f"{source.name}: {len(source)} samples{extra}",
        f"placed {len(result.placed)} of {n} frames ({by_label}); {len(result.unplaced)} not placed "
        f"(kept as recorded) -> {args.out}",
    ]
    lines += [f"  frame {seq}: {miss.code}: {miss.detail}" for seq, miss in result.unplaced]
    return result, "\n".join(lines)


def cmd_regeotag(args: argparse.Namespace) -> int:
    _, text = run_regeotag(args)
    print(text, file=sys.stdout)
    return 0


def add_regeotag_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", type=Path, help="the recording (.mcap)")
    parser.add_argument("--trajectory", type=Path, required=True, help="the trajectory file")
    parser.add_argument("--format", choices=("tum", "rtklib"), required=True, help="tum (SLAM/VIO) or rtklib (.pos)")
    parser.add_argument("--out", type=Path, required=True, help="FRAMES.csv or FRAMES.json")
    parser.add_argument(
        "--time-base", choices=("utc", "host"), default="utc", help="TUM timestamps: UTC or the log's host monotonic"
    )
    parser.add_argument("--time-offset-s", type=float, default=0.0, help="added to the file's times [s]")
    parser.add_argument(
        "--geoid-separation", default="auto", help="N [m] for .pos ellipsoidal heights (auto: from GPS_RAW_INT)"
    )
    parser.add_argument(
        "--lever-arm", help="camera from the trajectory's point, body FRD X,Y,Z [m] (default: the log's)"
    )
    parser.add_argument("--position-error-m", type=float, default=0.05, help="TUM: the SLAM's own error bound [m]")
    parser.add_argument("--yaw-deg", type=float, default=0.0, help="TUM: yaw of the file's frame to ENU [deg]")
    parser.add_argument("--translation", help="TUM: the file's origin in the log's ENU E,N,U [m]")
    parser.add_argument("--body-axes", choices=("flu", "frd"), default="flu", help="TUM: body axes of the poses")
    parser.add_argument("--no-attitude", action="store_true", help="TUM: use the positions only")
    parser.add_argument("--max-gap-s", type=float, help="longest interpolated gap [s] (TUM 0.5, .pos 1.5)")
