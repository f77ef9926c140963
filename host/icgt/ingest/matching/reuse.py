"""A match remembered: `icgt match` keeps its result, `icgt export` of the same log and card reuses it.

The result is stored as its JSON report (`MatchResult.to_json`) in the user's cache folder
(`$ICGT_MATCH_CACHE`, else `$XDG_CACHE_HOME/icgt/match`, else `~/.cache/icgt/match`; never on the card
or beside the log), under a key that covers everything the match depends on: the matcher's version, its
parameters, every frame field it reads, and every image's resolved path, size and modification time.
Changing the log, the card or a parameter changes the key, so a stale result is never reused; a file
that does not read back to the same frames and images is ignored and the match is made again.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from icgt.geotag.record import FrameRecord
from icgt.ingest.matching.core import Progress, match_images
from icgt.ingest.matching.exif import list_images
from icgt.ingest.matching.results import (
    Ambiguous,
    MatchError,
    MatchResult,
    Pair,
    UnmatchedFrame,
    UnmatchedImage,
)

log = logging.getLogger(__name__)

MATCHER_VERSION = 2
"""Bumped whenever the matcher can decide differently on the same input."""


def cache_dir() -> Path:
    env = os.environ.get("ICGT_MATCH_CACHE")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "icgt" / "match"


def match_key(
    frames: Sequence[FrameRecord], paths: Sequence[Path], camera_id: int | None, tolerance_s: float, drift_ppm: float
) -> str:
    """SHA-256 over the matcher's inputs (frames as the matcher reads them, images by path, size, mtime)."""
    h = hashlib.sha256()
    h.update(json.dumps([MATCHER_VERSION, camera_id, tolerance_s, drift_ppm]).encode())
    for f in frames:
        fields = (
            f.frame_seq,
            f.camera_id,
            f.trigger_device_us,
            f.start_device_us,
            f.mid_device_us,
            f.mid_host_ns,
            f.mid_host_uncertainty_ns,
            f.mid_utc_us,
            sorted(f.flags),
        )
        h.update(json.dumps(fields).encode())
    for p in paths:
        try:
            st = p.stat()
        except OSError as exc:
            raise MatchError(f"cannot read {p}: {exc.strerror or exc}") from None
        h.update(json.dumps([str(p.resolve()), st.st_size, st.st_mtime_ns]).encode())
    return h.hexdigest()


def save(key: str, result: MatchResult, paths: Sequence[Path]) -> Path | None:
    """Store the result under `key`; a cache that cannot be written only costs a repeated match later."""
    folder = cache_dir()
    target = folder / f"{key}.json"
    doc = {"key": key, "resolved": {str(p): str(p.resolve()) for p in paths}, "result": result.to_json()}
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = target.with_suffix(".tmp")
        tmp.write_text(json.dumps(doc))
        tmp.replace(target)
        if json.loads(target.read_text()).get("key") != key:
            raise OSError("the written file does not read back")
    except OSError as exc:
        log.warning("cannot keep the match for icgt export in %s: %s", folder, exc)
        return None
    return target


def load(key: str, frames: Sequence[FrameRecord], paths: Sequence[Path]) -> MatchResult | None:
    """The result stored under `key`, rebuilt on these frames and paths; None if absent or not consistent."""
    target = cache_dir() / f"{key}.json"
    try:
        doc = json.loads(target.read_text())
    except (OSError, ValueError):
        return None
    try:
        return _rebuild(doc, key, frames, paths)
    except (KeyError, TypeError, ValueError) as exc:
        log.warning("ignoring the stored match %s (%s): matching again", target, exc)
        return None


def _rebuild(doc: dict[str, Any], key: str, frames: Sequence[FrameRecord], paths: Sequence[Path]) -> MatchResult:
    if doc.get("key") != key:
        raise ValueError("a different key")
    by_seq = {f.frame_seq: f for f in frames}
    if len(by_seq) != len(frames):
        raise ValueError("frame numbers repeat in the log")
    by_resolved = {str(p.resolve()): p for p in paths}
    resolved: dict[str, str] = doc["resolved"]

    def image(text: str) -> Path:
        return by_resolved[resolved[text]]

    def frame(ref: dict[str, Any]) -> FrameRecord:
        return by_seq[int(ref["frame_seq"])]

    r = doc["result"]
    out = MatchResult(
        pairs=[Pair(image(p["image"]), frame(p), p["residual_s"]) for p in r["pairs"]],
        unmatched_images=[UnmatchedImage(image(u["image"]), u["reason"], u["detail"]) for u in r["unmatched_images"]],
        unmatched_frames=[UnmatchedFrame(frame(u), u["reason"], u["detail"]) for u in r["unmatched_frames"]],
        ambiguous=[
            Ambiguous(image(a["image"]), tuple(frame(c) for c in a["candidates"]), a["why"]) for a in r["ambiguous"]
        ],
        camera_offset_s=r["camera_offset_s"],
        camera_drift_ppm=r["camera_drift_ppm"],
        resolution_s=r["resolution_s"],
        notes=list(r["notes"]),
    )
    seen = [p.image for p in out.pairs] + [a.image for a in out.ambiguous] + [u.image for u in out.unmatched_images]
    if len(seen) != len(paths) or set(seen) != set(paths):
        raise ValueError("it does not account for every image of the card exactly once")
    return out


def match_images_reusing(
    frames: Sequence[FrameRecord],
    images: Sequence[Path] | Path,
    *,
    camera_id: int | None = None,
    time_tolerance_s: float = 0.02,
    max_drift_ppm: float = 100.0,
    progress: Progress | None = None,
    align_progress: Progress | None = None,
    reuse: bool = True,
    keep: bool = False,
) -> tuple[MatchResult, Path | None]:
    """`match_images`, or the stored result of the same match; (result, the file reused or written).

    `reuse`: look for a stored result (icgt export does; icgt match always matches afresh). `keep`: store
    a result that was computed (icgt match does; icgt export only reads)."""
    paths = list_images(images) if isinstance(images, Path) else [Path(p) for p in images]
    if not paths:
        raise MatchError(f"no JPEG images in {images}")
    key = match_key(frames, paths, camera_id, time_tolerance_s, max_drift_ppm)
    stored = load(key, frames, paths) if reuse else None
    if stored is not None:
        log.info("reusing the match made by icgt match of this log and card (%s)", cache_dir() / f"{key}.json")
        if progress is not None:
            progress(len(paths), len(paths))
        return stored, cache_dir() / f"{key}.json"
    result = match_images(
        frames,
        paths,
        camera_id=camera_id,
        time_tolerance_s=time_tolerance_s,
        max_drift_ppm=max_drift_ppm,
        progress=progress,
        align_progress=align_progress,
    )
    return result, save(key, result, paths) if keep else None
