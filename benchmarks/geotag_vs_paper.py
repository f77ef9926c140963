#!/usr/bin/env python3
"""Benchmark: geotag error against ground truth, ICGT host against the paper's method, per scenario.

    .venv/bin/python benchmarks/geotag_vs_paper.py [--scenarios deck_pass hover pier_scan]
                                                   [--out build/bench/geotag] [--reuse DIR ...]

For each scenario of hil_sim/scenarios a simulated flight is flown with `icgt.demo.fly` (or an
existing flight folder is reused: `--reuse` takes folders as `icgt demo --out` leaves them, with
recording/*.mcap and sim/truth_exposures.jsonl). Every true exposure is then geotagged two ways:

- ours: the log's FrameRecord (pose interpolated to mid-exposure, lever arm applied), matched to
  the truth by the exposure-start edge on the device clock;
- the paper's: the LATEST GPS_RAW_INT position the host had received (host_rx_ns <= the arrival of
  the exposure's EXPOSURE message), as the ICGT firmware took the latest GPS string from ROS, and a
  time stamp from a 1 s RTC: the UTC of that arrival truncated to the second.

Printed per scenario: 3D position error [cm] against the true camera position and time error [ms]
against the true mid-exposure UTC, p50 / p95 / max, for both methods and their ratio (paper / ours).
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icgt.geodesy import LocalFrame
from icgt.sim.scenario import SCENARIO_DIR, Scenario, load_scenario

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Stats:
    p50: float
    p95: float
    max: float
    n: int

    @staticmethod
    def of(values: list[float]) -> Stats:
        if not values:
            return Stats(math.nan, math.nan, math.nan, 0)
        a = np.abs(np.asarray(values, dtype=float))
        return Stats(float(np.percentile(a, 50)), float(np.percentile(a, 95)), float(a.max()), len(a))

    def text(self, unit: str) -> str:
        return f"p50 {self.p50:9.3f}  p95 {self.p95:9.3f}  max {self.max:9.3f} {unit}  (n={self.n})"


def _scenario_of(folder: Path) -> Scenario:
    summary = folder / "summary.json"
    if summary.exists():
        name = json.loads(summary.read_text()).get("scenario")
        if isinstance(name, str):
            return load_scenario(name)
    first = (folder / "recorder.toml").read_text().splitlines()[0]
    return load_scenario(first.rsplit(" ", 1)[-1])


def evaluate_flight(scenario: Scenario, mcap: Path, truth_path: Path) -> dict[str, Stats | int]:
    from icgt.ingest import read

    recording = read(mcap)
    truth = [json.loads(line) for line in truth_path.read_text().splitlines() if line.strip()]
    by_start = {int(t["start_device_us"]): t for t in truth}
    enu = LocalFrame(scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.alt_m)

    def err_cm(lat: float, lon: float, alt: float, t: dict[str, Any]) -> float:
        got = enu.geodetic_to_enu(lat, lon, alt)
        want = enu.geodetic_to_enu(t["lat_deg"], t["lon_deg"], t["alt_msl_m"])
        return float(np.linalg.norm(np.asarray(got) - np.asarray(want))) * 100.0

    ours_pos: list[float] = []
    ours_time: list[float] = []
    for frame in recording.frames():
        t = by_start.get(frame.start_device_us)
        if t is None:
            continue
        if frame.lat_deg is not None and frame.lon_deg is not None and frame.alt_msl_m is not None:
            ours_pos.append(err_cm(frame.lat_deg, frame.lon_deg, frame.alt_msl_m, t))
        if frame.mid_utc_us is not None:
            ours_time.append((frame.mid_utc_us - int(t["mid_utc_us"])) / 1000.0)

    gps = sorted(
        (int(m["host_rx_ns"]), m)
        for _, m in recording.messages("/mavlink/gps_raw_int")
        if isinstance(m.get("host_rx_ns"), int)
    )
    gps_rx = [g[0] for g in gps]
    paper_pos: list[float] = []
    paper_time: list[float] = []
    paper_no_fix = 0
    for _, e in recording.messages("/device/exposure"):
        start = int(e.get("feedback_start_t_us") or e.get("trigger_t_us") or 0)
        t = by_start.get(start)
        rx = e.get("host_rx_ns")
        if t is None or not isinstance(rx, int):
            continue
        # RTC time of the log line: UTC at the exposure's arrival, truncated to the second
        arrival_utc_us = int(t["mid_utc_us"]) + (rx - int(t["mid_host_monotonic_ns"])) / 1000.0
        paper_time.append((math.floor(arrival_utc_us / 1e6) * 1e6 - int(t["mid_utc_us"])) / 1000.0)
        k = bisect.bisect_right(gps_rx, rx) - 1
        if k < 0:
            paper_no_fix += 1
            continue
        g = gps[k][1]
        if int(g.get("fix_type", 0)) < 2 or (g.get("lat") == 0 and g.get("lon") == 0):
            paper_no_fix += 1
            continue
        paper_pos.append(err_cm(g["lat"] / 1e7, g["lon"] / 1e7, g["alt"] / 1000.0, t))
    return {
        "ours_pos": Stats.of(ours_pos),
        "paper_pos": Stats.of(paper_pos),
        "ours_time": Stats.of(ours_time),
        "paper_time": Stats.of(paper_time),
        "paper_no_fix": paper_no_fix,
        "true_exposures": len(truth),
    }


def _ratio(a: float, b: float) -> str:
    return f"{a / b:8.1f}x" if b > 0 and math.isfinite(a) and math.isfinite(b) else "     n/a"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenarios", nargs="*", help="scenario names (default: every file in hil_sim/scenarios)")
    parser.add_argument("--out", type=Path, default=ROOT / "build" / "bench" / "geotag", help="where flights go")
    parser.add_argument("--reuse", nargs="*", type=Path, default=[], help="existing flight folders to evaluate")
    args = parser.parse_args()
    flights: list[tuple[Scenario, Path, Path]] = []
    for folder in args.reuse:
        mcaps = sorted((folder / "recording").glob("*.mcap"))
        if not mcaps:
            parser.error(f"{folder}: no recording/*.mcap")
        flights.append((_scenario_of(folder), mcaps[-1], folder / "sim" / "truth_exposures.jsonl"))
    if not args.reuse:
        from icgt.demo import fly

        names = args.scenarios or sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))
        for name in names:
            sc = load_scenario(name)
            print(f"flying {sc.name} ({sc.duration_s:.0f} s) ...", flush=True)
            flight = fly(sc, args.out / sc.name)
            flights.append((sc, flight.mcap, flight.truth_exposures))
    print()
    print("geotag error against truth: ours (interpolated to mid-exposure) vs the paper (latest GPS, 1 s RTC)")
    for sc, mcap, truth in flights:
        r = evaluate_flight(sc, mcap, truth)
        op, pp, ot, pt = r["ours_pos"], r["paper_pos"], r["ours_time"], r["paper_time"]
        assert isinstance(op, Stats) and isinstance(pp, Stats) and isinstance(ot, Stats) and isinstance(pt, Stats)
        print(f"\n== {sc.name}: {r['true_exposures']} true exposures ==")
        print(f"  position  ours  {op.text('cm')}")
        print(
            f"  position  paper {pp.text('cm')}"
            + (f"  ({r['paper_no_fix']} without a fix)" if r["paper_no_fix"] else "")
        )
        print(f"  position  ratio paper/ours: p50 {_ratio(pp.p50, op.p50)}  p95 {_ratio(pp.p95, op.p95)}")
        print(f"  time      ours  {ot.text('ms')}")
        print(f"  time      paper {pt.text('ms')}")
        print(f"  time      ratio paper/ours: p50 {_ratio(pt.p50, ot.p50)}  p95 {_ratio(pt.p95, ot.p95)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
