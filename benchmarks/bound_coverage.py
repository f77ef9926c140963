#!/usr/bin/env python3
"""Do the frames' error bounds cover their true error? Coverage and sharpness per gap class (issue 32).

    .venv/bin/python benchmarks/bound_coverage.py [--flights N] [--mode live|recompute|both]

Flights: the VTOL survey of `icgt.sim.survey.vtol_survey` (21-24 m/s, 25-35 deg banked turns, a speed-up, a
climb), N random survey flights (`random_flight`), and the pier scan and deck pass scenarios (rows "scan ...").
Position telemetry (GLOBAL_POSITION_INT and LOCAL_POSITION_NED) at 10 Hz with RTK-fixed accuracy, silent in gaps
of 0.5, 1, 2, 3.5 and 5 s placed on straights, in turns and under acceleration (speed changes and climbs; the
scans' ramps and steps); attitude at 50 Hz throughout. Every frame (5 fps) is placed by the real geotagger
(`icgt.sim.bound_check`) and scored against the truth at its true mid-exposure.

Per class: coverage (fraction of placed frames whose true error is within the bound, horizontal / vertical /
attitude), sharpness (median bound / median true error), frames withheld (no_pose: no position rather than a
guess), the largest error, and frames more than 1 m off without a flag (stale_pose or pose_extrapolated).
Goal: coverage >= 95 % in every class, sharpness <= 3, no unflagged frame > 1 m off.

The peer, on the same frames: the receiver's own h_acc / v_acc as the bound (what a geotagger that copies
GPS accuracy into its output claims; PX4's and ArduPilot's camera feedback carries no bound at all).
"""

from __future__ import annotations

import argparse
import math
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from icgt.sim.bound_check import FlightTruth, FrameScore, Gap, ScenarioFlight, score_flight
from icgt.sim.scenario import load_scenario
from icgt.sim.survey import random_flight, vtol_survey

GAPS_S = (0.5, 1.0, 2.0, 3.5, 5.0)
PLACES = {"straight": ("straight",), "turn": ("turn",), "accel": ("speed", "climb")}


def place_gaps(flight: FlightTruth, rng: np.random.Generator) -> list[Gap]:
    """One gap per (duration, place) where the flight has a segment of that kind; gaps 4 s apart at least."""
    gaps: list[Gap] = []
    for duration in GAPS_S:
        for kinds in PLACES.values():
            segs = [(a, b) for k, a, b in flight.segments if k in kinds and b - a > 1.0]
            rng.shuffle(segs)
            for a, b in segs:
                centre = float(rng.uniform(a, b))
                g = Gap(max(3.0, centre - duration / 2), duration)
                if g.start_s + g.duration_s > flight.duration_s - 3.0:
                    continue
                if all(
                    g.start_s > o.start_s + o.duration_s + 4.0 or o.start_s > g.start_s + g.duration_s + 4.0
                    for o in gaps
                ):
                    gaps.append(g)
                    break
    return gaps


def _place(flight: FlightTruth, gap: Gap) -> str:
    mid = flight.segment_at(gap.start_s + gap.duration_s / 2)
    return next(name for name, kinds in PLACES.items() if mid in kinds) if mid != "straight" else "straight"


@dataclass
class Row:
    n: int
    placed: int
    h_cov: float
    v_cov: float
    a_cov: float
    h_sharp: float
    v_sharp: float
    a_sharp: float
    worst_m: float
    unflagged_1m: int
    naive_h_cov: float
    naive_v_cov: float


def _ratio(bounds: list[float], errs: list[float]) -> float:
    e = float(np.median(errs)) if errs else math.nan
    return float(np.median(bounds)) / e if e > 0 else math.inf


def summarise(frames: list[FrameScore]) -> Row:
    placed = [f for f in frames if f.placed]
    att = [f for f in frames if not math.isnan(f.att_err_deg)]

    def cov(sel: list[FrameScore], err: str, bound: str) -> float:
        return float(np.mean([getattr(f, err) <= getattr(f, bound) for f in sel])) if sel else math.nan

    return Row(
        n=len(frames),
        placed=len(placed),
        h_cov=cov(placed, "h_err_m", "h_bound_m"),
        v_cov=cov(placed, "v_err_m", "v_bound_m"),
        a_cov=cov(att, "att_err_deg", "att_bound_deg"),
        h_sharp=_ratio([f.h_bound_m for f in placed], [f.h_err_m for f in placed]),
        v_sharp=_ratio([f.v_bound_m for f in placed], [f.v_err_m for f in placed]),
        a_sharp=_ratio([f.att_bound_deg for f in att], [f.att_err_deg for f in att]),
        worst_m=max((math.hypot(f.h_err_m, f.v_err_m) for f in placed), default=0.0),
        unflagged_1m=sum(1 for f in placed if math.hypot(f.h_err_m, f.v_err_m) > 1.0 and not f.flagged),
        naive_h_cov=cov(placed, "h_err_m", "h_acc_m"),
        naive_v_cov=cov(placed, "v_err_m", "v_acc_m"),
    )


def run(n_flights: int, mode: str) -> dict[str, list[FrameScore]]:
    classes: dict[str, list[FrameScore]] = defaultdict(list)
    rng = np.random.default_rng(32)
    flights: list[tuple[str, FlightTruth]] = [("survey", vtol_survey())]
    flights += [("survey", random_flight(np.random.default_rng([32, k]), 90.0)) for k in range(n_flights)]
    flights += [("pier", ScenarioFlight(load_scenario(name))) for name in ("pier_scan", "deck_pass")]
    for k, (family, flight) in enumerate(flights):
        gaps = place_gaps(flight, rng)
        places = {g: _place(flight, g) for g in gaps}
        for f in score_flight(flight, gaps, mode=mode, seed=k):  # type: ignore[arg-type]
            gap = next((g for g in gaps if g.holds(f.t_s)), None)
            key = "no gap" if gap is None else f"{gap.duration_s:g} s {places[gap]}"
            if family == "pier":  # the inspection scenarios apart: slow scans, the deck pass's ramps
                key = f"scan {key}"
            classes[key].append(f)
            classes["all"].append(f)
    return classes


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--flights", type=int, default=8, help="random survey flights besides the VTOL survey")
    ap.add_argument("--mode", choices=("live", "recompute", "both"), default="both")
    args = ap.parse_args()
    modes = ("live", "recompute") if args.mode == "both" else (args.mode,)
    for mode in modes:
        classes = run(args.flights, mode)
        print(f"\n{mode}: coverage = fraction of placed frames within their 95 % bound (goal >= 0.95)")
        head = (
            f"{'class':<20}{'frames':>7}{'placed':>7}  {'cover h/v/att':>17}  {'sharp h/v/att':>18}"
            f"  {'worst m':>8}  {'>1m unflagged':>13}  {'peer cover h/v':>14}"
        )
        print(head)
        order = ["no gap"] + [f"{g:g} s {p}" for g in GAPS_S for p in PLACES]
        order += ["scan no gap"] + [f"scan {g:g} s {p}" for g in GAPS_S for p in PLACES] + ["all"]
        for key in order:
            if key not in classes:
                continue
            r = summarise(classes[key])
            print(
                f"{key:<20}{r.n:>7}{r.placed:>7}  {r.h_cov:>5.3f} {r.v_cov:>5.3f} {r.a_cov:>5.3f}"
                f"  {r.h_sharp:>5.1f} {r.v_sharp:>5.1f} {r.a_sharp:>5.1f}  {r.worst_m:>8.2f}  {r.unflagged_1m:>13}"
                f"  {r.naive_h_cov:>6.3f} {r.naive_v_cov:>6.3f}"
            )


if __name__ == "__main__":
    main()
