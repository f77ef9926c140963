"""`icgt export`'s exit status and problems.csv for a card that holds a file it does not read (issue 33).

An uppercase `.PNG` next to the camera's JPEGs (a screenshot copied to the card) is named in problems.csv
as a warning; warnings alone exit 0 (said on stderr and in problems.csv), `--strict` makes them exit 1.
Through the real command on the shared export flight (tests/conftest.py `export_flight`).
"""

from __future__ import annotations

import csv
import logging
import shutil
from pathlib import Path
from typing import Any

import pytest
from export_exit import expected_export_exit
from PIL import Image

from icgt.cli import main


@pytest.fixture(scope="module")
def card(export_flight: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    card = tmp_path_factory.mktemp("card_png") / "DCIM"
    shutil.copytree(export_flight.card, card)
    Image.new("RGB", (40, 30), (200, 10, 10)).save(card / "SCREEN01.PNG", format="PNG")
    return card


def _problems(out: Path) -> list[dict[str, str]]:
    with (out / "problems.csv").open(newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.parametrize("strict", [False, True])
def test_warnings_exit_0_and_strict_makes_them_fail(
    export_flight: Any, card: Path, tmp_path: Path, strict: bool, caplog: pytest.LogCaptureFixture
) -> None:
    args = ["export", str(export_flight.mcap), "--images", str(card), "--out", str(tmp_path),
            "--formats", "csv", "--no-progress", *(["--strict"] if strict else [])]  # fmt: skip
    with caplog.at_level(logging.WARNING):
        code = main(args)
    rows = _problems(tmp_path)
    png = [r for r in rows if r["image"] == "SCREEN01.PNG"]
    assert [(r["severity"], r["code"]) for r in png] == [("warning", "image_not_supported")]
    assert "SCREEN01.PNG" in png[0]["detail"] and ".PNG" in png[0]["detail"]
    said = [r.getMessage() for r in caplog.records if "SCREEN01.PNG" in r.getMessage()]
    assert said and said[0].startswith("warning: SCREEN01.PNG: image_not_supported")  # on stderr too
    assert code == expected_export_exit(tmp_path, strict=strict)
    assert code == (1 if strict else 0)
