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

from dataclasses import dataclass

import numpy as np

from icgt.ingest.matching.state import Card, FloatArray, Frames

OFFSET_MARGIN = 2.0
"""Contradictions (a triggered exposure without an image: 1, an image inside the log without an exposure:
EXTRA_IMAGE_WEIGHT) by which an offset must beat every offset outside its neighbourhood to be accepted."""
EXTRA_IMAGE_WEIGHT = 1.0
"""An image inside the log's span without an exposure, against a triggered exposure without an image."""
MAX_VOTE_IMAGES = 400
"""Images whose times vote for offsets (evenly spread over the card); every eligible exposure votes with each."""
MAX_OFFSETS = 1500
"""Offsets scored, the most voted for."""


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

    @property
    def decided(self) -> bool:
        return not self.rivals

    def admits(self, offset_s: float, reach_s: float) -> bool:
        """Is `offset_s` in the neighbourhood of the accepted offset?"""
        return abs(offset_s - self.best.offset_s) <= reach_s

    def note(self) -> str:
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


def contradictions(card: Card, fr: Frames, offsets: FloatArray, slack_s: float) -> tuple[FloatArray, FloatArray]:
    """Per offset (drift 0, windows padded by `slack_s` more): contradictions and exposures paired."""
    lo, hi, hi_run = _windows(card)
    xe = fr.x[fr.eligible]
    tol = float(np.median(fr.tol)) + slack_s
    out_c = np.zeros(len(offsets))
    out_n = np.zeros(len(offsets))
    if not len(xe) or not len(lo):
        return out_c + float(len(xe)), out_n
    for k in range(0, len(offsets), 64):
        o = offsets[k : k + 64, None]
        p = xe[None, :] + o  # the exposures on the camera's clock
        fits = _fits(lo, hi_run, p, tol)
        missing = (~fits).sum(axis=1)
        # an image fits an exposure if one lies in its window; only images inside the log's span count
        pe = np.sort(p, axis=1)
        # one search for all rows: row r's values and queries lifted by r * lift keep the rows apart
        lift = float(max(pe.max(), hi.max()) - min(pe.min(), lo.min()) + 4.0 * tol + 1.0)
        rows = np.arange(pe.shape[0])[:, None] * lift
        flat = np.searchsorted((pe + rows).ravel(), ((lo[None, :] - tol) + rows).ravel(), side="left")
        a = flat.reshape(pe.shape[0], len(lo)) - np.arange(pe.shape[0])[:, None] * pe.shape[1]
        has = (a < pe.shape[1]) & (np.take_along_axis(pe, np.minimum(a, pe.shape[1] - 1), axis=1) <= hi[None, :] + tol)
        inside = (hi[None, :] >= pe[:, :1] - tol) & (lo[None, :] <= pe[:, -1:] + tol)
        extra = (inside & ~has).sum(axis=1) * EXTRA_IMAGE_WEIGHT
        out_c[k : k + 64] = missing + extra
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
    for k in range(0, len(offsets), 256):
        p = xe[None, :] + offsets[k : k + 256, None]
        idx = np.searchsorted(lo, p + tol, side="right") - 1
        out[k : k + 256] = (~((idx >= 0) & (hi_run[np.maximum(idx, 0)] >= p - tol))).sum(axis=1)
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
    score, overlap = _scores(card, fr, offsets, slack_s)
    # Only offsets under which the log and the card overlap at all can be judged (an exposure paired).
    useful = overlap > 0
    if not useful.any():
        return None
    offsets, score, overlap = offsets[useful], score[useful], overlap[useful]
    order = np.lexsort((-overlap, score))
    best = OffsetScore(float(offsets[order[0]]), float(score[order[0]]), int(overlap[order[0]]))
    rivals: list[OffsetScore] = []
    seen = [best.offset_s]
    for k in order[1:]:
        if score[k] > best.contradictions + OFFSET_MARGIN - 1e-9:
            break
        o = float(offsets[k])
        if all(abs(o - s) > reach_s for s in seen):
            seen.append(o)
            rivals.append(OffsetScore(o, float(score[k]), int(overlap[k])))
    return Verdict(best, rivals)
