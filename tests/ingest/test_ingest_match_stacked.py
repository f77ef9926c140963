"""The stacked alignment DP (icgt.ingest.matching.batch) against the row-by-row one (align.solve_segment):
the same costs and the same decisions, dict order included, on random segments; and icgt match gives the
same result with the stacked DP as with the row-by-row DP alone, on a card where the stack is used."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from synthetic_cards import capture

from icgt.geotag import FrameRecord
from icgt.ingest.match import ImageTime, match_times
from icgt.ingest.matching import align, batch
from icgt.ingest.matching.state import Card, Frames, Outcome, Ranges

Seg = tuple[list[int], int, int]


@st.composite
def _cards(draw: st.DrawFn) -> tuple[Card, Frames, list[list[int]], Ranges, list[Seg]]:
    """Segments side by side: frames (some not eligible: skip 0), images with a window of frames (some
    reaching past their segment, some empty) or without a time (a frame range), costs 2 or 10."""
    skip: list[float] = []
    eligible: list[bool] = []
    cands: list[list[int]] = []
    has: list[bool] = []
    lo_r: list[int] = []
    hi_r: list[int] = []
    segs: list[Seg] = []
    for _ in range(draw(st.integers(1, 6))):
        q, p = draw(st.integers(1, 18)), draw(st.integers(2, 14))
        lo = len(skip)
        for _ in range(q):
            ok = draw(st.booleans()) or draw(st.booleans())
            eligible.append(ok)
            skip.append(draw(st.sampled_from([2.0, 10.0])) if ok else 0.0)
        imgs: list[int] = []
        centre = 0.0
        for _ in range(p):
            centre += draw(st.floats(0.0, 2.0))
            a = lo + min(q - 1, max(0, int(centre) + draw(st.integers(-3, 2))))
            b = min(lo + q - 1, a + draw(st.integers(0, 4)))
            imgs.append(len(has))
            if draw(st.integers(0, 7)) == 0:  # no EXIF time: a frame range
                has.append(False)
                cands.append([])
            else:
                has.append(True)
                # a window may reach a frame or two into the next segment (filtered out there)
                b_w = b + draw(st.integers(0, 2))
                cands.append([j for j in range(a, b_w + 1) if j < lo + q + 2])
            lo_r.append(a)
            hi_r.append(b)
        segs.append((imgs, lo, lo + q - 1))
    m = len(skip)
    for c in cands:  # windows only hold eligible frames (extra frames past the end are dropped)
        c[:] = [j for j in c if j < m and eligible[j]]
    times = [ImageTime(Path(f"{i}.JPG"), 1000.0 + i if h else None, 1.0 if h else None) for i, h in enumerate(has)]
    si = draw(st.sampled_from([2.0, 10.0]))
    fr = Frames([], np.zeros(m), np.zeros(m), np.array(eligible, dtype=bool), skip, si, 0)
    fr.skip_prefix = np.concatenate([[0.0], np.cumsum(np.array(skip))])
    fr.eligible_prefix = np.concatenate([[0], np.cumsum(np.array(eligible, dtype=np.int64))])
    ranges = Ranges(np.array(lo_r, dtype=np.int64), np.array(hi_r, dtype=np.int64))
    return Card.of(times), fr, cands, ranges, segs


def _flat(cands: list[list[int]]) -> tuple[Any, Any]:
    frames = np.array([j for c in cands for j in c], dtype=np.int64)
    start = np.concatenate([[0], np.cumsum([len(c) for c in cands])]).astype(np.int64)
    return frames, start


@settings(max_examples=250, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_cards())
def test_stacked_dp_equals_the_row_by_row_dp(case: tuple[Card, Frames, list[list[int]], Ranges, list[Seg]]) -> None:
    card, fr, cands, ranges, segs = case
    assert batch.exact_costs(fr)
    m = batch.many(fr, card.has, _flat(cands), ranges, segs)
    ok, wide = batch.fits(m, align.MAX_SEGMENT_CELLS)
    assert ok == list(range(len(segs))) and not wide
    assert batch.fits(m, 0) == ([], list(range(len(segs))))  # too many cells: all row by row
    stacked = batch.outcomes(card, fr, m)
    costs = batch.costs(fr, m)
    windows = [tuple(c) for c in cands]
    for s, (imgs, lo, hi) in enumerate(segs):
        ref = Outcome(0.0, {}, {}, {}, set())
        align.solve_segment(card, fr, windows, ranges, imgs, lo, hi, ref)  # type: ignore[arg-type]
        got = stacked[s]
        assert got.cost == ref.cost == costs[s]
        assert list(got.pairs.items()) == list(ref.pairs.items())
        assert list(got.ambiguous.items()) == list(ref.ambiguous.items())
        assert list(got.extra.items()) == list(ref.extra.items())
        assert got.frame_ambiguous == ref.frame_ambiguous


def test_fractional_costs_stay_with_the_row_by_row_dp() -> None:
    """Sums of costs that are not whole numbers depend on their order: the stack is then not used."""
    fr = Frames([], np.zeros(3), np.zeros(3), np.ones(3, dtype=bool), [10.0, 2.5, 10.0], 10.0, 0)
    assert not batch.exact_costs(fr)
    fr.skip = [10.0, 2.0, 10.0]
    assert batch.exact_costs(fr)
    fr.image_skip = 0.5
    assert not batch.exact_costs(fr)


def _pass_card(seed: int) -> tuple[list[FrameRecord], list[ImageTime]]:
    """Eight passes of 40 shots at 5 fps, 1 s EXIF times: windows chain over each pass (a segment of ~40
    images each), with missed triggers, manual shots and images without a time."""
    params = {
        "seed": seed, "dt": 0.2, "res": 1.0, "offset": 3600.37, "drift": 30e-6, "wired": True, "passes": 8,
        "shots": 40, "pause": 30.0, "jitter": 0.002, "p_miss": 0.03, "p_manual": 0.03, "p_untimed": 0.02,
        "test_shot": False,
    }  # fmt: skip
    frames, images, _ = capture(params)
    return frames, images


@pytest.mark.parametrize("seed", [1, 2])
def test_match_is_the_same_with_and_without_the_stack(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    frames, images = _pass_card(seed)
    calls: list[int] = []
    outcomes = batch.outcomes

    def counting(card: Card, fr: Frames, m: batch.Many) -> list[Outcome]:
        calls.append(len(m.p))
        return outcomes(card, fr, m)

    monkeypatch.setattr(batch, "outcomes", counting)
    stacked = match_times(frames, images).to_json()
    assert calls and max(calls) >= 8  # the passes were solved abreast
    monkeypatch.setattr(align, "STACK_MIN_ABREAST", 10**9)  # every segment row by row
    calls.clear()
    alone = match_times(frames, images).to_json()
    assert not calls
    assert stacked == alone
    assert len(stacked["pairs"]) > 250
