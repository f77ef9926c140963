"""The vehicle's position at one instant of the autopilot's clock, from the telemetry real autopilots send.

Each estimate carries a 95 % bound, horizontal and vertical, split into the source's own accuracy and the
motion the samples do not show (`icgt.geotag.bounds`, docs/error-bounds.md). The candidates, of which the
one with the smallest bound places the frame (each frame says which rule and source):

1. **GPS between two samples.** Usable GLOBAL_POSITION_INT samples bracket the instant and are at most
   ``max_interpolation_gap_s`` apart (real autopilots stream them at 2-4 Hz when nobody sets the rate, and
   radios drop seconds of them): the cubic Hermite interpolation of the two positions with their own
   velocities. Its motion bound grows with the gap (`bounds.interpolation_bound`): what the accelerations at
   both ends say the cubic misses, plus an unseen acceleration change inside the gap.
2. **Local position** (GPS denied, or a gap in GLOBAL_POSITION_INT only): the latest usable GPS sample
   before the instant is the anchor; LOCAL_POSITION_NED, interpolated both at the anchor's and at the
   instant's stamp, moves it. Never across a local-origin reset (`LocalPositionSample.epoch`), never from a
   local position that is itself extrapolated at the anchor. Bound: the anchor's source accuracy, the local
   frame's drift ``local_drift_m_per_s`` times the time since the anchor, and the local samples' own
   interpolation (or extrapolation) bound.
3. **Dead reckoning.** Only an earlier GPS sample: its position moved by its own velocity, flagged
   extrapolated. Bound: (|a| + A) dt^2 / 2 with the acceleration seen at the sample.
4. Nothing usable: no position (`None`, the frame says no_fix). An extrapolation whose motion bound would
   exceed ``max_extrapolation_m`` is not made (`PoseGap`, the frame says no_pose with the gap): beyond that
   horizon a guess is not a position. Once the later sample is there (a later poll, a recompute with
   look-ahead), rule 1 places the frame across the gap.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from icgt.geodesy import LocalFrame
from icgt.geotag.bounds import (
    MotionAllowance,
    SourceAccuracy,
    extrapolation_bound,
    interpolation_bound,
    source_accuracy,
)
from icgt.geotag.motion import (
    LearnedScale,
    end_accel,
    hermite,
    hermite_velocity,
    learn_motion_scale,
    motion_interpolated,
    scaled_motion,
)
from icgt.mavlink.telemetry import FusedPositionSample, GpsSample, LocalPositionSample, TelemetryStore

__all__ = ["PoseGap", "PositionEstimate", "PositionRules", "estimate_position"]

_ANCHOR_HISTORY_US = 600_000_000  # a GPS-denied stretch may be placed from a fix up to 10 min old


@dataclass(frozen=True)
class PositionRules:
    max_gps_gap_s: float = 1.5  # the recorder holds a frame this long for the next GPS sample (geotagger)
    max_accel_m_s2: float = 3.0  # stands in for the acceleration when no neighbouring sample shows it
    local_drift_m_per_s: float = 0.05
    max_interpolation_gap_s: float = 10.0
    max_extrapolation_m: float = 1.0
    allowance: MotionAllowance = field(default_factory=MotionAllowance)
    # Across a span longer than learn_min_span_s, the motion bound is scaled by what the flight's own spans
    # within learn_window_s of the gap needed (`motion.learn_motion_scale`), times learn_margin (few spans
    # estimate a 95 % quantile), never below learned_scale_floor; learn_window_s 0: the model as it is.
    learn_window_s: float = 30.0
    learn_min_span_s: float = 0.5
    learn_margin: float = 1.25
    # The floor keeps an allowance for what leaves no trace at either end of a gap (an out-and-back inside it):
    # 0.02 x the 2 m/s^2 allowance. It was 0.1 until stop 46, and decided the bound of every long gap in a calm
    # flight (4-10 x the true error in benchmarks/bound_coverage.py), while the flight's own spans needed 0.01-0.03.
    learned_scale_floor: float = 0.02


@dataclass(frozen=True)
class PositionEstimate:
    enu: np.ndarray  # autopilot reference point, local ENU [m]
    rule: str  # "gps", "local", "dead_reckoning"
    gps: GpsSample | None  # the GPS_RAW_INT sample at or before the instant
    gap_before_ms: float
    gap_after_ms: float  # inf when nothing after the instant was used
    source: SourceAccuracy  # the source's own 95 % error
    motion_h_m: float  # 95 % bound on what the samples do not show, horizontal [m]
    motion_v_m: float
    extrapolated: bool
    velocity_enu_m_s: np.ndarray  # at the instant (for the timing part of the bound)

    @property
    def motion_m(self) -> float:
        return math.hypot(self.motion_h_m, self.motion_v_m)

    @property
    def horizontal_m(self) -> float:
        return self.source.horizontal_m + self.motion_h_m

    @property
    def vertical_m(self) -> float:
        return self.source.vertical_m + self.motion_v_m


@dataclass(frozen=True)
class PoseGap:
    """No position: the nearest samples are too far for the dynamics to bound (no_pose)."""

    gap_before_ms: float
    gap_after_ms: float
    gps: GpsSample | None


def _usable(s: FusedPositionSample | None) -> bool:
    return s is not None and s.usable and s.lat_deg is not None


def _velocity_enu(s: FusedPositionSample) -> np.ndarray:
    return np.array([s.ve_mps, s.vn_mps, -s.vd_mps])


def _local_enu(s: LocalPositionSample) -> np.ndarray:
    return np.array([s.y_m, s.x_m, -s.z_m])  # local NED -> ENU axes


def _local_velocity_enu(s: LocalPositionSample) -> np.ndarray:
    return np.array([s.vy_mps, s.vx_mps, -s.vz_mps])


def _accel(v_a: np.ndarray, t_a_us: int, v_b: np.ndarray, t_b_us: int) -> np.ndarray | None:
    return end_accel(v_a, v_b, (t_b_us - t_a_us) / 1e6)


def _fused_accel_at(tm: TelemetryStore, s: FusedPositionSample, *, outside: int) -> np.ndarray | None:
    """The acceleration at sample s from its neighbour on the ``outside`` (-1 earlier, +1 later) side."""
    if outside < 0:
        n, _ = tm.fused.bracket(s.boot_us - 1)
        if not _usable(n):
            return None
        assert n is not None
        return _accel(_velocity_enu(n), n.boot_us, _velocity_enu(s), s.boot_us)
    _, n = tm.fused.bracket(s.boot_us + 1)
    if not _usable(n):
        return None
    assert n is not None
    return _accel(_velocity_enu(s), s.boot_us, _velocity_enu(n), n.boot_us)


def _local_accel_at(tm: TelemetryStore, s: LocalPositionSample, *, outside: int) -> np.ndarray | None:
    """The acceleration at local sample s from its neighbour on the ``outside`` side (same origin epoch only).

    An extrapolation carries it: a 35 deg bank at 22 m/s is 6.9 m/s^2, twice the stand-in (``max_accel_m_s2``)
    used when no neighbour shows it; with the stand-in a live gap in a turn claimed 0.41 m for 0.49 m off."""
    n = tm.local_position.bracket(s.boot_us - 1)[0] if outside < 0 else tm.local_position.bracket(s.boot_us + 1)[1]
    if n is None or n.epoch != s.epoch:
        return None
    if outside < 0:
        return _accel(_local_velocity_enu(n), n.boot_us, _local_velocity_enu(s), s.boot_us)
    return _accel(_local_velocity_enu(s), s.boot_us, _local_velocity_enu(n), n.boot_us)


# The learned scale of a span, by (store, span ends, the window's samples): every frame in one gap asks.
_LEARNED: dict[tuple[int, int, int, int, int, int], LearnedScale | None] = {}
_LEARNED_KEPT = 64


def _motion_scale(
    tm: TelemetryStore,
    frame: LocalFrame,
    before: FusedPositionSample,
    after: FusedPositionSample,
    src: SourceAccuracy,
    rules: PositionRules,
) -> LearnedScale | None:
    """What the flight's spans like (before, after) needed (`motion.learn_motion_scale`), when the span is long
    enough to hide a manoeuvre and the window around it holds enough of them; else None (the model as it is)."""
    span_s = (after.boot_us - before.boot_us) / 1e6
    if rules.learn_window_s <= 0 or span_s <= rules.learn_min_span_s:
        return None
    # A flight with many gaps close together leaves few spans as long as this one near it: look farther
    for window_s in (rules.learn_window_s, 4.0 * rules.learn_window_s):
        learned = _learn_in(tm, frame, before, after, int(window_s * 1e6), span_s, src, rules)
        if learned is not None:
            return learned
    return None


def _learn_in(
    tm: TelemetryStore,
    frame: LocalFrame,
    before: FusedPositionSample,
    after: FusedPositionSample,
    w_us: int,
    span_s: float,
    src: SourceAccuracy,
    rules: PositionRules,
) -> LearnedScale | None:
    around = [
        s
        for s in tm.fused.between(before.boot_us - w_us, after.boot_us + w_us)
        if _usable(s) and not before.boot_us < s.boot_us < after.boot_us
    ]
    if len(around) < 4:
        return None
    key = (id(tm), before.boot_us, after.boot_us, around[0].boot_us, around[-1].boot_us, len(around))
    if key in _LEARNED:
        return _LEARNED[key]
    t_s = np.array([s.boot_us for s in around], dtype=float) / 1e6
    lat, lon, alt = (
        np.array([getattr(s, k) for s in around], dtype=float) for k in ("lat_deg", "lon_deg", "alt_msl_m")
    )
    p = np.asarray(frame.geodetic_to_enu(lat, lon, alt), dtype=float)
    v = np.array([_velocity_enu(s) for s in around], dtype=float)
    learned = learn_motion_scale(t_s, p, v, span_s, rules.allowance, src.horizontal_m, src.vertical_m)
    if len(_LEARNED) >= _LEARNED_KEPT:
        _LEARNED.pop(next(iter(_LEARNED)))
    _LEARNED[key] = learned
    return learned


@dataclass(frozen=True)
class _Local:
    enu: np.ndarray
    velocity: np.ndarray
    epoch: int
    gap_before_ms: float
    gap_after_ms: float
    motion_h_m: float
    motion_v_m: float
    extrapolated: bool


def _local_at(tm: TelemetryStore, t_us: float, rules: PositionRules) -> _Local | None:
    """Local ENU at t (interpolated, or extrapolated from the nearest sample), with its own motion bound."""
    lb, la = tm.local_position.bracket(int(t_us))
    if lb is None and la is None:
        return None
    if lb is not None and la is not None and la.boot_us == lb.boot_us:
        return _Local(_local_enu(lb), _local_velocity_enu(lb), lb.epoch, 0.0, 0.0, 0.0, 0.0, False)
    if lb is not None and la is not None and la.epoch == lb.epoch:
        span_s = (la.boot_us - lb.boot_us) / 1e6
        f = (t_us - lb.boot_us) / (la.boot_us - lb.boot_us)
        a, b = _local_enu(lb), _local_enu(la)
        va, vb = _local_velocity_enu(lb), _local_velocity_enu(la)
        # LOCAL_POSITION_NED is interpolated linearly (the log's replay depends on it); its bound is the
        # chord's: the Hermite's motion bound plus how far the chord is from the Hermite.
        h, v = interpolation_bound(span_s, f, None, vb - va, rules.allowance, (vb - va) / span_s)
        chord = a + (b - a) * f
        cubic = hermite(a, va, b, vb, span_s, f)
        d = cubic - chord
        return _Local(
            chord,
            va + (vb - va) * f,
            lb.epoch,
            (t_us - lb.boot_us) / 1000.0,
            (la.boot_us - t_us) / 1000.0,
            h + math.hypot(float(d[0]), float(d[1])),
            v + abs(float(d[2])),
            False,
        )
    s = lb if lb is not None else la
    assert s is not None
    dt_s = (t_us - s.boot_us) / 1e6
    h, v = extrapolation_bound(
        dt_s, _local_accel_at(tm, s, outside=-1 if s is lb else +1), rules.allowance, rules.max_accel_m_s2
    )
    return _Local(
        _local_enu(s) + _local_velocity_enu(s) * dt_s,
        _local_velocity_enu(s),
        s.epoch,
        max(0.0, dt_s * 1000.0),
        math.inf,
        h,
        v,
        True,
    )


def _source(gps: GpsSample | None) -> SourceAccuracy:
    if gps is None:
        return source_accuracy(3, None, None)
    return source_accuracy(gps.fix_type, gps.h_acc_m, gps.v_acc_m)


def estimate_position(
    tm: TelemetryStore, frame: LocalFrame, t_us: float, rules: PositionRules
) -> PositionEstimate | PoseGap | None:
    """The autopilot's position at boot time ``t_us`` by the rules of the module docstring.

    None: no usable position at all (no fix); `PoseGap`: the samples are too far apart to bound a position."""
    t = int(t_us)
    before, after = tm.fused.bracket(t)
    gps, _ = tm.gps.bracket(t)
    src = _source(gps)

    def enu(s: FusedPositionSample) -> np.ndarray:
        assert s.lat_deg is not None and s.lon_deg is not None and s.alt_msl_m is not None
        return np.asarray(frame.geodetic_to_enu(s.lat_deg, s.lon_deg, s.alt_msl_m), dtype=float)

    candidates: list[PositionEstimate] = []
    if _usable(before) and _usable(after):
        assert before is not None and after is not None
        span_us = after.boot_us - before.boot_us
        if span_us <= 0:
            return PositionEstimate(enu(before), "gps", gps, 0.0, 0.0, src, 0.0, 0.0, False, _velocity_enu(before))
        if span_us <= rules.max_interpolation_gap_s * 1e6:
            span_s = span_us / 1e6
            f = (t_us - before.boot_us) / span_us
            p0, p1 = enu(before), enu(after)
            v0, v1 = _velocity_enu(before), _velocity_enu(after)
            a0 = _fused_accel_at(tm, before, outside=-1)
            a1 = _fused_accel_at(tm, after, outside=+1)
            parts = motion_interpolated(p0, v0, a0, p1, v1, a1, span_s, f, rules.allowance)
            learned = _motion_scale(tm, frame, before, after, src, rules)
            h, v = scaled_motion(parts, learned, rules.learn_margin, rules.learned_scale_floor)
            candidates.append(
                PositionEstimate(
                    hermite(p0, v0, p1, v1, span_s, f),
                    "gps",
                    gps,
                    (t_us - before.boot_us) / 1000.0,
                    (after.boot_us - t_us) / 1000.0,
                    src,
                    h,
                    v,
                    False,
                    hermite_velocity(p0, v0, p1, v1, span_s, f),
                )
            )
            if span_us <= rules.max_gps_gap_s * 1e6:
                return candidates[0]  # a GPS stream at its rate: nothing else is closer to the truth
    anchor = before if _usable(before) else None
    if anchor is None:
        history = [s for s in tm.fused.between(t - _ANCHOR_HISTORY_US, t) if _usable(s)]
        anchor = history[-1] if history else None
    if anchor is None:
        return candidates[0] if candidates else None
    gap_b = (t_us - anchor.boot_us) / 1000.0
    anchor_src = _source(tm.gps.bracket(anchor.boot_us)[0])
    here = _local_at(tm, t_us, rules)
    there = _local_at(tm, anchor.boot_us, rules)
    if here is not None and there is not None and here.epoch == there.epoch and not there.extrapolated:
        drift = rules.local_drift_m_per_s * gap_b / 1000.0
        if not here.extrapolated or math.hypot(here.motion_h_m, here.motion_v_m) <= rules.max_extrapolation_m:
            candidates.append(
                PositionEstimate(
                    enu(anchor) + (here.enu - there.enu),
                    "local",
                    gps,
                    here.gap_before_ms,
                    here.gap_after_ms,
                    anchor_src,
                    drift + here.motion_h_m + there.motion_h_m,
                    drift + here.motion_v_m + there.motion_v_m,
                    here.extrapolated,
                    here.velocity,
                )
            )
    if any(c.rule == "gps" for c in candidates):
        # Interpolation knows more than a guess: an extrapolated local position never wins over it (its bound
        # is sized by an allowance, the interpolation's by samples on both sides)
        measured = [c for c in candidates if not c.extrapolated]
        return min(measured, key=lambda c: c.horizontal_m + c.vertical_m)
    dt_s = gap_b / 1000.0
    h, v = extrapolation_bound(dt_s, _fused_accel_at(tm, anchor, outside=-1), rules.allowance, rules.max_accel_m_s2)
    if math.hypot(h, v) <= rules.max_extrapolation_m:
        candidates.append(
            PositionEstimate(
                enu(anchor) + _velocity_enu(anchor) * dt_s,
                "dead_reckoning",
                gps,
                gap_b,
                math.inf,
                anchor_src,
                h,
                v,
                True,
                _velocity_enu(anchor),
            )
        )
    if not candidates:
        gap_a = (after.boot_us - t_us) / 1000.0 if after is not None else math.inf
        return PoseGap(gap_b, gap_a, gps)
    return min(candidates, key=lambda c: c.horizontal_m + c.vertical_m)
