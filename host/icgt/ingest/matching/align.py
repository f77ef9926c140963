"""The alignment for one camera clock model: monotone pairing of images and exposures, banded DP.

Per image the exposures its padded EXIF window admits (`windows`); the card splits into independent
segments wherever no window overlaps the next (`solve`); each segment is aligned by dynamic
programming over the order of both sequences (`solve_segment`), forward and backward, so that for
every image the cost of the best alignment that does not pair it the way the optimum does is known.

Banded: row r of the DP (r images placed) is only kept on the columns [A_r, B_r] where it can differ
from a plain sum of frame skips: A_r is the least frame any image from r - 1 on may pair with (a suffix
minimum), B_r one past the greatest frame any image up to r may pair with (a running maximum), both
non-decreasing. Left of A_r nothing later can pair, right of B_r nothing earlier did, so the values
there follow from the band's edge plus the frames' skip costs (prefix sums), and every minimum the
ambiguity test takes lies inside the band. The result equals the full DP's; time and memory are the
sum of the band widths, a few exposures per image, instead of images x exposures per segment.

Stacked: the segments of one solve are independent, so `batch` runs the same banded DP for all of them
at once, one numpy step per row (what it computes is the same, see its docstring); `solve_segment` is
the row-by-row DP, used where stacking does not pay (a card of one long pass: nothing to run abreast)
or does not apply (costs that are not whole numbers, very wide bands), and the reference the stacked DP
is tested against. Windows and ranges are kept as arrays (`Flat`, `Ranges`): per-image Python tuples
are only built where a segment is cached or solved row by row.
"""

from __future__ import annotations

import bisect
import math
import operator
from typing import Any

import numpy as np

from icgt.ingest.matching import batch
from icgt.ingest.matching.decide import decide
from icgt.ingest.matching.results import (
    AMBIGUITY_MARGIN,
    IMAGE_NO_EXPOSURE,
    IMAGE_NO_TIME_UNPLACED,
)
from icgt.ingest.matching.state import Card, Frames, Model, Outcome, Ranges

MAX_SEGMENT_CELLS = 4_000_000
"""Band cells of one segment beyond which runs of images without EXIF time are left out of it."""
STACK_MIN_ABREAST = 4
"""The stacked DP is used when the segments' rows add up to at least this many times the longest's."""
_CACHE_MAX_IMAGES = 64  # segments up to this many images are remembered (offset scans repeat most of them)


Flat = tuple[np.ndarray[Any, np.dtype[np.int64]], np.ndarray[Any, np.dtype[np.int64]]]
"""The windows' frames as arrays: image i's are flat[0][flat[1][i] : flat[1][i + 1]] (none if untimed)."""


class Cands:
    """Per image, the frames its window admits (ascending tuples), made from `Flat` when asked for: most
    images are only ever seen through the arrays (the stacked DP), building 18 000 tuples per solve is not
    free."""

    def __init__(self, flat: Flat) -> None:
        self.jj = flat[0]
        self.counts = np.diff(flat[1])
        self.frames: list[int] = flat[0].tolist()
        self.start: list[int] = flat[1].tolist()

    def __getitem__(self, i: int) -> tuple[int, ...]:
        return tuple(self.frames[self.start[i] : self.start[i + 1]])


IntArray = np.ndarray[Any, np.dtype[np.int64]]


def windows(card: Card, fr: Frames, model: Model, widen: float) -> tuple[Cands, IntArray, IntArray, Flat]:
    """Per image: the frames its padded EXIF window admits (timed images), and the frame range it may use
    (first, last; -1 where none)."""
    n, m = len(card), len(fr.recs)
    p = np.asarray(model.predict(fr.x), dtype=np.float64)
    tol = fr.tol + widen
    tmax = float(tol.max()) if len(tol) else 0.0
    r0 = np.full(n, -1, dtype=np.int64)
    r1 = np.full(n, -1, dtype=np.int64)
    ti = card.timed
    per_image = np.zeros(n, dtype=np.int64)
    jj = np.zeros(0, dtype=np.int64)
    if len(ti) and m:
        lo_t, hi_t = card.c[ti], card.c[ti] + card.r[ti]
        a = np.searchsorted(p, lo_t - tmax, side="left")
        b = np.searchsorted(p, hi_t + tmax, side="right")
        cnt = np.maximum(b - a, 0)
        rep = np.repeat(np.arange(len(ti)), cnt)
        starts = np.cumsum(cnt) - cnt
        j = np.arange(int(cnt.sum()), dtype=np.int64) - np.repeat(starts, cnt) + np.repeat(a, cnt)
        pj = p[j]
        dist = np.maximum(np.maximum(lo_t[rep] - pj, pj - hi_t[rep]), 0.0)
        keep = fr.eligible[j] & (dist <= tol[j])  # inside the padded window: timing noise carries no evidence
        jj, rr = j[keep].astype(np.int64), rep[keep]
        counts = np.bincount(rr, minlength=len(ti))
        ends = np.cumsum(counts)
        nz = np.flatnonzero(counts)
        per_image[ti] = counts
        r0[ti[nz]] = jj[ends[nz] - counts[nz]]
        r1[ti[nz]] = jj[ends[nz] - 1]
    flat = (jj, np.concatenate([[0], np.cumsum(per_image)]).astype(np.int64))
    # Images without a time may take any exposure between their timed neighbours' windows.
    untimed = [i for i in range(n) if not card.has_time(i)] if len(ti) < n else []
    if untimed:
        placed = ti[r0[ti] >= 0].tolist()
        for i in untimed:
            k = bisect.bisect_left(placed, i)
            lo = int(r0[placed[k - 1]]) if k > 0 else 0
            hi = int(r1[placed[k]]) if k < len(placed) else m - 1
            has = m > 0 and lo <= hi and int(fr.eligible_prefix[hi + 1] - fr.eligible_prefix[lo]) > 0
            if has:
                r0[i], r1[i] = lo, hi
    return Cands(flat), r0, r1, flat


Segments = list[tuple[list[int], int, int]]


def segments(card: Card, fr: Frames, model: Model, widen: float) -> tuple[Cands, Ranges, Segments, Flat]:
    """Windows, ranges, the independent segments (images, first, last frame).

    A segment ends where every later image's range starts past every earlier one's end (`_segments`). The
    card's order is the camera's, and the alignment inside a segment keeps it. The last answer is
    remembered (a cost-only pass is often followed by the full solve of the same model); callers only
    read what is returned."""
    key = (model.offset, model.drift, widen)
    if fr.last_segments is not None and fr.last_segments[0] == key:
        known: tuple[Cands, Ranges, Segments, Flat] = fr.last_segments[1]
        return known
    found = _segments(card, fr, model, widen)
    fr.last_segments = (key, found)
    return found


def _segments(card: Card, fr: Frames, model: Model, widen: float) -> tuple[Cands, Ranges, Segments, Flat]:
    cands, r0_all, r1_all, flat = windows(card, fr, model, widen)
    segs: Segments = []
    with_range = np.flatnonzero(r0_all >= 0)
    lo_r = np.full(len(card), -1, dtype=np.int64)
    hi_r = np.full(len(card), -1, dtype=np.int64)
    if len(with_range):
        # The ranges are not clipped to the running maximum of the starts before them: that holds only if
        # every earlier image is paired, and an earlier image may be an extra (another flight's, on a card
        # whose two sessions interleave in time). Clipped, the true alignment of such a card was costed as if
        # its images could not pair, and a wrong offset won (property test of issue 36). A segment ends where
        # every later image's range starts past every earlier one's end (prefix maximum of the ends below
        # the suffix minimum of the starts): segments then share no exposure, whatever is skipped.
        ki = with_range
        klo, khi = r0_all[ki], r1_all[ki]
        lo_r[ki], hi_r[ki] = klo, khi
        reach = np.maximum.accumulate(khi)
        floor = np.minimum.accumulate(klo[::-1])[::-1]
        starts = np.flatnonzero(np.concatenate([[True], floor[1:] > reach[:-1]]))
        ends = np.concatenate([starts[1:], [len(ki)]]).astype(np.int64)
        ki_l, floor_l, reach_l = ki.tolist(), floor.tolist(), reach.tolist()
        for s0, s1 in zip(starts.tolist(), ends.tolist(), strict=True):
            segs.append((ki_l[s0:s1], floor_l[s0], reach_l[s1 - 1]))
    ranges = Ranges(lo_r, hi_r)
    return cands, ranges, segs, flat


def _segment_key(
    card: Card, cands: Cands, ranges: Ranges, imgs: list[int], lo: int, hi: int
) -> tuple[object, ...] | None:
    """The same images seeing the same exposures give the same answer (offset scans repeat most segments).

    As bytes, not per-image tuples (a solve keys thousands of small segments): the frames of the windows
    of every image from the segment's first to its last with their counts (which say which frames are
    whose), and the ranges of its images without a time. Images in between that are not in the segment
    only make the key stricter (a miss, solved again), never a wrong hit."""
    if len(imgs) > _CACHE_MAX_IMAGES:
        return None
    i0, i1 = imgs[0], imgs[-1] + 1
    s0, s1 = cands.start[i0], cands.start[i1]
    key: tuple[object, ...] = (lo, hi, tuple(imgs), cands.jj[s0:s1].tobytes(), cands.counts[i0:i1].tobytes())
    if card.untimed_prefix[i1] > card.untimed_prefix[i0]:
        has = card.has
        key += tuple(ranges[i] for i in imgs if not has[i])
    return key


def solve_cost(card: Card, fr: Frames, model: Model, widen: float, limit: float) -> float:
    """The cost of `solve` (forward passes only), or infinity when it exceeds `limit`."""
    cands, ranges, segs, flat = segments(card, fr, model, widen)
    cost = fr.image_skip * len(ranges.missing) + float(fr.skip_prefix[-1])  # (whole numbers: exact)
    for _imgs, lo, hi in segs:
        cost -= float(fr.skip_prefix[hi + 1] - fr.skip_prefix[lo])
    todo: Segments = []
    keys: list[tuple[object, ...] | None] = []
    for imgs, lo, hi in segs:
        if cost > limit:  # segment costs are never negative: the rest cannot bring it back
            return math.inf
        if len(imgs) == 1:
            one = _pair_sets(card, fr, cands, ranges, imgs, lo, hi)[0]
            total = float(fr.skip_prefix[hi + 1] - fr.skip_prefix[lo])
            cost += min([total + fr.image_skip] + [total - fr.skip[j + lo] for j in one])
            continue
        key = _segment_key(card, cands, ranges, imgs, lo, hi)
        known = fr.cache.get(key) if key is not None else None
        if known is not None:
            cost += known.cost
            continue
        seg_cost = fr.cost_cache.get(key) if key is not None else None
        if seg_cost is None:  # costed below, all at once
            todo.append((imgs, lo, hi))
            keys.append(key)
            continue
        cost += seg_cost
    if cost > limit:
        return math.inf
    for key, seg_cost in zip(keys, _costs(card, fr, cands, ranges, flat, todo), strict=True):
        if key is not None:
            fr.cost_cache[key] = seg_cost
        cost += seg_cost
    return cost if cost <= limit else math.inf


def _costs(card: Card, fr: Frames, cands: Cands, ranges: Ranges, flat: Flat, segs: Segments) -> list[float]:
    """The optimal cost of each segment: stacked (`batch`) where `_split` says so, else row by row."""
    stacked, alone, m = _split(card, fr, ranges, flat, segs)
    out = [0.0] * len(segs)
    if m is not None:
        for s, c in zip(stacked, batch.costs(fr, m), strict=True):
            out[s] = c
    for s in alone:
        imgs, lo, hi = segs[s]
        _imgs, pair, band_a, band_b, pf, sf = _prepare(card, fr, cands, ranges, imgs, lo, hi, None)
        f = _forward(pair, band_a, band_b, pf, sf, fr.image_skip)
        out[s] = _f_at(f, band_a, band_b, pf, len(pair), hi - lo + 1)
    return out


def _split(
    card: Card, fr: Frames, ranges: Ranges, flat: Flat, segs: Segments
) -> tuple[list[int], list[int], batch.Many | None]:
    """(segments for the stacked DP, segments for the row-by-row one). Stacked only with whole-number
    costs (`batch.exact_costs`), where there are enough rows abreast to be worth a numpy step per row
    (a card of one long pass is faster row by row), and where `batch.fits`; with the stacked ones' arrays."""
    if not segs or not batch.exact_costs(fr):
        return [], list(range(len(segs))), None
    rows = [len(s[0]) for s in segs]
    if sum(rows) < STACK_MIN_ABREAST * max(rows):
        return [], list(range(len(segs))), None
    m = batch.many(fr, card.has, flat, ranges, segs)
    ok, wide = batch.fits(m, MAX_SEGMENT_CELLS)
    if not wide:
        return ok, wide, m
    # (rare) the arrays again, without the segments left to the row-by-row DP
    return ok, wide, batch.many(fr, card.has, flat, ranges, [segs[s] for s in ok]) if ok else None


def solve(card: Card, fr: Frames, model: Model, widen: float) -> Outcome:
    """The alignment under `model` with every window widened by `widen` [s]."""
    cands, ranges, segs, flat = segments(card, fr, model, widen)
    out = Outcome(0.0, {}, {}, {}, set())
    # The segments of several images solved first (stacked where `_split` says so, else one by one),
    # then merged in card order (dict order is the report's order).
    parts: dict[int, Outcome] = {}
    todo: list[int] = []
    keys: dict[int, tuple[object, ...] | None] = {}
    for s, (imgs, lo, hi) in enumerate(segs):
        if len(imgs) == 1:
            continue
        key = _segment_key(card, cands, ranges, imgs, lo, hi)
        part = fr.cache.get(key) if key is not None else None
        if part is None:
            todo.append(s)
            keys[s] = key
        else:
            parts[s] = part
    stacked, alone, m = _split(card, fr, ranges, flat, [segs[s] for s in todo])
    if m is not None:
        for k, part in zip(stacked, batch.outcomes(card, fr, m), strict=True):
            parts[todo[k]] = part
    for k in alone:
        imgs, lo, hi = segs[todo[k]]
        part = Outcome(0.0, {}, {}, {}, set())
        solve_segment(card, fr, cands, ranges, imgs, lo, hi, part)
        parts[todo[k]] = part
    for s in todo:
        key = keys[s]
        if key is not None:
            fr.cache[key] = parts[s]
    in_seg_skip = 0.0
    for s, (imgs, lo, hi) in enumerate(segs):
        in_seg_skip += float(fr.skip_prefix[hi + 1] - fr.skip_prefix[lo])
        if len(imgs) == 1:
            out.cost += _solve_single(card, fr, cands, ranges, imgs[0], lo, hi, out)
            continue
        part = parts[s]
        out.cost += part.cost
        out.pairs.update(part.pairs)
        out.ambiguous.update(part.ambiguous)
        out.extra.update(part.extra)
        out.frame_ambiguous.update(part.frame_ambiguous)
    for i in ranges.missing:
        if i not in out.extra:
            out.extra[i] = IMAGE_NO_EXPOSURE if card.has_time(i) else IMAGE_NO_TIME_UNPLACED
        out.cost += fr.image_skip
    out.cost += float(fr.skip_prefix[-1]) - in_seg_skip
    return out


def _prepare(
    card: Card,
    fr: Frames,
    cands: Cands,
    ranges: Ranges,
    imgs: list[int],
    lo: int,
    hi: int,
    out: Outcome | None,
) -> tuple[list[int], list[list[int]], list[int], list[int], list[float], list[float]]:
    """(images, pair columns, bands A and B, skip prefix sums, skip costs) of a segment in local columns."""
    q = hi - lo + 1
    pair = _pair_sets(card, fr, cands, ranges, imgs, lo, hi)
    band_a, band_b = _bands(pair, q)
    if sum(b - a + 1 for a, b in zip(band_a, band_b, strict=True)) > MAX_SEGMENT_CELLS:
        # Only long runs of images without EXIF time make bands this wide: leave them out.
        if out is not None:
            for i in imgs:
                if not card.has_time(i):
                    out.ambiguous[i] = ([], "no EXIF time, in a run of such images too long to place by order")
        imgs = [i for i in imgs if card.has_time(i)]
        pair = _pair_sets(card, fr, cands, ranges, imgs, lo, hi)
        band_a, band_b = _bands(pair, q)
    pf: list[float] = (fr.skip_prefix[lo : hi + 2] - fr.skip_prefix[lo]).tolist()  # pf[b]: skip local 0..b-1
    return imgs, pair, band_a, band_b, pf, fr.skip[lo : hi + 1]


def _forward(
    pair: list[list[int]], band_a: list[int], band_b: list[int], pf: list[float], sf: list[float], si: float
) -> list[list[float]]:
    """f[r][b - A_r] = best cost of images[:r] with frames[:b], on the bands."""
    p = len(pair)
    f: list[list[float]] = [pf[band_a[0] : band_b[0] + 1]]
    for r in range(p):
        ar, br = band_a[r], band_b[r]
        an, bn = band_a[r + 1], band_b[r + 1]
        prev = f[r]
        row = [v + si for v in prev[an - ar :]]  # columns an..br
        if bn > br:
            base = prev[-1] + si - pf[br]
            row.extend([base + pf[b] for b in range(br + 1, bn + 1)])
        for bb in pair[r]:  # pair image r with frame bb: from column bb to bb + 1
            w = prev[bb - ar]
            k = bb + 1 - an
            if w < row[k]:
                row[k] = w
        last = row[0]
        for k in range(1, len(row)):
            w = last + sf[an + k - 1]
            if w < row[k]:
                row[k] = w
            last = row[k]
        f.append(row)
    return f


def _f_at(f: list[list[float]], band_a: list[int], band_b: list[int], pf: list[float], r: int, b: int) -> float:
    if r == 0:
        return pf[b]
    ar, br = band_a[r], band_b[r]
    if b > br:
        return f[r][br - ar] + (pf[b] - pf[br])
    return f[r][b - ar]


def solve_segment(
    card: Card,
    fr: Frames,
    cands: Cands,
    ranges: Ranges,
    imgs: list[int],
    lo: int,
    hi: int,
    out: Outcome,
) -> None:
    """Align the images `imgs` with frames lo..hi (local columns 0..q) and record what is decided."""
    q = hi - lo + 1
    imgs, pair, band_a, band_b, pf, sf = _prepare(card, fr, cands, ranges, imgs, lo, hi, out)
    p = len(imgs)
    si = fr.image_skip
    f = _forward(pair, band_a, band_b, pf, sf, si)
    # backward: g[r][b - A_r] = best cost of images[r:] with frames[b:]
    g: list[list[float]] = [[] for _ in range(p + 1)]
    total = pf[q]
    g[p] = [total - pf[b] for b in range(band_a[p], band_b[p] + 1)]
    for r in range(p - 1, -1, -1):
        ar, br = band_a[r], band_b[r]
        an = band_a[r + 1]
        nxt = g[r + 1]
        if an > ar:
            base = nxt[0] + pf[an] + si
            row = [base - pf[b] for b in range(ar, an)]
            row.extend([v + si for v in nxt[: br - an + 1]])
        else:
            row = [v + si for v in nxt[: br - an + 1]]
        for bb in pair[r]:
            w = nxt[bb + 1 - an]
            k = bb - ar
            if w < row[k]:
                row[k] = w
        last = row[-1]
        for k in range(len(row) - 2, -1, -1):
            w = last + sf[ar + k]
            if w < row[k]:
                row[k] = w
            last = row[k]
        g[r] = row

    opt = _f_at(f, band_a, band_b, pf, p, q)
    out.cost += opt
    limit = opt + AMBIGUITY_MARGIN
    for r in range(p):
        ar, br = band_a[r], band_b[r]
        an = band_a[r + 1]
        fr_row, g_row = f[r], g[r + 1]
        cols = pair[r]
        vals = [fr_row[bb - ar] + g_row[bb + 1 - an] for bb in cols]
        # the best alignment leaving image r out: min over columns of f[r] + g[r + 1]; outside
        # [A_{r+1}, B_r] both sides only add frame skips, so the minimum lies inside
        with_skip = min(map(operator.add, fr_row[an - ar : br - ar + 1], g_row[: br - an + 1])) + si
        if with_skip > limit:
            near_k = [k for k, v in enumerate(vals) if v <= limit]
            if len(near_k) == 1 and abs(vals[near_k[0]] - opt) < 1e-9:
                # the usual case: one exposure fits within the margin, it is the optimum's, and leaving
                # the image out costs too much (what `decide` concludes, without its bookkeeping)
                out.pairs[imgs[r]] = cols[near_k[0]] + lo
                continue
        with_pair = {bb + lo: v for bb, v in zip(cols, vals, strict=True)}
        # The optimum's own pairing of image r. Where several alignments are optimal any of them will
        # do: the image is then ambiguous whichever is taken (the others are within the margin).
        mine = next((j for j, v in with_pair.items() if abs(v - opt) < 1e-9), None)
        decide(card, imgs[r], with_pair, with_skip, mine, limit, out)


def _solve_single(
    card: Card,
    fr: Frames,
    cands: Cands,
    ranges: Ranges,
    i: int,
    lo: int,
    hi: int,
    out: Outcome,
) -> float:
    """A segment of one image: the DP in closed form (pair with one frame and skip the others, or skip
    all); the optimal path's tie rule (pair first, walking back from the end) takes the last best frame."""
    pair = [j + lo for j in _pair_sets(card, fr, cands, ranges, [i], lo, hi)[0]]
    total = float(fr.skip_prefix[hi + 1] - fr.skip_prefix[lo])
    skip = fr.skip
    with_pair = {j: total - skip[j] for j in pair}
    with_skip = total + fr.image_skip
    opt = min(with_skip, *with_pair.values()) if with_pair else with_skip
    mine = None
    for j in reversed(pair):
        if abs(with_pair[j] - opt) < 1e-9:
            mine = j
            break
    decide(card, i, with_pair, with_skip, mine, opt + AMBIGUITY_MARGIN, out)
    return opt


def _pair_sets(
    card: Card,
    fr: Frames,
    cands: Cands,
    ranges: Ranges,
    imgs: list[int],
    lo: int,
    hi: int,
) -> list[list[int]]:
    """Per image of the segment, the local columns it may pair with (every pair inside its window costs 0)."""
    pair: list[list[int]] = []
    has = card.has
    for i in imgs:
        if has[i]:
            pair.append([j - lo for j in cands[i] if lo <= j <= hi])
        else:
            r = ranges[i]
            r0, r1 = (max(lo, r[0]), min(hi, r[1])) if r is not None else (lo, hi)
            pair.append([j - lo for j in range(r0, r1 + 1) if fr.eligible[j]])
    return pair


def _bands(pair: list[list[int]], q: int) -> tuple[list[int], list[int]]:
    """[A_r, B_r] for rows r = 0..p: A_r the least column images r-1.. may pair with (suffix minimum,
    row 0 and 1 alike), B_r one past the greatest images ..r may pair with (running maximum), B_p = q."""
    p = len(pair)
    least = [min(s) if s else q for s in pair]
    suffix = [q] * (p + 1)
    for r in range(p - 1, -1, -1):
        suffix[r] = min(least[r], suffix[r + 1])
    band_a = [suffix[0]] + [suffix[r - 1] for r in range(1, p + 1)]
    band_b = [0] * (p + 1)
    reach = 0
    for r in range(p):
        if pair[r]:
            reach = max(reach, max(pair[r]) + 1)
        band_b[r] = min(q, max(reach, band_a[r + 1], band_a[r]))
    band_b[p] = q
    return band_a, band_b
