"""The error model behind every frame's position and attitude bound (docs/error-bounds.md).

Each bound is meant as a **95 % bound**: of many frames placed under the same conditions, about 95 % have
their true error within it. A frame's horizontal and vertical bounds are sums of independent parts, each
sized to 95 % on its own (a sum of 95 % bounds covers at least 95 %; the parts are listed so that
`benchmarks/bound_coverage.py` can show which one decides):

- **source**: the autopilot's own accuracy (GPS_RAW_INT ``h_acc``/``v_acc``, else a figure by fix type);
- **motion**: what the samples do not show between (or beyond) them: `interpolation_bound` and
  `extrapolation_bound`;
- **timing**: the clock uncertainty at mid-exposure times the speed;
- **lever**: the lever arm times the attitude bound.

Pure functions of numbers: no telemetry, no clocks. Units are in the names.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "AXIS_95",
    "RADIAL_95",
    "InterpolationParts",
    "MotionAllowance",
    "SourceAccuracy",
    "extrapolation_bound",
    "interpolation_bound",
    "interpolation_parts",
    "quintic_correction",
    "source_accuracy",
]

# A normal error with standard deviation s is within 1.96 s 95 % of the time; a circular horizontal error
# whose radial RMS is r (both axes r / sqrt(2)) is within sqrt(-2 ln 0.05) / sqrt(2) r = 1.731 r.
AXIS_95 = 1.96
RADIAL_95 = math.sqrt(-2.0 * math.log(0.05)) / math.sqrt(2.0)

# When the receiver does not report h_acc / v_acc (0 in GPS_RAW_INT): typical 1-sigma figures by fix type
# (u-blox F9P / M8 datasheets; RTK float as a few decimetres; a 3D fix a few metres) [m].
_DEFAULT_ACCURACY_M: dict[int, tuple[float, float]] = {
    6: (0.02, 0.04),  # RTK fixed
    5: (0.40, 0.80),  # RTK float
    4: (1.0, 2.0),  # DGPS / SBAS
    3: (2.5, 5.0),  # 3D fix
}


@dataclass(frozen=True)
class SourceAccuracy:
    """The position source's own 95 % error [m], horizontal and vertical, and where the figure came from."""

    horizontal_m: float
    vertical_m: float
    reported: bool  # from the receiver's h_acc / v_acc (False: the fix type's typical figure)


def source_accuracy(fix_type: int, h_acc_m: float | None, v_acc_m: float | None) -> SourceAccuracy:
    """The 95 % source bound: ``h_acc`` read as the radial RMS, ``v_acc`` as one standard deviation."""
    dh, dv = _DEFAULT_ACCURACY_M.get(fix_type, _DEFAULT_ACCURACY_M[3])
    reported = h_acc_m is not None and v_acc_m is not None
    h = h_acc_m if h_acc_m is not None else dh
    v = v_acc_m if v_acc_m is not None else dv
    return SourceAccuracy(RADIAL_95 * h, AXIS_95 * v, reported)


@dataclass(frozen=True)
class MotionAllowance:
    """How much the vehicle may do that the samples do not show (the recorder's [camera] settings).

    ``unseen_accel_*``: an acceleration change that starts and ends inside a gap (a gust, a bank started and
    stopped between two samples) [m/s^2]. ``unseen_rate_rad_s2``: the same for the body rate [rad/s^2]."""

    unseen_accel_h_m_s2: float = 2.0
    unseen_accel_v_m_s2: float = 1.0
    unseen_rate_rad_s2: float = 0.5


def quintic_correction(
    p0: np.ndarray,
    v0: np.ndarray,
    a0: np.ndarray,
    p1: np.ndarray,
    v1: np.ndarray,
    a1: np.ndarray,
    span_s: float,
    f: float,
) -> np.ndarray:
    """What the end accelerations say a cubic Hermite between (p0, v0) and (p1, v1) misses at fraction f [m].

    The cubic's own accelerations at the ends are fixed by the positions and velocities; where the samples
    around the pair show other accelerations (a turn: the acceleration turns with the velocity), the quintic
    Hermite that also matches them differs from the cubic by this. Its second-derivative basis functions are
    T^2/2 u^2 (1-u)^3 at the start and T^2/2 u^3 (1-u)^2 at the end."""
    t = span_s
    dp = p1 - p0
    a_cubic_0 = 6.0 * dp / t**2 - (4.0 * v0 + 2.0 * v1) / t
    a_cubic_1 = -6.0 * dp / t**2 + (2.0 * v0 + 4.0 * v1) / t
    u = f
    h0 = 0.5 * t**2 * u**2 * (1.0 - u) ** 3
    h1 = 0.5 * t**2 * u**3 * (1.0 - u) ** 2
    out: np.ndarray = (a0 - a_cubic_0) * h0 + (a1 - a_cubic_1) * h1
    return out


def _h_v(vec: np.ndarray) -> tuple[float, float]:
    return float(math.hypot(float(vec[0]), float(vec[1]))), abs(float(vec[2]))


@dataclass(frozen=True)
class InterpolationParts:
    """`interpolation_bound`'s four parts [m], each (horizontal, vertical), and the two accelerations behind them.

    ``seen``: what the samples show (the quintic correction, or the bend allowance); ``transition``: the
    change of acceleration between the ends, placed anywhere inside the span; ``unexplained``: the
    velocity change the end accelerations do not explain, at its worst placed inside the span (one impulse at
    the instant); ``unseen``: the allowance A for what leaves no trace at either end."""

    seen: tuple[float, float]
    unexplained: tuple[float, float]
    unseen: tuple[float, float]
    unexplained_m_s2: tuple[float, float]  # the unexplained mean acceleration itself
    transition: tuple[float, float] = (0.0, 0.0)
    accel_change_m_s2: tuple[float, float] = (0.0, 0.0)  # |a1 - a0| itself

    def total(self) -> tuple[float, float]:
        return (
            self.seen[0] + self.transition[0] + self.unexplained[0] + self.unseen[0],
            self.seen[1] + self.transition[1] + self.unexplained[1] + self.unseen[1],
        )


def interpolation_parts(
    span_s: float,
    f: float,
    correction_enu_m: np.ndarray | None,
    dv_enu_m_s: np.ndarray,
    allowance: MotionAllowance,
    unexplained_accel_m_s2: np.ndarray | None = None,
    accel_change_m_s2: np.ndarray | None = None,
) -> InterpolationParts:
    """The parts of the 95 % bound on the cubic Hermite's error at fraction f of a span (`interpolation_bound`).

    ``accel_change_m_s2``: a1 - a0, the end accelerations' difference. The quintic correction has it change
    smoothly across the span; a bank rolled in at some instant inside it departs from that by at most
    |a1 - a0| all along, hence |a1 - a0| T^2 u (1 - u) / 4 more (the bound of the unseen part, with that A)."""
    shape = f * (1.0 - f)
    unseen = span_s**2 * shape / 4.0
    if correction_enu_m is not None:
        seen_h, seen_v = _h_v(correction_enu_m)
    else:
        dv_h, dv_v = _h_v(dv_enu_m_s)
        seen_h, seen_v = dv_h * span_s * shape / 2.0, dv_v * span_s * shape / 2.0
    da_h, da_v = _h_v(accel_change_m_s2) if accel_change_m_s2 is not None else (0.0, 0.0)
    m_h, m_v = _h_v(unexplained_accel_m_s2) if unexplained_accel_m_s2 is not None else (0.0, 0.0)
    # The unexplained velocity change m T as one impulse at the instant is the worst placing: with the ends'
    # positions and velocities matched, 2 m T^2 u (1 - u) / 4 (a smooth manoeuvre of mean m peaks near 2 m).
    return InterpolationParts(
        (seen_h, seen_v),
        (2.0 * m_h * unseen, 2.0 * m_v * unseen),
        (allowance.unseen_accel_h_m_s2 * unseen, allowance.unseen_accel_v_m_s2 * unseen),
        (m_h, m_v),
        (da_h * unseen, da_v * unseen),
        (da_h, da_v),
    )


def interpolation_bound(
    span_s: float,
    f: float,
    correction_enu_m: np.ndarray | None,
    dv_enu_m_s: np.ndarray,
    allowance: MotionAllowance,
    unexplained_accel_m_s2: np.ndarray | None = None,
) -> tuple[float, float]:
    """95 % bound [m] (horizontal, vertical) on the cubic Hermite's error at fraction f of a span.

    With matched positions and velocities at both ends, a path whose acceleration departs from the cubic's by
    at most A stays within A T^2 u (1 - u) / 4 of it (the bang-bang worst case is A T^2 / 16 at the centre,
    A t^2 / 2 near an end; u (1 - u) / 4 covers both). What the samples show is added as it is: the quintic
    correction when the end accelerations are known, else the old bend allowance |v1 - v0| T / 8 times the
    shape 4 u (1 - u).

    A is the allowance plus ``unexplained_accel_m_s2``: the part of the gap's mean acceleration (v1 - v0) / T
    that the end accelerations do not explain, twice over (a braking or a bank that began and ended inside the
    gap: its profile is unknown; a smooth one peaks near twice its mean)."""
    return interpolation_parts(span_s, f, correction_enu_m, dv_enu_m_s, allowance, unexplained_accel_m_s2).total()


def extrapolation_bound(
    dt_s: float, accel_enu_m_s2: np.ndarray | None, allowance: MotionAllowance, max_accel_m_s2: float
) -> tuple[float, float]:
    """95 % bound [m] (horizontal, vertical) on holding a sample's velocity for dt_s beyond it.

    The vehicle's acceleration at the sample (from the sample before it) is carried as it is, plus the unseen
    change: (|a| + A) dt^2 / 2. Without a known acceleration, ``max_accel_m_s2`` stands in for |a|."""
    dt = abs(dt_s)
    if accel_enu_m_s2 is None:
        a_h, a_v = max_accel_m_s2, max_accel_m_s2
    else:
        a_h, a_v = _h_v(accel_enu_m_s2)
    return (
        (a_h + allowance.unseen_accel_h_m_s2) * dt**2 / 2.0,
        (a_v + allowance.unseen_accel_v_m_s2) * dt**2 / 2.0,
    )
