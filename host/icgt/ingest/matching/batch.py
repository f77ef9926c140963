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
from icgt.ingest.matching.state import Card, Frames, Outcome, Ranges

Seg = tuple[list[int], int, int]

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
class Many:
    """Segments for the stacked DP, as arrays. Segment s has p[s] images, frames lo[s] .. lo[s] + q[s] - 1
    (local columns 0..q[s]-1) and DP rows 0..p[s], row r of segment s at `base[s] + r` (segment-major)."""

    lo: _I
    q: _I
    p: _I
    base: _I
    imgs: list[list[int]]  # per segment its images (card order)
    band_a: _I  # [segment-major row] A_r (`align._bands`)
    band_b: _I  # B_r
    cell_row: _I  # pair cells: segment-major row (image r of its segment) ...
    cell_col: _I  # ... and local column, ascending within a row
    cell_start: _I  # [segment-major row] its first cell (rows in order; p rows of a segment then its last)


def many(fr: Frames, has: list[bool], flat: tuple[_I, _I], ranges: Ranges, segs: list[Seg]) -> Many:
    """The pair columns and bands of `segs` (each (images, first frame, last frame)), all at once: what
    `align._pair_sets` and `align._bands` give per segment, vectorised over the card."""
    cflat, cstart = flat
    n_seg = len(segs)
    p = np.array([len(s[0]) for s in segs], dtype=np.int64)
    lo = np.array([s[1] for s in segs], dtype=np.int64)
    q = np.array([s[2] - s[1] + 1 for s in segs], dtype=np.int64)
    base = np.concatenate([[0], np.cumsum(p + 1)[:-1]]).astype(np.int64)
    n_rows = int((p + 1).sum())
    imgs = [s[0] for s in segs]
    img = np.fromiter((i for s in segs for i in s[0]), dtype=np.int64, count=int(p.sum()))
    seg_of_img = np.repeat(np.arange(n_seg), p)
    row_of_img = base[seg_of_img] + np.arange(len(img)) - (np.cumsum(p) - p)[seg_of_img]
    # timed images: their window's frames inside the segment (`align._pair_sets`)
    cnt = cstart[img + 1] - cstart[img]
    rep = np.repeat(np.arange(len(img)), cnt)
    within = np.arange(int(cnt.sum()), dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)
    j = cflat[np.repeat(cstart[img], cnt) + within]
    seg_lo, seg_hi = lo[seg_of_img][rep], (lo + q - 1)[seg_of_img][rep]
    ok = (j >= seg_lo) & (j <= seg_hi)
    cell_img, cell_frame = rep[ok], j[ok]
    # images without a time: every eligible frame of their range inside the segment (few)
    untimed = [k for k, i in enumerate(img.tolist()) if not has[i]]
    if untimed:
        extra_img, extra_frame = [cell_img], [cell_frame]
        for k in untimed:
            s = int(seg_of_img[k])
            r = ranges[int(img[k])]
            s_lo, s_hi = int(lo[s]), int(lo[s] + q[s] - 1)
            r0, r1 = (max(s_lo, r[0]), min(s_hi, r[1])) if r is not None else (s_lo, s_hi)
            fj = np.flatnonzero(fr.eligible[r0 : r1 + 1]).astype(np.int64) + r0
            extra_img.append(np.full(len(fj), k, dtype=np.int64))
            extra_frame.append(fj)
        cell_img, cell_frame = np.concatenate(extra_img), np.concatenate(extra_frame)
        order = np.lexsort((cell_frame, cell_img))
        cell_img, cell_frame = cell_img[order], cell_frame[order]
    cell_row = row_of_img[cell_img]
    cell_col = cell_frame - lo[seg_of_img][cell_img]
    per_row = np.bincount(cell_row, minlength=n_rows)
    cell_start = np.concatenate([[0], np.cumsum(per_row)]).astype(np.int64)
    # bands (`align._bands`): least[r] the least column of image r (q if none), suffix minima within each
    # segment (suffix[p] = q); reach[r] one past the greatest column of images ..r (running maximum).
    # Segments are kept apart by adding s * big: a suffix minimum never reaches into an earlier segment
    # (later ones are larger), a running maximum never into a later one.
    seg_of_row = np.repeat(np.arange(n_seg), p + 1)
    q_row = q[seg_of_row]
    has_cells = per_row > 0
    least = q_row.copy()
    least[has_cells] = cell_col[cell_start[:-1][has_cells]]
    most1 = np.zeros(n_rows, dtype=np.int64)
    most1[has_cells] = cell_col[cell_start[1:][has_cells] - 1] + 1
    big = int(q.max(initial=0)) + 2
    off = seg_of_row * big
    suffix = np.minimum.accumulate((least + off)[::-1])[::-1] - off
    reach = np.maximum.accumulate(most1 + off) - off
    first_row = np.zeros(n_rows, dtype=bool)
    first_row[base] = True
    band_a = np.where(first_row, suffix, np.concatenate([[0], suffix[:-1]]))
    last_row = base + p
    nxt_a = np.concatenate([band_a[1:], [0]])
    band_b = np.minimum(q_row, np.maximum(np.maximum(reach, nxt_a), band_a))
    band_b[last_row] = q
    return Many(lo, q, p, base, imgs, band_a, band_b, cell_row, cell_col, cell_start)


def fits(m: Many, max_cells: int) -> tuple[list[int], list[int]]:
    """(segments the stack takes, segments left to the row-by-row DP): those whose band cells exceed
    `max_cells` (`align.MAX_SEGMENT_CELLS`: it then leaves images out) or whose band is wider than
    MAX_WIDTH."""
    widths = m.band_b - m.band_a + 1
    cells = np.add.reduceat(widths, m.base)
    wide = np.maximum.reduceat(widths, m.base)
    ok = (cells <= max_cells) & (wide <= MAX_WIDTH)
    return np.flatnonzero(ok).tolist(), np.flatnonzero(~ok).tolist()


@dataclass
class Solved:
    """Per segment its optimum; per image row (stacked, see `_Stack`) what `align.solve_segment`
    decides on: leaving the image out, pairing it with each column."""

    opt: list[float]
    pos: _I  # [segment-major row] its stacked row
    with_skip: _F  # [row] best alignment not pairing the image
    vals: _F  # [row, k] best alignment pairing it with column A_r + k (inf: not a pair column)


class _Stack:
    """The segments' DP rows stacked level by level: row r of every segment with at least r rows is in
    level r, segments longest first, so that a level's rows, and the rows of the segments that go on to
    the next level, are contiguous slices (a DP step is then a few numpy operations on views).

    Tables (f, g) have one row per stacked row, w + 1 columns, and one last row that stays infinite:
    gathers that fall outside a band read it."""

    def __init__(self, fr: Frames, m: Many) -> None:
        n_seg = len(m.p)
        p = m.p
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
        seg_base = m.base
        seg_of = np.repeat(np.arange(n_seg), p + 1)
        r_of = np.arange(self.n_rows) - seg_base[seg_of]
        pos = self.start[r_of] + rank[seg_of]  # stacked position of each segment-major row
        self.pos = pos
        a_seg, b_seg = m.band_a, m.band_b
        self.w = w = int((b_seg - a_seg).max()) + 1
        ks = np.arange(w, dtype=np.int64)
        a = np.empty(self.n_rows, dtype=np.int64)
        a[pos] = a_seg
        band_w = np.empty(self.n_rows, dtype=np.int64)
        band_w[pos] = b_seg - a_seg
        inf = np.inf
        self.invalid: _F = np.where(ks[None, :] <= band_w[:, None], 0.0, inf)  # added: inf outside the band
        lo_seg, q_seg = m.lo, m.q
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
        rows = pos[m.cell_row]
        cols = m.cell_col
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


def costs(fr: Frames, m: Many) -> list[float]:
    """Each segment's optimal cost (what `align._forward` then `align._f_at` give)."""
    if len(m.p) == 0:
        return []
    st = _Stack(fr, m)
    f = _forward(st, fr.image_skip)
    return [float(v) for v in f[st.last, st.last_k]]


def solve(fr: Frames, m: Many) -> Solved:
    """Forward and backward passes over all segments, and per image row the costs its decision needs."""
    st = _Stack(fr, m)
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
    return Solved(opt, st.pos, with_skip, vals)


def outcomes(card: Card, fr: Frames, m: Many) -> list[Outcome]:
    """Each segment's Outcome, as `align.solve_segment` records it."""
    if len(m.p) == 0:
        return []
    solved = solve(fr, m)
    pos = solved.pos
    # per segment-major row (image r of segment s at base[s] + r): its optimum, what it decides on
    opt_sm = np.repeat(np.array(solved.opt), m.p + 1)
    vals = solved.vals[pos]
    with_skip = solved.with_skip[pos]
    limit_sm = opt_sm + AMBIGUITY_MARGIN
    near = vals <= limit_sm[:, None]
    first = np.argmax(near, axis=1)
    # solve_segment's shortcut: leaving the image out is beyond the margin and exactly one pairing is
    # within it, the optimum's; then the image is paired without `decide`'s bookkeeping
    fast = (
        (with_skip > limit_sm) & (near.sum(axis=1) == 1) & (np.abs(vals[np.arange(len(first)), first] - opt_sm) < 1e-9)
    ).tolist()
    pair_frame = (m.band_a + first + np.repeat(m.lo, m.p + 1)).tolist()
    base = m.base.tolist()
    cols_all = m.cell_col.tolist()
    cell_start = m.cell_start.tolist()
    band_a = m.band_a.tolist()
    out: list[Outcome] = []
    for s, imgs in enumerate(m.imgs):
        part = Outcome(solved.opt[s], {}, {}, {}, set())
        x0 = base[s]
        x1 = x0 + len(imgs)
        if all(fast[x0:x1]):  # the usual case: every image of the segment paired (in card order)
            part.pairs = dict(zip(imgs, pair_frame[x0:x1], strict=True))
            out.append(part)
            continue
        opt, limit, lo = solved.opt[s], solved.opt[s] + AMBIGUITY_MARGIN, int(m.lo[s])
        for x, i in zip(range(x0, x1), imgs, strict=True):
            if fast[x]:
                part.pairs[i] = pair_frame[x]
                continue
            ar = band_a[x]
            row = vals[x].tolist()
            with_pair = {bb + lo: row[bb - ar] for bb in cols_all[cell_start[x] : cell_start[x + 1]]}
            mine = next((j for j, v in with_pair.items() if abs(v - opt) < 1e-9), None)
            decide(card, i, with_pair, float(with_skip[x]), mine, limit, part)
        out.append(part)
    return out
