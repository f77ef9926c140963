"""Score a recording against the simulator's ground truth: matching, geotag, timing and clock errors.

Frames are paired with true exposures by the exposure-start edge on the device clock, which
the simulated device stamps exactly; a frame whose trigger the camera ignored has no true
exposure (and must be flagged feedback_missing), and a true exposure without a frame is a
loss. Errors are measured in the scenario's ENU frame against the camera position truth.
"""

from __future__ import annotations

import json
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icgt.geodesy import LocalFrame
from icgt.recording import RecordingError
from icgt.sim.scenario import Scenario
from icgt.sim.trajectory import Trajectory

_POSE_FLAGS = {"stale_pose", "pose_extrapolated", "no_fix", "no_attitude", "clock_unsynced"}


@dataclass(frozen=True)
class Percentiles:
    p50: float
    p95: float
    max: float
    n: int

    @staticmethod
    def of(values: list[float]) -> Percentiles:
        if not values:
            return Percentiles(float("nan"), float("nan"), float("nan"), 0)
        a = np.abs(np.asarray(values, dtype=float))
        return Percentiles(float(np.percentile(a, 50)), float(np.percentile(a, 95)), float(a.max()), len(values))

    def as_dict(self) -> dict[str, float | int]:
        return {"p50": self.p50, "p95": self.p95, "max": self.max, "n": self.n}


def read_frames(mcap_path: Path) -> list[dict[str, Any]]:
    """The /frames records of a recording, read with the official mcap reader."""
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with mcap_path.open("rb") as f:
            return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=["/frames"])]
    except (McapError, OSError, ValueError) as exc:
        raise RecordingError(f"cannot read frames from {mcap_path}: {exc} (try `icgt recover`)") from exc


def read_truth(path: Path) -> list[dict[str, Any]]:
    with path.open() as f:
        return [json.loads(line) for line in f if line.strip()]


def evaluate(scenario: Scenario, frames: list[dict[str, Any]], truth: list[dict[str, Any]]) -> dict[str, Any]:
    """Everything the demo summary and the benchmarks print."""
    by_start = {int(t["start_device_us"]): t for t in truth}
    frame = LocalFrame(scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.alt_m)
    traj = Trajectory(scenario)
    matched: list[tuple[dict[str, Any], dict[str, Any]]] = []
    unmatched_frames: list[dict[str, Any]] = []
    seen: set[int] = set()
    for fr in frames:
        t = by_start.get(int(fr["start_device_us"]))
        if t is None or int(fr["start_device_us"]) in seen:
            unmatched_frames.append(fr)
        else:
            seen.add(int(fr["start_device_us"]))
            matched.append((fr, t))
    missed = [t for start, t in by_start.items() if start not in seen]
    wrongly_unflagged = [fr for fr in unmatched_frames if "feedback_missing" not in fr.get("flags", [])]

    pos_err_cm: list[float] = []
    trusted_err_cm: list[float] = []  # frames without a pose-quality flag: what a user would keep
    horiz_err_cm: list[float] = []
    time_err_ms: list[float] = []
    timing_part_cm: list[float] = []
    utc_err_ms: list[float] = []
    for fr, t in matched:
        dt_ns = int(fr["mid_host_ns"]) - int(t["mid_host_monotonic_ns"])
        time_err_ms.append(dt_ns / 1e6)
        speed = float(np.linalg.norm(traj.state(np.array([float(t["mid_tau_s"])])).velocity_enu_m_s[0]))
        timing_part_cm.append(abs(dt_ns) * 1e-9 * speed * 100.0)
        if fr.get("mid_utc_us") is not None:
            utc_err_ms.append((int(fr["mid_utc_us"]) - int(t["mid_utc_us"])) / 1000.0)
        if fr.get("lat_deg") is None:
            continue
        got = frame.geodetic_to_enu(fr["lat_deg"], fr["lon_deg"], fr["alt_msl_m"])
        want = frame.geodetic_to_enu(t["lat_deg"], t["lon_deg"], t["alt_msl_m"])
        d = np.asarray(got, dtype=float) - np.asarray(want, dtype=float)
        pos_err_cm.append(float(np.linalg.norm(d)) * 100.0)
        if not _POSE_FLAGS & set(fr.get("flags", [])):
            trusted_err_cm.append(pos_err_cm[-1])
        horiz_err_cm.append(float(np.linalg.norm(d[:2])) * 100.0)
    flags = Counter(f for fr in frames for f in fr.get("flags", []))
    return {
        "scenario": scenario.name,
        "frames": len(frames),
        "true_exposures": len(truth),
        "matched": len(matched),
        "exposures_missing_from_log": len(missed),
        "frames_without_exposure": len(unmatched_frames),
        "frames_without_exposure_not_flagged": len(wrongly_unflagged),
        "frames_with_position": len(pos_err_cm),
        "geotag_error_cm": Percentiles.of(pos_err_cm).as_dict(),
        "geotag_error_unflagged_cm": Percentiles.of(trusted_err_cm).as_dict(),
        "geotag_horizontal_error_cm": Percentiles.of(horiz_err_cm).as_dict(),
        "mid_exposure_time_error_ms": Percentiles.of(time_err_ms).as_dict(),
        "timing_part_of_geotag_error_cm": Percentiles.of(timing_part_cm).as_dict(),
        "utc_error_ms": Percentiles.of(utc_err_ms).as_dict(),
        "flags": dict(sorted(flags.items())),
    }
