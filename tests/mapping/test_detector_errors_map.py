"""The damage map from a detector that errs: merged precision and recall hold, look-alikes are not confirmed.

The projected detections of the test flight go through the error model (icgt.sim.detector_errors:
per-image precision 0.8, recall 0.85, cracks in pieces, missed stretches, end and width noise,
random false positives, and the stains and formwork joint painted on the face reported now and then).
`icgt map` merges them with multi-view consensus; only confirmed defects count. Checked: every true
defect is confirmed once and nothing else is (precision and recall 1 here, >= 0.95 asked), crack
lengths within 5 % (p95), positions within the geotag p95 + the LiDAR's range noise (p95), every
defect carries how many images saw it and could have; on the same flight over a face with only the
stains and the joint, nothing is confirmed. Deterministic: fixed seeds, the session's flight.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import shapely

from icgt.mapping.cli import MapResult, run_map
from icgt.mapping.consensus import CONFIRMED, DOUBTFUL, Consensus
from icgt.mapping.model import CRACK, midpoint
from icgt.mapping.place import Errors
from icgt.sim.detector import write_polylines
from icgt.sim.detector_errors import detect_with_errors
from icgt.sim.map_truth import MappedItem, compare, geotag_errors_m, load_truth, p50_p95

from .conftest import LOOKAHEAD_S, DamageFlight, with_lookalikes

ERRORS = Errors(position_m=0.015)


def _map(df: DamageFlight, out: Path, *, defects: bool, seed: int) -> MapResult:
    sc = with_lookalikes(df.scenario, defects=defects)
    dets, rep = detect_with_errors(sc, df.exposures, seed=seed)
    if defects:
        assert rep.lookalike_reports > 0 and rep.random_reports > 0 and rep.found < rep.true_detections
    out.mkdir(parents=True)
    write_polylines(out / "dets.json", dets)
    return run_map(
        df.flight.mcap, df.flight.card, [out / "dets.json"], out / "map", calibration=df.calibration, errors=ERRORS,
        mm_per_px=None, lookahead_s=LOOKAHEAD_S,
    )  # fmt: skip


def _items(res: MapResult) -> list[MappedItem]:
    out = []
    for inst in res.instances:
        if inst.status != CONFIRMED:
            continue
        mid = (
            midpoint(inst.enu)
            if inst.kind == CRACK
            else res.session.face.to_enu(np.asarray(shapely.Polygon(inst.face).centroid.coords[0]))
        )
        out.append(MappedItem(inst.kind, mid, inst.length_mm, inst.area_mm2))
    return out


@pytest.mark.parametrize("seed", [7, 5])
def test_merged_defects_hold_against_a_detector_that_errs(
    damage_flight: DamageFlight, tmp_path: Path, seed: int
) -> None:
    res = _map(damage_flight, tmp_path / "err", defects=True, seed=seed)
    truth = load_truth(damage_flight.truth, res.session.origin)
    cmp = compare(truth, _items(res))
    precision = cmp.matched / max(cmp.reported, 1)
    recall = cmp.matched / cmp.truth
    assert precision >= 0.95 and recall >= 0.95, (cmp.reported, cmp.false, cmp.duplicates, cmp.missed)
    # the merge had work to do: many more reports than defects, most of them left doubtful
    doubtful = [i for i in res.instances if i.status == DOUBTFUL]
    assert len(doubtful) >= 5
    assert all(i.n_seen < 2 or i.n_seen < Consensus().threshold * i.n_could for i in doubtful)
    for inst in res.instances:
        assert 1 <= inst.n_seen <= inst.n_could, inst.id
        if inst.status == CONFIRMED:
            assert inst.n_seen >= 2
    assert p50_p95(cmp.length_err_pct)[1] <= 5.0, cmp.length_err_pct
    geotag = geotag_errors_m(res.session.frames, damage_flight.flight.truth_exposures, damage_flight.scenario,
                             res.session.origin)  # fmt: skip
    bound_mm = (float(np.percentile(geotag, 95)) + 0.025) * 1000.0
    assert p50_p95(cmp.position_err_mm)[1] <= bound_mm, (cmp.position_err_mm, bound_mm)
    # widths fused with their spread: the model scatters each image's width by ~25 %
    for t in truth:
        if t.width_mm is not None:
            (k,) = cmp.assignment[t.id]
            conf = [i for i in res.instances if i.status == CONFIRMED]
            inst = conf[k]
            assert inst.width_mm is not None and inst.width_spread_mm is not None
            assert 0.0 < inst.width_spread_mm < inst.width_mm


def test_a_face_with_only_stains_and_a_joint_has_no_confirmed_defect(
    damage_flight: DamageFlight, tmp_path: Path
) -> None:
    res = _map(damage_flight, tmp_path / "bare", defects=False, seed=7)
    assert res.instances, "the look-alikes were reported in some images"
    assert [i.id for i in res.instances if i.status == CONFIRMED] == []
    assert max(i.n_seen for i in res.instances) >= 3  # seen consistently by several images, still rejected


def test_the_consensus_threshold_follows_from_the_detector_rates() -> None:
    c = Consensus()
    r, q = c.recall, c.lookalike_rate
    f = c.threshold
    # at f the binomial likelihoods of "defect" and "look-alike" are equal
    assert math.isclose(f * math.log(r / q) + (1 - f) * math.log((1 - r) / (1 - q)), 0.0, abs_tol=1e-12)
    assert 0.5 < f < 0.6
    assert c.status(1, 1) == DOUBTFUL  # one image proves nothing
    assert c.status(6, 10) == CONFIRMED and c.status(5, 10) == DOUBTFUL
    assert c.status(2, 3) == CONFIRMED and c.status(3, 12) == DOUBTFUL
    with pytest.raises(ValueError):
        _ = Consensus(recall=0.3, lookalike_rate=0.4).threshold
