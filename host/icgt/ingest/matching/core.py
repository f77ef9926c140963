"""`match_times` and `match_images`: the matcher's pipeline from EXIF times and frames to a MatchResult."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path

from icgt.geotag.record import FrameRecord
from icgt.ingest.matching.clock import offset_candidates
from icgt.ingest.matching.evidence import evidence_reach, judge
from icgt.ingest.matching.exif import list_images, read_image_times
from icgt.ingest.matching.report import report
from icgt.ingest.matching.results import (
    AMBIGUITY_MARGIN,
    IMAGE_NO_EXPOSURE,
    ImageTime,
    MatchError,
    MatchResult,
    UnmatchedImage,
)
from icgt.ingest.matching.rules import CLOCK_AMBIGUITY, swap_rule, timed_first_rule, untimed_rule
from icgt.ingest.matching.search import MAX_SCAN_S, grid, refine, scan, settle
from icgt.ingest.matching.sessions import match_sessions, split_sessions
from icgt.ingest.matching.state import Card, Model, Outcome, frames_from

FIRST_PASS_WIDEN_MAX_S = 0.05
"""Cap on how far the first pass widens the windows for the not yet known drift [s]."""

Progress = Callable[[int, int], None]
"""progress(done, total): images read, or alignment steps done."""


def match_times(
    frames: Sequence[FrameRecord],
    times: Sequence[ImageTime],
    *,
    camera_id: int | None = None,
    time_tolerance_s: float = 0.02,
    max_drift_ppm: float = 100.0,
    progress: Progress | None = None,
) -> MatchResult:
    """Pair images (in card order, with their EXIF times) with frames; see the module docstring.

    `time_tolerance_s`: how far a camera's time stamp may be from the exposure start beyond its
    resolution (latency, the recording's own timing error is added per frame). `max_drift_ppm`:
    the largest camera clock rate error believed. `progress(done, total)` after each alignment step.
    A card of several sessions (`sessions.split_sessions`) is matched one session at a time.
    """
    images = list(times)
    sessions = split_sessions(images)
    if len(sessions) < 2:
        return _match_session(frames, images, camera_id, time_tolerance_s, max_drift_ppm, progress)
    return match_sessions(
        images,
        sessions,
        lambda part: _match_session(frames, part, camera_id, time_tolerance_s, max_drift_ppm, progress),
    )


def _match_session(
    frames: Sequence[FrameRecord],
    times: Sequence[ImageTime],
    camera_id: int | None,
    time_tolerance_s: float,
    max_drift_ppm: float,
    progress: Progress | None,
) -> MatchResult:
    """`match_times` for the images of one session."""
    result = MatchResult()
    ids = sorted({f.camera_id for f in frames})
    if camera_id is None and len(ids) > 1:
        raise MatchError(f"the log has frames of cameras {ids}: say which camera's card this is (camera_id)")
    recs = [f for f in frames if camera_id is None or f.camera_id == camera_id]
    images = list(times)
    if not images:
        raise MatchError("no images to match")
    res = [t.resolution_s for t in images if t.resolution_s is not None]
    result.resolution_s = max(res) if res else None
    if not recs:
        result.unmatched_images = [UnmatchedImage(t.path, IMAGE_NO_EXPOSURE, "the log has no frames") for t in images]
        return result
    fr = frames_from(recs, time_tolerance_s)
    card = Card.of(images)
    span = float(fr.x[-1] - fr.x[0]) if len(fr.x) else 0.0
    # The drift's worst effect before it is estimated, capped: on a long flight the first pass pairs
    # the part near where the offset fits best, and the drift fitted there extends it to the rest.
    widen = min(max_drift_ppm * 1e-6 * span, FIRST_PASS_WIDEN_MAX_S)
    candidates = offset_candidates(images, fr, widen)
    # Offsets many intervals away are judged by the whole overlap's pattern first (evidence.py): only the
    # neighbourhood of the one the card supports is aligned, or none when the card does not single one out.
    reach = grid(fr, card, time_tolerance_s, coarse=False)[1]
    verdict = judge(card, fr, evidence_reach(card, fr, reach, time_tolerance_s, MAX_SCAN_S), widen)
    if verdict is not None and verdict.decided:
        near_best = [c for c in candidates if verdict.admits(c.offset, reach)]
        candidates = near_best or [Model(verdict.best.offset_s, 0.0)]
    if not candidates:
        result.notes.append("no image has an EXIF time: images can only be placed by order")
        candidates = [Model(0.0, 0.0)]
    steps, done = len(candidates) + 3, 0

    def step_done(final: bool = False) -> None:
        nonlocal done
        done = steps if final else min(done + 1, steps - 1)
        if progress is not None:
            progress(done, steps)

    solutions: list[tuple[float, Model, Outcome]] = []
    for start in candidates:
        # Where in its neighbourhood does the offset fit best (with steady triggers a candidate can be
        # a fraction of an interval off, which shifts pairs near the seconds' boundaries)? Then the drift.
        settled = settle(card, fr, start, time_tolerance_s)
        # (a candidate ending beyond the margin of one already found can neither win nor rival it)
        hopeless = min((c for c, _m, _o in solutions), default=math.inf) + AMBIGUITY_MARGIN
        model, outcome = refine(card, fr, settled, widen, max_drift_ppm, give_up_above=hopeless)
        solutions.append((outcome.cost, model, outcome))
        step_done()
    solutions.sort(key=lambda s: s[0])
    cost, model, outcome = solutions[0]
    # The offset is only known as well as the card pins it: with steady triggers an offset a few
    # intervals away, or a fraction of the EXIF resolution away, can explain the card about as well
    # (then only the ends or irregular shots decide). Scan the offsets around the fit; a cheaper
    # solution replaces it, and every pair not made the same way by all solutions within
    # AMBIGUITY_MARGIN of the best is not made.
    rivals: list[tuple[float, Model, Outcome]] = []
    for _ in range(3):
        step, reach = grid(fr, card, time_tolerance_s, coarse=False)
        rivals = [(c, m, o) for c, m, o, _k in scan(card, fr, model, cost, step, reach)]
        step_done()
        cheaper = [t for t in rivals if t[0] < cost - 1e-9]
        if not cheaper:
            break
        start = min(cheaper, key=lambda t: t[0])[1]
        better_model, better = refine(card, fr, start, 0.0, max_drift_ppm)
        if better.cost >= cost - 1e-9:
            break
        model, outcome, cost = better_model, better, better.cost
    else:
        step, reach = grid(fr, card, time_tolerance_s, coarse=False)
        rivals = [(c, m, o) for c, m, o, _k in scan(card, fr, model, cost, step, reach)]
    near: list[tuple[float, Model, Outcome]] = []
    for t in solutions[1:] + rivals:
        if t[0] <= cost + AMBIGUITY_MARGIN and t[2].pairs != outcome.pairs and all(t[2] is not u[2] for u in near):
            near.append(t)
    for _other_cost, other_model, other in near:
        differ = [i for i in outcome.pairs if other.pairs.get(i) != outcome.pairs[i]]
        for i in differ:
            cands = {outcome.pairs[i]}
            if i in other.pairs:
                cands.add(other.pairs[i])
            if i in other.ambiguous:
                cands.update(other.ambiguous[i][0])
            outcome.ambiguous[i] = (
                sorted(cands),
                f"{CLOCK_AMBIGUITY}: an offset {other_model.offset - model.offset:+.3f} s from "
                "the best fit explains the card about as well and pairs this image otherwise",
            )
            outcome.frame_ambiguous.update(cands)
            del outcome.pairs[i]
        if differ:
            note = "the camera clock offset is ambiguous: the pairs that depend on it are not made"
            if note not in result.notes:
                result.notes.append(note)
    if verdict is not None and not verdict.plausible:
        # the images are not of this log (another flight, a test shot, a session of another recording)
        for i in [*outcome.pairs, *outcome.ambiguous]:
            if card.has_time(i):
                outcome.extra[i] = IMAGE_NO_EXPOSURE
                outcome.pairs.pop(i, None)
                outcome.ambiguous.pop(i, None)
        outcome.frame_ambiguous.clear()
        result.notes.append(verdict.note())
    elif verdict is not None and not verdict.decided:
        # No exposure is named as an image's candidate: which ones it could be depends on the offset, and the
        # one that fits best here is no more the camera's than its rivals (the note lists them).
        why = "the camera clock offset is not decided (see the notes): not paired by its time"
        result.undecided_exposures = verdict.best.overlap
        for i in [*outcome.pairs, *outcome.ambiguous]:
            if card.has_time(i):
                if i in outcome.pairs:
                    outcome.frame_ambiguous.add(outcome.pairs.pop(i))
                outcome.ambiguous[i] = ([], why)
        result.notes.append(verdict.note())
    swap_rule(images, fr, model, outcome)
    timed_first_rule(images, outcome)
    untimed_rule(images, fr, outcome)
    report(images, fr, model, outcome, result)
    step_done(final=True)
    return result


def match_images(
    frames: Sequence[FrameRecord],
    images: Sequence[Path] | Path,
    *,
    camera_id: int | None = None,
    time_tolerance_s: float = 0.02,
    max_drift_ppm: float = 100.0,
    progress: Progress | None = None,
    align_progress: Progress | None = None,
) -> MatchResult:
    """Pair the camera card's images with the recorded frames.

    `images`: a folder (its JPEGs, subfolders included, in the camera's numbering order) or paths in
    card order. `progress` is told the images read, `align_progress` the alignment steps. See
    `match_times` for the other arguments.
    """
    paths = list_images(images) if isinstance(images, Path) else [Path(p) for p in images]
    if not paths:
        raise MatchError(f"no JPEG images in {images}")
    times = read_image_times(paths, progress)
    result = match_times(
        frames,
        times,
        camera_id=camera_id,
        time_tolerance_s=time_tolerance_s,
        max_drift_ppm=max_drift_ppm,
        progress=align_progress,
    )
    untimed = [p.name for p, t in zip(paths, times, strict=True) if t.time_s is None]
    if untimed:
        more = f" and {len(untimed) - 10} more" if len(untimed) > 10 else ""
        result.notes.append(
            f"{len(untimed)} images without EXIF DateTimeOriginal (not paired by time): {', '.join(untimed[:10])}{more}"
        )
    return result
