"""The two-way engine's exact searches (slope of the widest band, feasible slopes, worst-case bound)
against brute force on dense grids: they replaced golden-section and bisection searches and must find
the same optima."""

from __future__ import annotations

import random

import numpy as np
import pytest

from icgt.clocks.hull_geometry import concave_argmax, level_crossing
from icgt.clocks.two_way import _TwoWayLine


def _random_concave(
    rng: random.Random,
) -> tuple[list[tuple[float, float]], list[float]]:
    """A min of random lines (concave, piecewise linear) and its breakpoints (all pairwise crossings:
    a superset of the real ones is fine, a subset would not be)."""
    lines = [(rng.uniform(-5, 5), rng.uniform(-3, 3)) for _ in range(rng.randint(1, 8))]
    knots = sorted((b2 - b1) / (a1 - a2) for i, (a1, b1) in enumerate(lines) for a2, b2 in lines[i + 1 :] if a1 != a2)
    return lines, knots


@pytest.mark.parametrize("seed", range(100))
def test_concave_argmax_matches_a_dense_grid(seed: int) -> None:
    rng = random.Random(seed)
    lines, knots = _random_concave(rng)

    def f(s: float) -> float:
        return min(a * s + b for a, b in lines)

    lo, hi = sorted((rng.uniform(-4, 4), rng.uniform(-4, 4)))
    best = concave_argmax(f, knots, lo, hi)
    assert lo <= best <= hi
    grid = np.linspace(lo, hi, 20001)
    assert f(best) >= max(f(float(s)) for s in grid) - 1e-9


@pytest.mark.parametrize("seed", range(100))
def test_level_crossing_is_the_edge_of_the_interval(seed: int) -> None:
    rng = random.Random(seed)
    lines, knots = _random_concave(rng)

    def f(s: float) -> float:
        return min(a * s + b for a, b in lines)

    inside = concave_argmax(f, knots, -10.0, 10.0)
    level = f(inside) - rng.uniform(0.1, 5.0)
    for outside in (-10.0, 10.0):
        if f(outside) >= level:
            continue
        edge = level_crossing(f, knots, inside, outside, level)
        assert f(edge) >= level  # still inside
        assert f(edge) == pytest.approx(level, abs=1e-9)  # and at the edge, not short of it
        beyond = edge + (1e-6 if outside > inside else -1e-6)
        assert f(beyond) < level


def _line_with_exchanges(seed: int, remote_single_stamp: bool) -> tuple[_TwoWayLine, list[float]]:
    rng = random.Random(seed)
    line = _TwoWayLine(
        resolution_us=1.0,
        window_s=120.0,
        max_samples=512,
        min_span_s=2.0,
        max_drift_ppm=1000.0,
        rtt_limit_ns=10_000_000,
        rtt_limit_inclusive=False,
        wander_ppm=0.5,
        prior_drift_uncertainty_ppm=5.0,
        path_asymmetry_ns=0.0,
        jump_margin_ns=2_000_000,
    )
    drift = rng.uniform(-80e-6, 80e-6)
    t = 1_000_000_000
    remote_times = []
    for _ in range(rng.randint(3, 120)):
        t += int(rng.uniform(0.05e9, 0.3e9))
        out_ns = rng.uniform(50_000, 900_000)
        turn_ns = 0.0 if remote_single_stamp else rng.uniform(0, 1_000_000)
        back_ns = rng.uniform(50_000, 900_000)
        rx_us = (t + out_ns) * (1 + drift) / 1000.0 + 12345.0
        tx_us = rx_us + turn_ns * (1 + drift) / 1000.0
        line.add(t, int(rx_us), int(tx_us), int(t + out_ns + turn_ns + back_ns))
        remote_times.append(rx_us)
        t += int(out_ns + turn_ns + back_ns)
    return line, remote_times


@pytest.mark.parametrize("seed", range(30))
@pytest.mark.parametrize("single", [False, True])
def test_bound_is_the_extreme_consistent_line(seed: int, single: bool) -> None:
    """bound_ns at any remote time (inside the window, before and after it) equals the largest distance to a
    consistent line of a considered slope, found here by scanning the slopes densely."""
    line, remote = _line_with_exchanges(seed, single)
    fit = line.fit()
    assert fit is not None and fit.n > 0
    slopes = np.linspace(fit.b_lo, fit.b_hi, 4001)
    half_res_ns = 500.0
    for remote_us in (
        remote[0] - 5e5,
        remote[0],
        remote[len(remote) // 2],
        remote[-1],
        remote[-1] + 3e6,
    ):
        x = (remote_us - fit.ref_x) * 1000.0
        est = fit.a + fit.s * x
        top = np.min([u + slopes * (x - xb) for xb, u in fit.hull_b.points], axis=0)
        bottom = np.max([u + slopes * (x - xa) for xa, u in fit.hull_a.points], axis=0)
        spread = max(float(top.max()) - est, est - float(bottom.min()), 0.0)
        outside = max(x - fit.x_max, fit.x_min - x, 0.0)
        expected = spread + 2 * half_res_ns + 0.5e-6 * outside
        got = line.bound_ns(fit, remote_us)
        assert got >= expected - 1e-6 * max(1.0, expected)  # never smaller than what the grid finds
        assert got <= expected + 1e-3 * max(1.0, expected)  # and no wider than the grid's resolution explains
