"""Multi-view consensus: is a merged defect confirmed by the images that could have seen it?

A crack detector reports a real defect in an image that shows it with its per-image recall r (about
0.85 for published detectors); it also reports things that are not defects. Of those, the random
ones (texture, noise) sit at a place no other image reports, so a defect seen in a single image is
doubtful however good the detector. The physical look-alikes (formwork joints, stains, shadows) are
on the face: every image that sees one may report it at the same place, so *that several images agree*
proves nothing. What separates them is *how often*: the detector reports a look-alike in a view with
a probability q well below r (it was trained to tell them apart, imperfectly; q about 0.25 is assumed).
Over n images that could see the spot, the number k that reported it is Binomial(n, r) for a defect
and Binomial(n, q) for a look-alike; the likelihood ratio of the two passes 1 where

    k / n >= f* = ln((1 - q) / (1 - r)) / (ln(r / q) + ln((1 - q) / (1 - r)))

(0.57 for r = 0.85, q = 0.25). A merged defect is **confirmed** when k >= 2 and k / n >= f*; else it
is **doubtful** and says why (k of n). With n = 10 views the two errors are then each about 1 %
(P[Bin(10, 0.85) < 6] = 0.010 and P[Bin(10, 0.25) >= 6] = 0.020); fewer views give less certainty,
which k and n, carried by every defect, let a reader judge.

"Could have seen it": the image's footprint on the surface (its four corners through the image's
own pose and range), shrunk by `margin_m`, holds at least half of the defect, or (for a crack) at
least `min_visible_m` of it; an image that reported it counts as one that could, whatever its
footprint says.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import shapely

CONFIRMED = "confirmed"
DOUBTFUL = "doubtful"


@dataclass(frozen=True)
class Consensus:
    """The detector's per-image rates that the rule assumes (module docstring)."""

    recall: float = 0.85
    lookalike_rate: float = 0.25
    min_seen: int = 2
    margin_m: float = 0.01
    min_visible_m: float = 0.10

    @property
    def threshold(self) -> float:
        r, q = self.recall, self.lookalike_rate
        if not 0.0 < q < r < 1.0:
            raise ValueError(f"consensus needs 0 < look-alike rate {q} < recall {r} < 1")
        a = math.log((1.0 - q) / (1.0 - r))
        return a / (math.log(r / q) + a)

    def status(self, seen: int, could: int) -> str:
        return CONFIRMED if seen >= self.min_seen and seen >= self.threshold * could - 1e-9 else DOUBTFUL


@dataclass(frozen=True)
class View:
    """One image's footprint on the face (face coordinates [m])."""

    image: str
    footprint: shapely.Polygon


def could_see(geom: shapely.Geometry, views: Sequence[View], rule: Consensus) -> set[str]:
    """The images whose footprint shows the defect (module docstring)."""
    out = set()
    for v in views:
        fp = v.footprint.buffer(-rule.margin_m)
        if fp.is_empty or not fp.intersects(geom):
            continue
        if isinstance(geom, shapely.LineString):
            inside = fp.intersection(geom).length
            if inside >= min(0.5 * geom.length, rule.min_visible_m):
                out.add(v.image)
        elif fp.intersection(geom).area >= 0.5 * geom.area:
            out.add(v.image)
    return out
