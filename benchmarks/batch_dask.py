#!/usr/bin/env python3
"""Benchmark: `icgt batch catalog-add` of N flights on a Dask LocalCluster of 1 and of 2 workers.

    .venv/bin/python benchmarks/batch_dask.py [--flights 20] [--frames 2000]

The flights are synthesised (tests/catalog/synth_logs.py: frame records with the project's MCAP writer, a
camera card and detections, so each task reads the log, pairs the card and runs the damage map). Each run
adds every flight into a fresh catalogue through `icgt.batch.run_batch` (a LocalCluster of 1 or 2 worker
processes, one thread each); the wall time includes starting the cluster. The two catalogues are checked
to hold the same flights.

Goal: wall(1 worker) / wall(2 workers) >= 1.7 (on a machine with 2 free cores: the ratio measures the
machine as much as the code when other work shares the cores).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "catalog"))

import synth_logs as sl  # noqa: E402
from conftest import make_flight  # noqa: E402

from icgt.batch import resolve, run_batch  # noqa: E402
from icgt.catalog.store import Catalog  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--frames", type=int, default=2000)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="icgt-bench-batch-"))
    try:
        for i in range(args.flights):
            make_flight(work / f"f{i:03d}", sl.Synth(n=args.frames, seed=i, serial=f"{2000000 + i}",
                                                      recording_id=0x2000 + i))  # fmt: skip
        flights = [resolve(work / f"f{i:03d}") for i in range(args.flights)]
        walls = {}
        for n in (1, 2):
            cat = work / f"cat{n}"
            t = time.perf_counter()
            outcomes = run_batch("catalog-add", flights, {"catalog": str(cat), "structure": "pier-7"}, workers=n,
                                 progress=False)  # fmt: skip
            walls[n] = time.perf_counter() - t
            bad = [o for o in outcomes if not o.ok]
            if bad:
                print(f"{n} worker(s): {len(bad)} flights failed: {bad[0].error}")
                return 1
            tasks = sum(o.seconds for o in outcomes)
            # the wall split: the tasks' own time (what a busier core stretches) against the rest (the cluster's
            # start, the scheduler, a worker idle at the end)
            print(f"{n} worker(s): {args.flights} flights x {args.frames} frames in {walls[n]:.1f} s "
                  f"({args.flights / walls[n]:.2f} flights/s); tasks {tasks:.1f} s in all, "
                  f"{tasks / len(outcomes):.2f} s each; wall - tasks / {n}: {walls[n] - tasks / n:.1f} s")  # fmt: skip
        same = [p.name for p in Catalog(work / "cat1").partitions()] == [
            p.name for p in Catalog(work / "cat2").partitions()
        ]
        ratio = walls[1] / walls[2]
        print(f"wall ratio 1 / 2 workers: {ratio:.2f} (goal >= 1.7); catalogues {'equal' if same else 'DIFFER'}; "
              f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")  # fmt: skip
        ok = ratio >= 1.7 and same
        print("goal met" if ok else "goal NOT met")
        return 0 if ok else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
