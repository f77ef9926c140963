#!/usr/bin/env python3
"""Benchmark: the recorder's CPU use, at nominal rates and under a MAVLink flood, next to a floor.

    .venv/bin/python benchmarks/recorder_cpu.py [--out bench-out/recorder_cpu] [--flood-hz 10000]

1. Nominal: the deck_pass scenario (5 fps, IMU 100 Hz, range 500 Hz, GLOBAL_POSITION_INT 50 Hz and the
   other telemetry) flown through the real links with `icgt record` as its own process; its CPU time is
   read from /proc between two instants of the capture (steady state: start-up and imports excluded).
2. Flood: the same flight while another process sends ``--flood-hz`` MAVLink messages per second from
   ten foreign systems to the recorder's UDP port (a busy shared network or a swarm on one radio).
3. Floor: the same raw inputs (every MAVLink frame and every device message of the nominal flight's
   log, re-framed) pushed through what any recorder must do at least: pymavlink's parser for MAVLink,
   the protocol decoder for the device bytes, and the official mcap Writer storing each message raw.
   Measured in one process as CPU seconds per second of flight (no threads, no I/O waits: a floor).

4. Recompute: the nominal flight's log recomputed offline with its own settings (the same synchroniser);
   CPU time per second of flight, scaled to one hour.

Targets (issue 14): nominal <= 5 % of one core, flood < 30 %.
"""

from __future__ import annotations

import argparse
import base64
import io
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

from icgt.demo import fly
from icgt.ingest.reader import read
from icgt.sim.scenario import load_scenario

CLK_TCK = os.sysconf("SC_CLK_TCK")


def cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLK_TCK


def find_recorder(out: Path, timeout_s: float = 60.0) -> tuple[int, int]:
    """(pid, MAVLink UDP port) of the `icgt record` process writing under `out`."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for d in Path("/proc").iterdir():
            if not d.name.isdigit():
                continue
            try:
                argv = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"record" in argv and str(out.resolve()).encode() in b" ".join(argv):
                url = argv[argv.index(b"--mavlink") + 1].decode()
                return int(d.name), int(url.rsplit(":", 1)[1])
        time.sleep(0.2)
    raise RuntimeError(f"no recorder process for {out}")


class Sampler(threading.Thread):
    """Reads the recorder's CPU time at two wall-clock offsets after it appears."""

    def __init__(self, out: Path, t0_s: float, t1_s: float, flood_hz: float = 0.0) -> None:
        super().__init__(daemon=True)
        self.out, self.t0, self.t1, self.flood_hz = out, t0_s, t1_s, flood_hz
        self.result = float("nan")
        self.flood_sent = 0

    def run(self) -> None:
        pid, port = find_recorder(self.out)
        start = time.monotonic()
        flooder = None
        if self.flood_hz > 0:
            flooder = subprocess.Popen(
                [sys.executable, __file__, "--flood-worker", str(port), str(self.flood_hz), str(self.t1 + 5)],
                stdout=subprocess.PIPE,
                text=True,
            )
        time.sleep(max(0.0, self.t0 - (time.monotonic() - start)))
        c0, w0 = cpu_s(pid), time.monotonic()
        time.sleep(max(0.0, self.t1 - (time.monotonic() - start)))
        c1, w1 = cpu_s(pid), time.monotonic()
        self.result = 100.0 * (c1 - c0) / (w1 - w0)
        if flooder is not None:
            out, _ = flooder.communicate(timeout=30)
            self.flood_sent = int(out.strip() or 0)


def flood_worker(port: int, hz: float, duration_s: float) -> None:
    """Send `hz` MAVLink 2 telemetry messages per second (ten foreign systems) to 127.0.0.1:port."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    frames: list[bytes] = []
    for sysid in range(42, 52):
        mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=1)
        for k in range(20):
            msgs = [
                mav.attitude_encode(k * 20, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0),
                mav.global_position_int_encode(k * 20, 473_977_419, 85_455_938, 488_000, 10_000, 0, 0, 0, 0),
                mav.gps_raw_int_encode(k * 20_000, 3, 473_977_419, 85_455_938, 488_000, 80, 120, 0, 0, 12),
                mav.param_value_encode(b"PARAM_%d" % k, float(k), 9, 900, k),
            ]
            frames += [bytes(m.pack(mav)) for m in msgs]
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sent = 0
    start = time.monotonic()
    period = 0.005
    per_tick = max(1, round(hz * period))
    i = 0
    while time.monotonic() - start < duration_s:
        for _ in range(per_tick):
            sock.sendto(frames[i % len(frames)], ("127.0.0.1", port))
            i += 1
        sent += per_tick
        time.sleep(max(0.0, start + sent / hz - time.monotonic()))
    print(sent)


def _flight_inputs(mcap: Path) -> tuple[list[tuple[int, str, Any]], float]:
    """The flight's raw inputs in log order: (host receive ns, kind, raw MAVLink frame or device message)."""
    from icgt.ingest.recompute import device_message, iter_inputs
    from icgt.recording import layout

    out: list[tuple[int, str, Any]] = []
    for m in iter_inputs(read(mcap)):
        if m.topic.startswith(layout.MAVLINK_PREFIX) and isinstance(m.data.get("raw"), str):
            out.append((int(m.data["host_rx_ns"]), "mavlink", base64.b64decode(m.data["raw"])))
        elif m.topic in layout.DEVICE_TOPIC_TYPES:
            msg = device_message(layout.DEVICE_TOPIC_TYPES[m.topic], m.data)
            out.append((int(m.data["host_rx_ns"]), "device", msg))
    times = [t for t, _, _ in out]
    return out, (max(times) - min(times)) / 1e9


def floor_cpu_percent(inputs: list[tuple[int, str, Any]], flight_s: float) -> float:
    """CPU % of one core for the inputs parsed and stored raw, as a minimal recorder would."""
    from mcap.writer import Writer
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from icgt.protocol import StreamDecoder, encode_frame

    framed = [(t, k, encode_frame(x, i) if k == "device" else x) for i, (t, k, x) in enumerate(inputs, start=1)]
    t0 = time.process_time()
    w = Writer(io.BytesIO())
    w.start()
    schema = w.register_schema("raw", "", b"")
    ch_m = w.register_channel("/mavlink", "raw", schema)
    ch_d = w.register_channel("/device", "raw", schema)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    dec = StreamDecoder()
    for t, kind, b in framed:
        if kind == "mavlink":
            for msg in parser.parse_buffer(b) or []:
                w.add_message(ch_m, t, bytes(msg.get_msgbuf()), t)
        else:
            for _ in dec.feed(b):
                w.add_message(ch_d, t, b, t)
    w.finish()
    return 100.0 * (time.process_time() - t0) / flight_s


def ours_offline_cpu_percent(inputs: list[tuple[int, str, Any]], flight_s: float, tmp: Path) -> float:
    """CPU % of one core for the same inputs through the recorder's worker (payloads, log, synchroniser,
    frames every 10 ms of flight time) and the MAVLink parser, without threads or links."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink2

    from icgt.mavlink.link import MavlinkMessage
    from icgt.protocol import StreamDecoder, encode_frame
    from icgt.recorder import Recorder
    from icgt.recorder.config import RecorderConfig
    from icgt.recorder.recorder import _DEVICE, _MAVLINK
    from icgt.recording import McapRecorder

    framed = [(t, k, encode_frame(x, i) if k == "device" else x) for i, (t, k, x) in enumerate(inputs, start=1)]
    t0 = time.process_time()
    rec = Recorder(RecorderConfig())
    rec.mcap = McapRecorder(tmp)
    rec._register_topics()  # the benchmark drives the worker's own steps (no device, no links)
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    dec = StreamDecoder()
    next_poll = framed[0][0]
    for t, kind, b in framed:
        if kind == "mavlink":
            for msg in parser.parse_buffer(b) or []:
                rec._handle((_MAVLINK, MavlinkMessage(msg, t), t))
        else:
            for received in dec.feed(b):
                rec._handle((_DEVICE, received, t))
        if t >= next_poll:
            rec._work_once(t)
            next_poll = t + 10_000_000
    rec.mcap.close()
    cpu = time.process_time() - t0
    tmp.unlink(missing_ok=True)
    return 100.0 * cpu / flight_s


def main() -> int:
    if len(sys.argv) > 1 and sys.argv[1] == "--flood-worker":
        flood_worker(int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4]))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("bench-out/recorder_cpu"))
    parser.add_argument("--flood-hz", type=float, default=10_000.0)
    parser.add_argument("--scenario", default="deck_pass")
    parser.add_argument("--offline-only", type=Path, metavar="MCAP", help="only part 3, on an existing log")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.offline_only is None:
        sc = load_scenario(args.scenario)
        results: dict[str, tuple[float, int, Any]] = {}
        for name, flood_hz in (("nominal", 0.0), ("flood", args.flood_hz)):
            out = (args.out / name).resolve()
            sampler = Sampler(out, 12.0, 27.0, flood_hz)
            sampler.start()
            flight = fly(sc, out)
            sampler.join(timeout=60)
            results[name] = (sampler.result, sampler.flood_sent, flight)
        nominal_cpu, _, flight = results["nominal"]
        flood_cpu, sent, flood_flight = results["flood"]
        counters = [d for _, d in read(flood_flight.mcap).messages("/icgt/counters")]
        got = counters[-1].get("mavlink", {}).get("undecoded_frames", 0) if counters else 0
        print(f"recorder CPU, steady state, {sc.name} (5 fps, IMU 100 Hz, range 500 Hz, telemetry 50 Hz)")
        print(f"  nominal rates                 {nominal_cpu:6.1f} % of one core   (target <= 5 %)")
        flood = f"  + {args.flood_hz:,.0f} foreign msg/s flood"
        print(f"{flood:32s}{flood_cpu:6.1f} % of one core   (target < 30 %; {sent} sent, {got} logged)")
        mcap = flight.mcap
    else:
        mcap = args.offline_only
    inputs, flight_s = _flight_inputs(mcap)
    floor = floor_cpu_percent(inputs, flight_s)
    ours = ours_offline_cpu_percent(inputs, flight_s, args.out / "offline.mcap")
    print(f"  the same {flight_s:.0f} s of inputs in one process, no threads or links:")
    print(f"    floor: pymavlink parse + mcap raw write            {floor:6.1f} % of one core")
    print(f"    the recorder's worker (log, synchroniser, frames)  {ours:6.1f} % of one core")
    from icgt.ingest.recompute import recompute

    t0 = time.process_time()
    result = recompute(mcap)
    cpu = time.process_time() - t0
    per_hour_s = cpu / flight_s * 3600.0
    print(
        f"  recompute (icgt.ingest.recompute, own settings): {cpu:.1f} s CPU for {flight_s:.0f} s of flight, "
        f"{len(result.frames)} frames -> {per_hour_s / 60:.1f} min per hour of flight at these rates"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
