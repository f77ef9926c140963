"""The cubic Hermite between two position samples, its motion bound, and the allowance learned from the flight.

`hermite` places a frame between two samples from their positions and velocities; `motion_interpolated` is
the 95 % bound on what that cubic misses (`icgt.geotag.bounds.interpolation_bound`, with the end
accelerations turned into the quintic correction). The part no sample shows, an acceleration change that
begins and ends inside the gap, is ``A T^2 u (1 - u) / 4``; `learn_unseen_accel` measures A on the flight
itself: it leaves out the samples inside spans as long as the gap, elsewhere in the same flight, places
them by the same rule and asks which A the bound needed to cover each of them (a leave-out cross-validation
of the interpolation, as used to size kriging and resampling errors). A vehicle flying smoothly earns a
small A; gusts, or an autopilot that weaves, a large one. docs/error-bounds.md gives the model.

Pure functions of numbers: no telemetry, no clocks. Positions ENU [m], velocities [m/s], times [s].
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from icgt.geotag.bounds import InterpolationParts, MotionAllowance, interpolation_parts, quintic_correction

__all__ = [
    "ACCEL_WINDOW_S",
    "LearnedScale",
    "end_accel",
    "hermite",
    "hermite_velocity",
    "learn_motion_scale",
    "motion_interpolated",
    "scaled_motion",
    "turned_with_velocity",
]


def hermite(p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, span_s: float, f: float) -> np.ndarray:
    """The cubic through (p0, v0) and (p1, v1) at fraction f of a span of span_s."""
    f2, f3 = f * f, f * f * f
    out: np.ndarray = (
        (2 * f3 - 3 * f2 + 1) * p0 + (f3 - 2 * f2 + f) * span_s * v0 + (-2 * f3 + 3 * f2) * p1 + (f3 - f2) * span_s * v1
    )
    return out


def hermite_velocity(
    p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, span_s: float, f: float
) -> np.ndarray:
    """The derivative of `hermite` [m/s]."""
    f2 = f * f
    out: np.ndarray = (
        (6 * f2 - 6 * f) * p0 / span_s
        + (3 * f2 - 4 * f + 1) * v0
        + (-6 * f2 + 6 * f) * p1 / span_s
        + (3 * f2 - 2 * f) * v1
    )
    return out


def motion_interpolated(
    p0: np.ndarray,
    v0: np.ndarray,
    a0: np.ndarray | None,
    p1: np.ndarray,
    v1: np.ndarray,
    a1: np.ndarray | None,
    span_s: float,
    f: float,
    allowance: MotionAllowance,
) -> InterpolationParts:
    """The parts of the 95 % bound [m] on `hermite`'s error at fraction f; a0 / a1: the accelerations at the
    ends from their outer neighbours (None: unknown)."""
    correction = None
    change = None
    mean = (v1 - v0) / span_s
    unexplained = mean
    if a0 is not None or a1 is not None:
        # One end's acceleration unknown: the gap's mean acceleration stands in for it (a linear change)
        a0e = a0 if a0 is not None else 2.0 * mean - (a1 if a1 is not None else mean)
        a1e = a1 if a1 is not None else 2.0 * mean - a0e
        correction = quintic_correction(p0, v0, a0e, p1, v1, a1e, span_s, f)
        change = a1e - turned_with_velocity(a0e, v0, v1)
        # what the known ends do not explain (one end known: as if the other were like it)
        known = [a for a in (a0, a1) if a is not None]
        unexplained = mean - sum(known) / len(known)
    return interpolation_parts(span_s, f, correction, v1 - v0, allowance, unexplained, change)


# Below this horizontal speed [m/s] the heading is noise, and nothing is turned (a hover's drift).
_MIN_TURN_SPEED_M_S = 2.0


def turned_with_velocity(a: np.ndarray, v0: np.ndarray, v1: np.ndarray) -> np.ndarray:
    """The acceleration ``a`` (at the start of a span) turned by the angle the horizontal velocity turns through
    from v0 to v1; the vertical part as it is.

    In a steady coordinated turn the acceleration (centripetal, towards the turn's centre) turns with the
    velocity, so at the far end of the span it is ``a`` turned, not ``a``: comparing the end accelerations as
    vectors would read a steady turn as a bank rolled in somewhere inside the span (|a1 - a0| = 2 |a|
    sin(dpsi / 2), 0.68 |a| for 40 deg). A bank rolled in or out inside the span still differs from this by
    the whole acceleration it changes."""
    s0, s1 = float(np.hypot(v0[0], v0[1])), float(np.hypot(v1[0], v1[1]))
    if min(s0, s1) < _MIN_TURN_SPEED_M_S:
        return a
    dpsi = float(np.arctan2(v0[0] * v1[1] - v0[1] * v1[0], v0[0] * v1[0] + v0[1] * v1[1]))
    c, s = np.cos(dpsi), np.sin(dpsi)
    out: np.ndarray = np.array([c * a[0] - s * a[1], s * a[0] + c * a[1], a[2]], dtype=float)
    return out


@dataclass(frozen=True)
class LearnedScale:
    """What the flight's own spans needed, each (horizontal, vertical): ``scale`` on the transition, unexplained
    and unseen parts of the bound; ``ordinary_m_s2`` the unexplained acceleration and ``ordinary_change_m_s2``
    the change of acceleration between the ends they showed (95 % of spans at or below)."""

    scale: tuple[float, float]
    ordinary_m_s2: tuple[float, float]
    spans: int
    ordinary_change_m_s2: tuple[float, float] = (0.0, 0.0)


# Leave-out spans are drawn at most this many per gap (evenly over the window), interior samples between
# these fractions of the span (near an end the bound's shape u (1 - u) vanishes and the source noise alone
# would decide the ratio).
_MAX_SPANS = 48
_U_RANGE = (0.2, 0.8)
ACCEL_WINDOW_S = 1.0  # an end acceleration from a neighbour at most this far away


def learn_motion_scale(
    t_s: np.ndarray,
    p_enu_m: np.ndarray,
    v_enu_m_s: np.ndarray,
    span_s: float,
    allowance: MotionAllowance,
    source_h_m: float,
    source_v_m: float,
    *,
    quantile: float = 0.95,
    min_spans: int = 8,
) -> LearnedScale | None:
    """How much of the bound's unexplained and unseen parts covered ``quantile`` of this flight's left-out samples.

    ``t_s`` sorted, with ``p_enu_m`` / ``v_enu_m_s`` (n, 3) the samples around a gap (not inside it). A span
    is the first sample at or after ``t_s[i] + span_s`` from a start i; it must hold no spacing wider than
    twice the median (it would cross this gap, or another one). Each interior sample needed the factor
    ``(|error| - source - seen) / (transition + unexplained + unseen)``: the source's own 95 % part and what the samples
    show given (the left-out sample's own noise stays in the error: the factor errs on the safe side).
    None: fewer than ``min_spans`` spans (the caller keeps the bound as the model gives it)."""
    n = len(t_s)
    if n < 4:
        return None
    dt = np.diff(t_s)
    step = float(np.median(dt))
    wide_before = np.concatenate([[0], np.cumsum(dt > 2.0 * step)])  # wide spacings before each sample
    ends = np.searchsorted(t_s, t_s + span_s, side="left")
    starts = [
        i
        for i in range(1, n - 1)
        if ends[i] < n - 1 and ends[i] - i >= 2 and wide_before[ends[i]] == wide_before[i]
        and t_s[ends[i]] - t_s[i] <= span_s + 2.0 * step
    ]  # fmt: skip
    if len(starts) < min_spans:
        return None
    if len(starts) > _MAX_SPANS:
        starts = [starts[k] for k in np.linspace(0, len(starts) - 1, _MAX_SPANS).round().astype(int)]
    need: tuple[list[float], list[float]] = ([], [])
    ordinary: tuple[list[float], list[float]] = ([], [])
    change: tuple[list[float], list[float]] = ([], [])
    for i in starts:
        j = int(ends[i])
        span = float(t_s[j] - t_s[i])
        a0 = _end_accel(t_s, v_enu_m_s, i - 1, i)
        a1 = _end_accel(t_s, v_enu_m_s, j, j + 1)
        for k in range(i + 1, j):
            f = float((t_s[k] - t_s[i]) / span)
            if not _U_RANGE[0] <= f <= _U_RANGE[1]:
                continue
            err = p_enu_m[k] - hermite(p_enu_m[i], v_enu_m_s[i], p_enu_m[j], v_enu_m_s[j], span, f)
            parts = motion_interpolated(p_enu_m[i], v_enu_m_s[i], a0, p_enu_m[j], v_enu_m_s[j], a1, span, f, allowance)
            errs = (float(np.hypot(err[0], err[1])), abs(float(err[2])))
            for ax, src in enumerate((source_h_m, source_v_m)):
                scaled = parts.transition[ax] + parts.unexplained[ax] + parts.unseen[ax]
                need[ax].append(max(0.0, errs[ax] - src - parts.seen[ax]) / max(scaled, 1e-9))
        for ax in (0, 1):
            ordinary[ax].append(parts.unexplained_m_s2[ax])
            change[ax].append(parts.accel_change_m_s2[ax])
    if not need[0]:
        return None
    q = (float(np.quantile(need[0], quantile)), float(np.quantile(need[1], quantile)))
    o = (float(np.quantile(ordinary[0], quantile)), float(np.quantile(ordinary[1], quantile)))
    c = (float(np.quantile(change[0], quantile)), float(np.quantile(change[1], quantile)))
    return LearnedScale(q, o, len(starts), c)


def scaled_motion(
    parts: InterpolationParts, learned: LearnedScale | None, margin: float, floor: float
) -> tuple[float, float]:
    """The motion bound [m] (horizontal, vertical) with what the flight taught: the unseen part, and as much of
    the unexplained and transition parts as the flight's spans showed as ordinary, are scaled by the learned
    factor (times ``margin``, at least ``floor``); beyond the ordinary they keep their worst case (a manoeuvre
    inside the gap, unlike anything the flight did around it). None: the parts as they are."""
    if learned is None:
        return parts.total()
    out = []
    for ax in (0, 1):
        k = max(floor, margin * learned.scale[ax])
        unexplained = _ordinary_scaled(parts.unexplained[ax], parts.unexplained_m_s2[ax], learned.ordinary_m_s2[ax], k)
        transition = _ordinary_scaled(
            parts.transition[ax], parts.accel_change_m_s2[ax], learned.ordinary_change_m_s2[ax], k
        )
        out.append(parts.seen[ax] + transition + unexplained + k * parts.unseen[ax])
    return out[0], out[1]


def _ordinary_scaled(part_m: float, size: float, ordinary: float, k: float) -> float:
    """``part_m`` with the fraction of ``size`` up to ``ordinary`` scaled by k, the rest kept at its worst case."""
    share = 1.0 if size <= ordinary else ordinary / size
    return part_m * (k * share + (1.0 - share))


def end_accel(v_a: np.ndarray, v_b: np.ndarray, dt_s: float) -> np.ndarray | None:
    """The acceleration [m/s^2] from velocity v_a to v_b, dt_s later; None if dt_s is not in (0, ACCEL_WINDOW_S]."""
    if dt_s <= 0 or dt_s > ACCEL_WINDOW_S:
        return None
    out: np.ndarray = (v_b - v_a) / dt_s
    return out


def _end_accel(t_s: np.ndarray, v: np.ndarray, a: int, b: int) -> np.ndarray | None:
    if a < 0 or b >= len(t_s):
        return None
    return end_accel(v[a], v[b], float(t_s[b] - t_s[a]))
