#!/usr/bin/env python3
"""Benchmark: a MAVLink flood on the recorder's UDP port with every core busy: read, dropped, accounted.

    .venv/bin/python benchmarks/mavlink_flood.py [--rates 2000,5000,10000] [--flood-s 8] [--burners N] [--out DIR]

For each rate, the deck_pass scenario is flown with `icgt record` as its own process (icgt.demo.fly) while
one busy-loop process per core (or `--burners`) keeps the machine loaded. Once the recorder's MAVLink socket
is bound, another process sends real pymavlink-encoded telemetry of ten foreign systems (the flood of
benchmarks/recorder_cpu.py: ATTITUDE, GLOBAL_POSITION_INT, GPS_RAW_INT, PARAM_VALUE; one frame per datagram)
at that rate for `--flood-s` seconds. From the log's last /icgt/counters: the flood frames the recorder read
(undecoded_frames: foreign frames are kept raw), the datagrams the kernel dropped for its socket
(kernel_drops) and the receive buffer it was granted; the kernel's own count (/proc/net/udp 'drops' of that
port) is read after the flood as a check. Printed per rate: sent, read, dropped, sent - read - dropped (0:
every datagram accounted for; negative: autopilot datagrams were dropped too), and the bound: how long the
granted buffer lets the recorder be held up at that rate before the kernel drops (twice the granted size, as
Linux books it, / the kernel's per-datagram charge, measured, / rate).
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from recorder_cpu import find_recorder, flood_frames

from icgt.demo import fly
from icgt.ingest.reader import read
from icgt.mavlink.udp_stamps import SO_MEMINFO, rmem_max
from icgt.sim.cpu_load import CpuBurners
from icgt.sim.scenario import load_scenario

FLOODER = Path(__file__).with_name("recorder_cpu.py")


def per_datagram_charge() -> float:
    """Bytes of receive buffer the kernel charges for one flood datagram (its skb truesize), measured."""
    frames = flood_frames()[:200]
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        rx.bind(("127.0.0.1", 0))
        for f in frames:
            tx.sendto(f, rx.getsockname())
        time.sleep(0.05)
        used = int.from_bytes(rx.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 64)[:4], "little")
        return used / len(frames)
    finally:
        rx.close()
        tx.close()


def proc_udp_drops(port: int) -> int | None:
    """The 'drops' column of /proc/net/udp for the socket bound to `port`."""
    for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[1].split(":")[1], 16) == port:
            return int(fields[-1])
    return None


class Flood(threading.Thread):
    """Waits for the recorder's MAVLink socket, then floods it for `seconds` at `hz` (a separate process)."""

    def __init__(self, out: Path, hz: float, seconds: float) -> None:
        super().__init__(daemon=True)
        self.out, self.hz, self.seconds = out, hz, seconds
        self.sent = 0
        self.kernel_drops: int | None = None
        self.took_s = 0.0

    def run(self) -> None:
        _, port = find_recorder(self.out, timeout_s=120.0)
        deadline = time.monotonic() + 60.0
        while proc_udp_drops(port) is None and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(1.0)  # the recorder's first steps (stream-rate requests, the camera) before the flood
        t0 = time.monotonic()
        got = subprocess.run(
            [sys.executable, str(FLOODER), "--flood-worker", str(port), str(self.hz), str(self.seconds)],
            capture_output=True, text=True, check=True,
        )  # fmt: skip
        self.took_s = time.monotonic() - t0
        self.sent = int(got.stdout.strip() or 0)
        time.sleep(1.0)  # the recorder reads what is still in the buffer
        self.kernel_drops = proc_udp_drops(port)


def last_counters(flight: Any) -> dict[str, int]:
    counters = [d for _, d in read(flight.mcap).messages("/icgt/counters")]
    mav = counters[-1].get("mavlink", {}) if counters else {}
    return {k: int(v) for k, v in mav.items() if isinstance(v, int)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[1])
    parser.add_argument("--rates", default="2000,5000,10000", help="flood rates [msg/s], comma-separated")
    parser.add_argument("--flood-s", type=float, default=8.0)
    parser.add_argument("--out", type=Path, default=Path("bench-out/mavlink_flood"))
    parser.add_argument("--burners", type=int, default=None, help="busy loops (default: one per core)")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    sc = load_scenario("deck_pass")
    charge = per_datagram_charge()
    print(f"load average at start {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")
    print(f"net.core.rmem_max {rmem_max()} bytes; the kernel charges {charge:.0f} bytes of buffer per flood datagram")
    rows = []
    subprocess.run([sys.executable, "-c", "import icgt.cli, icgt.recorder.recorder"], check=True)  # warm caches
    for hz in rates:
        out = (args.out / f"flood-{int(hz)}").resolve()
        with CpuBurners(args.burners) as burners:
            flood = Flood(out, hz, args.flood_s)
            flood.start()
            flight = fly(sc, out)
            flood.join(timeout=120)
            load = os.getloadavg()[0]
        c = last_counters(flight)
        read_n, drops = c.get("undecoded_frames", 0), c.get("kernel_drops", 0)
        granted, asked = c.get("udp_receive_buffer_bytes", 0), c.get("udp_receive_buffer_asked_bytes", 0)
        # Linux books twice the SO_RCVBUF value it reports as granted (room for its overhead): sk_rcvbuf
        hold_s = 2 * granted / charge / hz if granted else float("nan")
        rows.append((hz, flood.sent, flood.took_s, read_n, drops, flood.kernel_drops, granted, asked, hold_s))
        print(f"  {hz:,.0f} msg/s: {burners.count} burners, load {load:.1f}: sent {flood.sent} in "
              f"{flood.took_s:.1f} s, read {read_n}, kernel drops {drops} (kernel's count {flood.kernel_drops})",
              flush=True)  # fmt: skip
        time.sleep(3.0)
    print(f"MAVLink flood on the recorder's UDP port, {burners.count} busy loops on {os.cpu_count()} CPUs, deck_pass")
    print(f"{'rate msg/s':>11s} {'sent':>7s} {'read':>7s} {'dropped':>8s} {'kernel':>7s} {'unaccounted':>12s}  bound")
    for hz, sent, _, read_n, drops, kdrops, granted, asked, hold_s in rows:
        verdict = "kept up" if drops == 0 else "drops counted"
        print(
            f"{hz:11,.0f} {sent:7d} {read_n:7d} {drops:8d} {kdrops if kdrops is not None else '?':>7} "
            f"{sent - read_n - drops:12d}  buffer {granted} bytes granted of {asked} asked: the recorder may be "
            f"held up {hold_s:.2f} s at this rate before the kernel drops ({verdict})"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
