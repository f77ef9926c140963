"""The interpreter settings a recording runs with, applied when it starts and restored when it stops.

- GIL switch interval 1 ms (Python's default is 5 ms). The readers release the GIL for every read; a
  thread busy in Python (the worker, the log writer) that grabs it keeps it for the switch interval, so a
  reader could take one datagram per 5 ms and a flood backs up in the socket until the kernel drops it.
- The cyclic garbage collector. By default it runs a young collection every 700 container allocations and
  a full one every 100 young ones; a full collection walks every object of the process, ~100 ms for the
  recorder's (pymavlink's dialect, protobuf, the telemetry buffers), several times a minute: measured on
  a replayed flight, 0.45 s of collections per 31 s of flight, the largest single cost after the inputs
  themselves. What exists once the recorder is up (modules, configuration) is frozen (`gc.freeze`: never
  scanned again) and the young generation collected every 10 000 allocations: 0.16 s per 31 s. The data
  path makes almost no reference cycles (messages are freed by reference counting as soon as they are
  written), so collecting less often holds little garbage.
"""

from __future__ import annotations

import gc
import sys

SWITCH_INTERVAL_S = 0.001
"""The GIL's switch interval while recording [s]."""
GC_THRESHOLDS = (10_000, 20, 10)
"""gc.set_threshold while recording: young collection every 10 000 allocations, older ones rarer."""


class InterpreterTuning:
    """`apply()` when the recording is up (after start-up, so that start-up's objects are frozen), `restore()`
    when it stops; both idempotent."""

    def __init__(self) -> None:
        self._saved: tuple[float, tuple[int, int, int]] | None = None

    def apply(self) -> None:
        if self._saved is not None:
            return
        threshold = gc.get_threshold()
        self._saved = (sys.getswitchinterval(), (threshold[0], threshold[1], threshold[2]))
        sys.setswitchinterval(min(self._saved[0], SWITCH_INTERVAL_S))
        gc.collect()
        gc.freeze()
        gc.set_threshold(*GC_THRESHOLDS)

    def restore(self) -> None:
        if self._saved is None:
            return
        interval, threshold = self._saved
        self._saved = None
        sys.setswitchinterval(interval)
        gc.set_threshold(*threshold)
        gc.unfreeze()
