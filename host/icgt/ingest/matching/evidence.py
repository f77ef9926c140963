"""Which camera clock offsets the card allows at all: a check over every offset, that steady triggers cannot alias.

The alignment (`align`) finds the best pairing near a candidate offset and `search.scan` compares the offsets
around it. Neither sees an offset many intervals away, and when the card holds more images than the log (the
recorder stopped while the camera kept shooting, images from before the recording, two flights on one card)
such an offset can explain the card at the same alignment cost: the log's exposures laid on another run of
images, every image paired, all of them wrongly. What tells the offsets apart is the pattern of the overlap:
a missed trigger, a pause between passes, the ends of a burst. So every offset that the votes of image and
exposure times propose is scored by its contradictions over the whole overlap:

- an exposure the device triggered (and the camera did not report missing) with no image whose EXIF window
  admits it: 1 (the alignment charges an unconfirmed trigger less; here it counts in full, since a shift by a
  few intervals at the ends of a log is told from the truth only by such exposures);
- an image inside the log's span (between its first and last exposure) that no exposure fits: 1 (a shift
  that lays a missed trigger of the log on an image of the card is as unlikely as one that lays an exposure
  on a missing image);
- an image outside the log's span: nothing. A card that outnumbers the log is expected. (Weighing them,
  even lightly, makes laying the log on a larger flight of the card look cheaper than on its own.)

An offset is accepted only when every offset outside its neighbourhood (`evidence_reach`: there the
alignment's cost and `search.scan` decide) has at least OFFSET_MARGIN more contradictions; otherwise no pair
is made by time, and the note gives the candidates and their scores.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from icgt.ingest.matching.state import Card, FloatArray, Frames

OFFSET_MARGIN = 2.0
"""Contradictions (a triggered exposure without an image: 1, an image inside the log without an exposure:
EXTRA_IMAGE_WEIGHT) by which an offset must beat every offset outside its neighbourhood to be accepted."""
EXTRA_IMAGE_WEIGHT = 1.0
"""An image inside the log's span without an exposure, against a triggered exposure without an image."""
MAX_UNEXPLAINED_SHARE = 0.1
"""The best offset is believed only when it leaves at most this share of the log's triggered exposures (plus
OFFSET_MARGIN) contradicted: a card that does not hold the log (another flight, a session of the card that is
not this recording) is otherwise 'explained' best by the offset laying part of the log on the end of it."""
MAX_VOTE_IMAGES = 400
"""Images whose times vote for offsets (evenly spread over the card); every eligible exposure votes with each."""
MAX_OFFSETS = 1500
"""Offsets scored, the most voted for."""
FINE_BINS = 64
"""The most voted bins of coarse EXIF times that are also scanned at the tolerance's spacing (`judge`)."""


@dataclass(frozen=True)
class OffsetScore:
    offset_s: float
    """Camera minus recording time at the recording's first exposure [s] (as `Model.offset`)."""
    contradictions: float
    """Weighted contradictions over the overlap (see OFFSET_MARGIN)."""
    overlap: int
    """Eligible exposures that found an image under this offset."""


@dataclass(frozen=True)
class Verdict:
    best: OffsetScore
    rivals: list[OffsetScore]
    """The best offset of each other neighbourhood within OFFSET_MARGIN of the best, best first."""
    exposures: int = 0
    """The log's exposures that may have an image (the share of MAX_UNEXPLAINED_SHARE is of these)."""

    @property
    def plausible(self) -> bool:
        """Does the best offset explain the log at all (see MAX_UNEXPLAINED_SHARE)?"""
        return self.best.contradictions <= OFFSET_MARGIN + MAX_UNEXPLAINED_SHARE * self.exposures

    @property
    def decided(self) -> bool:
        return not self.rivals and self.plausible

    def admits(self, offset_s: float, reach_s: float) -> bool:
        """Is `offset_s` in the neighbourhood of the accepted offset?"""
        return abs(offset_s - self.best.offset_s) <= reach_s

    def note(self) -> str:
        if not self.plausible:
            return (
                "the card does not hold this log: the offset that explains it best still leaves "
                f"{self.best.contradictions:g} contradictions over the log's {self.exposures} exposures (at most "
                f"{MAX_UNEXPLAINED_SHARE:.0%} are believed; an image for {self.best.overlap} of them): "
                "no image is paired by its time"
            )
        listed = ", ".join(
            f"{s.offset_s - self.best.offset_s:+.3f} s ({s.contradictions:g} contradictions, {s.overlap} exposures)"
            for s in self.rivals[:4]
        )
        return (
            "the camera clock offset is not decided: offsets several intervals apart explain the card about as well "
            f"(best: {self.best.contradictions:g} contradictions over {self.best.overlap} exposures; relative to "
            f"it {listed}; an offset must beat every other by {OFFSET_MARGIN:g}): no image is paired by its time"
        )


def _windows(card: Card) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The timed images' EXIF windows sorted by start: (starts, ends, the greatest end so far)."""
    ti = card.timed
    order = np.argsort(card.c[ti], kind="stable")
    lo, hi = card.c[ti][order], (card.c[ti] + card.r[ti])[order]
    return lo, hi, (np.maximum.accumulate(hi) if len(hi) else hi)


def _fits(lo: FloatArray, hi_run: FloatArray, p: FloatArray, tol: float) -> np.ndarray:
    """Which exposures (camera-clock times p) fit an image: some window [lo - tol, hi + tol] contains them, i.e.
    the last window starting at or before p + tol ends at or after p - tol (hi_run: the greatest end so far)."""
    idx = np.searchsorted(lo, p + tol, side="right") - 1
    out: np.ndarray = (idx >= 0) & (hi_run[np.maximum(idx, 0)] >= p - tol)
    return out


def _groups(card: Card) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The timed images' distinct EXIF windows sorted by start: (starts, ends, images in each). With 1 s times a
    window is one second of the camera clock and holds every image taken in it."""
    ti = card.timed
    keys = np.stack([card.c[ti], card.r[ti]], axis=1)
    uniq, counts = np.unique(keys, axis=0, return_counts=True)  # sorted by start, then length
    return uniq[:, 0].copy(), (uniq[:, 0] + uniq[:, 1]).copy(), counts.astype(np.float64)


def _count_between(p: FloatArray, rows: FloatArray, a: FloatArray, b: FloatArray) -> np.ndarray:
    """Per row of `p` (each row sorted; `rows` lifts row r by r * lift above the row before, so that one search
    serves them all), how many values lie in each closed interval [a, b] (none where a > b)."""
    flat = (p + rows).ravel()
    first = np.searchsorted(flat, (a[None, :] + rows).ravel(), side="left")
    last = np.searchsorted(flat, (b[None, :] + rows).ravel(), side="right")
    out: np.ndarray = np.clip(last - first, 0, None).reshape(p.shape[0], len(a))
    return out


def contradictions(card: Card, fr: Frames, offsets: FloatArray, slack_s: float) -> tuple[FloatArray, FloatArray]:
    """Per offset (drift 0, windows padded by `slack_s` more): contradictions and exposures paired.

    Counted one-to-one over blocks of EXIF windows: neighbouring windows (the images of one EXIF time share
    one) are joined into a block where an exposure may belong to either, and each block must hold as many
    images as exposures. So coarse times still see a missing image: with 1 s times and two shots a second
    the neighbours' windows cover a missed shot's exposure, but the block then holds one exposure more than
    images. Every exposure whose own image window holds it lies in that window's block (the windows between
    its block and its image's are joined by it), so at the true offset a block is short only by real misses."""
    lo, _hi, hi_run = _windows(card)
    g_lo, g_hi, g_n = _groups(card)
    g_run = np.maximum.accumulate(g_hi)
    n_g = len(g_lo)
    xe = fr.x[fr.eligible]
    tol = float(np.median(fr.tol)) + slack_s
    out_c = np.zeros(len(offsets))
    out_n = np.zeros(len(offsets))
    if not len(xe) or not len(lo):
        return out_c + float(len(xe)), out_n
    for k in range(0, len(offsets), 64):
        p = xe[None, :] + offsets[k : k + 64, None]  # the exposures on the camera's clock (sorted: x is)
        n_rows = p.shape[0]
        fits = _fits(lo, hi_run, p, tol)
        missing = (~fits).sum(axis=1)
        lift = float(max(p.max(), g_hi.max()) - min(p.min(), g_lo.min()) + 4.0 * tol + 1.0)
        rows = np.arange(n_rows, dtype=np.float64)[:, None] * lift
        # Window g and g + 1 are one block when an exposure lies where both (g's run of ends) may hold it
        soft = _count_between(p, rows, g_lo[1:] - tol, g_run[:-1] + tol) > 0
        block = np.concatenate([np.zeros((n_rows, 1), dtype=np.int64), np.cumsum(~soft, axis=1)], axis=1)
        gid = (block + np.arange(n_rows)[:, None] * n_g).ravel()  # blocks numbered across the rows
        g_of = np.clip(np.searchsorted(g_lo, p + tol, side="right") - 1, 0, None)  # an exposure's block's window
        e_gid = np.take_along_axis(block, g_of, axis=1) + np.arange(n_rows)[:, None] * n_g
        exposures = np.bincount(e_gid[fits], minlength=n_rows * n_g)
        images = np.bincount(gid, weights=np.tile(g_n, n_rows), minlength=n_rows * n_g)
        starts = np.flatnonzero(np.r_[True, gid[1:] != gid[:-1]])
        b_lo = np.full(n_rows * n_g, np.inf)
        b_hi = np.full(n_rows * n_g, -np.inf)
        b_lo[gid[starts]] = np.tile(g_lo, n_rows)[starts]
        b_hi[gid[starts]] = np.maximum.reduceat(np.tile(g_hi, n_rows), starts)
        first = np.repeat(p[:, 0], n_g)
        last = np.repeat(p[:, -1], n_g)
        # Images without exposures: a block wholly inside the log's span counts each image beyond its exposures;
        # one reaching past the span's ends only when it has no exposure at all (the rest of it may lie before
        # the recording started or after it ended). Exposures beyond the images count anywhere.
        within = (b_lo - tol >= first) & (b_hi + tol <= last)
        touching = (b_hi >= first - tol) & (b_lo <= last + tol)
        short = np.where(within, np.clip(images - exposures, 0, None), np.where(exposures == 0, images, 0.0))
        per_block = short * touching * EXTRA_IMAGE_WEIGHT + np.clip(exposures - images, 0, None)
        out_c[k : k + 64] = missing + per_block.reshape(n_rows, n_g).sum(axis=1)
        out_n[k : k + 64] = fits.sum(axis=1)
    return out_c, out_n


LOWER_BOUND_SAMPLE = 2000
"""About this many exposures give the lower bound that spares most offsets their full scoring (`_scores`)."""


def missing_lower_bound(card: Card, fr: Frames, offsets: FloatArray, slack_s: float, stride: int) -> FloatArray:
    """Per offset, the exposures among every ``stride``-th one that fit no image (`_fits`, as `contradictions`
    counts them): never more than the offset's contradictions over all exposures, at a fraction of their cost."""
    lo, _, hi_run = _windows(card)
    xe = fr.x[fr.eligible][::stride]
    tol = float(np.median(fr.tol)) + slack_s
    out = np.zeros(len(offsets))
    if not len(xe) or not len(lo):
        return out
    for k in range(0, len(offsets), 256):
        out[k : k + 256] = (~_fits(lo, hi_run, xe[None, :] + offsets[k : k + 256, None], tol)).sum(axis=1)
    return out


def _scores(card: Card, fr: Frames, offsets: FloatArray, slack_s: float) -> tuple[FloatArray, FloatArray]:
    """`contradictions` for the offsets that can be the best or its rivals (the others get +inf, overlap 0).

    A lower bound from a sample of the exposures first (`missing_lower_bound`); the offsets with the least of it
    are scored in full, and only those whose bound leaves them within OFFSET_MARGIN of that best are scored too:
    the rest score more than the best plus the margin, so they can be neither. Same verdict as scoring them all
    (an hour at 5 fps: 4 500 offsets x 18 000 exposures)."""
    n = len(offsets)
    stride = max(1, int(fr.eligible.sum()) // LOWER_BOUND_SAMPLE)
    if stride == 1 or n <= 64:
        return contradictions(card, fr, offsets, slack_s)
    bound = missing_lower_bound(card, fr, offsets, slack_s, stride)
    first = np.argsort(bound, kind="stable")[:64]
    score = np.full(n, np.inf)
    overlap = np.zeros(n)
    score[first], overlap[first] = contradictions(card, fr, offsets[first], slack_s)
    useful = overlap[first] > 0
    if not useful.any():
        return contradictions(card, fr, offsets, slack_s)
    best = float(score[first][useful].min())
    rest = np.flatnonzero(bound <= best + OFFSET_MARGIN + 1e-9)
    rest = rest[~np.isin(rest, first)]
    if len(rest):
        score[rest], overlap[rest] = contradictions(card, fr, offsets[rest], slack_s)
    return score, overlap


def evidence_reach(card: Card, fr: Frames, scan_reach_s: float, tolerance_s: float, max_scan_s: float) -> float:
    """Offsets this close to the best are its neighbourhood [s]: at least as far as the scan around the fit reaches,
    and a whole EXIF interval and two trigger intervals where the scan's cap allows (a shift by about one EXIF
    interval of coarse times moves too few exposures past the log's ends to be told apart by contradictions:
    the alignment's cost, which pairs one image with one exposure, tells it)."""
    xe = fr.x[fr.eligible]
    dt = float(np.median(np.diff(xe))) if len(xe) >= 2 else 0.0
    r_max = float(card.r[card.timed].max()) if len(card.timed) else 0.0
    return max(scan_reach_s, min(max_scan_s, r_max + 2.0 * dt + 2.0 * tolerance_s))


def judge(card: Card, fr: Frames, reach_s: float, slack_s: float) -> Verdict | None:
    """Score the offsets the times vote for; None when nothing can be judged (no timed image or exposure)."""
    ti = card.timed
    xe = fr.x[fr.eligible]
    if not len(ti) or not len(xe):
        return None
    pick = ti[np.linspace(0, len(ti) - 1, min(len(ti), MAX_VOTE_IMAGES)).round().astype(np.int64)]
    mids = card.c[pick] + card.r[pick] / 2.0
    votes = (mids[:, None] - xe[None, :]).ravel()
    # Bins as fine as the finest EXIF times need (three points per bin, each within the tolerance of
    # any offset in it): a card of 10 ms times beside one of 1 s times must not lose its exact offset.
    r_min = float(card.r[ti].min())
    q = max(2.0 * float(np.median(fr.tol)) + 2.0 * slack_s, r_min / 2.0, 0.01)
    bins, counts = np.unique(np.floor(votes / q), return_counts=True)
    top = bins[np.argsort(-counts, kind="stable")[:MAX_OFFSETS]]
    # three points per bin: the optimum may lie anywhere in a bin of 1 s EXIF times
    offsets = np.concatenate([(top + f) * q for f in (0.2, 0.5, 0.8)])
    # An offset that fits every image of coarse times may only do so over a few hundredths of a second (an
    # image stamped 26 s for an exposure at 27.0005 s beside one stamped 26 s at 26.0005 s): three points in a
    # 0.5 s bin miss it, and a shifted offset that fits more loosely was decided without its rival (6 and 9
    # wrong pairs, property tests). The bins most voted for are also scanned at the tolerance's spacing: a fit
    # as wide as the tolerance is always sampled, and one narrower is sampled within a contradiction or two
    # of it (which OFFSET_MARGIN counts as a rival). They only add rivals: the best, and whether the card holds
    # the log at all, stay those of the three points per bin.
    coarse = len(offsets)
    spacing = float(np.median(fr.tol)) + slack_s
    n_fine = math.ceil(q / spacing) if spacing > 0 else 0
    if n_fine > 3:
        steps = (np.arange(n_fine) + 0.5) / n_fine
        offsets = np.concatenate([offsets, ((top[:FINE_BINS, None] + steps[None, :]) * q).ravel()])
    score, overlap = _scores(card, fr, offsets, slack_s)
    # Only offsets under which the log and the card overlap at all can be judged (an exposure paired).
    useful = overlap > 0
    if not useful[:coarse].any():
        return None
    is_coarse = np.arange(len(offsets)) < coarse
    offsets, score, overlap, is_coarse = offsets[useful], score[useful], overlap[useful], is_coarse[useful]
    order = np.lexsort((-overlap, score))
    first = int(next(k for k in order if is_coarse[k]))
    best = OffsetScore(float(offsets[first]), float(score[first]), int(overlap[first]))
    order = np.array([first] + [int(k) for k in order if k != first])
    rivals: list[OffsetScore] = []
    seen = [best.offset_s]
    for k in order[1:]:
        if score[k] > best.contradictions + OFFSET_MARGIN - 1e-9:
            break
        o = float(offsets[k])
        if all(abs(o - s) > reach_s for s in seen):
            seen.append(o)
            rivals.append(OffsetScore(o, float(score[k]), int(overlap[k])))
    return Verdict(best, rivals, len(xe))
