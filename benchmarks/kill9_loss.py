"""kill -9 loss of the MCAP recorder on a loaded machine, next to its bound; and what smaller chunks cost.

    python benchmarks/kill9_loss.py [--kills 8] [--rate-hz 200]

Part 1. The recorder (`McapRecorder`, default chunk interval, fsync on) in a child process
(tests/recording/kill_writer.py) writes a LocationFix / JSON pair at `--rate-hz`, while one busy-loop process
per core keeps every core loaded. The parent follows the file (ChunkTail, every 10 ms) and kills the child
with SIGKILL after 2-4 s. For each kill it prints the loss at the kill (the age of the oldest message handed
over but not in the file `icgt recover` makes of it) and the worst such age at any look along the way (what a
kill at that moment would have lost), next to KILL9_LOSS_BOUND_S (0.5 s: chunk interval 0.25 s + 0.25 s in
flight) and the recorder's promise of 1 s.

Part 2. The size and CPU of the same message stream (60 s at `--rate-hz`, zstd) in 0.25 s chunks against
1 s chunks, written by `McapFileWriter` to memory: the overhead of flushing more often.
"""

from __future__ import annotations

import argparse
import io
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix

from icgt.recording import recover
from icgt.recording.mcap_file import McapFileWriter
from icgt.recording.writer import CHUNK_INTERVAL_S, KILL9_LOSS_BOUND_S, ChunkTail
from icgt.sim.cpu_load import CpuBurners

CHILD = Path(__file__).resolve().parents[1] / "tests" / "recording" / "kill_writer.py"
PROMISE_S = 1.0


def _one_kill(path: Path, rate_hz: float, run_s: float) -> tuple[float, float, int]:
    """(loss at the kill [s], worst loss along the way [s], messages handed over)."""
    proc = subprocess.Popen([sys.executable, str(CHILD), str(path), str(rate_hz)], stdout=subprocess.PIPE, text=True)
    lines: list[str] = []
    try:
        assert proc.stdout is not None
        if proc.stdout.readline().strip() != "started":
            raise RuntimeError("the writer did not start")
        reader = threading.Thread(target=lambda: lines.extend(proc.stdout or ()), daemon=True)
        reader.start()
        tail = ChunkTail(path)
        looks: list[tuple[int, int | None]] = []
        end = time.monotonic() + run_s
        while time.monotonic() < end:
            now = time.time_ns()
            looks.append((now, tail.poll()))
            time.sleep(0.01)
        kill_ns = time.time_ns()
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=10)
        reader.join(timeout=10)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    handed = [int(line) for line in lines]
    fixed = path.with_suffix(".recovered.mcap")
    recover(path, fixed)
    newest = ChunkTail(fixed).poll()
    saved_to = -1 if newest is None else newest
    lost = [t for t in handed if t > saved_to]
    at_kill = (kill_ns - lost[0]) / 1e9 if lost else 0.0
    worst = 0.0
    for look_ns, on_disk in looks:
        floor = -1 if on_disk is None else on_disk
        missing = next((t for t in handed if floor < t <= look_ns), None)
        if missing is not None:
            worst = max(worst, (look_ns - missing) / 1e9)
    return at_kill, max(worst, at_kill), len(handed)


def _messages(rate_hz: float, seconds: float) -> list[tuple[int, int, bytes]]:
    """(channel, log time, data) of kill_writer's mix: a LocationFix and a small JSON record, alternating."""
    out = []
    t0 = 1_700_000_000_000_000_000
    for n in range(int(rate_hz * seconds)):
        t = t0 + int(n * 1e9 / rate_hz)
        if n % 2:
            out.append((2, t, f'{{"n":{n},"value_m":{n * 0.01}}}'.encode()))
        else:
            fix = LocationFix(latitude=47.0 + n * 1e-6, longitude=8.0, altitude=500.0, frame_id="gps")
            fix.timestamp.FromNanoseconds(t)
            out.append((1, t, fix.SerializeToString()))
    return out


def _chunked_size(messages: list[tuple[int, int, bytes]], per_chunk: int) -> tuple[int, float]:
    """(file bytes, CPU s) of `messages` closed into chunks of `per_chunk` messages."""
    stream = io.BytesIO()
    cpu0 = time.process_time()
    writer = McapFileWriter(stream)
    writer.add_schema(1, "foxglove.LocationFix", "protobuf", b"")
    writer.add_schema(2, "Tick", "jsonschema", b"{}")
    writer.add_channel(1, "/fix", "protobuf", 1, {})
    writer.add_channel(2, "/tick", "json", 2, {})
    for k, (channel, t, data) in enumerate(messages):
        writer.add_message(channel, t, t, data, k)
        if (k + 1) % per_chunk == 0:
            writer.close_chunk()
    writer.finish()
    return len(stream.getvalue()), time.process_time() - cpu0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=8)
    parser.add_argument("--rate-hz", type=float, default=200.0)
    args = parser.parse_args()
    print(f"load average at start {' '.join(f'{x:.1f}' for x in os.getloadavg())} on {os.cpu_count()} CPUs")
    print(
        f"kill -9 of the recorder at {args.rate_hz:.0f} msg/s, chunk interval {CHUNK_INTERVAL_S} s, "
        f"{os.cpu_count()} busy-loop processes (every core loaded)"
    )
    worst_at_kill = worst_any = 0.0
    with tempfile.TemporaryDirectory() as tmp, CpuBurners() as burners:
        for k in range(args.kills):
            at_kill, worst, n = _one_kill(Path(tmp) / f"kill{k}.mcap", args.rate_hz, random.uniform(2.0, 4.0))
            worst_at_kill, worst_any = max(worst_at_kill, at_kill), max(worst_any, worst)
            print(f"  kill {k + 1}: {n:5d} messages written, lost at the kill {at_kill:.3f} s, "
                  f"worst along the way {worst:.3f} s", flush=True)  # fmt: skip
        load = os.getloadavg()[0]
    print(f"load average under the burners ({burners.count}) {load:.1f}")
    verdict = "holds" if worst_any <= KILL9_LOSS_BOUND_S else "BROKEN"
    print(
        f"worst loss: {worst_at_kill:.3f} s at a kill, {worst_any:.3f} s at any moment; "
        f"bound {KILL9_LOSS_BOUND_S} s ({verdict}), promise {PROMISE_S} s"
    )
    messages = _messages(args.rate_hz, 60.0)
    quarter, quarter_cpu = _chunked_size(messages, max(1, int(args.rate_hz * CHUNK_INTERVAL_S)))
    whole, whole_cpu = _chunked_size(messages, max(1, int(args.rate_hz * 1.0)))
    print(
        f"write overhead, 60 s at {args.rate_hz:.0f} msg/s (zstd): {CHUNK_INTERVAL_S} s chunks {quarter / 1e3:.1f} kB, "
        f"{quarter_cpu * 1e3:.0f} ms CPU; 1 s chunks {whole / 1e3:.1f} kB, {whole_cpu * 1e3:.0f} ms CPU "
        f"(+{(quarter / whole - 1) * 100:.1f} % size)"
    )
    return 0 if worst_any <= KILL9_LOSS_BOUND_S else 1


if __name__ == "__main__":
    sys.exit(main())
