#!/usr/bin/env python3
"""Benchmark: the inspection catalogue against reading every MCAP, on N flights x M frames.

    .venv/bin/python benchmarks/catalog.py [--flights 200] [--frames 1000] [--repeat 5]

The flights are synthesised frame records written with the project's MCAP writer (tests/catalog/synth_logs.py:
the recorder's metadata, /frames, one HEARTBEAT), two structures, five years, some frames without a pose and
some flights with lost exposures. Printed, all measured in this run:

- add throughput: `icgt catalog add` of every flight, one after the other (flights/s, frames/s), with add's own
  compaction (a structure's partitions merged into a group once there are 32 of them: icgt.catalog.compact);
- the catalogue's size against the MCAPs' size, and its Parquet files;
- then twice, on the catalogue as the adds left it and after `icgt catalog compact` (timed):
  query latency (p95 of --repeat runs) of the README's example queries, with a fresh DuckDB connection
  each (what `icgt catalog query` pays: loading the spatial extension, listing the partitions) and on an
  open connection (`icgt.catalog.query.connect`, a notebook's or a service's way), against the peer: the
  same answer computed by reading every MCAP with `icgt.read` (the frames and the metadata); both answers
  are compared and must be equal.

Goal: every query >= 100x faster than its peer (open connection), p95 < 1 s (fresh connection). (The
defects query has no peer here: it needs each flight's damage map; its latency is printed alone.)
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyproj

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "catalog"))

import synth_logs as sl  # noqa: E402

import icgt  # noqa: E402
from icgt.catalog.cli import add_flight  # noqa: E402
from icgt.catalog.query import connect, query  # noqa: E402
from icgt.catalog.store import compact  # noqa: E402
from icgt.geodesy import LocalFrame  # noqa: E402

RADIUS_M = 5.0
GSD_MAX = 0.43


def synth(i: int, frames: int) -> tuple[sl.Synth, str]:
    structure = "pier-7" if i % 2 == 0 else "bridge-2"
    s = sl.Synth(n=frames, seed=i, serial=f"{1000000 + i}", recording_id=0x1000 + i,
                 start_utc=datetime(2021 + i % 5, 5, 1 + i % 28, 9, 0, tzinfo=UTC),
                 no_pose_every=0 if i % 3 else 97, lost_exposures=1 if i % 7 == 0 else 0)  # fmt: skip
    return s, structure


def peer_near(logs: list[Path], lat: float, lon: float) -> set[tuple[str, int]]:
    geod = pyproj.Geod(ellps="WGS84")
    out = set()
    for log in logs:
        rec = icgt.read(log)
        md = rec.metadata
        fid = f"{md['icgt.device']['serial_number']}-{md['icgt.flight']['recording_id'].removeprefix('0x').lower()}"
        frames = [f for f in rec.frames() if f.lat_deg is not None and f.scale_mm_per_px is not None]
        if not frames:
            continue
        lons = np.array([f.lon_deg for f in frames])
        lats = np.array([f.lat_deg for f in frames])
        d = geod.inv(np.full(len(frames), lon), np.full(len(frames), lat), lons, lats)[2]
        for f, dist in zip(frames, d, strict=True):
            if dist <= RADIUS_M and f.scale_mm_per_px is not None and f.scale_mm_per_px < GSD_MAX:
                out.add((fid, f.frame_seq))
    return out


def peer_losses(logs: list[Path]) -> set[str]:
    out = set()
    for log in logs:
        rec = icgt.read(log)
        md = rec.metadata
        fid = f"{md['icgt.device']['serial_number']}-{md['icgt.flight']['recording_id'].removeprefix('0x').lower()}"
        lost = int(md.get("icgt.device_link", {}).get("lost_exposures", "0"))
        if lost > 0 or any(f.lat_deg is None for f in rec.frames()):
            out.add(fid)
    return out


def timed(fn: Any, repeat: int) -> tuple[float, Any]:
    times, result = [], None
    for _ in range(repeat):
        t = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t)
    return float(np.percentile(times, 95)), result


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--flights", type=int, default=200)
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="icgt-bench-catalog-"))
    try:
        logs, structures = [], []
        for i in range(args.flights):
            s, structure = synth(i, args.frames)
            (work / "logs").mkdir(exist_ok=True)
            log = work / "logs" / f"flight{i:04d}.mcap"
            sl.write_log(log, replace(s))
            logs.append(log)
            structures.append(structure)
        cat = work / "cat"
        t = time.perf_counter()
        compactions = sum(add_flight(cat, log, structure).compacted > 0 for log, structure in
                          zip(logs, structures, strict=True))  # fmt: skip
        add_s = time.perf_counter() - t
        mcap_bytes = sum(p.stat().st_size for p in logs)
        n = args.flights * args.frames
        print(f"{args.flights} flights x {args.frames} frames ({n} frames)")
        print(f"add: {args.flights / add_s:.2f} flights/s, {n / add_s:.0f} frames/s ({add_s:.1f} s in all, "
              f"{compactions} of the adds compacted their structure)")  # fmt: skip

        lat, lon, _ = (float(v) for v in LocalFrame(*sl.ORIGIN).enu_to_geodetic([2.5, 8.0, 3.0]))
        near_sql = (f"SELECT flight, frame_seq FROM frames WHERE within_m(geometry, ST_Point({lon!r}, {lat!r}), "
                    f"{RADIUS_M}) AND scale_mm_per_px < {GSD_MAX}")  # fmt: skip
        loss_sql = ("SELECT DISTINCT fl.flight FROM flights fl LEFT JOIN frames fr ON fr.flight = fl.flight AND "
                    "fr.geometry IS NULL WHERE fl.lost_exposures > 0 OR fr.frame_seq IS NOT NULL")  # fmt: skip
        cases = [
            ("frames within 5 m, GSD < 0.43 mm/px", near_sql,
             lambda t: {(r["flight"], r["frame_seq"]) for r in t.to_pylist()}, lambda: peer_near(logs, lat, lon)),
            ("flights with a lost exposure or a frame without pose", loss_sql,
             lambda t: {r["flight"] for r in t.to_pylist()}, lambda: peer_losses(logs)),
        ]  # fmt: skip
        peers = {}
        for name, _sql, _as_set, peer in cases:
            peers[name] = timed(peer, max(1, args.repeat // 5))
        ok = measure(cat, mcap_bytes, "as the adds left it", cases, peers, args.repeat)
        t = time.perf_counter()
        results = compact(cat)
        print(f"icgt catalog compact: {time.perf_counter() - t:.1f} s "
              f"({sum(r.merged for r in results)} folders merged)")  # fmt: skip
        ok &= measure(cat, mcap_bytes, "after icgt catalog compact", cases, peers, args.repeat)
        print("goal met" if ok else "goal NOT met")
        return 0 if ok else 1
    finally:
        shutil.rmtree(work, ignore_errors=True)


DEFECTS_SQL = ("SELECT d.structure, year(f.start_utc) AS year, d.kind, count(*) AS n, sum(d.length_mm) "
               "FROM defects d JOIN flights f USING (structure, flight) GROUP BY ALL")  # fmt: skip


def measure(cat: Path, mcap_bytes: int, state: str, cases: list[Any], peers: dict[str, Any], repeat: int) -> bool:
    """Every query's latency on the catalogue in its present state against its peer; whether the goals are met."""
    cat_bytes = sum(p.stat().st_size for p in cat.rglob("*") if p.is_file())
    files = len(list(cat.rglob("*.parquet")))
    print(f"catalogue {state}: {cat_bytes / 1e6:.1f} MB in {files} Parquet files, MCAPs {mcap_bytes / 1e6:.1f} MB "
          f"({cat_bytes / mcap_bytes:.2f} of the MCAPs)")  # fmt: skip
    ok = True
    con = connect(cat)
    for name, sql, as_set, _peer in cases:
        q_p95, table = timed(lambda sql=sql: query(cat, sql), repeat)
        w_p95, warm = timed(lambda sql=sql: con.sql(sql).to_arrow_table(), repeat)
        p_p95, truth = peers[name]
        same = as_set(table) == truth == as_set(warm)
        ok &= same and p_p95 / w_p95 >= 100 and q_p95 < 1.0
        print(f"  query '{name}': {len(truth)} rows, answers {'equal' if same else 'DIFFER'}\n"
              f"    reading every MCAP with icgt.read (peer): {p_p95 * 1000:.0f} ms\n"
              f"    fresh connection (icgt catalog query): p95 {q_p95 * 1000:.0f} ms (goal < 1000 ms), "
              f"{p_p95 / q_p95:.1f}x faster\n"
              f"    open connection (icgt.catalog.query.connect): p95 {w_p95 * 1000:.1f} ms, "
              f"{p_p95 / w_p95:.0f}x faster (goal >= 100x)")  # fmt: skip
    con.close()
    d_p95, _ = timed(lambda: query(cat, DEFECTS_SQL), repeat)
    ok &= d_p95 < 1.0
    print(f"  query 'defects by class per structure per year': p95 {d_p95 * 1000:.0f} ms (goal < 1000 ms; no peer)")
    return ok


if __name__ == "__main__":
    sys.exit(main())
