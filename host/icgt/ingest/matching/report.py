"""From an outcome to the MatchResult: pairs with residuals, every leftover with its reason, the clock."""

from __future__ import annotations

import math

from icgt.ingest.matching.results import (
    FRAME_AMBIGUOUS,
    FRAME_FEEDBACK_MISSING,
    FRAME_NO_IMAGE,
    IMAGE_NO_EXPOSURE,
    IMAGE_NO_TIME_UNPLACED,
    IMAGE_UNREADABLE,
    Ambiguous,
    ImageTime,
    MatchResult,
    Pair,
    UnmatchedFrame,
    UnmatchedImage,
)
from icgt.ingest.matching.state import Frames, Model, Outcome


def report(times: list[ImageTime], fr: Frames, model: Model, out: Outcome, result: MatchResult) -> None:
    p = model.predict(fr.x)
    used: set[int] = set()
    for i in sorted(out.pairs):
        j = out.pairs[i]
        t = times[i]
        residual = None
        if t.time_s is not None and t.resolution_s is not None:
            residual = float(p[j]) - (t.time_s + t.resolution_s / 2.0)
        result.pairs.append(Pair(t.path, fr.recs[j], residual))
        used.add(j)
    for i in sorted(out.ambiguous):
        cands, why = out.ambiguous[i]
        result.ambiguous.append(Ambiguous(times[i].path, tuple(fr.recs[j] for j in cands if j not in used), why))
    for i in sorted(out.extra):
        t = times[i]
        reason = out.extra[i]
        if t.problem is not None:
            result.unmatched_images.append(UnmatchedImage(t.path, IMAGE_UNREADABLE, t.problem))
        elif reason == IMAGE_NO_EXPOSURE:
            result.unmatched_images.append(
                UnmatchedImage(t.path, reason, "no recorded exposure near its EXIF time (shot while not recording?)")
            )
        elif reason == IMAGE_NO_TIME_UNPLACED:
            result.unmatched_images.append(UnmatchedImage(t.path, reason, "no EXIF time and no exposure left for it"))
        else:
            result.unmatched_images.append(
                UnmatchedImage(t.path, reason, "the exposures near its time belong to other images (an extra shot?)")
            )
    timed = [float(t.time_s) for t in times if t.time_s is not None]
    first_t, last_t = (min(timed), max(timed) + 1.0) if timed else (-math.inf, math.inf)
    for j, rec in enumerate(fr.recs):
        if j in used:
            continue
        if not fr.eligible[j]:
            result.unmatched_frames.append(
                UnmatchedFrame(
                    rec, FRAME_FEEDBACK_MISSING, "the camera did not confirm this trigger: no image expected"
                )
            )
        elif j in out.frame_ambiguous:
            result.unmatched_frames.append(UnmatchedFrame(rec, FRAME_AMBIGUOUS, "a candidate of an ambiguous image"))
        elif not first_t - 1.0 <= float(p[j]) <= last_t + 1.0:
            result.unmatched_frames.append(
                UnmatchedFrame(rec, FRAME_NO_IMAGE, "outside the time span of the card's images")
            )
        else:
            result.unmatched_frames.append(
                UnmatchedFrame(rec, FRAME_NO_IMAGE, "a confirmed exposure without an image on the card")
            )
    result.camera_drift_ppm = model.drift * 1e6 if model.drift_known else None
    utc = [
        (float(p[j]) - (r.mid_utc_us - (r.mid_device_us - r.start_device_us)) * 1e-6)
        for j, r in ((out.pairs[i], fr.recs[out.pairs[i]]) for i in sorted(out.pairs))
        if r.mid_utc_us is not None
    ]
    result.camera_offset_s = utc[0] if utc else None
