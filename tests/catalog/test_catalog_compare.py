"""`icgt compare`: the repeat-inspection scenario pair (tests/catalog/synth_compare.py) end to end against truth:
logs written by the project's recorder, `icgt catalog add` with the card and detections (the damage map), then
the comparison read back from its GeoJSON and image."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import synth_compare as sc
from conftest import SynthFlight
from PIL import Image

from icgt.catalog import CatalogError
from icgt.catalog.cli import add_flight
from icgt.catalog.compare import Alignment, classify, compare
from icgt.cli import main

BEFORE_ID, AFTER_ID = "1234567-00002025", "1234567-00002026"


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("cmp")
    cat = root / "cat"
    for insp in (sc.BEFORE, sc.AFTER):
        log, card, det = sc.write_inspection(root / insp.which, insp)
        add_flight(cat, log, "pier-7", images=card, detections=[det])
    return cat


def _truth_of(line: list[list[float]], which: str) -> sc.Crack:
    """The truth crack nearest to a defect's polyline on the before flight's face (whose GPS bias is zero, so
    its face coordinates are the true face's east and up, offset by the face origin)."""
    mid = np.mean(np.asarray(line), axis=0)

    def dist(c: sc.Crack) -> float:
        ref = c.before if which == "before" else c.after
        return math.inf if ref is None else float(np.linalg.norm(np.mean(np.asarray(ref), axis=0) - mid))

    return min(sc.CRACKS, key=dist)


def test_the_scenario_pair_is_classified_right_with_growth_and_alignment_against_truth(
    pair: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    code = main(["compare", "--structure", "pier-7", "--before", BEFORE_ID, "--after", AFTER_ID,
                 "--catalog", str(pair), "--out", str(out)])  # fmt: skip
    printed = capsys.readouterr().out
    assert code == 0 and "alignment: shift s" in printed
    data = json.loads((out / "compare.geojson").read_text())
    frame = data["icgt_face_frame"]
    origin = np.asarray(frame["origin_enu_m"])[[0, 2]]  # the face's s is east and t is up here
    assert frame["s_axis_enu"] == [1.0, 0.0, -0.0] or frame["s_axis_enu"] == [1.0, 0.0, 0.0]
    found: dict[str, dict[str, object]] = {}
    for feat in data["features"]:
        p = feat["properties"]
        which = "after" if p["after_id"] is not None else "before"
        line = (np.asarray(feat["geometry"]["coordinates"]) + origin).tolist()
        crack = _truth_of(line, which)
        assert crack.name not in found, (crack.name, p)
        found[crack.name] = p
    assert {n: p["change"] for n, p in found.items()} == {c.name: c.truth for c in sc.CRACKS}
    growth_err = []
    for c in sc.CRACKS:
        p = found[c.name]
        if c.truth in ("grown", "unchanged"):
            true = sc.Crack.length_mm(c.after) - sc.Crack.length_mm(c.before)
            got = p["length_change_mm"]
            assert isinstance(got, float) and abs(got - true) <= 3 * p["length_change_sigma_mm"], (c.name, got, true)
            if c.truth == "grown":
                growth_err.append(abs(got - true))
    assert len(growth_err) == 3 and float(np.percentile(growth_err, 95)) <= 2.0, growth_err
    assert found["new"]["seen_before"] is True
    al = data["icgt_comparison"]["alignment"]
    true_shift = np.asarray(sc.BEFORE.bias_m) - np.asarray(sc.AFTER.bias_m)  # after + shift = before
    err = np.asarray([al["shift_s_m"], al["shift_t_m"]]) - true_shift
    assert np.all(np.abs(err) <= np.maximum(3 * np.asarray([al["sigma_s_m"], al["sigma_t_m"]]), 1e-3)), (al, err)
    assert np.all(np.abs(err) < 0.005) and al["defects_used"] == 4
    assert data["icgt_comparison"]["counts"] == {"new": 1, "grown": 3, "unchanged": 1, "repaired": 1, "not_seen": 1}
    with Image.open(out / "compare.png") as img:
        assert img.format == "PNG" and img.size[0] > img.size[1] > 200


def test_without_the_alignment_the_shifted_flight_would_not_match(pair: Path) -> None:
    """The residual alignment does the work: without it (a zero shift) the 0.37 m between the two flights' GPS
    biases leaves every defect unmatched, so nothing would be called unchanged or grown."""
    cmp = compare(pair, "pier-7", before=BEFORE_ID, after=AFTER_ID)
    assert cmp.counts()["grown"] == 3
    none = Alignment(np.zeros(2), np.eye(2) * 1e-8, 0, math.nan)
    changes = classify(cmp.before, cmp.after, none)
    assert {c.change for c in changes} <= {"new", "repaired", "not_seen"}
    assert sum(c.change == "new" for c in changes) == len(cmp.after.defects)


def test_bad_comparisons_are_refused_in_one_line(
    pair: Path, flight_b: SynthFlight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import shutil

    cat = tmp_path / "cat"
    shutil.copytree(pair, cat)
    add_flight(cat, flight_b.log, "pier-7", images=flight_b.card, detections=[flight_b.detections])  # 200 m away
    add_flight(cat, flight_b.log, "pier-9", images=flight_b.card)  # no detections
    base = ["compare", "--catalog", str(cat), "--out", str(tmp_path / "o")]
    cases = [
        (["--structure", "pier-7", "--before", BEFORE_ID, "--after", BEFORE_ID], "the same flight"),
        (["--structure", "pier-7", "--before", BEFORE_ID, "--after", "nope"], f"its flights: {BEFORE_ID}, {AFTER_ID}"),
        (["--structure", "pier-7", "--before", BEFORE_ID, "--after", "7654321-0badcafe"], "not the same face"),
        (["--structure", "pier-9", "--before", "7654321-0badcafe", "--after", BEFORE_ID], "without --detections"),
        (["--structure", "../x", "--before", BEFORE_ID, "--after", AFTER_ID], "structure name"),
    ]
    for extra, pattern in cases:
        code = main([*base, *extra])
        err = [ln for ln in capsys.readouterr().err.splitlines() if " INFO " not in ln]
        assert code != 0 and len(err) == 1 and err[0].startswith("icgt: ") and pattern in err[0], (extra, err)
    assert not (tmp_path / "o").exists()
    with pytest.raises(CatalogError, match="no such catalogue"):
        compare(tmp_path / "missing", "pier-7", before=BEFORE_ID, after=AFTER_ID)
