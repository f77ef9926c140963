"""A card of several sessions: split where the camera's clock says a new session began, merge their matches.

A camera numbers its files in the order it takes them, so within one session the EXIF times grow with the
card order. Two flights on one card are two sessions, and between them the camera clock may have been set
(a reset to a default date, a daylight-saving change, a new time zone): the second session then has its own
offset, and its times may even fall among the first's. One offset for the whole card cannot explain both,
and matching it as one lays exposures of one flight on images of the other. So the card is split where the
time goes back (by more than the EXIF resolution and the jitter of a manual shot) or pauses longer than
SESSION_GAP_S, and each session is matched on its own, with its own camera clock, or left unmatched.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Sequence
from pathlib import Path

from icgt.ingest.matching.results import (
    FRAME_AMBIGUOUS,
    FRAME_NO_IMAGE,
    Ambiguous,
    ImageTime,
    MatchResult,
    Pair,
    UnmatchedFrame,
)

SESSION_GAP_S = 300.0
"""A pause in the camera's times longer than this starts a new session [s]: a battery swap between flights
takes longer, a pause between the passes of one flight rarely does. (A flight paused longer is matched as
two sessions: each must then single out its own clock, which only a very short part can fail to.)"""
BACKWARD_SLACK_S = 1.0
"""A time going back by no more than this beyond the EXIF resolution stays in its session [s] (a manual shot
taken during a trigger's shutter lag may be numbered before it)."""


def split_sessions(times: Sequence[ImageTime]) -> list[range]:
    """The card's sessions as ranges of card indices (an image without an EXIF time joins the session of the
    images before it; the card's leading untimed images join the first session)."""
    breaks: list[int] = []
    timed = [i for i, t in enumerate(times) if t.time_s is not None and t.resolution_s is not None]
    for a, b in itertools.pairwise(timed):
        if _breaks(times[a], times[b]):
            breaks.append(b)
    # One timed image whose time leaves the run and comes back (another device's file among the camera's, or a
    # picture with a wrong clock) is no session of its own: the images on either side go on as one, and split
    # there a flight's images lost their neighbours (a CI run: 1 wrong pair).
    lone: set[int] = set()
    for k in range(1, len(timed) - 1):
        a, i, b = timed[k - 1], timed[k], timed[k + 1]
        if i in breaks and b in breaks and not _breaks(times[a], times[b]):
            lone.update((i, b))
    breaks = [i for i in breaks if i not in lone]
    edges = [0, *breaks, len(times)]
    return [range(a, b) for a, b in itertools.pairwise(edges)]


def _breaks(last: ImageTime, t: ImageTime) -> bool:
    """Whether the camera's time from ``last`` to ``t`` (both timed) starts a new session."""
    assert last.time_s is not None and last.resolution_s is not None
    assert t.time_s is not None and t.resolution_s is not None
    back = last.time_s - t.time_s
    gap = t.time_s - (last.time_s + last.resolution_s)
    return back > max(last.resolution_s, t.resolution_s) + BACKWARD_SLACK_S or gap > SESSION_GAP_S


def _label(times: Sequence[ImageTime], k: int, span: range) -> str:
    first, last = times[span.start].path, times[span.stop - 1].path
    return f"session {k + 1} ({Path(first).name} .. {Path(last).name}, {len(span)} images)"


def match_sessions(
    times: Sequence[ImageTime], sessions: list[range], match_one: Callable[[list[ImageTime]], MatchResult]
) -> MatchResult:
    """Match each session alone and merge: an exposure that two sessions pair is paired by neither (the images
    become ambiguous), and every note says which session it is about."""
    results = [match_one(list(times[s.start : s.stop])) for s in sessions]
    merged = MatchResult()
    res = [r.resolution_s for r in results if r.resolution_s is not None]
    merged.resolution_s = max(res) if res else None
    merged.notes.append(
        f"the card holds {len(sessions)} sessions (split where the EXIF time goes back, or pauses longer than "
        f"{SESSION_GAP_S:g} s): each is matched on its own, with its own camera clock"
    )
    claims: dict[int, list[int]] = {}
    for k, r in enumerate(results):
        for p in r.pairs:
            claims.setdefault(p.frame.frame_seq, []).append(k)
    contested = {seq for seq, ks in claims.items() if len(ks) > 1}
    # A session whose clock is not decided may hold the log as well as one that pairs it (two flights of one
    # trigger pattern, the other's clock set 1 h away): its rival offsets could lay the same exposures on its
    # own images, so the pairing session's claim is not exclusive. Unless it could explain fewer than half of
    # them (a test shot of one image does not doubt a flight).
    doubted: dict[int, str] = {}
    for k, r in enumerate(results):
        n = r.undecided_exposures
        for j, other in enumerate(results):
            if n > 0 and j != k and other.pairs and 2 * n >= len(other.pairs):
                doubted.setdefault(
                    j,
                    f"session {k + 1} of the card, whose camera clock is not decided, could hold {n} of the log's "
                    "exposures as well: this session's pairs are not its alone",
                )
    contested |= {p.frame.frame_seq for j in doubted for p in results[j].pairs}
    # An exposure that one session pairs and another's ambiguous image may be (it fits its time): not the first's
    # alone either.
    maybe: dict[int, set[int]] = {}
    for k, r in enumerate(results):
        for a in r.ambiguous:
            for f in a.candidates:
                maybe.setdefault(f.frame_seq, set()).add(k)
    contested |= {seq for seq, ks in claims.items() if maybe.get(seq, set()) - set(ks)}
    paired: set[int] = set()
    for k, (span, r) in enumerate(zip(sessions, results, strict=True)):
        label = _label(times, k, span)
        kept: list[Pair] = []
        for p in r.pairs:
            if k in doubted:
                merged.ambiguous.append(Ambiguous(p.image, (p.frame,), doubted[k]))
            elif p.frame.frame_seq in contested:
                seq = p.frame.frame_seq
                pairing = [j for j in claims[seq] if j != k]
                if pairing:
                    others = ", ".join(str(j + 1) for j in pairing)
                    why = f"sessions {k + 1} and {others} of the card both pair this exposure"
                else:
                    others = ", ".join(str(j + 1) for j in sorted(maybe.get(seq, set()) - {k}))
                    why = f"session {others} of the card has an image that may be this exposure too"
                merged.ambiguous.append(Ambiguous(p.image, (p.frame,), why))
            else:
                kept.append(p)
                paired.add(p.frame.frame_seq)
        merged.pairs.extend(kept)
        merged.ambiguous.extend(r.ambiguous)
        merged.unmatched_images.extend(r.unmatched_images)
        offset = "unknown" if r.camera_offset_s is None else f"{r.camera_offset_s:+.3f} s from UTC"
        merged.notes.append(f"{label}: {len(kept)} paired, camera clock {offset}")
        merged.notes.extend(f"{label}: {n}" for n in r.notes)
    # The clock of the session that pairs most is the card's (the others' are in the notes)
    best = max(range(len(results)), key=lambda k: len(results[k].pairs))
    merged.camera_offset_s = results[best].camera_offset_s
    merged.camera_drift_ppm = results[best].camera_drift_ppm
    # An exposure no session pairs: a candidate of an ambiguous image if any session says so, else without an
    # image on the card (inside some session's times if any says so), else what every session says
    chosen: dict[int, UnmatchedFrame] = {}
    for r in results:
        for u in r.unmatched_frames:
            seq = u.frame.frame_seq
            if seq not in paired and (seq not in chosen or _rank(u) < _rank(chosen[seq])):
                chosen[seq] = u
    for seq in contested:
        frame = next(p.frame for r in results for p in r.pairs if p.frame.frame_seq == seq)
        two = len(claims.get(seq, ())) > 1
        why = "two sessions of the card pair it" if two else "two sessions of the card may hold it"
        chosen[seq] = UnmatchedFrame(frame, FRAME_AMBIGUOUS, why)
    merged.unmatched_frames = [chosen[s] for s in sorted(chosen)]
    return merged


def _rank(u: UnmatchedFrame) -> int:
    """Which session's account of an unpaired exposure is kept: the lowest rank."""
    if u.reason == FRAME_AMBIGUOUS:
        return 0
    if u.reason == FRAME_NO_IMAGE:
        return 3 if "outside" in u.detail else 2
    return 1
