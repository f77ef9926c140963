#!/usr/bin/env python3
"""Benchmark: the recorder at 5, 10 and 20 fps, each figure next to the 5 fps baseline of the same run.

    .venv/bin/python benchmarks/capture_rates.py [--fps 5,10,20] [--capture-s 12] [--out bench-out/capture_rates]

Flies the deck_pass scenario (its unplug and link-drop faults removed) once per rate (interval capture,
started and stopped by the ground station, a camera with the Sony Alpha 9's 20 fps top rate, a 48 +- 2 ms
shutter lag and a buffer that never fills) through the real links (icgt.demo.fly) and prints, per rate:
- frames recorded against true exposures (every exposure paired: the derived feedback timeout at work);
- the recorder's CPU time (user + system of the `icgt record` process, not wall time) over the flight,
  in % of one core, and its increase over the 5 fps flight (the same start-up and telemetry in each);
- frame latency: from mid-exposure to the frame's CAMERA_IMAGE_CAPTURED at the ground station
  (p50 / p95 / max; the frame waits for the autopilot's pose after mid-exposure). A recorder that
  could not keep up would show a latency growing over the flight; the last tenth's p95 is printed too.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from icgt.demo import Flight, fly
from icgt.sim.evaluate import evaluate, read_frames, read_truth
from icgt.sim.scenario import Scenario, load_scenario


def scenario_at(fps: float, capture_s: float) -> Scenario:
    sc = load_scenario("deck_pass")
    start_s = 16.0  # the recorder and its camera component are up by then, even on a loaded machine
    cap = dataclasses.replace(
        sc.camera.capture, mode="interval", interval_ms=round(1000.0 / fps), start_s=start_s, stop_s=start_s + capture_s
    )
    cam = dataclasses.replace(sc.camera, capture=cap, max_fps=20.0, shutter_latency_us=48_000, shutter_jitter_us=2_000)
    faults = dataclasses.replace(sc.faults, manual_shots_s=(), autopilot_link_drops_s=(), device_unplugs_s=())
    return dataclasses.replace(
        sc, name=f"deck_{fps:g}fps", camera=cam, faults=faults, duration_s=start_s + capture_s + 3.0
    )


def latencies_ms(flight: Flight) -> list[float]:
    """Mid-exposure to CAMERA_IMAGE_CAPTURED at the ground station [ms] (both on the host's monotonic clock)."""
    mid = {int(fr["image_index"]): int(fr["mid_host_ns"]) for fr in read_frames(flight.mcap) if fr["image_index"]}
    return [
        (rx - mid[m.image_index]) / 1e6
        for m, rx in zip(flight.gcs.images, flight.gcs.image_rx_ns, strict=True)
        if m.image_index in mid
    ]


def pct(values: list[float]) -> str:
    a = np.asarray(values, dtype=float)
    if a.size == 0:
        return "n=0"
    return f"p50 {np.percentile(a, 50):7.1f}  p95 {np.percentile(a, 95):7.1f}  max {a.max():7.1f} ms"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fps", default="5,10,20", help="capture rates to fly, the first is the baseline")
    parser.add_argument("--capture-s", type=float, default=12.0)
    parser.add_argument("--out", type=Path, default=Path("bench-out/capture_rates"))
    args = parser.parse_args()
    rates = [float(x) for x in args.fps.split(",")]
    rows: list[dict[str, Any]] = []
    for fps in rates:
        sc = scenario_at(fps, args.capture_s)
        flight = fly(sc, args.out / sc.name)
        frames = read_frames(flight.mcap)
        result = evaluate(sc, frames, read_truth(flight.truth_exposures))
        lat = latencies_ms(flight)
        tail = lat[-max(1, len(lat) // 10) :]
        rows.append(
            {
                "fps": fps,
                "frames": result["frames"],
                "true_exposures": result["true_exposures"],
                "matched": result["matched"],
                "cpu_s": flight.recorder_cpu_s,
                "wall_s": flight.recorder_wall_s,
                "latency": lat,
                "tail_p95": float(np.percentile(tail, 95)) if tail else float("nan"),
            }
        )
    base = rows[0]
    print(f"\n== recorder at {', '.join(f'{r:g}' for r in rates)} fps (deck_pass, {args.capture_s:g} s of capture) ==")
    for r in rows:
        cpu_pct = 100.0 * r["cpu_s"] / r["wall_s"] if r["wall_s"] else float("nan")
        extra = r["cpu_s"] - base["cpu_s"]
        print(
            f"{r['fps']:5g} fps  frames {r['frames']:4d} ({r['matched']}/{r['true_exposures']} exposures paired)  "
            f"CPU {r['cpu_s']:6.2f} s = {cpu_pct:5.1f} % of a core ({extra:+.2f} s vs {base['fps']:g} fps)"
        )
        print(f"           frame latency {pct(r['latency'])}; last tenth p95 {r['tail_p95']:.1f} ms")
    (args.out / "capture_rates.json").write_text(
        json.dumps([{k: v for k, v in r.items() if k != "latency"} for r in rows], indent=1) + "\n"
    )
    return 0 if all(r["matched"] == r["true_exposures"] for r in rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
