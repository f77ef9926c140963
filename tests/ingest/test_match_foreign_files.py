"""Another device's file among the camera's images (a phone photo, a copy, a file with its metadata stripped).

A card with one image more than the exposures is expected; where in the run the extra one sits decides what
can be said. Found on real cards (issue 33): with 10 ms EXIF times a file without EXIF time made its timed
neighbours ambiguous, though their times single them out; and with 1 s EXIF times a file whose time fell
among the camera's shifted a run of pairs by one exposure (the offset scan's lower bound counted exposures
as only one window's where windows overlapped, so the rival alignment was never costed).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from synthetic_cards import capture, with_foreign_file

from icgt.ingest.match import match_times

FLIGHT = {"seed": 1, "dt": 0.2, "res": 0.01, "offset": 3600.0, "drift": 0.0, "wired": True, "passes": 1,
          "shots": 60, "pause": 5.0, "jitter": 0.002, "p_miss": 0.0, "p_manual": 0.0, "p_untimed": 0.0,
          "test_shot": False}  # fmt: skip
FOREIGN = Path("FOREIGN_0001.JPG")


def _card(seed: int, res: float, after_s: float | None) -> tuple[Any, Any, dict[Path, int | None]]:
    frames, images, truth = capture({**FLIGHT, "seed": seed, "res": res})
    images, truth = with_foreign_file(images, truth, (20 + seed) / len(images), after_s)
    return frames, images, truth


@pytest.mark.parametrize("seed", range(8))
def test_a_file_without_time_leaves_its_timed_neighbours_paired(seed: int) -> None:
    frames, images, truth = _card(seed, 0.01, None)
    result = match_times(frames, images)
    assert not [p for p in result.pairs if truth[p.image] != p.frame.frame_seq]
    assert len(result.pairs) == len(frames) and not result.ambiguous, [a.image.name for a in result.ambiguous]
    (left,) = result.unmatched_images
    assert left.image == FOREIGN and left.reason == "no_exif_time"


@pytest.mark.parametrize("res", [1.0, 0.01])
@pytest.mark.parametrize("after_s", [0.1, 0.45])
def test_a_file_whose_time_falls_among_the_cameras_never_shifts_the_pairs(res: float, after_s: float) -> None:
    """With 1 s times the images of that second (and the run whose offset the extra one leaves open) are not
    paired; never one wrongly."""
    for seed in range(12):
        frames, images, truth = _card(seed, res, after_s)
        result = match_times(frames, images)
        wrong = [(p.image.name, p.frame.frame_seq, truth[p.image]) for p in result.pairs
                 if truth[p.image] != p.frame.frame_seq]  # fmt: skip
        assert not wrong, (seed, wrong[:5])
        if res == 0.01:  # centisecond times single out every camera image: only the foreign file is left
            assert len(result.pairs) == len(frames), (seed, [a.image.name for a in result.ambiguous])
