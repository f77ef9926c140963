"""Offsets around a fit: settle a candidate, refine it with the drift, scan the neighbourhood for rivals."""

from __future__ import annotations

import math

import numpy as np

from icgt.ingest.matching.align import solve, solve_cost
from icgt.ingest.matching.clock import fit
from icgt.ingest.matching.results import AMBIGUITY_MARGIN
from icgt.ingest.matching.state import Card, Frames, Model, Outcome

MAX_SCAN_S = 3.0
"""Offsets are scanned at most this far from the fit [s]."""


def refine(
    card: Card, fr: Frames, start: Model, widen: float, max_drift_ppm: float, give_up_above: float = math.inf
) -> tuple[Model, Outcome]:
    """Align with widened windows (the drift is unknown), fit, and close the windows to the tolerance.

    `give_up_above`: a final alignment costing more is not solved (its outcome is empty, cost infinite)."""
    model = start
    solved: dict[tuple[float, float, float], Outcome] = {}  # a fit that settled is not solved again

    def solve_once(m: Model, w: float) -> Outcome:
        key = (m.offset, m.drift, w)
        if key not in solved:
            solved[key] = solve(card, fr, m, w)
        return solved[key]

    for w in (widen, widen, widen / 2.0, 0.0) if widen > 0 else (0.0, 0.0):
        outcome = solve_once(model, w)
        model = fit(card, fr, outcome.pairs, model, max_drift_ppm)
    if (
        (model.offset, model.drift, 0.0) not in solved
        and give_up_above < math.inf
        and solve_cost(card, fr, model, 0.0, give_up_above) > give_up_above
    ):
        return model, Outcome(math.inf, {}, {}, {}, set())
    final = solve_once(model, 0.0)
    if final.cost > 1e-9 and (start.offset, start.drift, 0.0) != (model.offset, model.drift, 0.0):
        # A drift fitted to pairs that were partly wrong (an extra image shifting a run by one exposure
        # fits a drift as well as the truth does) can end costlier than where it started: the start's
        # alignment is then the better one, and the scan for rivals must be made around it.
        base = solve_once(start, 0.0)
        if base.cost < final.cost - 1e-9:
            model, final = start, base
    return model, Outcome(
        final.cost, dict(final.pairs), dict(final.ambiguous), dict(final.extra), set(final.frame_ambiguous)
    )


def grid(fr: Frames, card: Card, tolerance_s: float, *, coarse: bool) -> tuple[float, float]:
    """(step, reach) of an offset scan [s]: fine for the ambiguity scan, coarser to settle a candidate."""
    xe = fr.x[fr.eligible]
    dt = float(np.median(np.diff(xe))) if len(xe) >= 2 else 0.0
    r_max = float(card.r[card.timed].max()) if len(card.timed) else 0.0
    if coarse:
        return max(0.004, tolerance_s / 2.0, r_max / 20.0), min(MAX_SCAN_S, r_max / 2.0 + dt)
    return max(0.004, tolerance_s / 2.0), min(MAX_SCAN_S, r_max / 2.0 + 2.0 * dt + 2.0 * tolerance_s)


def settle(card: Card, fr: Frames, start: Model, tolerance_s: float) -> Model:
    """The middle of the run of scanned offsets around `start` that cost least."""
    step, reach = grid(fr, card, tolerance_s, coarse=True)
    base = solve_cost(card, fr, start, 0.0, math.inf)
    # Widened windows only add options, so the scan's own centre costs at most the base: no offset
    # costing more can be among the least.
    found = _scan(card, fr, start, base - AMBIGUITY_MARGIN + 1e-6, step, reach, centre=True, outcomes=False)
    if not found:
        return start
    least = min(c for c, _m, _o, _k in found)
    ks = {k for c, _m, _o, k in found if c <= least + 1e-9}
    best_k = min(ks, key=abs)
    lo = hi = best_k
    while lo - 1 in ks:
        lo -= 1
    while hi + 1 in ks:
        hi += 1
    return Model(start.offset + (lo + hi) / 2.0 * step, start.drift)


def scan(
    card: Card, fr: Frames, model: Model, best: float, step: float, reach: float
) -> list[tuple[float, Model, Outcome, int]]:
    """Solutions at offsets around `model` (a grid) that may cost at most `best` + AMBIGUITY_MARGIN.

    Each offset is solved with its windows widened by half the grid step, so an alignment that fits
    anywhere between two grid offsets is seen (the scan errs towards ambiguity).
    """
    return [(c, m, o, k) for c, m, o, k in _scan(card, fr, model, best, step, reach) if o is not None]


def _scan(
    card: Card,
    fr: Frames,
    model: Model,
    best: float,
    step: float,
    reach: float,
    *,
    centre: bool = False,
    outcomes: bool = True,
) -> list[tuple[float, Model, Outcome | None, int]]:
    """`scan`; without `outcomes` only the offsets that may cost least, with their costs (forward passes
    stopped once past the margin or past the least cost found so far)."""
    xe = fr.x[fr.eligible]
    if len(xe) < 2 or len(card.timed) == 0:
        return []
    c, r = card.c[card.timed], card.r[card.timed]
    order = np.argsort(c, kind="stable")
    c_sorted, r_sorted = c[order], r[order]
    skip_e = np.array(fr.skip, dtype=np.float64)[fr.eligible]
    min_skip = float(skip_e[skip_e > 0].min()) if bool((skip_e > 0).any()) else 0.0
    t_pad = float(fr.tol.max()) + step / 2.0
    untimed = float(len(card) - len(card.timed))
    uniq, first, counts = np.unique(c, return_index=True, return_counts=True)
    ext_lo = uniq - t_pad  # each distinct EXIF window with the padding, sorted by start
    ext_hi_sorted = np.sort(uniq + r[first] + t_pad)
    limit = best + AMBIGUITY_MARGIN
    # Offsets whose windows admit the same exposures for every image (the same signature) share the
    # first one's solution; each first one gets a lower bound on its cost: images with fewer exposures
    # in reach than images of the same EXIF time, exposures in reach of no image, exposures deep inside
    # one window outnumbering its images.
    groups: dict[int, list[tuple[int, Model]]] = {}
    firsts: list[tuple[float, int, int, Model]] = []  # (bound, k, signature, model)
    for k in range(-math.floor(reach / step), math.floor(reach / step) + 1):
        if k == 0 and not centre:
            continue
        m = Model(model.offset + k * step, model.drift)
        pe = np.asarray(m.predict(xe), dtype=np.float64)
        lo = np.searchsorted(pe, c - t_pad, side="left")
        hi = np.searchsorted(pe, c + r + t_pad, side="right")
        signature = hash(lo.tobytes() + hi.tobytes())
        if signature in groups:  # every image sees the same exposures as at an offset already tried
            groups[signature].append((k, m))
            continue
        groups[signature] = [(k, m)]
        bound = 0.0
        avail = hi[first] - lo[first]
        bound += float(np.clip(counts - avail, 0, None).sum()) * fr.image_skip
        k_idx = np.searchsorted(c_sorted, pe + t_pad, side="right") - 1
        covered = (k_idx >= 0) & (pe <= c_sorted[np.clip(k_idx, 0, None)] + r_sorted[np.clip(k_idx, 0, None)] + t_pad)
        uncovered = float(np.count_nonzero(~covered & (skip_e > 0)))
        core_lo = np.searchsorted(pe, uniq + t_pad, side="left")
        core_hi = np.searchsorted(pe, uniq + r[first] - t_pad, side="left")
        # only exposures that no other EXIF window reaches: where windows overlap (an image whose time is
        # not on the second, another camera's) an exposure deep inside one may be another's image's
        inside = np.searchsorted(ext_lo, pe, side="right") - np.searchsorted(ext_hi_sorted, pe, side="left")
        only = np.concatenate([[0], np.cumsum(inside == 1)])
        excess = float(np.clip((only[core_hi] - only[core_lo]) - counts, 0, None).sum())
        # (an image without EXIF time may take any of those exposures)
        bound += max(0.0, uncovered + excess - untimed) * min_skip
        firsts.append((bound, k, signature, m))
    if not outcomes:
        # Costs only (settle): what matters are the offsets that cost least, so the most promising
        # go first and, once one is costed, the others are only followed while they can still tie.
        firsts.sort(key=lambda t: (t[0], t[1]))
    out: list[tuple[float, Model, Outcome | None, int]] = []
    for bound, _k, signature, m in firsts:
        if bound > limit:
            continue
        cost = solve_cost(card, fr, m, step / 2.0, limit)
        if cost > limit:
            continue
        alt = solve(card, fr, m, step / 2.0) if outcomes else None
        out.extend((cost, mm, alt, kk) for kk, mm in groups[signature])
        if not outcomes:
            limit = min(limit, cost + 1e-6)
    out.sort(key=lambda t: t[3])
    return out
