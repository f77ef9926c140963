"""Child process of the kill -9 test: records at a fixed rate until it is killed.

    python kill_writer.py OUT.mcap RATE_HZ

Alternates a foxglove.LocationFix and a JSON dataclass record, log_time = time.time_ns(). After each
write() returns it prints the log time (ns since the Unix epoch), so the parent knows what was
handed to the recorder before the kill. Prints "started" once the recorder is open.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Annotated

from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix

from icgt.recording import Doc, McapRecorder


@dataclass(frozen=True)
class Tick:
    """A counter sample."""

    n: Annotated[int, Doc("message number")]
    value_m: Annotated[float, Doc("some distance", unit="m")]


def main() -> None:
    path, rate_hz = sys.argv[1], float(sys.argv[2])
    period_s = 1.0 / rate_hz
    recorder = McapRecorder(path)
    recorder.add_metadata("device", {"serial": "KILLTEST"})
    print("started", flush=True)
    n = 0
    next_t = time.monotonic()
    while True:
        t_ns = time.time_ns()
        if n % 2:
            recorder.write("/tick", Tick(n, n * 0.01), t_ns)
        else:
            fix = LocationFix(latitude=47.0 + n * 1e-6, longitude=8.0, altitude=500.0, frame_id="gps")
            fix.timestamp.FromNanoseconds(t_ns)
            recorder.write("/fix", fix, t_ns)
        print(t_ns, flush=True)
        n += 1
        next_t += period_s
        time.sleep(max(0.0, next_t - time.monotonic()))


if __name__ == "__main__":
    main()
