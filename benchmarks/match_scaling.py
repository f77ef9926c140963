#!/usr/bin/env python3
"""Benchmark: `icgt match` on whole-day cards against reading the same cards' EXIF alone (the floor).

    .venv/bin/python benchmarks/match_scaling.py [--sizes 500,2000,8000,18000] [--resolutions 1s,10ms]
        [--baseline DIR]

`--baseline DIR`: also measure the `icgt` package under DIR (another revision's host/ folder, e.g.
`git archive main host | tar -x -C /tmp/base` then DIR=/tmp/base/host) on the same cards in the same run,
printed as a `base` row right after each `match` row (its output is compared too: "same" when both
revisions give byte-identical JSON results).

The captures are synthetic but faulty the way real ones are: 5 fps triggered capture in passes of
600 shots with 20-60 s pauses between them, 2 ms timing jitter, a camera clock an hour and 0.37 s
ahead of UTC running 30 ppm fast, 0.5 % missed triggers (flagged feedback_missing by the device), 0.2 %
manual shots (recorded as unsolicited exposures), 0.1 % images without EXIF time, and a test shot
before the flight. Each card is a folder of small real JPEGs (16x16 px, EXIF DateTimeOriginal and,
for 10 ms, SubSecTimeOriginal) written once with Pillow and cached under build/bench/match_cards/;
a size n is the first n images of the 18 000-image card and the frames recorded up to them.

Each figure is measured in its own subprocess (clean peak RSS, `resource.getrusage` ru_maxrss), after
the card has been read once untimed (both then read it from the page cache):
(a) the floor: `read_image_time` on every image of the card (exifread, the same function and tags
    `icgt match` reads), measured before and after (b); the lesser time is the floor;
(b) `match_images(frames, paths)`: reading plus the alignment; every pair is checked against the
    truth (a wrong pair is reported and makes the exit status 1).
Targets (issue 17): 18 000 images in under 60 s and 1 GB peak RSS, (b) within 3 x (a). Wall and
CPU (process) time are both printed: on a machine shared with other work the CPU times and their
ratio are the steadier figures.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import os
import random
import resource
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "build" / "bench" / "match_cards"
SIZES = (500, 2_000, 8_000, 18_000)
RESOLUTIONS = ("1s", "10ms")
N_MAX = 18_000
SEED = 17
FPS = 5.0
PASS_SHOTS = 600
UTC0_S = 1_795_300_000.0
CAMERA_OFFSET_S = 3600.37
CAMERA_DRIFT = 30e-6
P_MISS, P_MANUAL, P_UNTIMED = 0.005, 0.002, 0.001
CARD_VERSION = 1


def _events() -> list[dict[str, Any]]:
    """Every exposure attempt of the day in time order: kind, time [s from the recording's start], faults."""
    rng = random.Random(SEED)
    events: list[dict[str, Any]] = [{"t": -300.0, "kind": "test_shot", "index": 0}]
    t = 10.0
    index = 0
    while sum(1 for e in events if e["kind"] != "missed") < N_MAX + 10:
        for _ in range(PASS_SHOTS):
            t += 1.0 / FPS + rng.gauss(0.0, 0.002)
            index += 1
            missed = rng.random() < P_MISS
            events.append({"t": t, "kind": "missed" if missed else "trigger", "index": index})
            if rng.random() < P_MANUAL:
                events.append({"t": t + rng.uniform(0.05, 0.15), "kind": "manual", "index": 0})
        t += rng.uniform(20.0, 60.0)
    events.sort(key=lambda e: e["t"])
    for e in events:
        e["camera_s"] = UTC0_S + CAMERA_OFFSET_S + e["t"] * (1.0 + CAMERA_DRIFT) + rng.gauss(0.0, 0.002)
        e["untimed"] = rng.random() < P_UNTIMED
    return events


def _frames_and_truth(events: list[dict[str, Any]], n_images: int) -> tuple[list[Any], dict[str, int | None]]:
    """The frames the device recorded up to the n-th image, and image file name -> true frame_seq."""
    from icgt.geotag.record import FrameRecord

    frames: list[FrameRecord] = []
    truth: dict[str, int | None] = {}
    images = 0
    for e in events:
        if images >= n_images:
            break
        seq = None
        if e["kind"] != "test_shot":
            flags = {"missed": ["feedback_missing", "no_feedback"], "manual": ["unsolicited"]}.get(e["kind"], [])
            start_us = round(e["t"] * 1e6) + 5_000_000
            seq = len(frames) + 1
            frames.append(
                FrameRecord(
                    frame_seq=seq,
                    image_index=e["index"],
                    camera_id=0,
                    device_flags=0,
                    trigger_device_us=0 if e["kind"] == "manual" else start_us - 48_000,
                    start_device_us=start_us,
                    mid_device_us=start_us + 500,
                    duration_us=1000,
                    mid_host_ns=round(e["t"] * 1e9) + 500_000,
                    mid_host_uncertainty_ns=300_000,
                    time_source="pps",
                    flags=flags,
                    position_source="gps_3d",
                    fix_type=3,
                    pose_gap_before_ms=1.0,
                    pose_gap_after_ms=1.0,
                    mid_utc_us=round((UTC0_S + e["t"]) * 1e6) + 500,
                )
            )
        if e["kind"] == "missed":
            continue
        truth[_file_name(images)] = seq
        images += 1
    return frames, truth


def _file_name(k: int) -> str:
    return f"{100 + k // 9999}MSDCF/DSC{k % 9999 + 1:05d}.JPG"


def _card(resolution: str) -> Path:
    """The cached 18 000-image card of this EXIF resolution (written on first use, about a minute)."""
    from PIL import Image

    from icgt.sim.truth import exif_strings

    folder = CACHE / f"v{CARD_VERSION}_{resolution}"
    done = folder / "complete.json"
    if done.is_file():
        return folder
    events = [e for e in _events() if e["kind"] != "missed"][:N_MAX]
    print(f"writing the {resolution} card ({len(events)} JPEGs) to {folder} ...", file=sys.stderr, flush=True)
    img = Image.new("RGB", (16, 16), (90, 90, 90))
    for k, e in enumerate(events):
        path = folder / _file_name(k)
        path.parent.mkdir(parents=True, exist_ok=True)
        exif = img.getexif()
        exif.clear()
        ifd = exif.get_ifd(0x8769)
        ifd.clear()
        exif[0x010F], exif[0x0110] = "ICGT", "bench camera"
        if not e["untimed"]:
            text, subsec = exif_strings(e["camera_s"], resolution)
            exif[0x0132] = text
            ifd[0x9003] = text
            if subsec is not None:
                ifd[0x9291] = subsec
        img.save(path, format="JPEG", quality=80, exif=exif)
    done.write_text(json.dumps({"images": len(events)}))
    return folder


def _paths(card: Path, n: int) -> list[Path]:
    return [card / _file_name(k) for k in range(n)]


def _use_source(src: str) -> None:
    """Import `icgt` from `src` instead of the installed (editable) package: its import hook sits in
    sys.meta_path ahead of sys.path, so it is taken out."""
    sys.meta_path[:] = [f for f in sys.meta_path if not type(f).__module__.startswith("_editable")]
    sys.path.insert(0, src)


def _child(what: str, resolution: str, n: int) -> dict[str, Any]:
    card = _card(resolution)
    paths = _paths(card, n)
    out: dict[str, Any] = {}
    if what == "exif":
        from icgt.ingest.match import read_image_time

        t0, c0 = time.perf_counter(), time.process_time()
        times = [read_image_time(p) for p in paths]
        out["wall_s"], out["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        out["timed"] = sum(1 for t in times if t.time_s is not None)
    else:
        from icgt.ingest.match import match_images

        frames, truth = _frames_and_truth(_events(), n)
        t0, c0 = time.perf_counter(), time.process_time()
        result = match_images(frames, paths)
        out["wall_s"], out["cpu_s"] = time.perf_counter() - t0, time.process_time() - c0
        by_name = {p.image.relative_to(card).as_posix(): p.frame.frame_seq for p in result.pairs}
        out["wrong"] = sum(1 for name, seq in by_name.items() if truth[name] != seq)
        out["pairs"] = len(result.pairs)
        out["ambiguous"] = len(result.ambiguous)
        out["unmatched_images"] = len(result.unmatched_images)
        out["frames"] = len(frames)
        out["digest"] = hashlib.sha256(json.dumps(result.to_json()).encode()).hexdigest()
    out["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    return out


def _warm(paths: list[Path]) -> None:
    """Read the card once, untimed: floor and match then both read it from the page cache (measured cold,
    whichever ran first would pay the disk for both)."""
    for p in paths:
        p.read_bytes()


def _measure(what: str, resolution: str, n: int, src: str | None = None) -> dict[str, Any]:
    cmd = [sys.executable, __file__, "--child", what, "--resolutions", resolution, "--sizes", str(n)]
    if src is not None:
        cmd += ["--src", src]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    result: dict[str, Any] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default=",".join(str(s) for s in SIZES))
    parser.add_argument("--resolutions", default=",".join(RESOLUTIONS))
    parser.add_argument("--baseline", help="another revision's host/ folder, measured in the same run")
    parser.add_argument("--child", choices=("exif", "match"), help=argparse.SUPPRESS)
    parser.add_argument("--src", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.src:
        _use_source(args.src)
    sizes = [int(s) for s in args.sizes.split(",") if s]
    resolutions = [r for r in args.resolutions.split(",") if r]
    if any(not 0 < n <= N_MAX for n in sizes) or any(r not in RESOLUTIONS for r in resolutions):
        raise SystemExit(f"sizes 1..{N_MAX}, resolutions from {','.join(RESOLUTIONS)}")
    if args.child:
        print(json.dumps(_child(args.child, resolutions[0], sizes[0])))
        return 0
    for r in resolutions:
        _card(r)  # written outside the timed children
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores at the start")
    print(
        f"{'EXIF':>5} {'images':>6} | {'floor s':>7} {'cpu s':>6} {'MB':>5} | {'match s':>7} {'cpu s':>6} {'MB':>5} |"
        f" {'x floor':>7} {'(cpu)':>6} | {'pairs':>6} {'ambig':>5} {'wrong':>5}"
    )
    ok = True
    for r in resolutions:
        for n in sizes:
            _warm(_paths(_card(r), n))
            floor = _measure("exif", r, n)
            match = _measure("match", r, n)
            base = _measure("match", r, n, str(Path(args.baseline).resolve())) if args.baseline else None
            again = _measure("exif", r, n)
            floor = {
                **floor,
                "wall_s": min(floor["wall_s"], again["wall_s"]),
                "cpu_s": min(floor["cpu_s"], again["cpu_s"]),
            }
            ratio = match["wall_s"] / floor["wall_s"] if floor["wall_s"] > 0 else math.inf
            ratio_cpu = match["cpu_s"] / floor["cpu_s"] if floor["cpu_s"] > 0 else math.inf
            print(
                f"{r:>5} {n:>6} | {floor['wall_s']:>7.2f} {floor['cpu_s']:>6.2f} {floor['peak_rss_mb']:>5.0f} |"
                f" {match['wall_s']:>7.2f} {match['cpu_s']:>6.2f} {match['peak_rss_mb']:>5.0f} |"
                f" {ratio:>7.2f} {ratio_cpu:>6.2f} | {match['pairs']:>6} {match['ambiguous']:>5} {match['wrong']:>5}",
                flush=True,
            )
            ok = ok and match["wrong"] == 0
            if base is not None:
                same = "same" if base["digest"] == match["digest"] else "DIFFERENT results"
                print(
                    f"{'base':>5} {n:>6} | {'':>7} {'':>6} {'':>5} |"
                    f" {base['wall_s']:>7.2f} {base['cpu_s']:>6.2f} {base['peak_rss_mb']:>5.0f} |"
                    f" {base['wall_s'] / floor['wall_s']:>7.2f} {base['cpu_s'] / floor['cpu_s']:>6.2f} |"
                    f" {base['pairs']:>6} {base['ambiguous']:>5} {base['wrong']:>5}  {same}",
                    flush=True,
                )
                ok = ok and same == "same"
            if n == N_MAX:
                wall_ok = match["wall_s"] < 60.0 and match["peak_rss_mb"] < 1024.0 and ratio <= 3.0
                cpu_ok = match["cpu_s"] < 60.0 and match["peak_rss_mb"] < 1024.0 and ratio_cpu <= 3.0
                print(
                    f"    target (18 000 images: < 60 s, < 1 GB, <= 3 x floor): wall {'met' if wall_ok else 'MISSED'},"
                    f" cpu {'met' if cpu_ok else 'MISSED'}"
                )
    print(f"load average {os.getloadavg()[0]:.1f} at the end (other work on the machine inflates wall times)")
    print("peak RSS: ru_maxrss of each subprocess (interpreter and imports included); cpu: process time")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
