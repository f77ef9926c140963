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
from icgt.recording import RecordingError, layout
from icgt.sim.scenario import Scenario
from icgt.sim.trajectory import Trajectory
from icgt.sim.truth import ClockMaps

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
            return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[layout.FRAMES])]
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


# --- the autopilot clock's part of the error, and the reasons frames have no pose ---------------


def replayed_autopilot_times(mcap_path: Path) -> dict[int, float]:
    """For each frame's mid_host_ns, the autopilot boot time [us] the geotagger put it at.

    The frame record does not carry that instant, so the log is recomputed (`icgt.ingest.recompute`,
    which reproduces every frame exactly: tests/replay_check.py) while watching the geotagger's
    question to the autopilot clock. A frame asks at each poll until it is built; the last answer
    per instant is the one its pose was taken at.
    """
    from unittest import mock

    from icgt.geotag import clock_views
    from icgt.ingest.recompute import recompute

    seen: dict[int, float] = {}
    original = clock_views.AutopilotClockView.host_to_autopilot_us

    def spy(view: clock_views.AutopilotClockView, host_ns: int) -> float | None:
        value = original(view, host_ns)
        if value is not None:
            seen[int(host_ns)] = float(value)
        return value

    with mock.patch.object(clock_views.AutopilotClockView, "host_to_autopilot_us", spy):
        recompute(mcap_path)
    return seen


def _speed_at(traj: Trajectory, tau_s: float) -> float:
    return float(np.linalg.norm(traj.state(np.array([tau_s])).velocity_enu_m_s[0]))


def autopilot_timing(
    scenario: Scenario,
    frames: list[dict[str, Any]],
    truth: list[dict[str, Any]],
    mapped: dict[int, float],
    clocks: ClockMaps | None = None,
) -> dict[str, Any]:
    """Error of mid-exposure on the autopilot's clock (device -> host -> autopilot, all of it) per frame.

    ``mapped`` is `replayed_autopilot_times`. The true instant is the autopilot boot time at the true
    mid-exposure (the scenario's autopilot clock; ``clocks``: the session's maps, `Flight.clocks`, which a
    held session moved by the time it held). The timing part of the geotag error is that error
    times the true speed.
    """
    if clocks is None:  # a session that was not held: the autopilot clock does not depend on t0 or utc0
        clocks = ClockMaps.from_scenario(scenario, 0, 0)
    by_start = {int(t["start_device_us"]): t for t in truth}
    traj = Trajectory(scenario)
    err_ms: list[float] = []
    part_cm: list[float] = []
    for fr in frames:
        t = by_start.get(int(fr["start_device_us"]))
        got = mapped.get(int(fr["mid_host_ns"]))
        if t is None or got is None:
            continue
        want = float(clocks.tau_to_autopilot_us(float(t["mid_tau_s"])))
        err_ms.append((got - want) / 1000.0)
        part_cm.append(abs(got - want) * 1e-6 * _speed_at(traj, float(t["mid_tau_s"])) * 100.0)
    return {
        "autopilot_time_error_ms": Percentiles.of(err_ms).as_dict(),
        "timing_part_cm": Percentiles.of(part_cm).as_dict(),
    }


def latest_pose_peer(scenario: Scenario, mcap_path: Path, truth: list[dict[str, Any]]) -> dict[str, float | int]:
    """What PX4 / ArduPilot do (copy the latest estimate when the camera fires), measured on this log.

    For each true exposure: the age of the latest GLOBAL_POSITION_INT that had arrived here by the true
    mid-exposure, less the ~2 ms it took to arrive (the peer is given those), times the true speed [cm]
    (as benchmarks/recorder_flight.py).
    """
    from mcap.reader import make_reader

    rx: list[int] = []
    with mcap_path.open("rb") as f:
        for _, _, m in make_reader(f).iter_messages(topics=[layout.mavlink_topic("GLOBAL_POSITION_INT")]):
            rx.append(int(json.loads(m.data)["host_rx_ns"]))
    rx.sort()
    traj = Trajectory(scenario)
    out: list[float] = []
    for t in truth:
        mid = int(t["mid_host_monotonic_ns"])
        i = int(np.searchsorted(rx, mid)) - 1
        if i >= 0:
            stale_ns = max(0, mid - rx[i] - 2_000_000)
            out.append(stale_ns * 1e-9 * _speed_at(traj, float(t["mid_tau_s"])) * 100.0)
    return Percentiles.of(out).as_dict()


def pose_report(frames: list[dict[str, Any]]) -> dict[str, Any]:
    """Frames without a position and why (their flags), frames with a pose-quality flag (stale_pose,
    pose_extrapolated, no_fix, no_attitude, clock_unsynced), the clock method and position source of each."""
    without = [fr for fr in frames if fr.get("lat_deg") is None]
    reasons = Counter(",".join(sorted(set(fr.get("flags", [])) & _POSE_FLAGS)) or "unflagged" for fr in without)
    flagged = [fr for fr in frames if set(fr.get("flags", [])) & _POSE_FLAGS]
    return {
        "frames_without_pose": len(without),
        "frames_pose_flagged": len(flagged),
        "without_pose_reasons": dict(sorted(reasons.items())),
        "autopilot_clock": dict(sorted(Counter(str(fr.get("autopilot_clock")) for fr in frames).items())),
        "position_source": dict(sorted(Counter(str(fr.get("position_source")) for fr in frames).items())),
    }


def camera_misses(device_events: Path, frames: list[dict[str, Any]]) -> dict[str, Any]:
    """The presses the simulated camera ignored (its truth) against what the recording reports.

    Every ignored press must be a frame flagged feedback_missing with its image index (the device's
    index and the camera's count of presses both start at 1), and no frame may be flagged missing
    for a press the camera answered."""
    ignored: dict[int, str] = {}
    with device_events.open() as f:
        for line in f:
            if line.strip():
                e = json.loads(line)
                if e.get("event") == "trigger_ignored":
                    ignored[int(e["trigger_index"])] = str(e.get("reason", ""))
    flagged = {int(fr["image_index"]) for fr in frames if "feedback_missing" in fr.get("flags", [])}
    return {
        "ignored_by_camera": len(ignored),
        "ignored_by_reason": dict(sorted(Counter(ignored.values()).items())),
        "ignored_and_flagged": len(set(ignored) & flagged),
        "ignored_not_flagged": sorted(set(ignored) - flagged),
        "flagged_but_answered": sorted(flagged - set(ignored)),
    }
