"""The motion bound learned from the flight (issue 32): sharper where the flight is calm, worst case where the
gap hides more than the flight shows around it."""

from __future__ import annotations

import numpy as np

from icgt.geotag.bounds import InterpolationParts, MotionAllowance
from icgt.geotag.motion import LearnedScale, motion_interpolated, scaled_motion, turned_with_velocity
from icgt.sim.bound_check import Gap, TelemetryPlan, score_flight
from icgt.sim.survey import Leg, SurveyFlight, Turbulence


def _parts(m: float) -> InterpolationParts:
    return InterpolationParts((0.01, 0.01), (2.0 * m, 2.0 * m), (1.0, 0.5), (m, m))


def test_the_calm_part_is_scaled_and_a_manoeuvre_beyond_the_ordinary_keeps_its_worst_case() -> None:
    learned = LearnedScale(scale=(0.2, 0.2), ordinary_m_s2=(0.5, 0.5), spans=40)
    h, _ = scaled_motion(_parts(0.25), learned, 1.0, 0.1)
    assert abs(h - (0.01 + 0.2 * 0.5 + 0.2 * 1.0)) < 1e-12  # all ordinary: scaled
    h, _ = scaled_motion(_parts(2.0), learned, 1.0, 0.1)
    # a quarter of 2 m/s^2 is ordinary (scaled), three quarters a manoeuvre (its worst case, 3 m of 4)
    assert abs(h - (0.01 + 4.0 * (0.25 * 0.2 + 0.75) + 0.2 * 1.0)) < 1e-12
    assert scaled_motion(_parts(2.0), None, 1.0, 0.1) == _parts(2.0).total()
    h, _ = scaled_motion(_parts(0.25), LearnedScale((0.0, 0.0), (0.5, 0.5), 40), 1.25, 0.1)
    assert abs(h - (0.01 + 0.1 * 1.5)) < 1e-12  # never below the floor


def test_a_calm_straight_gap_gets_a_bound_near_its_error_and_still_covers_it() -> None:
    """A 3.5 s gap on a long straight in light turbulence: the model alone (A = 2 m/s^2) claims about 1.5 m at
    the centre for a few decimetres of error; learned from the flight, within 7 x the median error (5.5; 8.8 with
    the learned floor of 0.1 before stop 46)."""
    flight = SurveyFlight([Leg("straight", 70.0)], speed_m_s=22.0, turbulence=Turbulence(seed=5))
    gap = Gap(40.0, 3.5)
    plan = TelemetryPlan(position_white_fraction=1.0)
    frames = [f for f in score_flight(flight, [gap], mode="recompute", seed=1, plan=plan) if gap.holds(f.t_s)]
    assert len(frames) >= 15 and all(f.placed for f in frames)
    h_err = np.array([f.h_err_m for f in frames])
    h_bound = np.array([f.h_bound_m for f in frames])
    assert float(np.mean(h_err <= h_bound)) >= 0.9
    assert float(np.median(h_bound)) <= 7.0 * float(np.median(h_err)), (np.median(h_bound), np.median(h_err))


def test_a_live_gap_in_a_35_degree_turn_is_covered_by_every_extrapolation() -> None:
    """The CI failure of stop 43: 0.37 s into a gap in a 35 deg bank at 22 m/s (6.9 m/s^2), LOCAL_POSITION_NED
    extrapolated with a 3 m/s^2 stand-in for the acceleration claimed 0.41 m for 0.49 m of error. Every frame
    the live recorder places in the gap (the first few tenths of a second) is inside its bounds."""
    flight = SurveyFlight(
        [Leg("straight", 10.0), Leg("turn", turn_deg=360.0, bank_deg=35.0), Leg("straight", 10.0)],
        speed_m_s=22.0,
        turbulence=Turbulence(seed=3),
    )
    # 3.5 s: longer than the live recorder waits for the next sample; in the 20 s turn, at four phases of 4 Hz
    gaps = [Gap(t, 3.5) for t in (12.0, 16.57, 21.13, 25.7)]
    plan = TelemetryPlan(fused_hz=4.0)
    scores = score_flight(flight, gaps, mode="live", seed=2, plan=plan)
    frames = [f for f in scores if any(g.holds(f.t_s) for g in gaps)]
    placed = [f for f in frames if f.placed]
    assert len(placed) >= 6, len(placed)
    for f in placed:
        assert f.h_err_m <= f.h_bound_m and f.v_err_m <= f.v_bound_m, (f.t_s, f.h_err_m, f.h_bound_m, f.source)


def _circle(t: float, speed: float, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration on a steady horizontal turn (ENU) at time t."""
    w = speed / radius
    c, s = np.cos(w * t), np.sin(w * t)
    return (
        np.array([radius * s, radius * (1 - c), 0.0]),
        np.array([speed * c, speed * s, 0.0]),
        np.array([-speed * w * s, speed * w * c, 0.0]),
    )


def test_a_steady_turn_is_not_read_as_a_bank_rolled_in_inside_the_gap() -> None:
    """In a steady turn the acceleration turns with the velocity: across 2 s of a 30 deg bank at 22 m/s (40 deg of
    heading) the end accelerations differ by 0.7 |a| as vectors, which the bound read as a bank rolled in at
    some instant inside the gap. Turned with the velocity they agree; a bank rolled in inside the gap still
    shows its whole acceleration."""
    speed, radius, span = 22.0, 22.0**2 / (9.80665 * np.tan(np.radians(30.0))), 2.0
    p0, v0, a0 = _circle(0.0, speed, radius)
    p1, v1, a1 = _circle(span, speed, radius)
    allowance = MotionAllowance()
    steady = motion_interpolated(p0, v0, a0, p1, v1, a1, span, 0.5, allowance)
    assert steady.accel_change_m_s2[0] < 0.01 * float(np.linalg.norm(a0)), steady.accel_change_m_s2
    assert abs(float(np.linalg.norm(turned_with_velocity(a0, v0, v1) - a1))) < 1e-9
    rolled_in = motion_interpolated(p0, v0, np.zeros(3), p1, v1, a1, span, 0.5, allowance)
    assert abs(rolled_in.accel_change_m_s2[0] - float(np.linalg.norm(a1))) < 1e-9
    # below walking speed the heading is noise: nothing is turned
    slow = np.array([0.5, 0.0, 0.0]), np.array([0.0, 0.5, 0.0])
    assert np.array_equal(turned_with_velocity(a0, *slow), a0)


def test_gaps_in_a_steady_turn_get_a_bound_near_their_error_and_still_cover_it() -> None:
    """Four 2 s gaps in two full turns at 30 deg bank, light turbulence, recomputed: every frame covered, the
    median bound within 5 x the median error (9.9 x before the turn was understood and the learned floor
    lowered to what such flights need)."""
    flight = SurveyFlight(
        [Leg("straight", 10.0), Leg("turn", turn_deg=720.0, bank_deg=30.0), Leg("straight", 10.0)],
        speed_m_s=22.0,
        turbulence=Turbulence(seed=4),
    )
    gaps = [Gap(t, 2.0) for t in (16.0, 24.0, 32.0, 40.0)]
    frames = [f for f in score_flight(flight, gaps, mode="recompute", seed=3) if any(g.holds(f.t_s) for g in gaps)]
    assert len(frames) >= 36 and all(f.placed for f in frames)
    h_err = np.array([f.h_err_m for f in frames])
    h_bound = np.array([f.h_bound_m for f in frames])
    assert bool(np.all(h_err <= h_bound))
    assert float(np.median(h_bound)) <= 5.0 * float(np.median(h_err)), (np.median(h_bound), np.median(h_err))
