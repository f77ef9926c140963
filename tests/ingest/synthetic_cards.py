"""Synthetic captures for the matching tests: frames as the recorder logs them and the camera card's times."""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

from icgt.geotag import FrameRecord
from icgt.ingest.match import ImageTime


def capture(params: dict[str, Any]) -> tuple[list[FrameRecord], list[ImageTime], dict[Path, int | None]]:
    """A random capture: triggered passes with pauses, jitter, missed triggers, manual shots, untimed
    images, a test shot; wired (the device sees every exposure) or blind (no hot-shoe feedback)."""
    rng = random.Random(params["seed"])
    dt, res, wired = params["dt"], params["res"], params["wired"]
    events: list[tuple[float, str, int]] = []
    t, index = 10.0, 0
    for _ in range(params["passes"]):
        for _ in range(params["shots"]):
            t += dt + rng.gauss(0.0, params["jitter"])
            index += 1
            events.append((t, "trigger", index))
            if rng.random() < params["p_manual"]:
                lo, hi = params.get("manual_phase", (0.03 / dt, 1.0 - 0.03 / dt))  # in trigger intervals
                events.append((t + rng.uniform(lo * dt, hi * dt), "manual", 0))
        t += params["pause"]
    if params["test_shot"]:
        events.append((rng.uniform(-200.0, 5.0), "test_shot", 0))
    events.sort()
    frames: list[FrameRecord] = []
    images: list[ImageTime] = []
    truth: dict[Path, int | None] = {}
    for te, kind, idx in events:
        missed = kind == "trigger" and rng.random() < params["p_miss"]
        frame = None
        if kind == "trigger" or (kind == "manual" and wired):
            flags = [] if wired else ["no_feedback"]
            if missed and wired:
                flags = ["feedback_missing", "no_feedback"]
            if kind == "manual":
                flags = ["unsolicited"]
            frame = FrameRecord(
                frame_seq=len(frames) + 1,
                image_index=idx,
                camera_id=0,
                device_flags=0,
                trigger_device_us=0,
                start_device_us=round(te * 1e6),
                mid_device_us=round(te * 1e6) + 500,
                duration_us=1000,
                mid_host_ns=round(te * 1e9) + 500_000,
                mid_host_uncertainty_ns=rng.choice([300_000, 900_000]),
                time_source="system_time",
                flags=flags,
                position_source="gps_3d",
                fix_type=3,
                pose_gap_before_ms=1.0,
                pose_gap_after_ms=1.0,
                mid_utc_us=round((1.8e9 + te) * 1e6) + 500,
            )
            frames.append(frame)
        if missed:
            continue
        camera = 1.8e9 + te * (1 + params["drift"]) + params["offset"] + rng.gauss(0.0, 0.002)
        path = Path(f"IMG{len(images):05d}.JPG")
        untimed = rng.random() < params["p_untimed"]
        images.append(ImageTime(path, None, None) if untimed else ImageTime(path, (camera // res) * res, res))
        truth[path] = frame.frame_seq if frame is not None else None
    return frames, images, truth


def composed_card(
    params: dict[str, Any],
    other: dict[str, Any] | None,
    cut: tuple[float, float],
    other_after: bool,
    shift_s: float,
    step_s: float,
) -> tuple[list[FrameRecord], list[ImageTime], dict[Path, int | None]]:
    """A card that holds more than the log: the log keeps only the frames of `capture(params)` from fraction
    cut[0] to cut[1] (a recorder that started late or died), and the card may hold a second flight
    (`other`, not in the log) `shift_s` before or after it, its camera clock stepped by `step_s` (a reset, a
    daylight-saving change). Returns the log's frames, the card in card order and the truth."""
    frames, images, truth = capture(params)
    a, b = round(len(frames) * cut[0]), round(len(frames) * cut[1])
    kept = frames[a : max(b, a + 1)]
    keep = {f.frame_seq for f in kept}
    truth = {p: (s if s in keep else None) for p, s in truth.items()}
    if other is None:
        return kept, images, truth
    _, images2, _ = capture(other)
    # `shift_s` is the gap between the two flights: between A's last image and B's first (or B's last and A's
    # first), on the true clock; the step then moves B's camera times (by less than the gap in the tests:
    # flights whose camera times interleave on one card are left to a session split)
    t_a = [t.time_s for t in images if t.time_s is not None]
    t_b = [t.time_s for t in images2 if t.time_s is not None]
    if not t_a or not t_b:
        move = (shift_s if other_after else -shift_s) + step_s
    elif other_after:
        move = max(t_a) - min(t_b) + shift_s + step_s
    else:
        move = min(t_a) - max(t_b) - shift_s + step_s
    extra = [
        ImageTime(Path(f"B{t.path.name}"), None if t.time_s is None else t.time_s + move, t.resolution_s)
        for t in images2
    ]
    card = images + extra if other_after else extra + images
    truth.update({t.path: None for t in extra})
    return kept, card, truth


def with_foreign_file(
    images: list[ImageTime], truth: dict[Path, int | None], where: float, after_s: float | None
) -> tuple[list[ImageTime], dict[Path, int | None]]:
    """The card with another device's file put at fraction `where` of it: no EXIF time (`after_s` None), or the
    time of the camera image before it plus `after_s` at that image's resolution (a phone photo, a copy)."""
    k = min(len(images), round(where * len(images)))
    before = next((t for t in reversed(images[:k]) if t.time_s is not None), None)
    path = Path("FOREIGN_0001.JPG")
    if after_s is None or before is None or before.time_s is None:
        foreign = ImageTime(path, None, None)
    else:
        foreign = ImageTime(path, before.time_s + after_s, before.resolution_s)
    return [*images[:k], foreign, *images[k:]], {**truth, path: None}


def interleaving_step(params: dict[str, Any], shift_s: float, other_after: bool) -> float:
    """The `composed_card` clock step that sets the other flight's camera times to the middle of this flight's (a
    camera clock set back between flights, or forward before them): the card's times then interleave."""
    own = [t.time_s for t in capture(params)[1] if t.time_s is not None]
    half = (max(own) - min(own)) / 2.0 if own else 0.0
    return -(shift_s + half) if other_after else shift_s + half
