"""The camera clock: candidate offsets by voting, offset and drift fitted to the confident pairs."""

from __future__ import annotations

import numpy as np

from icgt.ingest.matching.results import ImageTime
from icgt.ingest.matching.state import Card, FloatArray, Frames, Model

DRIFT_REPORT_PPM = 20.0
"""The drift is reported when drifts this far from the fit explain the pairs clearly worse."""


def fit(card: Card, fr: Frames, pairs: dict[int, int], prior: Model, max_drift_ppm: float) -> Model:
    """Offset and drift from the confident timed pairs: weighted least squares, drift with a weak prior."""
    ii = np.fromiter(pairs.keys(), dtype=np.int64, count=len(pairs))
    jj = np.fromiter(pairs.values(), dtype=np.int64, count=len(pairs))
    timed = ~np.isnan(card.c[ii])
    ii, jj = ii[timed], jj[timed]
    if len(ii) == 0:
        return prior
    x = fr.x[jj]
    ref = float(card.c[ii[0]])  # camera times are ~1e9 s: work relative to one of them
    c = card.c[ii] - ref
    res = card.r[ii]
    y = c + res / 2.0 - x  # camera minus recording time: o + d x
    w = 1.0 / (res**2 / 12.0 + 1e-6)
    sd = max_drift_ppm * 1e-6 / 2.0
    # minimise sum w (y - o - d x)^2 + (d / sd)^2
    sw, sx, sxx = w.sum(), (w * x).sum(), (w * x * x).sum() + 1.0 / sd**2
    sy, sxy = (w * y).sum(), (w * x * y).sum()
    det = sw * sxx - sx * sx
    if det <= 0:
        return prior
    o = (sxx * sy - sx * sxy) / det
    d = (sw * sxy - sx * sy) / det
    d = float(np.clip(d, -max_drift_ppm * 1e-6, max_drift_ppm * 1e-6))
    # Better: the (offset, drift) farthest inside every pair's EXIF interval (widened by the timing
    # tolerance). For a drift d the offsets allowed form [max(lo - x(1+d)), min(hi - x(1+d))], whose width
    # is concave in d: maximise it (ties broken towards no drift, which a short flight cannot tell from
    # a small one), then take the middle. Truncated EXIF times pin the clock far better
    # through the seconds' boundaries than least squares on their centres does.
    tol = fr.tol[jj]
    lo_b, hi_b = c - tol - x, c + res + tol - x
    span = float(x.max() - x.min()) if len(x) else 0.0

    def bounds(dd: float) -> tuple[float, float]:
        return float((lo_b - dd * x).max()), float((hi_b - dd * x).min())

    def width(dd: float, penalty: float) -> float:
        a, b = bounds(dd)
        return b - a - penalty * abs(dd) * span

    lim = max_drift_ppm * 1e-6
    d_best = 0.0
    for penalty in (0.01,):  # breaks ties towards no drift where the width is flat
        a_d, b_d = -lim, lim
        for _ in range(100):
            m1, m2 = a_d + (b_d - a_d) / 3.0, b_d - (b_d - a_d) / 3.0
            if width(m1, penalty) < width(m2, penalty):
                a_d = m1
            else:
                b_d = m2
        d_best = (a_d + b_d) / 2.0
        o_lo, o_hi = bounds(d_best)
        if o_lo <= o_hi:
            # Known if drifts DRIFT_REPORT_PPM away narrow the allowed offsets by more than a millisecond.
            top = width(d_best, 0.0)
            step = DRIFT_REPORT_PPM * 1e-6
            known = width(d_best - step, 0.0) < top - 1e-3 and width(d_best + step, 0.0) < top - 1e-3
            return Model((o_lo + o_hi) / 2.0 + ref, d_best, known)
    return Model(float(o) + ref, d)


def offset_candidates(times: list[ImageTime], fr: Frames, widen: float, keep: int = 3) -> list[Model]:
    """A few distinct camera offsets (drift 0) under which most images and exposures find a partner."""
    timed = [t for t in times if t.time_s is not None and t.resolution_s is not None]
    xe = fr.x[fr.eligible]
    if not timed or len(xe) == 0:
        return []
    c = np.array([t.time_s for t in timed], dtype=np.float64)
    r = np.array([t.resolution_s for t in timed], dtype=np.float64)
    tol = float(np.median(fr.tol)) + widen
    c_sorted = np.sort(c)
    r_max = float(r.max())

    # Sentinels past the end: "the first element at or after the window's start lies inside it" is then
    # one search and one look-up per window (the same count as two searches, at half the cost).
    # The images in time order too (a count does not depend on the order; sorted keys search faster).
    xe_end = np.append(xe, np.inf)
    c_end = np.append(c_sorted, np.inf)
    r_by_c = r[np.argsort(c, kind="stable")]

    def scores(offsets: FloatArray, slack: float = 0.0) -> list[int]:
        """Per offset: images with an exposure in their window plus exposures with an image in theirs.
        A few dozen offsets per numpy call (hundreds are scored; the same element-wise arithmetic as one
        at a time, so the same counts)."""
        t = tol + slack
        out: list[int] = []
        for k in range(0, len(offsets), 32):
            o = offsets[k : k + 32, None]
            lo = np.searchsorted(xe, c_sorted[None, :] - o - t, side="left")
            images = np.count_nonzero(xe_end[lo] <= c_sorted[None, :] + r_by_c[None, :] - o + t, axis=1)
            pe = xe[None, :] + o
            a = np.searchsorted(c_sorted, pe - r_max - t, side="left")
            out.extend((images + np.count_nonzero(c_end[a] <= pe + t, axis=1)).tolist())
        return out

    step = max(1, len(timed) // 40)
    sample = np.arange(0, len(timed), step)[:40]
    votes = (c[sample, None] + r[sample, None] / 2.0 - xe[None, :]).ravel()
    coarse_q = max(1.0, r_max)
    bins, counts = np.unique(np.floor(votes / coarse_q), return_counts=True)
    top = bins[np.argsort(-counts, kind="stable")[:200]]
    coarse = sorted(zip(scores((top + 0.5) * coarse_q, coarse_q / 2), top.tolist(), strict=True), reverse=True)
    best_bins = [k for _, k in coarse[:3]]
    fine = np.unique(np.round(votes[np.isin(np.floor(votes / coarse_q), best_bins)], 3))
    scored = sorted(zip(scores(fine), fine.tolist(), strict=True), key=lambda t: (-t[0], t[1]))
    if not scored:
        return []
    # Among the best, keep the middle of each run of equal scores, and distinct ones only.
    best = scored[0][0]
    out: list[float] = []
    sep = 2.0 * tol + float(r.min())
    for s, o in scored:
        if s < best - max(4, best // 20):
            break
        group = [oo for ss, oo in scored if ss == s and abs(oo - o) <= r_max + 2 * tol]
        centre = (min(group) + max(group)) / 2.0
        if all(abs(centre - k) > sep for k in out):
            out.append(centre)
        if len(out) >= keep:
            break
    return [Model(o, 0.0) for o in out]
