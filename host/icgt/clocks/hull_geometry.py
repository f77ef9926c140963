"""The geometry under the two-way clock fit (icgt.clocks.two_way): convex hulls of exchange points and exact searches.

Points are (x, u) in the fit's relative coordinates (x: remote clock since the reference [ns], u: host minus remote
[ns]). Requests give an upper hull (every consistent line passes above it), replies a lower hull (below it); the
fit's feasible slopes and its max-margin line follow from their edges. Pure functions, no state: the clock engine
owns the window and the fit.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from itertools import pairwise

__all__ = [
    "Hull",
    "bucket_slope",
    "concave_argmax",
    "edge_slopes",
    "level_crossing",
    "lower_hull",
    "support_slope",
    "upper_hull",
]


@dataclass(frozen=True, slots=True)
class Hull:
    """A convex hull's vertices (x, u) sorted by x, their x, and the slopes of the edges between them."""

    points: tuple[tuple[float, float], ...]
    xs: tuple[float, ...]
    slopes: tuple[float, ...]

    @classmethod
    def of(cls, points: tuple[tuple[float, float], ...]) -> Hull:
        return cls(points, tuple(p[0] for p in points), tuple(edge_slopes(points)))


def cross(o: tuple[float, float], a: tuple[float, float], b: tuple[float, float]) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def upper_hull(points: Sequence[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    """Upper convex hull (monotone chain) of points sorted by x."""
    hull: list[tuple[float, float]] = []
    for p in sorted(points):
        while len(hull) >= 2 and cross(hull[-2], hull[-1], p) >= 0.0:
            hull.pop()
        hull.append(p)
    return tuple(hull)


def lower_hull(points: Sequence[tuple[float, float]]) -> tuple[tuple[float, float], ...]:
    hull: list[tuple[float, float]] = []
    for p in sorted(points):
        while len(hull) >= 2 and cross(hull[-2], hull[-1], p) <= 0.0:
            hull.pop()
        hull.append(p)
    return tuple(hull)


def bucket_slope(
    pts_a: Sequence[tuple[float, float]],
    pts_b: Sequence[tuple[float, float]],
    a0: float,
    s0: float,
) -> tuple[float, float]:
    """Drift from the envelope points of each side in equal time buckets, weighted by how sharp each side is.

    The max-margin slope rests on two or three extreme points, so one unlucky point near the end of
    the window tilts it. Here each side (requests below the line, replies above) contributes the
    point closest to the line in each of several equal time buckets; a common slope with one
    intercept per side is fitted by least squares, each side weighted by the inverse variance of
    its own bucket minima (a path with a sharp floor, e.g. a request that goes out at once, then
    dominates one whose floor is blurred by the frame wait and the scheduler).
    Returns the slope and its standard error (inf when there are too few buckets).
    """
    xs_all = [p[0] for p in pts_a] + [p[0] for p in pts_b]
    x_lo, x_hi = min(xs_all), max(xs_all)
    n_buckets = max(4, min(12, len(pts_a) // 8))
    width = (x_hi - x_lo) / n_buckets
    if width <= 0.0:
        return s0, math.inf
    sides: list[list[tuple[float, float]]] = []
    for pts, sign in ((pts_a, 1.0), (pts_b, -1.0)):
        best: dict[int, tuple[float, float, float]] = {}
        count: dict[int, int] = {}
        for x, u in pts:
            b = min(n_buckets - 1, int((x - x_lo) / width))
            clearance = sign * (a0 + s0 * x - u)
            count[b] = count.get(b, 0) + 1
            if b not in best or clearance < best[b][0]:
                best[b] = (clearance, x, u)
        # A bucket of one or two exchanges (a burst of rejected ones) says little about the floor.
        sides.append([(x, u) for b, (_, x, u) in best.items() if count[b] >= 3])
    num = 0.0
    den = 0.0
    for side in sides:
        if len(side) < 4:
            return s0, math.inf
        mx = sum(x for x, _ in side) / len(side)
        mu = sum(u for _, u in side) / len(side)
        sxx = sum((x - mx) ** 2 for x, _ in side)
        sxy = sum((x - mx) * (u - mu) for x, u in side)
        if sxx <= 0.0:
            return s0, math.inf
        slope = sxy / sxx
        resid = sum((u - mu - slope * (x - mx)) ** 2 for x, u in side) / max(1, len(side) - 2)
        w = 1.0 / max(resid, 1e6)  # floor: (1 us)^2
        num += w * sxy
        den += w * sxx
    return num / den, math.sqrt(1.0 / den)


def edge_slopes(hull: Sequence[tuple[float, float]]) -> list[float]:
    """Slopes of the edges of a hull given as vertices sorted by x (a vertical edge: +-inf)."""
    return [
        (u1 - u0) / (x1 - x0) if x1 > x0 else math.copysign(math.inf, u1 - u0) for (x0, u0), (x1, u1) in pairwise(hull)
    ]


def concave_argmax(f: Callable[[float], float], knots: Sequence[float], lo: float, hi: float) -> float:
    """Exact argmax on [lo, hi] of a concave function that is linear between sorted ``knots``.

    The maximum of such a function is at a knot or an end of the interval, and along the sorted
    candidates the values rise, then fall: a binary search on the sign of the step finds it with
    O(log n) evaluations (a golden-section search needs ~80 for double precision). Where the top is
    flat (a plateau: the supporting points of both sides share one x, as with TIMESYNC's single
    remote stamp), the middle of the plateau is returned, so the choice does not lean to one end.
    """
    if hi <= lo:
        return lo
    cand = [lo, *(k for k in knots if lo < k < hi), hi]
    vals: dict[int, float] = {}

    def val(i: int) -> float:
        v = vals.get(i)
        if v is None:
            v = vals[i] = f(cand[i])
        return v

    a, b = 0, len(cand) - 1  # first index whose next step does not rise, in [a, b]
    while a < b:
        m = (a + b) // 2
        if val(m + 1) > val(m):
            a = m + 1
        else:
            b = m
    top = val(a)
    last = a  # a plateau: equal values to the right of the first maximiser
    while last + 1 < len(cand) and val(last + 1) >= top:
        last += 1
    return cand[a] if last == a else 0.5 * (cand[a] + cand[last])


def level_crossing(
    f: Callable[[float], float], knots: Sequence[float], inside: float, outside: float, level: float
) -> float:
    """The point between ``inside`` (f >= level) and ``outside`` (f < level) where the piecewise-linear
    concave ``f`` (linear between ``knots``) falls to ``level``: exact, by a binary search over the
    knots in between and one linear interpolation (a bisection needs ~70 evaluations)."""
    lo, hi = min(inside, outside), max(inside, outside)
    pts = [inside, *sorted((k for k in knots if lo < k < hi), reverse=outside < inside), outside]
    a, b = 0, len(pts) - 1  # f(pts[a]) >= level > f(pts[b])
    fa, fb = f(pts[a]), f(pts[b])
    while b - a > 1:
        m = (a + b) // 2
        fm = f(pts[m])
        if fm >= level:
            a, fa = m, fm
        else:
            b, fb = m, fm
    if fa == fb:
        return pts[a]
    t = (fa - level) / (fa - fb)
    step = t * (pts[b] - pts[a])
    for shrink in (1.0, 1.0 - 2.0**-40, 1.0 - 2.0**-30, 1.0 - 2.0**-20, 1.0 - 2.0**-10):
        x = pts[a] + shrink * step
        if f(x) >= level:  # rounding may put the interpolated point a hair past the edge: step back
            return x
    return pts[a]


def support_slope(hull: Hull, x: float, before: float, after: float) -> float:
    """Slope of the hull edge over ``x`` (``before``/``after`` left of the first or right of the last vertex)."""
    i = bisect_right(hull.xs, x)
    if i == 0:
        return before
    if i >= len(hull.xs):
        return after
    return hull.slopes[i - 1]
