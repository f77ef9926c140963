"""Rules after the alignment: a manual shot during a shutter lag, a timed image before an untimed one, images
without EXIF time."""

from __future__ import annotations

import itertools

import numpy as np

from icgt.geotag.record import FrameFlag
from icgt.ingest.matching.results import IMAGE_NO_TIME_UNPLACED, ImageTime
from icgt.ingest.matching.state import Frames, Model, Outcome

SWAP_MARGIN_US = 10_000.0


def swap_rule(times: list[ImageTime], fr: Frames, model: Model, out: Outcome) -> None:
    """A manual shot during a trigger's shutter lag: the card may number the two either way.

    A camera numbers its files in the order it takes the shots, but a shot fired by hand while a
    triggered one waits out its shutter lag can be exposed first (and its flash-sync edge taken for
    the trigger's). If an unsolicited exposure starts between a neighbouring trigger and the end of
    that trigger's usual lag, and the EXIF times allow both orders, both images are ambiguous."""
    lags = [
        r.start_device_us - r.trigger_device_us
        for r in fr.recs
        if r.trigger_device_us > 0 and FrameFlag.NO_FEEDBACK.value not in r.flags
    ]
    if not lags:
        return
    lag_us = float(np.median(lags)) + SWAP_MARGIN_US
    p = model.predict(fr.x)
    frame_image = {j: i for i, j in out.pairs.items()}

    def fits(i: int, j: int) -> bool:
        t = times[i]
        if t.time_s is None or t.resolution_s is None:
            return True
        tol = float(fr.tol[j])
        return t.time_s - tol <= float(p[j]) <= t.time_s + t.resolution_s + tol

    eligible = [j for j in range(len(fr.recs)) if fr.eligible[j]]
    for j, k in itertools.pairwise(eligible):
        a, b = fr.recs[j], fr.recs[k]
        unsolicited = [x for x in (a, b) if FrameFlag.UNSOLICITED.value in x.flags]
        triggered = [x for x in (a, b) if x.trigger_device_us > 0]
        if len(unsolicited) != 1 or len(triggered) != 1:
            continue
        u, t = unsolicited[0], triggered[0]
        if not t.trigger_device_us - SWAP_MARGIN_US <= u.start_device_us <= t.trigger_device_us + lag_us:
            continue
        ij, ik = frame_image.get(j), frame_image.get(k)
        if ij is None or ik is None or ij not in out.pairs or ik not in out.pairs:
            continue
        if not (fits(ij, k) and fits(ik, j)):
            continue
        why = "a manual shot during a trigger's shutter lag: the card may number the two either way"
        for i in (ij, ik):
            out.ambiguous[i] = ([j, k], why)
            del out.pairs[i]
        out.frame_ambiguous.update((j, k))


CLOCK_AMBIGUITY = "the camera clock is not pinned down"  # the start of core.py's note for such images


def timed_first_rule(times: list[ImageTime], out: Outcome) -> None:
    """Images whose EXIF time fits one exposure each take them before images without EXIF time do.

    The alignment costs an image paired by its time and one placed by card order alike, so a file
    without EXIF time among timed images (another device's file, a camera file with its metadata
    stripped) makes its timed neighbours ambiguous: any of them could be an exposure's image. The time
    is the stronger evidence. In a run of ambiguous images on the card that holds an untimed one,
    whose neighbours on both sides are paired, the timed images are paired when each has one candidate
    exposure, between those neighbours' and in card order; the untimed images lose those candidates
    (with none left, one is an image without time and nothing to place it by). Ambiguity from the
    camera clock (rival offsets) is not touched: there the times themselves are in doubt."""
    n = len(times)
    paired = set(out.pairs.values())
    i = 0
    while i < n:
        if i not in out.ambiguous:
            i += 1
            continue
        start = i
        while i < n and i in out.ambiguous:
            i += 1
        run = range(start, i)
        if start == 0 or i == n or start - 1 not in out.pairs or i not in out.pairs:
            continue
        untimed = [k for k in run if times[k].time_s is None]
        timed = [k for k in run if times[k].time_s is not None]
        if not untimed or not timed:
            continue
        lo, hi = out.pairs[start - 1], out.pairs[i]
        picks: list[int] = []
        for k in timed:
            cands, why = out.ambiguous[k]
            if len(cands) != 1 or why.startswith(CLOCK_AMBIGUITY) or cands[0] in paired:
                break
            picks.append(cands[0])
        else:
            if all(a < b for a, b in itertools.pairwise([lo, *picks, hi])):
                _give_to_timed(timed, picks, untimed, out)
                paired.update(picks)


def _give_to_timed(timed: list[int], picks: list[int], untimed: list[int], out: Outcome) -> None:
    for k, j in zip(timed, picks, strict=True):
        out.pairs[k] = j
        del out.ambiguous[k]
    taken = set(picks)
    for k in untimed:
        left = [c for c in out.ambiguous[k][0] if c not in taken]
        if left:
            out.ambiguous[k] = (left, out.ambiguous[k][1])
        else:
            del out.ambiguous[k]
            out.extra[k] = IMAGE_NO_TIME_UNPLACED
    still = {c for cands, _w in out.ambiguous.values() for c in cands}
    out.frame_ambiguous -= taken - still


def untimed_rule(times: list[ImageTime], fr: Frames, out: Outcome) -> None:
    """An image without EXIF time keeps its pair only between two time-confident neighbours, one exposure apart."""
    n = len(times)
    for i in range(n):
        if times[i].time_s is not None or i not in out.pairs:
            continue
        prev_ok = i > 0 and times[i - 1].time_s is not None and (i - 1) in out.pairs
        next_ok = i + 1 < n and times[i + 1].time_s is not None and (i + 1) in out.pairs
        if prev_ok and next_ok:
            between = [j for j in range(out.pairs[i - 1] + 1, out.pairs[i + 1]) if fr.eligible[j]]
            if len(between) == 1 and between[0] == out.pairs[i]:
                continue
            why = f"no EXIF time and {len(between)} exposures lie between its neighbours' exposures"
        else:
            between = [out.pairs[i]]
            why = "no EXIF time and its neighbours on the card are not both paired by time"
        out.ambiguous[i] = (between, why)
        out.frame_ambiguous.update(between)
        del out.pairs[i]
