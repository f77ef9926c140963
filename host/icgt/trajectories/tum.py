"""A TUM-format trajectory (the output of SLAM/VIO systems) as a pose source.

Format (TUM RGB-D benchmark; the "tum" format of the evo evaluation tool): one pose per line,
eight numbers separated by spaces, ``timestamp tx ty tz qx qy qz qw``: the time in seconds, the
position of the tracked body's origin in the trajectory's world frame [m], and the body's
orientation relative to that world frame as a unit quaternion, **scalar last**. Lines starting
with ``#`` are comments; empty lines are skipped. Anything else is an error naming the file and
the line (a ninth column, a word, a non-finite number, a zero quaternion, a time that does not
increase).

Time base: the file does not say, so the caller does: ``utc`` (seconds since the Unix epoch, UTC,
what a SLAM system stamping with a GPS-disciplined or NTP clock writes) or ``host`` (seconds of the
recording host's CLOCK_MONOTONIC, when the SLAM ran on the companion computer that recorded the log,
as ROS 2 stamps with a steady clock do). ``time_offset_s`` is added to every timestamp to put it on
that base (t_base = t_file + offset).

Frame: the trajectory's world frame is a local metric frame. VIO and visual-inertial SLAM estimate
gravity, so that frame is gravity-aligned (its z axis up) and only its yaw and origin are arbitrary;
`Alignment4Dof` maps it to the recording's ENU frame by a rotation ``yaw_deg`` about up (the file's
x axis points ``yaw_deg`` counter-clockwise from east, seen from above) and a translation [m]:
``p_enu = Rz(yaw) p_file + t``. The default (yaw 0, translation 0) says the file is already in the
log's ENU (origin `Recording.enu_origin`). Roll and pitch need no alignment. A purely visual
(monocular, no IMU) trajectory is neither gravity-aligned nor metric: align it with a full 7-DoF
similarity first (evo's ``--align --correct_scale``).

Body axes: ``flu`` (x forward, y left, z up, the ROS REP-103 body convention VIO packages publish)
or ``frd`` (the autopilot's). The tracked point is taken as the vehicle reference point the
recording's lever arm starts from; if the SLAM tracks another point (its IMU, its camera), give the
lever arm from that point to the camera (`icgt.trajectories.regeotag.RegeotagConfig`).

Error bound: a TUM file carries no uncertainty; the caller declares ``position_error_m`` (the SLAM
system's accuracy over this flight: its drift, e.g. 0.5-1 % of the distance flown for VIO), to which
the interpolation terms of `icgt.trajectories.source` are added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from icgt.geodesy import Q_NED_TO_ENU, LocalFrame, q_from_euler_zyx, q_multiply, q_rotate
from icgt.trajectories.source import SampledTrajectory, TimeBase, TrajectoryError

__all__ = ["Alignment4Dof", "TumOptions", "read_tum", "tum_line"]

BodyAxes = Literal["flu", "frd"]
_Q_X_180 = np.array([0.0, 1.0, 0.0, 0.0])  # FRD <-> FLU: half a turn about x


@dataclass(frozen=True)
class Alignment4Dof:
    """The file's gravity-aligned world frame -> the recording's ENU: yaw about up, then a translation."""

    yaw_deg: float = 0.0
    translation_enu_m: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def quaternion(self) -> np.ndarray:
        return np.asarray(q_from_euler_zyx(0.0, 0.0, math.radians(self.yaw_deg)), dtype=float)


@dataclass(frozen=True)
class TumOptions:
    time_base: TimeBase = "utc"
    time_offset_s: float = 0.0
    alignment: Alignment4Dof = Alignment4Dof()
    body_axes: BodyAxes = "flu"
    position_error_m: float = 0.05
    """Declared bound on the file's own position error [m] (TUM carries none)."""
    max_gap_s: float = 0.5
    """Longest interval between two samples that is interpolated [s] (SLAM output at 10-30 Hz)."""
    max_accel_m_s2: float = 3.0
    use_attitude: bool = True
    label: str = "slam"


def _parse(path: Path) -> np.ndarray:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise TrajectoryError(f"cannot read {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TrajectoryError(f"{path}: not a text file ({exc.reason} at byte {exc.start})") from None
    rows: list[list[float]] = []
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        where = f"{path}:{number}"
        if len(fields) != 8:
            raise TrajectoryError(
                f"{where}: {len(fields)} columns, a TUM line has 8 (timestamp tx ty tz qx qy qz qw): {line[:80]!r}"
            )
        try:
            values = [float(v) for v in fields]
        except ValueError:
            raise TrajectoryError(f"{where}: not a number in {line[:80]!r}") from None
        if not all(math.isfinite(v) for v in values):
            raise TrajectoryError(f"{where}: a value is not finite: {line[:80]!r}")
        norm = math.sqrt(sum(v * v for v in values[4:8]))
        if not 0.5 < norm < 1.5:
            raise TrajectoryError(f"{where}: quaternion of norm {norm:.3g}, not a rotation (qx qy qz qw)")
        if rows and values[0] <= rows[-1][0]:
            raise TrajectoryError(
                f"{where}: timestamp {fields[0]} does not follow the previous one ({rows[-1][0]!r}): "
                "times must increase"
            )
        rows.append(values)
    if not rows:
        raise TrajectoryError(f"{path}: no poses (only comments or empty lines)")
    return np.asarray(rows, dtype=np.float64)


def read_tum(
    path: str | Path, origin: tuple[float, float, float], options: TumOptions = TumOptions()
) -> SampledTrajectory:
    """A TUM trajectory as a pose source in the recording's ENU frame at `origin` (lat, lon, MSL alt)."""
    p = Path(path)
    if options.position_error_m < 0.0 or not math.isfinite(options.position_error_m):
        raise TrajectoryError(f"{p}: position_error_m must be a finite bound >= 0")
    rows = _parse(p)
    a = options.alignment
    q_align = a.quaternion()
    pos = np.asarray(q_rotate(q_align, rows[:, 1:4]), dtype=float) + np.asarray(a.translation_enu_m, dtype=float)
    q_file = rows[:, [7, 4, 5, 6]]  # scalar last in the file -> w first
    q_body_enu = q_multiply(q_align, q_file)
    if options.body_axes == "flu":
        q_body_enu = q_multiply(q_body_enu, _Q_X_180)  # FRD body -> FLU body -> world
    elif options.body_axes != "frd":
        raise TrajectoryError(f"body axes {options.body_axes!r}: choose flu or frd")
    # Q_NED_TO_ENU is a half turn, its own inverse: it also takes ENU components to NED
    q_body_ned = np.asarray(q_multiply(Q_NED_TO_ENU, q_body_enu), dtype=float) if options.use_attitude else None
    n = len(rows)
    return SampledTrajectory(
        name=f"{p.name} (TUM)",
        time_base=options.time_base,
        t_s=rows[:, 0] + options.time_offset_s,
        enu_m=pos,
        frame=LocalFrame(*origin),
        bound_m=np.full(n, options.position_error_m),
        labels=[options.label] * n,
        q_body_ned=q_body_ned,
        max_gap_s=options.max_gap_s,
        max_accel_m_s2=options.max_accel_m_s2,
    )


def tum_line(t_s: float, p: np.ndarray, q_wxyz: np.ndarray) -> str:
    """One TUM line (timestamp with 9 decimals, metres with 6, quaternion scalar last with 9)."""
    return f"{t_s:.9f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} {q_wxyz[1]:.9f} {q_wxyz[2]:.9f} {q_wxyz[3]:.9f} {q_wxyz[0]:.9f}"
