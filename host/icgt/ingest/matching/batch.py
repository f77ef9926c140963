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
    """Per segment its optimum; per image row (stacked, see `_Stack`) what
    `align.solve_segment` decides on: leaving the image out, pairing it with each column."""

    opt: list[float]
    rows: list[_I]  # per segment the stacked row of each of its DP rows 0..p
    with_skip: _F  # [row] best alignment not pairing the image
    vals: _F  # [row, k] best alignment pairing it with column A_r + k (inf: not a pair column)


class _Stack:
    """The segments' DP rows stacked level by level: row r of every segment with at least r rows is in
    level r, segments longest first, so that a level's rows, and the rows of the segments that go on to
    the next level, are contiguous slices (a DP step is then a few numpy operations on views).

    Tables (f, g) have one row per stacked row, w + 1 columns, and one last row that stays infinite:
    gathers that fall outside a band read it."""

    def __init__(self, fr: Frames, segs: list[Prepared]) -> None:
        n_seg = len(segs)
        p = np.array([len(s.pair) for s in segs], dtype=np.int64)
        self.p = p
        order = np.argsort(-p, kind="stable")
        rank = np.empty(n_seg, dtype=np.int64)
        rank[order] = np.arange(n_seg)
        p_max = int(p.max(initial=0))
        # level r holds the segments with p >= r: the first n_level[r] in `order`
        n_level = np.array([int(np.count_nonzero(p >= r)) for r in range(p_max + 1)], dtype=np.int64)
        self.start = np.concatenate([[0], np.cumsum(n_level)]).astype(np.int64)
        self.n_level = n_level
        self.n_rows = int(self.start[-1])
        # segment-major arrays first (row r of segment s at seg_base[s] + r), then placed by level
        seg_base = np.concatenate([[0], np.cumsum(p + 1)[:-1]]).astype(np.int64)
        seg_of = np.repeat(np.arange(n_seg), p + 1)
        r_of = np.arange(self.n_rows) - seg_base[seg_of]
        pos = self.start[r_of] + rank[seg_of]  # stacked position of each segment-major row
        self.pos_of_seg = [pos[seg_base[s] : seg_base[s] + p[s] + 1] for s in range(n_seg)]
        a_seg = np.fromiter((x for s in segs for x in s.band_a), dtype=np.int64, count=self.n_rows)
        b_seg = np.fromiter((x for s in segs for x in s.band_b), dtype=np.int64, count=self.n_rows)
        self.w = w = int((b_seg - a_seg).max()) + 1
        ks = np.arange(w, dtype=np.int64)
        a = np.empty(self.n_rows, dtype=np.int64)
        a[pos] = a_seg
        band_w = np.empty(self.n_rows, dtype=np.int64)
        band_w[pos] = b_seg - a_seg
        inf = np.inf
        self.invalid: _F = np.where(ks[None, :] <= band_w[:, None], 0.0, inf)  # added: inf outside the band
        lo_seg = np.array([s.lo for s in segs], dtype=np.int64)
        q_seg = np.array([s.q for s in segs], dtype=np.int64)
        lo, q = np.empty(self.n_rows, dtype=np.int64), np.empty(self.n_rows, dtype=np.int64)
        lo[pos], q[pos] = lo_seg[seg_of], q_seg[seg_of]
        # skip prefix sums of each cell's column relative to its segment's first frame (cells past the
        # segment's end get its last value: finite, so inf - pf stays inf)
        col = np.minimum(a[:, None] + ks[None, :], q[:, None])
        sp = fr.skip_prefix
        self.pf: _F = sp[lo[:, None] + col] - sp[lo][:, None]
        self.last = pos[seg_base + p]  # each segment's last row (p images placed)
        self.last_k = (q - a)[self.last]  # column q there (inside the band: B_p = q)
        # Gathers between a row (level r) and the same segment's next row (level r + 1, same rank: the
        # next row of stacked row x < start[r] + n_level[r + 1] is x + n_level[r]), as flat indices
        # into a table: d = A_{r+1} - A_r.
        pad = self.n_rows * (w + 1)  # the infinite last row
        nxt = np.full(self.n_rows, -1, dtype=np.int64)
        for r in range(p_max):
            x = np.arange(self.start[r], self.start[r] + n_level[r + 1])
            nxt[x] = x + n_level[r]
        has_next = nxt >= 0
        d = np.zeros(self.n_rows, dtype=np.int64)
        d[has_next] = a[nxt[has_next]] - a[has_next]

        def flat(rows: _I, shift: _I) -> _I:
            idx = ks[None, :] + shift[:, None]
            ok = (idx >= 0) & (idx < w)
            return np.where(ok, rows[:, None] * (w + 1) + idx, pad)

        prev = np.full(self.n_rows, -1, dtype=np.int64)
        prev[nxt[has_next]] = np.flatnonzero(has_next)
        has_prev = prev >= 0
        d_in = np.zeros(self.n_rows, dtype=np.int64)
        d_in[has_prev] = d[prev[has_prev]]
        prev_rows = np.where(has_prev, prev, self.n_rows)
        # forward, indexed by the new row: the previous row at the new row's column + 0 and - 1
        self.f_same = flat(prev_rows, d_in)
        self.f_diag = flat(prev_rows, d_in - 1)
        # backward, indexed by the row: the next row at the row's column + 0 and + 1
        next_rows = np.where(has_next, nxt, self.n_rows)
        self.g_same = flat(next_rows, -d)
        self.g_diag = flat(next_rows, 1 - d)
        # pair cells: image r with local column bb, in row r's own index (backward, decisions) and in the
        # next row's index shifted by one (forward: pairing moves from column bb to bb + 1)
        counts = [len(c) for s in segs for c in s.pair]
        rows_seg = np.repeat(
            np.concatenate([seg_base[i] + np.arange(len(s.pair)) for i, s in enumerate(segs)]).astype(np.int64),
            counts,
        )
        rows = pos[rows_seg]
        cols = np.fromiter((c for s in segs for cs in s.pair for c in cs), dtype=np.int64, count=sum(counts))
        self.pm_back: _F = np.full((self.n_rows, w), inf)
        self.pm_back[rows, cols - a[rows]] = 0.0
        self.pm_fwd: _F = np.full((self.n_rows, w), inf)
        self.pm_fwd[nxt[rows], cols + 1 - a[nxt[rows]]] = 0.0

    def level(self, r: int, n: int | None = None) -> slice:
        """Level r's rows (its first n: the segments that go on to level r + 1)."""
        s0 = int(self.start[r])
        return slice(s0, s0 + int(self.n_level[r] if n is None else n))

    def table(self) -> _F:
        return np.full((self.n_rows + 1, self.w + 1), np.inf)


def _forward(st: _Stack, si: float) -> _F:
    """f on the stack: f[x, k] the best cost of the row's images placed with its segment's columns up to
    A_r + k (what `align._forward` computes, see the module docstring)."""
    f = st.table()
    ff = f.reshape(-1)
    w = st.w
    top = st.level(0)
    f[top, :w] = st.pf[top] + st.invalid[top]
    for r in range(len(st.n_level) - 1):
        new_rows = st.level(r + 1)
        same, diag = ff[st.f_same[new_rows]], ff[st.f_diag[new_rows]]
        new = np.minimum(same + si, diag + st.pm_fwd[new_rows]) + st.invalid[new_rows]
        pf = st.pf[new_rows]
        f[new_rows, :w] = np.minimum.accumulate(new - pf, axis=1) + pf + st.invalid[new_rows]
    return f


def costs(fr: Frames, segs: list[Prepared]) -> list[float]:
    """Each segment's optimal cost (what `align._forward` then `align._f_at` give)."""
    if not segs:
        return []
    st = _Stack(fr, segs)
    f = _forward(st, fr.image_skip)
    return [float(v) for v in f[st.last, st.last_k]]


def solve(fr: Frames, segs: list[Prepared]) -> Solved:
    """Forward and backward passes over all segments, and per image row the costs its decision needs."""
    st = _Stack(fr, segs)
    si = fr.image_skip
    w = st.w
    f = _forward(st, si)
    ff = f.reshape(-1)
    g = st.table()
    gf = g.reshape(-1)
    total = st.pf[st.last, st.last_k]
    g[st.last, :w] = total[:, None] - st.pf[st.last] + st.invalid[st.last]
    with_skip: _F = np.full(st.n_rows, np.inf)
    vals: _F = np.full((st.n_rows, w), np.inf)
    for r in range(len(st.n_level) - 2, -1, -1):
        rows = st.level(r, int(st.n_level[r + 1]))
        same, diag = gf[st.g_same[rows]], gf[st.g_diag[rows]]
        new = np.minimum(same + si, diag + st.pm_back[rows]) + st.invalid[rows]
        pf = st.pf[rows]
        g[rows, :w] = np.minimum.accumulate((new + pf)[:, ::-1], axis=1)[:, ::-1] - pf + st.invalid[rows]
        # the row's image left out: f[r] + g[r + 1] at every column both hold (f read in the next row's
        # index, as the forward pass does); paired with column A_r + k: f[r][k] + g[r + 1] one column on
        nxt_rows = st.level(r + 1)
        with_skip[rows] = (ff[st.f_same[nxt_rows]] + g[nxt_rows, :w]).min(axis=1) + si
        vals[rows] = f[rows, :w] + diag + st.pm_back[rows]
    opt = [float(x) for x in f[st.last, st.last_k]]
    return Solved(opt, st.pos_of_seg, with_skip, vals)


def outcomes(card: Card, fr: Frames, segs: list[Prepared], imgs: list[list[int]]) -> list[Outcome]:
    """Each segment's Outcome, as `align.solve_segment` records it (`imgs[s]`: segment s's images)."""
    if not segs:
        return []
    solved = solve(fr, segs)
    opt_row = np.zeros(len(solved.with_skip))
    for s, rows in enumerate(solved.rows):
        opt_row[rows] = solved.opt[s]
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
        rows_s = solved.rows[s].tolist()
        for r, i in enumerate(imgs[s]):
            g = int(rows_s[r])
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
