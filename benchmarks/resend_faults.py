#!/usr/bin/env python3
"""Exposures recovered vs lost per fault (issue 12), and what the recovered frames carry (issue 27).

    .venv/bin/python benchmarks/resend_faults.py [--out DIR]              # the issue-12 fault flight
    .venv/bin/python benchmarks/resend_faults.py --outage 30 300 720     # unplugs of 30 s, 5 min, 12 min

Without --outage: the flight of tests/e2e/test_resend_faults.py (about 80 s of real time: a 30 s USB unplug,
three 3 s unplugs, bit flips at 1e-3 per byte for 10 s, a recorder kill -9 and restart), printing per fault
the exposures the camera made, those recorded, those that came back through RESEND and those lost.

With --outage S...: the same hover at 5 fps with the nominal sensor rates (IMU and range 100 Hz, fused
position 50 Hz), once without an unplug and once per unplug of S seconds (at 8 s, the capture running until
10 s after the cable is back; real time: S + 28 s a flight). For the exposures the unplug covered, it prints
against the same exposures window of the flight without the unplug: exposures recovered, frames posed, frames
ranged (and of those, ranged from the exposure's own sensor snapshot because the device no longer held the
samples: `range_from_snapshot`), the geotag error (median, 95 %, max) and the range error against the
simulator's truth, the frames
that lack a pose or range because of the outage, and the host's telemetry buffer memory at the end of the
flight (`TelemetryStore.memory_bytes` of a recompute of the log: the same synchroniser as the recorder).
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
from icgt.sim.outage_flight import UNPLUG_AT_S, FrameScore, OutageFlight, fly_outage, percentile  # noqa: E402
from icgt.sim.scenario import load_scenario  # noqa: E402


def _fault_table(out: Path) -> int:
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


def _telemetry_mib(flight: OutageFlight) -> float:
    """The host's telemetry buffers at the end of the flight [MiB], from a recompute of each log."""
    from icgt.ingest.recompute import recompute

    return max(recompute(path).counts["telemetry_bytes"] for path in flight.result.recordings) / 2**20


def _row(label: str, frames: list[FrameScore], exposures: int) -> str:
    posed = [f.geotag_error_m for f in frames if f.geotag_error_m is not None]
    ranged = [f.range_error_m for f in frames if f.range_error_m is not None]
    with_true_range = sum(f.true_range for f in frames)
    no_pose = sum("telemetry_expired" in f.flags for f in frames)
    no_range = sum("range_samples_lost" in f.flags for f in frames)
    from_snapshot = sum("range_from_snapshot" in f.flags for f in frames)
    return (
        f"{label:<26} {exposures:>9} {len(frames):>9} {len(posed):>6} {len(ranged):>4}/{with_true_range:<4} "
        f"{from_snapshot:>8} "
        f"{percentile(posed, 50) * 100:>6.1f} {percentile(posed, 95) * 100:>6.1f} {percentile(posed, 100) * 100:>6.1f} "
        f"{percentile(ranged, 100) * 100:>7.1f} {no_pose:>7} {no_range:>8}"
    )  # fmt: skip


def _outages(seconds: list[float], out: Path) -> int:
    sc = load_scenario(SCENARIO)
    print(
        f"{'flight / exposures':<26} {'exposures':>9} {'recovered':>9} {'posed':>6} {'ranged':>9} {'snapshot':>8} "
        f"{'p50 cm':>6} {'p95 cm':>6} {'max cm':>6} {'rng max':>7} {'no pose':>7} {'no range':>8}  telemetry MiB"
    )
    ok = True
    for s in seconds:
        ref = fly_outage(sc, 0.0, out / f"ref_{s:g}", stop_after_s=s)
        cut = fly_outage(sc, s, out / f"unplug_{s:g}")
        t0, t1 = UNPLUG_AT_S, UNPLUG_AT_S + s
        window_ref, window_cut = ref.between(t0, t1), cut.between(t0, t1)
        exposures_ref, exposures = ref.exposures_between(t0, t1), cut.exposures_between(t0, t1)
        print(_row(f"no unplug, same {s:g} s", window_ref, exposures_ref) + f"  {_telemetry_mib(ref):.1f}")
        print(_row(f"{s:g} s unplug", window_cut, exposures) + f"  {_telemetry_mib(cut):.1f}")
        print(_row(f"{s:g} s unplug: live frames", cut.window(False), len(cut.window(False))))
        ok = ok and len(window_cut) == exposures
    return 0 if ok else 1


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=None, help="keep the flights here (default: a temporary folder)")
    ap.add_argument("--outage", type=float, nargs="+", default=None, help="unplug lengths [s] (e.g. 30 300 720)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = args.out or Path(tmp)
        return _outages(args.outage, out) if args.outage else _fault_table(out)


if __name__ == "__main__":
    sys.exit(main())
