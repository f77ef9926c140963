#!/usr/bin/env python3
"""Benchmark: the recorder's memory over a long capture (issue 30, part 4), RSS per minute next to its bound.

    .venv/bin/python benchmarks/soak.py [--minutes 30] [--fps 5] [--out bench-out/soak]

The deck_pass scenario (IMU 100 Hz, range 500 Hz, GLOBAL_POSITION_INT 50 Hz and the other telemetry) flown
for `--minutes` with the camera triggered at `--fps` throughout, `icgt record` as its own process (the real
serial and UDP links, a ground station commanding capture). The recorder's resident set (VmRSS of
/proc/PID/status) is read every 10 s and printed per minute; the growth is the least-squares slope over the
last third of the capture (WARM_UP_FRACTION). The first two thirds hold the warm-up: the telemetry kept for the
device's history horizon (about 11-12 min with the simulated Teensy 4.1's rings) fills, and the allocator's
arenas settle after it; measured, RSS rose until minute ~19 of a 30 min run. So only the default 30 min says
whether the rest is flat; a shorter run prints its slope but says it is inside the warm-up.
Bound: flat after warm-up, <= GROWTH_BOUND_MIB_PER_MIN. What still grows with the recording and is stated:
the published times of the camera images, 8 bytes per image in memory (0.002 MiB/min at 5 fps); the MCAP
chunk index and the image history wait on disk (icgt.spill).

Measured 2026-12-04, `--minutes 10` (inside the horizon): RSS 58.6 -> 133.7 MiB, +6.8 MiB/min, the rate at
which the retained telemetry grew before it was held packed. `--minutes 9` with the telemetry retention cut
to 90 s (warm-up over after ~2 min; a probe outside the repository read smaps, malloc_info and
sys.getallocatedblocks every 30 s): RSS 62.5 -> 75.3 MiB, +0.37 MiB/min over the second half (ABOVE the
bound) while Python's allocated blocks (~380 k) and glibc's main arena (13 MiB) stayed flat: the growth was
free memory kept in the reader/writer threads' malloc arenas, now given back by the recorder every 30 s
(`icgt.recorder.native_heap`). Measured 2026-12-06, `--minutes 30` after the chunk index and image history
moved to disk: RSS 66.6 -> 106.8 MiB, rising to minute ~19, then +0.09 MiB/min over minutes 20-30 (within).
Measured 2026-12-07, `--minutes 30` (tests shared the machine for its first 13 min): RSS 67.3 -> 108.3 MiB, rising to
minute 19 (107.1), then 107.2 -> 108.3 over minutes 20-30: the fit says +0.122 MiB/min, ABOVE the bound. The
two runs straddle it. Found (a probe outside the repository, the 90 s retention, 16 min): Python's traced
allocations flat (+0.03 MB in 10 min), glibc's in-use memory flat, the free chunks kept in the thread
arenas +0.1 MiB/min; the recorder now gives its threads one arena (icgt.recorder.native_heap). Measured
2026-12-07 after that, `--minutes 30` (a fresh-clone CI run and benchmarks shared the machine for its first
20 min): RSS 67.0 -> 108.1 MiB, rising to minute 19 (107.3), then +0.028 MiB/min over minutes 20-30 (within).
"""

from __future__ import annotations

import argparse
import tempfile
import threading
import time
from pathlib import Path

import msgspec
import numpy as np
from recorder_cpu import find_recorder

from icgt.demo import fly
from icgt.sim.scenario import Scenario, load_scenario

GROWTH_BOUND_MIB_PER_MIN = 0.1
"""Allowed RSS slope after the warm-up [MiB/min]: the 8 B/image that stays in memory is 0.002; the rest is the
allocator's noise (a few MiB up or down in one minute on a 100 MiB process)."""
WARM_UP_FRACTION = 2.0 / 3.0
"""The slope is fitted over the capture after this fraction of it: minute 20 of the default 30."""
WARM_UP_MIN = 19.0
"""Measured end of the warm-up [min] at deck_pass rates: a fit window starting earlier says nothing."""
SAMPLE_S = 10.0


def soak_scenario(minutes: float, fps: float) -> Scenario:
    sc = load_scenario("deck_pass")
    start_s = 16.0  # the recorder and its camera component are up by then, even on a loaded machine
    capture_s = minutes * 60.0
    cap = msgspec.structs.replace(
        sc.camera.capture, mode="interval", interval_s=1.0 / fps, start_s=start_s, stop_s=start_s + capture_s
    )
    faults = msgspec.structs.replace(sc.faults, manual_shots_s=(), autopilot_link_drops_s=(), device_unplugs_s=())
    return msgspec.structs.replace(
        sc, name=f"soak_{minutes:g}min", camera=msgspec.structs.replace(sc.camera, capture=cap), faults=faults,
        duration_s=start_s + capture_s + 3.0,
    )  # fmt: skip


def rss_mib(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


class Sampler(threading.Thread):
    """RSS of the recorder every SAMPLE_S seconds from the moment its log appears: (minutes, MiB) pairs."""

    def __init__(self, out: Path) -> None:
        super().__init__(daemon=True)
        self.out = out
        self.samples: list[tuple[float, float]] = []
        self.stop = threading.Event()

    def run(self) -> None:
        pid, _port = find_recorder(self.out)
        deadline = time.monotonic() + 120.0
        while not list((self.out / "recording").glob("*.mcap")) and time.monotonic() < deadline:
            time.sleep(0.1)
        t0 = time.monotonic()
        while not self.stop.is_set():
            value = rss_mib(pid)
            if value is None:
                return
            self.samples.append(((time.monotonic() - t0) / 60.0, value))
            self.stop.wait(SAMPLE_S)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--fps", type=float, default=5.0)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="icgt-soak-"))
    sc = soak_scenario(args.minutes, args.fps)
    sampler = Sampler(out)
    sampler.start()
    flight = fly(sc, out)
    sampler.stop.set()
    sampler.join(timeout=SAMPLE_S + 5)
    samples = sampler.samples
    print(f"soak: deck_pass, {args.minutes:g} min at {args.fps:g} fps, recorder exit {flight.recorder_exit}")
    print(" minute   RSS MiB")
    shown = -1
    for m, v in samples:
        if int(m) > shown:
            shown = int(m)
            print(f" {m:6.1f}   {v:7.1f}")
    if len(samples) < 4:
        print("too few samples for a slope")
        return 1
    t = np.array([m for m, _ in samples])
    v = np.array([x for _, x in samples])
    start = t[-1] * WARM_UP_FRACTION
    window = t >= start
    slope = float(np.polyfit(t[window], v[window], 1)[0])
    verdict = "within" if slope <= GROWTH_BOUND_MIB_PER_MIN else "ABOVE"
    if start < WARM_UP_MIN:
        verdict = f"run inside the warm-up, which lasts to minute ~{WARM_UP_MIN:g}: no verdict; " + verdict
    print(
        f"growth over minutes {start:.1f}-{t[-1]:.1f}: {slope:+.3f} MiB/min ({verdict} the bound "
        f"{GROWTH_BOUND_MIB_PER_MIN} MiB/min); "
        f"RSS {v[0]:.1f} -> {v[-1]:.1f} MiB; peer: the issue's measurement +0.7 MiB/min (58 -> 81 MiB in 10 min)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
