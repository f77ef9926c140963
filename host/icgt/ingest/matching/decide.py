"""One image's decision from the costs of the best alignments pairing it each way or leaving it out."""

from __future__ import annotations

import math

from icgt.ingest.matching.results import IMAGE_EXTRA
from icgt.ingest.matching.state import Card, Outcome


def decide(
    card: Card, i: int, with_pair: dict[int, float], with_skip: float, mine: int | None, limit: float, out: Outcome
) -> None:
    """Pair image i as the optimum does only if no alignment within the margin does otherwise."""
    alts = [v for j, v in with_pair.items() if j != mine]
    if mine is not None:
        alts.append(with_skip)
    alt = min(alts, default=math.inf)
    near = sorted(j for j, v in with_pair.items() if v <= limit)
    if alt > limit:
        if mine is not None:
            out.pairs[i] = mine
        else:
            out.extra[i] = IMAGE_EXTRA
        return
    if mine is None and not near:
        out.extra[i] = IMAGE_EXTRA
        return
    if not card.has_time(i):
        why = "no EXIF time and the order does not single out one exposure"
    elif with_skip <= limit:
        why = "its EXIF time fits these exposures and the counts do not say which image is the extra one"
    else:
        why = "its EXIF time fits several exposures and the order does not decide"
    out.ambiguous[i] = (near, why)
    out.frame_ambiguous.update(near)
