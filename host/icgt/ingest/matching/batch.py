"""The banded alignment DP of `align` for many segments at once: one numpy step per DP row, all segments abreast.

Why: with 1 s EXIF times at 5 fps every image's window admits about five exposures and the windows chain
over a whole pass, so a card is a few dozen segments of hundreds of rows each, a few columns wide. Row by
row in Python that is ~20 us per row and alignment (4-5 solves per camera-offset candidate, 3 candidates)
dominated `icgt match`. The rows of one segment depend on each other, but different segments do not: row t
of every segment is one vectorised step here, so a solve costs (longest segment) numpy steps instead of
(images) Python iterations.

Same values, by construction. Each step does what `align._forward` / the backward pass of
`align.solve_segment` do to a row, in the row's local coordinates (column A_r + k at index k, A_r the band's
start), with two rewrites:
- the row's columns right of B_r (forward) or left of A_{r+1} (backward), which `align` fills with the
  band edge's value plus frame skips, start at infinity here: the in-row scan that follows derives exactly
  those values from the edge (its value plus the same skips), so every cell is the minimum over the same
  set of path costs;
- the in-row scan `row[k] = min(row[k], row[k-1] + skip[k-1])` is a cumulative minimum of `row - pf`
  (pf the skip prefix sums), added back: the same minimum over the same path costs, summed in another
  order.
Both are exact only when every sum is exact: the costs are whole numbers (SKIP_COST, LIKELY_SKIP_COST:
10 and 2), so every DP value is an integer far below 2**53 and float addition is exact in any order.
`exact_costs` checks that and callers use the row-by-row DP otherwise. The decisions per image are then
`align.solve_segment`'s on the same numbers (tests/ingest/test_ingest_match_properties.py compares both
on random cards).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from icgt.ingest.matching.decide import decide
from icgt.ingest.matching.results import AMBIGUITY_MARGIN
from icgt.ingest.matching.state import Card, Frames, Outcome

MAX_WIDTH = 64
"""Segments with a band wider than this many columns stay with the row-by-row DP (the stacked tables
are as wide as the widest band: a long run of images without EXIF time would make them all wide)."""

_F = np.ndarray[Any, np.dtype[np.float64]]
_I = np.ndarray[Any, np.dtype[np.int64]]
_B = np.ndarray[Any, np.dtype[np.bool_]]


def exact_costs(fr: Frames) -> bool:
    """Every skip cost a whole number: DP sums are exact in any order (see the module docstring)."""
    sk = np.asarray(fr.skip, dtype=np.float64)
    return bool(np.all(sk == np.round(sk))) and float(fr.image_skip) == round(fr.image_skip)


@dataclass
class Prepared:
    """One segment as `align._prepare` gives it: pair columns per image (local, ascending), bands."""

    lo: int  # first frame (local column 0)
    q: int  # number of frames
    pair: list[list[int]]
    band_a: list[int]
    band_b: list[int]


def width(seg: Prepared) -> int:
    return max(b - a + 1 for a, b in zip(seg.band_a, seg.band_b, strict=True))


@dataclass
class Solved:
    """Per segment its optimum; per image row (stacked, row r of segment s at `base[s] + r`) what
    `align.solve_segment` decides on: leaving the image out, pairing it with each column."""

    opt: list[float]
    base: list[int]
    with_skip: _F  # [row] best alignment not pairing the image
    vals: _F  # [row, k] best alignment pairing it with column A_r + k (inf: not a pair column)


class _Stack:
    """The segments' rows stacked: row r of segment s is stacked row base[s] + r (rows 0..p_s)."""

    def __init__(self, fr: Frames, segs: list[Prepared]) -> None:
        self.segs = segs
        self.p = np.array([len(s.pair) for s in segs], dtype=np.int64)
        self.base = np.concatenate([[0], np.cumsum(self.p + 1)[:-1]]).astype(np.int64)
        n_rows = int((self.p + 1).sum())
        self.a = np.fromiter((x for s in segs for x in s.band_a), dtype=np.int64, count=n_rows)
        b = np.fromiter((x for s in segs for x in s.band_b), dtype=np.int64, count=n_rows)
        self.w = int((b - self.a).max()) + 1
        ks = np.arange(self.w, dtype=np.int64)
        self.ks = ks
        self.valid: _B = ks[None, :] <= (b - self.a)[:, None]
        # skip prefix sums of each stacked cell's column, relative to its segment's first frame (cells past
        # the segment's end get its last value: finite, so that inf - pf stays inf)
        seg_of_row = np.repeat(np.arange(len(segs)), self.p + 1)
        lo = np.array([s.lo for s in segs], dtype=np.int64)[seg_of_row]
        q = np.array([s.q for s in segs], dtype=np.int64)[seg_of_row]
        col = np.minimum(self.a[:, None] + ks[None, :], q[:, None])
        sp = fr.skip_prefix
        self.pf: _F = sp[lo[:, None] + col] - sp[lo][:, None]
        self.q_local = q - self.a  # column q in each row's local index (used on the last rows)
        # pair cells: image r with column bb, stacked at row base + r; in row r's own index (backward) and
        # in row r + 1's index shifted by one (forward: pairing moves from column bb to bb + 1)
        counts = [len(c) for s in segs for c in s.pair]
        rows = np.repeat(
            np.concatenate([self.base[i] + np.arange(len(s.pair)) for i, s in enumerate(segs)]).astype(np.int64),
            counts,
        )
        cols = np.fromiter((c for s in segs for cs in s.pair for c in cs), dtype=np.int64, count=sum(counts))
        self.pm_back: _B = np.zeros((n_rows, self.w + 1), dtype=bool)
        self.pm_back[rows, cols - self.a[rows]] = True
        self.pm_fwd: _B = np.zeros((n_rows, self.w + 1), dtype=bool)
        self.pm_fwd[rows, cols + 1 - self.a[rows + 1]] = True
        # segments longest first: those still active at step t are a prefix
        self.order = np.argsort(-self.p, kind="stable")
        self.p_sorted = self.p[self.order]
        self.n_rows = n_rows

    def active(self, t: int) -> _I:
        n = int(np.searchsorted(-self.p_sorted, -t, side="left"))  # segments with p > t
        return self.order[:n]

    def shifted(self, rows_vals: _F, offset: _I) -> _F:
        """rows_vals[i, k + offset[i]] for k in 0..w-1, inf where that index is outside 0..w-1."""
        idx = self.ks[None, :] + offset[:, None]
        idx = np.where((idx < 0) | (idx >= self.w), self.w, idx)
        return np.take_along_axis(rows_vals, idx, axis=1)


def _forward(st: _Stack, si: float) -> _F:
    """f on the stack (width w + 1, the last column always inf)."""
    inf = np.inf
    f: _F = np.full((st.n_rows, st.w + 1), inf)
    b0 = st.base
    f[b0, : st.w] = np.where(st.valid[b0], st.pf[b0], inf)
    for t in range(int(st.p.max(initial=0))):
        g = st.base[st.active(t)] + t
        gn = g + 1
        d = st.a[gn] - st.a[g]
        prev = f[g]
        new = np.minimum(st.shifted(prev, d) + si, np.where(st.pm_fwd[g, : st.w], st.shifted(prev, d - 1), inf))
        v, pf = st.valid[gn], st.pf[gn]
        new = np.where(v, new, inf)
        new = pf + np.minimum.accumulate(new - pf, axis=1)
        f[gn, : st.w] = np.where(v, new, inf)
    return f


def costs(fr: Frames, segs: list[Prepared]) -> list[float]:
    """Each segment's optimal cost (what `align._forward` then `align._f_at` give)."""
    if not segs:
        return []
    st = _Stack(fr, segs)
    f = _forward(st, fr.image_skip)
    last = st.base + st.p
    return [float(v) for v in f[last, st.q_local[last]]]


def solve(fr: Frames, segs: list[Prepared]) -> Solved:
    """Forward and backward passes over all segments, and per image row the costs its decision needs."""
    st = _Stack(fr, segs)
    si = fr.image_skip
    inf = np.inf
    f = _forward(st, si)
    g_tab: _F = np.full((st.n_rows, st.w + 1), inf)
    last = st.base + st.p
    total = st.pf[last, np.minimum(st.q_local[last], st.w - 1)]
    # row p: total - pf over the band (the band of the last row ends at q: inside the stack's width)
    g_tab[last, : st.w] = np.where(st.valid[last], total[:, None] - st.pf[last], inf)
    with_skip: _F = np.full(st.n_rows, inf)
    vals: _F = np.full((st.n_rows, st.w), inf)
    for t in range(int(st.p.max(initial=0)) - 1, -1, -1):
        g = st.base[st.active(t)] + t
        gn = g + 1
        d = st.a[gn] - st.a[g]
        nxt = g_tab[gn]
        # for row r's column A_r + k the next row's index is k - d
        new = np.minimum(st.shifted(nxt, -d) + si, np.where(st.pm_back[g, : st.w], st.shifted(nxt, 1 - d), inf))
        v, pf = st.valid[g], st.pf[g]
        new = np.where(v, new, inf)
        new = np.minimum.accumulate((new + pf)[:, ::-1], axis=1)[:, ::-1] - pf
        g_tab[g, : st.w] = np.where(v, new, inf)
        # the image of row r left out: f[r] + g[r + 1] over the columns both rows hold; paired with
        # column A_r + k: f[r][k] + g[r + 1] at that column + 1
        fr_row = f[g]
        with_skip[g] = (st.shifted(fr_row, d) + nxt[:, : st.w]).min(axis=1) + si
        vals[g] = np.where(st.pm_back[g, : st.w], fr_row[:, : st.w] + st.shifted(nxt, 1 - d), inf)
    opt = [float(x) for x in f[last, st.q_local[last]]]
    return Solved(opt, st.base.tolist(), with_skip, vals)


def outcomes(card: Card, fr: Frames, segs: list[Prepared], imgs: list[list[int]]) -> list[Outcome]:
    """Each segment's Outcome, as `align.solve_segment` records it (`imgs[s]`: segment s's images)."""
    if not segs:
        return []
    solved = solve(fr, segs)
    seg_of_row = np.repeat(np.arange(len(segs)), [len(s.pair) + 1 for s in segs])
    opt_row = np.array(solved.opt)[seg_of_row]
    limit_row = opt_row + AMBIGUITY_MARGIN
    near = solved.vals <= limit_row[:, None]
    first = np.argmax(near, axis=1)
    # solve_segment's shortcut: leaving the image out is beyond the margin and exactly one pairing is
    # within it, the optimum's; then the image is paired without `decide`'s bookkeeping
    fast = (
        (solved.with_skip > limit_row)
        & (near.sum(axis=1) == 1)
        & (np.abs(solved.vals[np.arange(len(first)), first] - opt_row) < 1e-9)
    ).tolist()
    first_l = first.tolist()
    out: list[Outcome] = []
    for s, seg in enumerate(segs):
        part = Outcome(solved.opt[s], {}, {}, {}, set())
        opt, limit, lo = solved.opt[s], solved.opt[s] + AMBIGUITY_MARGIN, seg.lo
        for r, i in enumerate(imgs[s]):
            g = solved.base[s] + r
            ar = seg.band_a[r]
            if fast[g]:
                part.pairs[i] = ar + first_l[g] + lo
                continue
            row = solved.vals[g].tolist()
            with_pair = {bb + lo: row[bb - ar] for bb in seg.pair[r]}
            mine = next((j for j, v in with_pair.items() if abs(v - opt) < 1e-9), None)
            decide(card, i, with_pair, float(solved.with_skip[g]), mine, limit, part)
        out.append(part)
    return out
