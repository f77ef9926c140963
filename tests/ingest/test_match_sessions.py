"""A card of several sessions (issue 36): split where the camera's times go back or pause, each matched alone."""

from __future__ import annotations

from pathlib import Path

from synthetic_cards import capture, composed_card, interleaving_step

from icgt.ingest.match import IMAGE_NO_EXPOSURE, ImageTime, match_times
from icgt.ingest.matching.sessions import SESSION_GAP_S, split_sessions


def _flight(seed: int, **over: object) -> dict[str, object]:
    params: dict[str, object] = {
        "seed": seed, "dt": 0.5, "res": 1.0, "offset": 2.3, "drift": 10e-6, "wired": True, "passes": 3,
        "shots": 60, "pause": 12.0, "jitter": 0.002, "p_miss": 0.03, "p_manual": 0.0, "p_untimed": 0.0,
        "test_shot": False,
    }  # fmt: skip
    params.update(over)
    return params


def _times(*seconds: float | None, res: float = 1.0) -> list[ImageTime]:
    return [ImageTime(Path(f"IMG{k:04d}.JPG"), t, None if t is None else res) for k, t in enumerate(seconds)]


def test_sessions_split_where_the_time_goes_back_or_pauses_long() -> None:
    t0 = 1.8e9
    card = _times(t0, t0 + 1, None, t0 + 2, t0 - 3600, t0 - 3599, t0 - 3599 + SESSION_GAP_S + 2, t0 - 3000)
    assert split_sessions(card) == [range(0, 4), range(4, 6), range(6, 8)]
    # a manual shot numbered before the triggered one it overtook, or a pause between passes: one session
    assert split_sessions(_times(t0, t0 + 2, t0 + 1, t0 + 40, t0 + 40 + SESSION_GAP_S - 1)) == [range(0, 5)]
    assert split_sessions(_times(None, None)) == [range(0, 2)]


def test_two_flights_whose_camera_times_interleave_are_each_matched_on_their_own() -> None:
    """The camera clock set back 1 h between flights lands the second flight's times among the first's: matched as
    one card, 463 of 1943 pairs were wrong on the benchmark's cards; as sessions every logged image is paired."""
    for other_after in (True, False):
        flight, other = _flight(7), _flight(8, dt=0.5, shots=70)
        step = interleaving_step(flight, 600.0, other_after)
        frames, card, truth = composed_card(flight, other, (0.0, 1.0), other_after, 600.0, step)
        result = match_times(frames, card)
        assert all(truth[p.image] == p.frame.frame_seq for p in result.pairs)
        assert len(result.pairs) == sum(1 for v in truth.values() if v is not None)
        assert result.notes[0].startswith("the card holds 2 sessions")
        other_images = {p for p, v in truth.items() if v is None}
        assert {u.image for u in result.unmatched_images} == other_images
        assert all(u.reason == IMAGE_NO_EXPOSURE for u in result.unmatched_images)


def test_a_card_of_another_flight_pairs_nothing_and_says_it_does_not_hold_the_log() -> None:
    """Before, the offset laying part of the log on the end of the other flight's images was clearly the best of bad
    ones: 59 images were paired, all wrongly (the share of the log left unexplained was not looked at)."""
    frames, _, _ = capture(_flight(3))
    _, other_card, _ = capture(_flight(4, passes=2))
    result = match_times(frames, other_card)
    assert result.pairs == [] and result.ambiguous == []
    assert len(result.unmatched_images) == len(other_card)
    assert any("the card does not hold this log" in n for n in result.notes), result.notes


def test_an_undecided_clock_names_no_image_a_candidate() -> None:
    """The first 10 % of a steady capture against the whole card (1 s EXIF): the log fits many places of the card.
    No image is paired and no image is said to fit exposures: which ones depends on an offset nobody knows (before,
    images 147-154 of such a card were said to fit frames 1-6, whose images are 1-6)."""
    frames, card, _ = composed_card(_flight(5, passes=1, shots=200, p_miss=0.0), None, (0.0, 0.1), True, 0, 0)
    result = match_times(frames, card)
    assert result.pairs == []
    assert any("the camera clock offset is not decided" in n for n in result.notes), result.notes
    assert result.ambiguous and all(a.candidates == () for a in result.ambiguous)
    assert all("not decided" in a.why for a in result.ambiguous)
