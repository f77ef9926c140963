"""The vehicle's position at one instant of the autopilot's clock, from the telemetry real autopilots send.

Rules, in order (each frame says which one placed it, and a bound on the position error):

1. **GPS between two samples.** When usable GLOBAL_POSITION_INT samples bracket the instant and are at
   most ``max_gps_gap_s`` apart (real autopilots stream them at 2-4 Hz when nobody sets the rate, 50 Hz
   when asked), the position is the cubic Hermite interpolation of the two positions with their own
   velocities. Bound: ``|v_after - v_before| * T / 8`` (how far the path can bend away from a straight
   line in T seconds with that change of velocity; the cubic removes most of it, so this is an upper
   estimate) plus ``max_accel_m_s2 * T**2 / 32`` for what the end velocities do not show.
2. **Local position in a gap, or when GPS is absent** (VIO, optical flow, an EKF that lost GPS): the
   latest usable GPS sample before the instant is the anchor; the local position (LOCAL_POSITION_NED,
   interpolated in time both at the anchor's and at the instant's stamp, never "the sample at or
   before") moves it. Never across a local-origin reset (`LocalPositionSample.epoch`). Bound: the
   local frame's drift allowance ``local_drift_m_per_s`` times the time since the anchor.
3. **Dead reckoning.** Only an earlier GPS sample and no local position: its position moved by its own
   velocity, flagged extrapolated. Bound: ``max_accel_m_s2 * dt**2 / 2``.
4. Nothing usable: no position (the frame says no_fix).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icgt.geodesy import LocalFrame
from icgt.mavlink.telemetry import FusedPositionSample, GpsSample, LocalPositionSample, TelemetryStore

__all__ = ["PositionEstimate", "PositionRules", "estimate_position"]

_ANCHOR_HISTORY_US = 600_000_000  # a GPS-denied stretch may be placed from a fix up to 10 min old


@dataclass(frozen=True)
class PositionRules:
    max_gps_gap_s: float = 1.5
    max_accel_m_s2: float = 3.0
    local_drift_m_per_s: float = 0.05


@dataclass(frozen=True)
class PositionEstimate:
    enu: np.ndarray  # autopilot reference point, local ENU [m]
    rule: str  # "gps", "local", "dead_reckoning"
    gps: GpsSample | None  # the GPS_RAW_INT sample at or before the instant
    gap_before_ms: float
    gap_after_ms: float  # inf when nothing after the instant was used
    bound_m: float
    extrapolated: bool


def _usable(s: FusedPositionSample | None) -> bool:
    return s is not None and s.usable and s.lat_deg is not None


def _velocity_enu(s: FusedPositionSample) -> np.ndarray:
    return np.array([s.ve_mps, s.vn_mps, -s.vd_mps])


def _local_enu(s: LocalPositionSample) -> np.ndarray:
    return np.array([s.y_m, s.x_m, -s.z_m])  # local NED -> ENU axes


def _hermite(p0: np.ndarray, v0: np.ndarray, p1: np.ndarray, v1: np.ndarray, span_s: float, f: float) -> np.ndarray:
    f2, f3 = f * f, f * f * f
    return (
        (2 * f3 - 3 * f2 + 1) * p0 + (f3 - 2 * f2 + f) * span_s * v0 + (-2 * f3 + 3 * f2) * p1 + (f3 - f2) * span_s * v1
    )


def _local_at(tm: TelemetryStore, t_us: float) -> tuple[np.ndarray, int, float, bool] | None:
    """Local ENU at t (interpolated), its epoch, the gap to the sample after [ms] and whether it was extrapolated."""
    lb, la = tm.local_position.bracket(int(t_us))
    if lb is None and la is None:
        return None
    if lb is not None and la is not None and la.epoch == lb.epoch and la.boot_us > lb.boot_us:
        f = (t_us - lb.boot_us) / (la.boot_us - lb.boot_us)
        a = _local_enu(lb)
        return a + (_local_enu(la) - a) * f, lb.epoch, (la.boot_us - t_us) / 1000.0, False
    s = lb if lb is not None else la
    assert s is not None
    if lb is not None and la is not None and la.boot_us == lb.boot_us:
        return _local_enu(s), s.epoch, 0.0, False
    v = np.array([s.vy_mps, s.vx_mps, -s.vz_mps])
    return _local_enu(s) + v * ((t_us - s.boot_us) / 1e6), s.epoch, math.inf, True


def estimate_position(
    tm: TelemetryStore, frame: LocalFrame, t_us: float, rules: PositionRules
) -> PositionEstimate | None:
    """The autopilot's position at boot time ``t_us`` by the rules of the module docstring (None: no fix)."""
    t = int(t_us)
    before, after = tm.fused.bracket(t)
    gps, _ = tm.gps.bracket(t)

    def enu(s: FusedPositionSample) -> np.ndarray:
        assert s.lat_deg is not None and s.lon_deg is not None and s.alt_msl_m is not None
        return np.asarray(frame.geodetic_to_enu(s.lat_deg, s.lon_deg, s.alt_msl_m), dtype=float)

    max_gap_us = rules.max_gps_gap_s * 1e6
    if _usable(before) and _usable(after):
        assert before is not None and after is not None
        span_us = after.boot_us - before.boot_us
        if span_us <= max_gap_us:
            gap_b, gap_a = (t_us - before.boot_us) / 1000.0, (after.boot_us - t_us) / 1000.0
            if span_us <= 0:
                return PositionEstimate(enu(before), "gps", gps, 0.0, 0.0, 0.0, False)
            span_s = span_us / 1e6
            v0, v1 = _velocity_enu(before), _velocity_enu(after)
            p = _hermite(enu(before), v0, enu(after), v1, span_s, (t_us - before.boot_us) / span_us)
            bound = float(np.linalg.norm(v1 - v0)) * span_s / 8.0 + rules.max_accel_m_s2 * span_s**2 / 32.0
            return PositionEstimate(p, "gps", gps, gap_b, gap_a, bound, False)
    anchor = before if _usable(before) else None
    if anchor is None:
        history = [s for s in tm.fused.between(t - _ANCHOR_HISTORY_US, t) if _usable(s)]
        anchor = history[-1] if history else None
    if anchor is None:
        return None
    gap_b = (t_us - anchor.boot_us) / 1000.0
    here = _local_at(tm, t_us)
    there = _local_at(tm, anchor.boot_us)
    if here is not None and there is not None and here[1] == there[1] and not there[3]:
        p = enu(anchor) + (here[0] - there[0])
        bound = rules.local_drift_m_per_s * gap_b / 1000.0
        lb, _ = tm.local_position.bracket(t)
        local_gap_b = (t_us - lb.boot_us) / 1000.0 if lb is not None else gap_b
        return PositionEstimate(p, "local", gps, local_gap_b, here[2], bound, here[3])
    dt_s = gap_b / 1000.0
    p = enu(anchor) + _velocity_enu(anchor) * dt_s
    return PositionEstimate(p, "dead_reckoning", gps, gap_b, math.inf, rules.max_accel_m_s2 * dt_s**2 / 2.0, True)
