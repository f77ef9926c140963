#!/usr/bin/env python3
"""Exposures recovered vs lost per fault (issue 12): one simulated flight with every fault.

    .venv/bin/python benchmarks/resend_faults.py [--out DIR]

Runs the flight of tests/e2e/test_resend_faults.py (about 80 s of real time: a 30 s USB unplug,
three 3 s unplugs, bit flips at 1e-3 per byte for 10 s, a recorder kill -9 and restart) and prints,
per fault, the exposures the camera made, those recorded, those that came back through RESEND and
those lost; then the totals and the recordings' own loss count.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests" / "e2e"), str(ROOT / "tests")]  # the flight of the e2e test

from test_resend_faults import PLAN, SCENARIO  # noqa: E402

from icgt.sim.fault_flight import fly_faults  # noqa: E402
from icgt.sim.scenario import load_scenario  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the flight here (default: a temporary folder)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        r = fly_faults(load_scenario(SCENARIO), PLAN, out)
    print(f"{'fault':<30} {'exposures':>9} {'recorded':>9} {'resent':>7} {'lost':>5}")
    for c in r.faults:
        print(f"{c.name:<30} {c.exposures:>9} {c.recorded:>9} {c.recovered:>7} {c.exposures - c.recorded:>5}")
    print(
        f"{'whole flight':<30} {r.true_exposures:>9} {r.recorded_exposures:>9} {'':>7} "
        f"{r.true_exposures - r.recorded_exposures:>5}"
    )
    print(f"lost exposures the recordings report: {r.reported_lost_exposures}")
    print("device link summary (last recording): " + ", ".join(f"{k}={v}" for k, v in sorted(r.link_summary.items())))
    return 0 if r.true_exposures == r.recorded_exposures else 1


if __name__ == "__main__":
    sys.exit(main())
