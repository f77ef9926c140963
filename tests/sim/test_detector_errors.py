"""The detector error model's statistics: the realised per-image precision and recall are what was asked.

Synthetic images (no flight): each has three true crack detections and a look-alike in view; the
model is applied and its realised recall (true detections with a reported piece) and precision (true
reports among all reports) must lie within 3 sigma of the asked figures: binomial for the recall,
and for the precision the spread of the false-positive count (binomial look-alikes + Poisson random
ones). Two different models, so a model that ignored its parameters would fail one of them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from icgt.sim.detector import SimDetection
from icgt.sim.detector_errors import LOOKALIKE, RANDOM, ErrorModel, apply_errors

SIZE = (600, 400)


def _images(n: int, rng: np.random.Generator) -> list[tuple[str, list[SimDetection], list[SimDetection]]]:
    out = []
    for k in range(n):
        name = f"DSC{k + 1:05d}.JPG"
        trues = []
        for j in range(3):
            a = rng.uniform([50, 50], [300, 200])
            b = a + rng.uniform([60, -40], [250, 150])
            pts = np.linspace(a, b, 20)
            trues.append(SimDetection(name, "crack", f"C{j}", pts, 1.5))
        look = SimDetection(name, "crack", LOOKALIKE + "J1", np.array([[0.0, 300.0], [599.0, 300.0]]), 2.0)
        out.append((name, trues, [look]))
    return out


@pytest.mark.parametrize("model", [ErrorModel(), ErrorModel(precision=0.6, recall=0.7, lookalike_rate=0.1)])
def test_realised_precision_and_recall_are_the_asked_ones(model: ErrorModel) -> None:
    rng = np.random.default_rng(35)
    images = _images(2000, rng)
    dets, rep = apply_errors(images, SIZE, model, np.random.default_rng(7))
    n = rep.true_detections
    assert n == 6000
    assert abs(rep.recall - model.recall) <= 3.0 * math.sqrt(model.recall * (1 - model.recall) / n), rep
    t = rep.true_reports
    f = rep.lookalike_reports + rep.random_reports
    var_f = rep.lookalikes_visible * model.lookalike_rate * (1 - model.lookalike_rate) + rep.random_reports
    margin = 3.0 * math.sqrt(var_f) * t / (t + f) ** 2
    assert abs(rep.precision - model.precision) <= margin, (rep.precision, margin, rep)
    # both kinds of false positive occur, and the report counts match the detections returned
    assert rep.lookalike_reports > 0 and rep.random_reports > 0
    assert sum(d.defect_id == RANDOM for d in dets) == rep.random_reports
    assert sum(d.defect_id.startswith(LOOKALIKE) for d in dets) == rep.lookalike_reports
    assert len(dets) == t + f


def test_cracks_come_in_pieces_with_noisy_ends_and_widths() -> None:
    images = _images(500, np.random.default_rng(1))
    dets, rep = apply_errors(images, SIZE, ErrorModel(), np.random.default_rng(2))
    true = [d for d in dets if d.defect_id.startswith("C")]
    assert rep.true_reports > rep.found * 1.2  # broken into pieces
    widths = np.array([d.width_px for d in true], dtype=float)
    assert 0.15 < float(np.std(np.log(widths / 1.5))) < 0.5  # the truth was 1.5 px everywhere
    # every piece lies on its crack (pieces of the true line, ends moved along it only)
    by = {(name, d.defect_id): d for name, ts, _ in images for d in ts}
    k = 0
    for name, ts, _ in images:
        for d in ts:
            assert (name, d.defect_id) in by
            k += 1
    assert k == rep.true_detections
    for d in true[:200]:
        src = by[(d.image, d.defect_id)].points_px
        a, b = src[0], src[-1]
        u = (b - a) / np.linalg.norm(b - a)
        off = (d.points_px - a) @ np.array([-u[1], u[0]])
        assert np.abs(off).max() < 1e-6
