"""One USB unplug through the simulator, and what the frames of the exposures it covered came back with (issue 27).

`fly_outage` flies `icgt.sim.fault_flight.fly_faults` with a single unplug (capture from 5 s, the unplug
at 8 s, the capture stopped 10 s after the cable is back) and scores every frame against the simulator's
truth: whether it has a position and a range, its geotag error [m] and its range error [m]. `OutageScore`
compares the exposures the unplug covered with the live ones of the same flight or of another flight
(`compare`: the same flight without the unplug). Used by tests/e2e/test_outage_frames.py and
benchmarks/resend_faults.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from icgt.geodesy import LocalFrame
from icgt.sim.evaluate import read_frames
from icgt.sim.fault_flight import Fault, FaultPlan, FlightResult, fly_faults
from icgt.sim.scenario import Scenario

__all__ = [
    "CAPTURE_START_S",
    "UNPLUG_AT_S",
    "FrameScore",
    "OutageFlight",
    "fly_outage",
    "outage_scenario",
    "percentile",
    "score_frames",
]

CAPTURE_START_S = 5.0  # scenario time the capture is started [s]
UNPLUG_AT_S = 8.0  # scenario time the cable is pulled [s]
AFTER_S = 10.0  # capture kept running after the cable is back [s]


@dataclass(frozen=True)
class FrameScore:
    """One exposure's frame against the truth: image index, in the unplug's window, resent, its errors [m]."""

    image_index: int
    start_s: float  # exposure start, scenario time [s]
    in_outage: bool  # made while the cable was out
    resent: bool  # the frame came back through RESEND
    geotag_error_m: float | None  # None: no position
    range_error_m: float | None  # None: no range (or no true range: then `true_range` is False)
    true_range: bool  # the simulator's LiDAR had a return at mid-exposure
    flags: tuple[str, ...]


@dataclass(frozen=True)
class OutageFlight:
    unplug_s: float
    result: FlightResult
    frames: list[FrameScore]

    def window(self, in_outage: bool) -> list[FrameScore]:
        return [f for f in self.frames if f.in_outage == in_outage]

    def between(self, t0_s: float, t1_s: float) -> list[FrameScore]:
        """The frames of the exposures started in [t0_s, t1_s) [scenario s]."""
        return [f for f in self.frames if t0_s <= f.start_s < t1_s]

    def exposures_between(self, t0_s: float, t1_s: float) -> int:
        """The exposures the camera made in [t0_s, t1_s) (the simulator's truth)."""
        return sum(1 for t in self.result.truth if t0_s <= float(t["start_tau_s"]) < t1_s)


def outage_scenario(sc: Scenario, unplug_s: float) -> Scenario:
    """``sc`` lengthened to hold a ``unplug_s`` unplug at `UNPLUG_AT_S` and `AFTER_S` of capture after it."""
    stop = UNPLUG_AT_S + unplug_s + AFTER_S
    capture = msgspec.structs.replace(sc.camera.capture, start_s=CAPTURE_START_S, stop_s=stop)
    camera = msgspec.structs.replace(sc.camera, capture=capture)
    return msgspec.structs.replace(sc, duration_s=stop + 5.0, camera=camera)


def fly_outage(sc: Scenario, unplug_s: float, out: Path, *, stop_after_s: float | None = None) -> OutageFlight:
    """One flight of ``outage_scenario(sc, unplug_s)``; ``unplug_s`` 0: the same flight without the unplug, as
    long as the flight with a ``stop_after_s`` unplug (default: ``unplug_s``)."""
    flight = outage_scenario(sc, max(unplug_s if stop_after_s is None else stop_after_s, 0.0))
    stop = flight.camera.capture.stop_s
    assert stop is not None
    faults = (Fault(f"{unplug_s:g} s unplug", "unplug", UNPLUG_AT_S, unplug_s),) if unplug_s > 0 else ()
    result = fly_faults(flight, FaultPlan(CAPTURE_START_S, stop, faults), out)
    frames = [fr for path in result.recordings for fr in read_frames(path)]
    return OutageFlight(unplug_s, result, score_frames(flight, frames, result.truth, unplug_s))


def score_frames(
    sc: Scenario, frames: list[dict[str, Any]], truth: list[dict[str, Any]], unplug_s: float
) -> list[FrameScore]:
    """Each frame of a triggered exposure scored against its truth (paired by the exposure start edge)."""
    local = LocalFrame(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_m)
    by_start = {int(t["start_device_us"]): t for t in truth if not t.get("manual")}
    out: list[FrameScore] = []
    for fr in frames:
        t = by_start.pop(int(fr["start_device_us"]), None)  # pop: a frame recorded twice is scored once
        if t is None:
            continue
        err = None
        if fr.get("lat_deg") is not None:
            got = np.asarray(local.geodetic_to_enu(fr["lat_deg"], fr["lon_deg"], fr["alt_msl_m"]), dtype=float)
            want = np.asarray(local.geodetic_to_enu(t["lat_deg"], t["lon_deg"], t["alt_msl_m"]), dtype=float)
            err = float(np.linalg.norm(got - want))
        true_range = t.get("range_m")
        rng = fr.get("range_m") if fr.get("range_valid") else None
        start = float(t["start_tau_s"])
        out.append(
            FrameScore(
                image_index=int(fr["image_index"]),
                start_s=start,
                in_outage=UNPLUG_AT_S <= start < UNPLUG_AT_S + unplug_s,
                resent="resent" in fr.get("flags", []),
                geotag_error_m=err,
                range_error_m=abs(float(rng) - float(true_range)) if rng is not None and true_range else None,
                true_range=bool(true_range),
                flags=tuple(fr.get("flags", [])),
            )
        )
    return out


def percentile(values: list[float], q: float) -> float:
    return float(np.percentile(np.asarray(values, dtype=float), q)) if values else math.nan
