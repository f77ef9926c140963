#!/usr/bin/env python3
"""Benchmark: the recorder on a simulated flight, each figure next to its peer.

    .venv/bin/python benchmarks/recorder_flight.py [--scenario deck_pass] [--out bench-out/recorder]

Runs one flight through the real links (icgt.demo.fly) and prints, against the simulator's truth:
- device -> host clock error at mid-exposure (p95 target 50 us; VersaVIS, quoted: sigma 311 us);
- the timing part of the geotag error (|true velocity| x mid-exposure time error; target p95 2 cm),
  next to what PX4 / ArduPilot do, measured here on the same log: copy the latest GLOBAL_POSITION_INT
  received before the exposure (its staleness x the true speed);
- exposure -> CAMERA_IMAGE_CAPTURED at the ground station (p95 target 100 ms, GLOBAL_POSITION_INT at 50 Hz);
- the recorder's CPU use at the scenario's rates, in % of one core.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from icgt.demo import fly
from icgt.sim.evaluate import read_frames, read_truth
from icgt.sim.scenario import load_scenario
from icgt.sim.trajectory import Trajectory


def pct(values: list[float]) -> str:
    a = np.abs(np.asarray(values, dtype=float))
    return f"p50 {np.percentile(a, 50):8.3f}  p95 {np.percentile(a, 95):8.3f}  max {a.max():8.3f}  (n={a.size})"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="deck_pass")
    parser.add_argument("--out", type=Path, default=Path("bench-out/recorder"))
    parser.add_argument(
        "--warmup-s",
        type=float,
        default=12.0,
        help="also report the clock error of exposures this long after the recorder started (a filter needs "
        "exchanges near the link's floor; real captures start minutes after the recorder)",
    )
    args = parser.parse_args()
    sc = load_scenario(args.scenario)
    flight = fly(sc, args.out)
    frames = read_frames(flight.mcap)
    truth = {int(t["start_device_us"]): t for t in read_truth(flight.truth_exposures)}
    traj = Trajectory(sc)

    from mcap.reader import make_reader

    fused_rx: list[int] = []
    with flight.mcap.open("rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=["/mavlink/global_position_int"]):
            fused_rx.append(int(json.loads(m.data)["host_rx_ns"]))
    fused_rx.sort()

    clock_us: list[float] = []
    clock_settled_us: list[float] = []
    ours_cm: list[float] = []
    peer_cm: list[float] = []
    for fr in frames:
        t = truth.get(int(fr["start_device_us"]))
        if t is None or "clock_unsynced" in fr["flags"]:
            continue
        true_mid = int(t["mid_host_monotonic_ns"])
        speed = float(np.linalg.norm(traj.state(np.array([float(t["mid_tau_s"])])).velocity_enu_m_s[0]))
        dt_ns = int(fr["mid_host_ns"]) - true_mid
        clock_us.append(dt_ns / 1000.0)
        if float(t["mid_tau_s"]) >= args.warmup_s:
            clock_settled_us.append(dt_ns / 1000.0)
        ours_cm.append(abs(dt_ns) * 1e-9 * speed * 100.0)
        if {"stale_pose", "pose_extrapolated", "no_fix", "no_attitude"} & set(fr["flags"]):
            continue  # an autopilot outage: both methods are blind, and ours says so in the flags
        # The peer at its best: the latest estimate the autopilot had at the true mid-exposure
        # (what PX4 and ArduPilot copy into CAMERA_FEEDBACK), aged from its arrival here, which is
        # ~2 ms after it was produced: the peer is given those 2 ms.
        i = int(np.searchsorted(fused_rx, true_mid)) - 1
        if i >= 0:
            stale_ns = max(0, true_mid - fused_rx[i] - 2_000_000)
            peer_cm.append(stale_ns * 1e-9 * speed * 100.0)

    pose_flags = {"stale_pose", "pose_extrapolated", "no_fix", "no_attitude"}
    seq_of_image: dict[int, int] = {}  # MAVLink image index -> frame_seq (the log's /camera/images)
    with flight.mcap.open("rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=["/camera/images"]):
            rec = json.loads(m.data)
            seq_of_image[int(rec["image_index"])] = int(rec["frame_seq"])
    by_seq = {int(fr["frame_seq"]): fr for fr in frames}
    mid_by_index = {}
    for index, seq in seq_of_image.items():
        fr = by_seq[seq]
        t = truth.get(int(fr["start_device_us"]))
        if t is not None and not pose_flags & set(fr["flags"]):
            mid_by_index[index] = int(t["mid_host_monotonic_ns"])
    latency_ms = [
        (rx - mid_by_index[m.image_index]) / 1e6
        for m, rx in zip(flight.gcs.images, flight.gcs.image_rx_ns, strict=True)
        if m.image_index in mid_by_index
    ]
    cpu = 100.0 * flight.recorder_cpu_s / flight.recorder_wall_s if flight.recorder_wall_s else float("nan")
    p95 = float(np.percentile(np.abs(clock_settled_us or clock_us), 95))
    timing95 = float(np.percentile(ours_cm, 95))
    peer95 = float(np.percentile(peer_cm, 95)) if peer_cm else float("nan")
    lat95 = float(np.percentile(latency_ms, 95)) if latency_ms else float("nan")
    print(f"scenario {sc.name}: {len(frames)} frames, {len(truth)} true exposures")
    print(f"device->host clock error [us]        {pct(clock_us)}  all frames")
    if clock_settled_us:
        print(f"                                     {pct(clock_settled_us)}  tau >= {args.warmup_s:.0f} s")
    print(
        f"   target p95 <= 50 us; VersaVIS (quoted, not measured here): mean 179 us, sigma 311 us"
        f"  -> {'OK' if p95 <= 50 else 'ABOVE TARGET'}"
    )
    print(f"timing part of geotag error [cm]     {pct(ours_cm)}")
    print(f"   latest-pose copy (PX4/ArduPilot)  {pct(peer_cm) if peer_cm else 'n/a'}")
    print(
        f"   target p95 <= 2 cm -> {'OK' if timing95 <= 2 else 'ABOVE TARGET'}; ratio peer/ours p95 "
        f"{peer95 / timing95 if timing95 else float('inf'):.0f}x"
    )
    print(
        f"exposure -> CAMERA_IMAGE_CAPTURED [ms] {pct(latency_ms) if latency_ms else 'n/a'}  (frames whose "
        "pose is not flagged: a frame waiting out an autopilot outage is late by design)"
    )
    print(f"   target p95 <= 100 ms -> {'OK' if lat95 <= 100 else 'ABOVE TARGET'}")
    print(
        f"recorder CPU                         {cpu:.1f} % of one core over {flight.recorder_wall_s:.0f} s "
        f"(IMU {sc.sensors.imu_rate_hz:.0f} Hz, range {sc.sensors.range_rate_hz:.0f} Hz, "
        f"GLOBAL_POSITION_INT {sc.autopilot.rates_hz.get('global_position_int', 0):.0f} Hz requested 50 Hz)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
