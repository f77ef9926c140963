"""Pose sources behind one interface, and the time-interpolated trajectory they share.

A `PoseSource` answers, for one frame, where the vehicle's reference point was at mid-exposure
(and, if it knows, the vehicle's attitude), with a bound on the position error, or says why it
cannot (`PoseMiss`). It reads the frame's time on the clock it declares (`time_base`):

* ``utc``: ``FrameRecord.mid_utc_us`` [us since the Unix epoch, UTC] and its bound
  ``mid_utc_uncertainty_us``;
* ``host``: ``FrameRecord.mid_host_ns`` [ns, the recording host's CLOCK_MONOTONIC, the clock the log
  keeps its inputs on] and its bound ``mid_host_uncertainty_ns``.

The sources: the autopilot's telemetry, which the recorder's geotagger has already applied
(`icgt.geotag`, ``position_source`` gps_3d/rtk_*/local_position/dead_reckoned; `icgt.trajectories.recorded` hands
it back through this interface), and the external trajectories of this package: a TUM trajectory from
SLAM/VIO (`icgt.trajectories.tum`) and an RTKLIB ``.pos`` PPK solution (`icgt.trajectories.rtklib_pos`),
both built on `SampledTrajectory`.

Positions are given in the recording's ENU frame: east/north/up metres from the log's ENU origin
(`Recording.enu_origin`: lat, lon, altitude above mean sea level), the frame the geotagger places
frames in, which treats MSL altitudes as heights of its tangent frame. `PoseFix.geodetic()` gives
WGS84 latitude/longitude and MSL altitude. Attitudes are vehicle body (FRD) -> NED quaternions,
Hamilton, w first (`icgt.geodesy`).

Interpolation (`SampledTrajectory.at`): linear in position, spherical-linear (slerp) in attitude,
between the two samples around the instant, never across a gap longer than ``max_gap_s`` and never
beyond the first or last sample. Linear is enough at the rates these files come at (SLAM/VIO 10-30 Hz,
PPK 1-20 Hz): a path whose acceleration stays below ``max_accel_m_s2`` leaves the chord between two
samples T apart by at most ``max_accel_m_s2 * T**2 / 8`` (1.5 cm at 5 Hz and 3 m/s^2, 0.4 cm at
10 Hz), and that is added to the bound. Slerp's error is the same expression with the angular
acceleration; a multirotor's attitude changes smoothly enough between samples at these rates that
its effect on the lever arm (below a metre) stays under a millimetre.

Error bound of an interpolated position [m] = the larger of the two samples' own bounds (from the
file's sigmas, or the bound the caller declares for a file without them) + the chord term above +
the speed between the samples times the frame's time bound on the source's clock (a time error moves
the answer along the path).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from icgt.errors import IcgtError
from icgt.geodesy import FloatArray, LocalFrame, q_normalize, q_slerp
from icgt.geotag.record import FrameRecord

__all__ = [
    "PoseFix",
    "PoseMiss",
    "PoseSource",
    "SampledTrajectory",
    "TimeBase",
    "TrajectoryError",
    "frame_time_s",
]

TimeBase = Literal["utc", "host"]
TIME_BASES: tuple[TimeBase, ...] = ("utc", "host")


class TrajectoryError(IcgtError):
    """A trajectory file that cannot be used (the message names the file and the line), or a bad request."""


@dataclass(frozen=True)
class PoseFix:
    """The vehicle's reference point (and attitude) at one frame's mid-exposure, from one source."""

    enu_m: FloatArray
    """Reference point in the recording's ENU frame [m] (see the module docstring)."""
    frame: LocalFrame
    """The recording's ENU frame (origin lat, lon, MSL altitude)."""
    q_body_ned: FloatArray | None
    """Vehicle body (FRD) -> NED, w first; None when the source has no attitude."""
    error_bound_m: float
    label: str
    """What placed it, for FrameRecord.position_source (slam, ppk_fixed, ppk_float, ...)."""
    gap_before_ms: float
    """Frame time minus the earlier sample used [ms]."""
    gap_after_ms: float
    """The later sample used minus the frame time [ms]."""
    extrapolated: bool = False
    """Held or extrapolated past the last sample (the trajectories here never are; recorded poses can be)."""
    horizontal_bound_m: float | None = None
    """95 % horizontal / vertical bounds [m] where the source has them apart (None: ``error_bound_m`` for both)."""
    vertical_bound_m: float | None = None
    stale: bool | None = None
    """The source's own stale_pose verdict (the recorded telemetry's); None: decided from the bound."""

    def geodetic(self) -> tuple[float, float, float]:
        """(lat [deg], lon [deg], altitude above MSL [m]) of the reference point."""
        la, lo, al = self.frame.enu_to_geodetic(self.enu_m)
        return float(la), float(lo), float(al)


@dataclass(frozen=True)
class PoseMiss:
    """Why a source could not place a frame: a short code and a sentence."""

    code: str
    """no_time, before_start, after_end, gap"""
    detail: str


class PoseSource(Protocol):
    """Anything that places a frame: an external trajectory, or a wrapper of the autopilot's telemetry."""

    @property
    def name(self) -> str:
        """What the source is (file name and format), for messages."""
        ...

    @property
    def time_base(self) -> TimeBase: ...

    @property
    def has_attitude(self) -> bool: ...

    def lookup(self, frame: FrameRecord) -> PoseFix | PoseMiss:
        """The pose at the frame's mid-exposure, or why there is none."""
        ...


def frame_time_s(frame: FrameRecord, time_base: TimeBase) -> tuple[float, float] | None:
    """(mid-exposure [s] on the time base, its bound [s]) of a frame; None if the frame lacks that time."""
    if time_base == "utc":
        if frame.mid_utc_us is None:
            return None
        unc = frame.mid_utc_uncertainty_us
        return frame.mid_utc_us / 1e6, (unc / 1e6 if unc is not None and math.isfinite(unc) else 0.0)
    return frame.mid_host_ns / 1e9, frame.mid_host_uncertainty_ns / 1e9


class SampledTrajectory:
    """Time-ordered positions (recording ENU), optional attitudes and per-sample bounds; interpolated by `at`."""

    def __init__(
        self,
        *,
        name: str,
        time_base: TimeBase,
        t_s: FloatArray,
        enu_m: FloatArray,
        frame: LocalFrame,
        bound_m: FloatArray,
        labels: list[str],
        q_body_ned: FloatArray | None = None,
        rank: list[int] | None = None,
        max_gap_s: float = 1.5,
        max_accel_m_s2: float = 3.0,
    ) -> None:
        if time_base not in TIME_BASES:
            raise TrajectoryError(f"{name}: time base {time_base!r}: choose utc or host")
        n = len(t_s)
        if n == 0:
            raise TrajectoryError(f"{name}: no samples")
        if enu_m.shape != (n, 3) or bound_m.shape != (n,) or len(labels) != n or (rank is not None and len(rank) != n):
            raise TrajectoryError(f"{name}: sample arrays of unequal lengths")
        if q_body_ned is not None and q_body_ned.shape != (n, 4):
            raise TrajectoryError(f"{name}: attitude array of the wrong shape {q_body_ned.shape}")
        if n > 1 and not np.all(np.diff(t_s) > 0.0):
            k = int(np.argmin(np.diff(t_s) > 0.0))
            raise TrajectoryError(
                f"{name}: timestamps must increase strictly; sample {k + 2} ({t_s[k + 1]!r} s) "
                f"does not follow sample {k + 1} ({t_s[k]!r} s)"
            )
        if max_gap_s <= 0.0 or max_accel_m_s2 < 0.0:
            raise TrajectoryError(f"{name}: max_gap_s must be > 0 and max_accel_m_s2 >= 0")
        self.name = name
        self.time_base: TimeBase = time_base
        self.t_s = t_s
        self.enu_m = enu_m
        self.frame = frame
        self.bound_m = bound_m
        self.labels = labels
        self.rank = rank if rank is not None else [0] * n
        """Per-sample quality rank, lower is better (RTKLIB's Q); an interpolated pose takes the worse label."""
        self.q_body_ned = q_normalize(q_body_ned) if q_body_ned is not None else None
        self.max_gap_s = max_gap_s
        self.max_accel_m_s2 = max_accel_m_s2

    @property
    def has_attitude(self) -> bool:
        return self.q_body_ned is not None

    def __len__(self) -> int:
        return len(self.t_s)

    def lookup(self, frame: FrameRecord) -> PoseFix | PoseMiss:
        t = frame_time_s(frame, self.time_base)
        if t is None:
            return PoseMiss("no_time", f"the frame has no mid-exposure {self.time_base.upper()} time")
        return self.at(t[0], t[1])

    def at(self, t_s: float, time_bound_s: float = 0.0) -> PoseFix | PoseMiss:
        """The interpolated pose at t [s on the time base]; `time_bound_s` widens the bound by speed x it."""
        ts = self.t_s
        if t_s < ts[0]:
            return PoseMiss("before_start", f"{ts[0] - t_s:.3f} s before the trajectory's first sample")
        if t_s > ts[-1]:
            return PoseMiss("after_end", f"{t_s - ts[-1]:.3f} s after the trajectory's last sample")
        k = int(np.searchsorted(ts, t_s, side="right")) - 1
        if k >= len(ts) - 1 or ts[k] == t_s:  # on a sample
            k = min(k, len(ts) - 1)
            q = self.q_body_ned[k] if self.q_body_ned is not None else None
            speed = self._speed(k)
            bound = float(self.bound_m[k]) + speed * time_bound_s
            return PoseFix(self.enu_m[k].copy(), self.frame, q, bound, self.labels[k], 0.0, 0.0)
        t0, t1 = float(ts[k]), float(ts[k + 1])
        span = t1 - t0
        if span > self.max_gap_s:
            return PoseMiss("gap", f"in a {span:.3f} s gap between samples (longer than the {self.max_gap_s} s limit)")
        f = (t_s - t0) / span
        p0, p1 = self.enu_m[k], self.enu_m[k + 1]
        p = p0 + (p1 - p0) * f
        q = None
        if self.q_body_ned is not None:
            q = np.asarray(q_slerp(self.q_body_ned[k], self.q_body_ned[k + 1], f), dtype=float)
        speed = float(np.linalg.norm(p1 - p0)) / span
        bound = (
            max(float(self.bound_m[k]), float(self.bound_m[k + 1]))
            + self.max_accel_m_s2 * span**2 / 8.0
            + speed * time_bound_s
        )
        # the worse of the two samples' labels (a float next to a fix is not a fix)
        label = self.labels[k] if self.rank[k] >= self.rank[k + 1] else self.labels[k + 1]
        return PoseFix(p, self.frame, q, bound, label, (t_s - t0) * 1e3, (t1 - t_s) * 1e3)

    def _speed(self, k: int) -> float:
        """Speed [m/s] around sample k (0 for a single sample)."""
        if len(self.t_s) < 2:
            return 0.0
        a, b = (k, k + 1) if k + 1 < len(self.t_s) else (k - 1, k)
        return float(np.linalg.norm(self.enu_m[b] - self.enu_m[a])) / float(self.t_s[b] - self.t_s[a])
