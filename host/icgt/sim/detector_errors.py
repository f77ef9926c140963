"""A crack detector's errors, applied to the projected detections of icgt.sim.detector.

The projected detector reports every visible defect exactly (the true pose, 0.3 px noise). A real one
(YOLO-seg, U-Net / DeepCrack-style segmenters) does not: the crack-detection literature reports, per
image and per instance on held-out concrete images, precisions around 0.8 and recalls around 0.85
(the usual figures of merit in those papers' result tables; the defaults below). This module makes
the projected detections behave so, per image:

- **misses**: each true detection is dropped with probability 1 - recall;
- **missed segments**: a kept crack loses a stretch of 5-20 % of its length at a random place (with
  probability `gap_rate`): an end is shortened, or the crack comes out in two pieces;
- **fragments**: a kept crack is broken at one or two places with a small gap (`fragment_rate`);
- **endpoint noise**: each end not at the image border moves along the crack by N(0, `end_px`);
- **width noise**: the width is scaled by exp(N(0, `width_log_sigma`)) plus N(0, `width_px`) pixels;
- **false positives** of two sorts, which matter differently to a map that merges views:
  *physical look-alikes* (the face's formwork joints reported as cracks, its stains and shadows as
  spalling: `Surface.joints`, `Surface.stains`) are on the face, so every image that sees one may
  report it at the same place: each visible look-alike is reported with probability `lookalike_rate`,
  independently per image; consensus across views cannot reject one of them by agreement alone,
  only by how *rarely* the images that could see it report it. *Random* false positives (texture,
  noise) land anywhere in one image: short crack-like polylines (and some blobs) at random places, as
  many per image (Poisson) as it takes for the pooled precision to come out at `precision`:

      E[random] = T * (1 - precision) / precision - L

  with T the true reports and L the look-alike reports made (pieces counted)
  over the set of images given (never below zero: when the look-alikes alone exceed the budget, the
  realised precision is below the target, as it is on a face with stains and no defect).

Recall and precision are per report: a true detection counts as found when at least one piece of it
is reported; a report is a true positive when it comes from a true defect (so a crack in two pieces
is two true positives). `ErrorReport` counts both so that a test can check the realised figures.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import msgspec
import numpy as np
import shapely

from icgt.geodesy import FloatArray
from icgt.sim.camera_card import file_name
from icgt.sim.detector import SimDetection, detect
from icgt.sim.scenario import Scenario
from icgt.sim.surface import CrackSpec, SpallSpec, Surface
from icgt.sim.truth import ExposureTruth

LOOKALIKE = "lookalike:"
"""defect_id prefix of a reported look-alike (the look-alike's id follows)."""
RANDOM = "random"
"""defect_id of a random false positive."""
MIN_PIECE_PX = 6.0
"""Pieces shorter than this are not reported (as icgt.sim.detector drops runs shorter than this)."""


@dataclass(frozen=True)
class ErrorModel:
    """A detector's error rates (module docstring); the defaults are the published order of magnitude."""

    precision: float = 0.80
    recall: float = 0.85
    lookalike_rate: float = 0.25
    """Probability that a visible look-alike is reported in one image."""
    gap_rate: float = 0.30
    fragment_rate: float = 0.25
    end_px: float = 1.5
    width_log_sigma: float = 0.25
    width_px: float = 0.3
    random_blob_share: float = 0.2
    """Share of the random false positives that are blobs (reported as spalling), the rest cracks."""


@dataclass
class ErrorReport:
    """What the model did, for checking its statistics."""

    true_detections: int = 0
    found: int = 0
    """True detections with at least one reported piece."""
    true_reports: int = 0
    lookalikes_visible: int = 0
    lookalike_reports: int = 0
    random_reports: int = 0

    @property
    def recall(self) -> float:
        return self.found / self.true_detections if self.true_detections else math.nan

    @property
    def precision(self) -> float:
        n = self.true_reports + self.lookalike_reports + self.random_reports
        return self.true_reports / n if n else math.nan


def lookalike_surface(surface: Surface) -> Surface:
    """The face's look-alikes as a detector mistakes them: joints as cracks, stains as spalled areas."""
    cracks = tuple(CrackSpec(LOOKALIKE + j.id, j.points_m, j.width_mm) for j in surface.joints)
    spalls = tuple(SpallSpec(LOOKALIKE + s.id, s.points_m) for s in surface.stains)
    return msgspec.structs.replace(surface, cracks=cracks, spalls=spalls, stains=(), joints=())


def _arc(points: FloatArray) -> FloatArray:
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(points, axis=0), axis=1))])


def _cut(points: FloatArray, s0: float, s1: float) -> FloatArray:
    """The piece of a polyline between arc lengths s0 < s1."""
    cum = _arc(points)
    inner = (cum > s0) & (cum < s1)
    a = np.array([np.interp(s0, cum, points[:, 0]), np.interp(s0, cum, points[:, 1])])
    b = np.array([np.interp(s1, cum, points[:, 0]), np.interp(s1, cum, points[:, 1])])
    return np.vstack([a, points[inner], b])


def _extend(points: FloatArray, start: float, end: float) -> FloatArray:
    """Lengthen (positive) or shorten (negative) a polyline at its start and end along its tangent."""
    p = points
    length = float(_arc(p)[-1])
    lo = max(0.0, -start)
    hi = length - max(0.0, -end)
    if hi - lo < 1e-6:
        return p[:1].copy()
    p = _cut(p, lo, hi)
    if start > 0:
        d = p[0] - p[1]
        p = np.vstack([p[0] + d / max(float(np.linalg.norm(d)), 1e-12) * start, p])
    if end > 0:
        d = p[-1] - p[-2]
        p = np.vstack([p, p[-1] + d / max(float(np.linalg.norm(d)), 1e-12) * end])
    return p


def _at_border(pt: FloatArray, size: tuple[int, int], margin: float = 1.5) -> bool:
    w, h = size
    return bool(pt[0] < margin or pt[1] < margin or pt[0] > w - 1 - margin or pt[1] > h - 1 - margin)


def _crack_pieces(
    d: SimDetection, model: ErrorModel, size: tuple[int, int], rng: np.random.Generator
) -> list[FloatArray]:
    w, h = size
    p = d.points_px
    # endpoint noise (an end at the image border stays there: the image cuts the crack)
    e0 = 0.0 if _at_border(p[0], size) else float(rng.normal(0.0, model.end_px))
    e1 = 0.0 if _at_border(p[-1], size) else float(rng.normal(0.0, model.end_px))
    p = np.clip(_extend(p, e0, e1), 0.0, [w - 1.0, h - 1.0])
    length = float(_arc(p)[-1])
    spans = [(0.0, length)]
    if rng.random() < model.gap_rate:
        g = rng.uniform(0.05, 0.20) * length
        a = rng.uniform(0.0, length - g)
        spans = [(0.0, a), (a + g, length)]
    if rng.random() < model.fragment_rate:
        for _ in range(int(rng.integers(1, 3))):
            k = int(np.argmax([b - a for a, b in spans]))
            a, b = spans[k]
            gap = rng.uniform(2.0, 4.0)
            if b - a < 3 * MIN_PIECE_PX:
                break
            c = rng.uniform(a + MIN_PIECE_PX, b - MIN_PIECE_PX - gap)
            spans[k : k + 1] = [(a, c), (c + gap, b)]
    return [_cut(p, a, b) for a, b in spans if b - a >= MIN_PIECE_PX]


def _random_fp(name: str, size: tuple[int, int], model: ErrorModel, rng: np.random.Generator) -> SimDetection:
    w, h = size
    c = rng.uniform([10.0, 10.0], [w - 11.0, h - 11.0])
    if rng.random() < model.random_blob_share:
        r = rng.uniform(4.0, 10.0)
        a = np.sort(rng.uniform(0, 2 * math.pi, 7))
        ring = c + np.stack([np.cos(a), np.sin(a)], axis=1) * r * rng.uniform(0.6, 1.0, (7, 1))
        return SimDetection(name, "spalling", RANDOM, np.clip(ring, 0.0, [w - 1.0, h - 1.0]), None)
    length = rng.uniform(15.0, 60.0)
    ang = rng.uniform(0, math.pi)
    bend = rng.normal(0.0, 0.3)
    s = np.linspace(-0.5, 0.5, 6)[:, None] * length
    d = np.array([math.cos(ang), math.sin(ang)])
    n = np.array([-d[1], d[0]])
    pts = c + s * d + (s**2 / length) * bend * n
    return SimDetection(name, "crack", RANDOM, np.clip(pts, 0.0, [w - 1.0, h - 1.0]), float(rng.uniform(1.0, 3.0)))


def apply_errors(
    truth_by_image: Sequence[tuple[str, Sequence[SimDetection], Sequence[SimDetection]]],
    size: tuple[int, int],
    model: ErrorModel,
    rng: np.random.Generator,
) -> tuple[list[SimDetection], ErrorReport]:
    """Per image (name, its true detections, its visible look-alikes as detections): what the detector reports."""
    rep = ErrorReport()
    out: list[SimDetection] = []
    for _name, trues, looks in truth_by_image:
        for d in trues:
            rep.true_detections += 1
            if rng.random() >= model.recall:
                continue
            pieces = _reported(d, size, model, rng)
            if pieces:
                rep.found += 1
                rep.true_reports += len(pieces)
                out += pieces
        for d in looks:
            rep.lookalikes_visible += 1
            if rng.random() < model.lookalike_rate:
                pieces = _reported(d, size, model, rng)
                rep.lookalike_reports += len(pieces)
                out += pieces
    # the random false positives fill the budget the true reports leave (module docstring)
    budget = rep.true_reports * (1.0 - model.precision) / model.precision
    lam = max(0.0, budget - rep.lookalike_reports) / max(len(truth_by_image), 1)
    for name, _, _ in truth_by_image:
        for _ in range(int(rng.poisson(lam))):
            out.append(_random_fp(name, size, model, rng))
            rep.random_reports += 1
    return out, rep


def _reported(
    d: SimDetection, size: tuple[int, int], model: ErrorModel, rng: np.random.Generator
) -> list[SimDetection]:
    w, h = size
    if d.kind != "crack":
        grow = float(rng.normal(0.0, 1.0))
        g = shapely.Polygon(d.points_px).buffer(grow, join_style="mitre")
        if g.is_empty or not isinstance(g, shapely.Polygon) or g.area < 9.0:
            return []
        ring = np.clip(np.asarray(g.exterior.coords)[:-1], 0.0, [w - 1.0, h - 1.0])
        return [replace(d, points_px=ring)]
    width = d.width_px or 1.0
    width = max(0.3, width * math.exp(rng.normal(0.0, model.width_log_sigma)) + rng.normal(0.0, model.width_px))
    return [replace(d, points_px=p, width_px=width) for p in _crack_pieces(d, model, size, rng)]


def detect_with_errors(
    scenario: Scenario,
    exposures: Sequence[ExposureTruth],
    *,
    model: ErrorModel = ErrorModel(),
    seed: int = 0,
) -> tuple[list[SimDetection], ErrorReport]:
    """icgt.sim.detector's projected detections of every exposure, with the model's errors (module docstring)."""
    from icgt.sim.render import render_size

    surface = scenario.surface
    assert surface is not None, "a scenario without [surface] has nothing to detect"
    rng = np.random.default_rng(seed)
    looks_sc = msgspec.structs.replace(scenario, surface=lookalike_surface(surface))
    per_image = []
    for e in sorted(exposures, key=lambda x: x.frame_number):
        name = file_name(scenario.camera.first_file_number + e.frame_number - 1)
        per_image.append((name, detect(scenario, e, rng), detect(looks_sc, e, rng)))
    return apply_errors(per_image, render_size(scenario, surface), model, rng)
