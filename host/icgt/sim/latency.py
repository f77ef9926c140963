"""When each frame's inputs were there and when the recorder emitted it, from the log alone.

A frame can be emitted once two inputs are in: the device's exposure record and the autopilot's telemetry
after mid-exposure (the first GLOBAL_POSITION_INT and the first ATTITUDE_QUATERNION stamped at or after it;
the later of their kernel receive stamps). What the recorder adds is its emission minus the later of the
two: the recorder's own share of the latency a ground station sees, whatever the simulator's or the
machine's load did to the inputs.

The device sends an exposure record once its sensor snapshot is settled: the first IMU and range samples
read at or after mid-exposure are in (firmware `SensorSnapshot::settled`), or the exposure has ended if
later. That moment, on the device clock from the log's own sample stamps and carried to the host clock by
the frame's mid-exposure, is when the record could be read; the USB transfer after it (about 1 ms) counts as
the recorder's, so the share is an upper bound.

Device times are compared within one device boot (a log whose device rebooted mixes two clocks here).
Used by benchmarks/capture_rates.py (with the truth's mid-exposure for the total) and by the end-to-end
tests that bound the recorder's share.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

import icgt
from icgt.recording import layout

__all__ = ["FrameTiming", "frame_timings"]

TELEMETRY_TOPICS = ("/mavlink/global_position_int", "/mavlink/attitude_quaternion")
SAMPLE_READ_STAMPS = {"/device/imu": "read_end_t_us", "/device/range": "read_t_us"}  # the device clock [us]


@dataclasses.dataclass(frozen=True)
class FrameTiming:
    """One emitted frame's times [host monotonic ns]; nan where the log does not say."""

    frame_seq: int
    start_device_us: int
    mid_host_ns: int
    exposure_end_host_ns: int
    record_ready_host_ns: int  # the device could send the record: exposure over and its snapshot settled
    exposure_rx_ns: float  # the exposure record's receipt stamp (when a reader or the worker read it)
    telemetry_rx_ns: float  # the later arrival of the first position and attitude samples at/after mid
    emitted_host_ns: float

    @property
    def inputs_in_ns(self) -> float:
        """When both inputs were there: the exposure record ready to send or the telemetry, the later."""
        return _later(float(self.record_ready_host_ns), self.telemetry_rx_ns)

    @property
    def recorder_ms(self) -> float:
        """The recorder's own share: emission minus `inputs_in_ns` [ms]."""
        return (self.emitted_host_ns - self.inputs_in_ns) / 1e6


def _later(*times: float) -> float:
    """The latest of `times`, nan if any is nan (Python's max() keeps or drops a nan by its position)."""
    return math.nan if any(math.isnan(t) for t in times) else max(times)


def _first_at_or_after(stamps: np.ndarray, rx: np.ndarray, t: float) -> float:
    """The receipt of the first sample stamped at or after t (stamps sorted), nan if none."""
    i = int(np.searchsorted(stamps, t, side="left"))
    return float(rx[i]) if i < stamps.size else math.nan


def frame_timings(mcap: Path) -> list[FrameTiming]:
    """Every emitted frame of the log, in frame order, with its inputs' arrivals (see the module doc)."""
    rec = icgt.read(mcap)
    clocks = [m for _, m in rec.messages(layout.CLOCK_AUTOPILOT) if m["valid"]]
    exposures = {
        int(m["feedback_start_t_us"] or m["trigger_t_us"]): int(m["host_rx_ns"])
        for _, m in rec.messages("/device/exposure")
    }
    streams = {}
    for topic in TELEMETRY_TOPICS:
        rows = sorted((int(m["time_boot_ms"]) * 1000, int(m["host_rx_ns"])) for _, m in rec.messages(topic))
        streams[topic] = (np.array([r[0] for r in rows], dtype=float), np.array([r[1] for r in rows], dtype=float))
    samples = [
        np.array(sorted(int(m[stamp]) for _, m in rec.messages(topic)), dtype=float)
        for topic, stamp in SAMPLE_READ_STAMPS.items()
    ]
    ref_ns = np.array([int(c["ref_host_ns"]) for c in clocks], dtype=float)
    out = []
    for f in rec.frames():
        mid = int(f.mid_host_ns)
        tel = math.nan
        if clocks:
            c = clocks[int(np.argmin(np.abs(ref_ns - mid)))]  # the autopilot clock map of the time
            mid_boot_us = float(c["ref_clock_us"]) + (mid - int(c["ref_host_ns"])) / 1e3 * (
                1 + float(c["drift_ppm"]) * 1e-6
            )
            tel = _later(*(_first_at_or_after(*streams[t], mid_boot_us) for t in TELEMETRY_TOPICS))
        end_us = int(f.mid_device_us) + int(f.duration_us) // 2
        ready_us = float(end_us)
        for read in samples:  # the first sample of each sensor read at or after mid-exposure, if any came
            i = int(np.searchsorted(read, float(f.mid_device_us), side="left"))
            if i < read.size:
                ready_us = max(ready_us, float(read[i]))
        out.append(
            FrameTiming(
                frame_seq=int(f.frame_seq),
                start_device_us=int(f.start_device_us),
                mid_host_ns=mid,
                exposure_end_host_ns=mid + int(f.duration_us) * 500,
                record_ready_host_ns=mid + round((ready_us - int(f.mid_device_us)) * 1000),
                exposure_rx_ns=float(exposures.get(int(f.start_device_us), math.nan)),
                telemetry_rx_ns=tel,
                emitted_host_ns=math.nan if f.emitted_host_ns is None else float(f.emitted_host_ns),
            )
        )
    return out
