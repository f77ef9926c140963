"""`icgt report --compare`: the repeat-inspection scenario pair (tests/catalog/synth_compare.py) through
`icgt catalog add`, `icgt compare` and `icgt report`; the page's section is checked against the compare output it
was made from (every defect's change and numbers, the alignment, the image) and that output against the truth."""

from __future__ import annotations

import base64
import html
import json
import re
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
import synth_compare as sc
from conftest import SynthFlight

from icgt.catalog.cli import add_flight
from icgt.cli import main

BEFORE_ID, AFTER_ID = "1234567-00002025", "1234567-00002026"


@pytest.fixture(scope="module")
def compared(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The pair in a catalogue, compared by `icgt compare`: {before, after: log, out: the compare folder}."""
    root = tmp_path_factory.mktemp("rep")
    logs = {}
    for insp in (sc.BEFORE, sc.AFTER):
        log, card, det = sc.write_inspection(root / insp.which, insp)
        add_flight(root / "cat", log, "pier-7", images=card, detections=[det])
        logs[insp.which] = log
    out = root / "cmp"
    args = ["compare", "--structure", "pier-7", "--before", BEFORE_ID, "--after", AFTER_ID]
    assert main([*args, "--catalog", str(root / "cat"), "--out", str(out)]) == 0
    return {**logs, "out": out}


def _text(cell: str) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", cell)).strip()


def _section(page: str) -> tuple[str, list[list[str]], dict[str, str], str]:
    """(title, rows of the defect table, the facts table, the image's data URI) of the one repeat section."""
    titles = re.findall(r"<h2>(Repeat inspection: [^<]*)</h2>", page)
    assert len(titles) == 1, titles
    body = page.split(f"<h2>{titles[0]}</h2>", 1)[1].split("<h2>", 1)[0]
    table = re.search(r'<table class="repeat">(.*?)</table>', body, re.S)
    assert table is not None
    rows = [
        [_text(c) for c in re.findall(r"<td[^>]*>(.*?)</td>", r, re.S)]
        for r in re.findall(r'<tr class="repeat-defect">(.*?)</tr>', table.group(1), re.S)
    ]
    facts_table = re.search(r'<table class="summary">(.*?)</table>', body, re.S)
    assert facts_table is not None
    facts = {_text(k): _text(v) for k, v in re.findall(r"<th>(.*?)</th><td>(.*?)</td>", facts_table.group(1), re.S)}
    img = re.search(r'<img id="repeat-image"[^>]* src="([^"]+)"', body)
    return html.unescape(titles[0]), rows, facts, img.group(1) if img else ""


def _pm(v: Any, sigma: Any, digits: int) -> str:
    return "" if v is None else f"{v:+.{digits}f} ± {sigma:.{digits}f}"


def test_the_report_carries_the_comparison_as_icgt_compare_wrote_it(compared: dict[str, Path], tmp_path: Path) -> None:
    data = json.loads((compared["out"] / "compare.geojson").read_text())
    feats = [f["properties"] for f in data["features"]]
    # the compare output is right (tests/catalog/test_catalog_compare.py checks each crack); the page must show it
    assert Counter(p["change"] for p in feats) == Counter(c.truth for c in sc.CRACKS)
    page = tmp_path / "after.html"
    assert main(["report", str(compared["after"]), "--compare", str(compared["out"]), "--out", str(page)]) == 0
    title, rows, facts, img = _section(page.read_text(encoding="utf-8"))
    assert title == f"Repeat inspection: {BEFORE_ID} -> {AFTER_ID}"
    assert facts["structure"] == "pier-7" and facts["after"] == f"{AFTER_ID} (this recording)"
    assert facts["before"] == BEFORE_ID
    assert len(rows) == len(feats) == len(sc.CRACKS)
    for row, p in zip(rows, feats, strict=True):
        assert row[0] == p["change"] and row[1] == p["kind"]
        assert row[2] == (p["before_id"] or "-") and row[3] == (p["after_id"] or "-")
        assert row[6] == _pm(p["length_change_mm"], p["length_change_sigma_mm"], 1), (row, p)
        assert row[9] == _pm(p["width_change_mm"], p["width_change_sigma_mm"], 3), (row, p)
        if p["change"] in ("grown", "unchanged"):
            assert row[4] == f"{p['length_before_mm']:.1f}" and row[5] == f"{p['length_after_mm']:.1f}"
            assert row[6] and row[9]  # a matched defect has both changes
        if p["change"] == "new":
            assert row[12] == ("yes" if p["seen_before"] else "no") and row[2] == "-"
    al = data["icgt_comparison"]["alignment"]
    want = (
        f"s {al['shift_s_m'] * 1000:+.1f} ± {al['sigma_s_m'] * 1000:.1f} mm, "
        f"t {al['shift_t_m'] * 1000:+.1f} ± {al['sigma_t_m'] * 1000:.1f} mm"
    )
    assert facts["alignment"].startswith(want) and f"from {al['defects_used']} defects" in facts["alignment"]
    counts = data["icgt_comparison"]["counts"]
    assert facts["defects"] == ", ".join(f"{k} {n}" for k, n in counts.items())
    prefix = "data:image/png;base64,"
    assert (
        img.startswith(prefix)
        and base64.b64decode(img[len(prefix) :]) == (compared["out"] / "compare.png").read_bytes()
    )


def test_the_before_flights_report_names_it_and_the_geojson_alone_works(
    compared: dict[str, Path], tmp_path: Path
) -> None:
    page = tmp_path / "before.html"
    geojson = compared["out"] / "compare.geojson"
    assert main(["report", str(compared["before"]), "--compare", str(geojson), "--out", str(page)]) == 0
    _title, rows, facts, img = _section(page.read_text(encoding="utf-8"))
    assert facts["before"] == f"{BEFORE_ID} (this recording)" and facts["after"] == AFTER_ID
    assert len(rows) == len(sc.CRACKS) and img.startswith("data:image/png;base64,")
    plain = tmp_path / "plain.html"  # without --compare: no such section
    assert main(["report", str(compared["before"]), "--out", str(plain)]) == 0
    assert "Repeat inspection" not in plain.read_text(encoding="utf-8")


def test_a_comparison_of_other_flights_or_a_bad_one_is_refused_in_one_line(
    compared: dict[str, Path], flight_a: SynthFlight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    not_compare = tmp_path / "other.geojson"
    not_compare.write_text(json.dumps({"type": "FeatureCollection", "features": []}))
    broken = tmp_path / "broken" / "compare.geojson"
    broken.parent.mkdir()
    broken.write_text("{")
    page = tmp_path / "r.html"
    cases = [
        (flight_a.log, compared["out"], f"compares {BEFORE_ID} -> {AFTER_ID} (pier-7); this recording is flight "),
        (compared["after"], tmp_path / "missing", "no such file or folder"),
        (compared["after"], not_compare, "not an `icgt compare` output"),
        (compared["after"], broken.parent, "is not JSON"),
    ]
    for log, where, pattern in cases:
        code = main(["report", str(log), "--compare", str(where), "--out", str(page)])
        err = [ln for ln in capsys.readouterr().err.splitlines() if " INFO " not in ln]
        assert code != 0 and len(err) == 1 and err[0].startswith("icgt: ") and pattern in err[0], (where, err)
        assert not page.exists()
