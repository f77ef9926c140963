"""Position source and flags through changing GPS quality: no fix, a fix, GPS denied (local position), a fix again."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.demo import Flight, fly
from icgt.sim.evaluate import evaluate, read_frames, read_truth
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("gps_denied.toml")


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return fly(load_scenario(SCENARIO), tmp_path_factory.mktemp("gps"))


@pytest.fixture(scope="module")
def frames_with_tau(flight: Flight) -> list[tuple[float, dict[str, Any]]]:
    truth = {int(t["start_device_us"]): t for t in read_truth(flight.truth_exposures)}
    return [
        (float(truth[int(f["start_device_us"])]["mid_tau_s"]), f)
        for f in read_frames(flight.mcap)
        if int(f["start_device_us"]) in truth
    ]


def test_before_the_first_fix_frames_have_no_position_and_say_so(frames_with_tau: list[Any]) -> None:
    early = [f for tau, f in frames_with_tau if tau < 4.5]
    assert early
    for f in early:
        assert f.get("lat_deg") is None and "no_fix" in f["flags"] and f["position_source"] == "none"


def test_gps_denied_frames_are_placed_by_local_position(frames_with_tau: list[Any]) -> None:
    denied = [f for tau, f in frames_with_tau if 9.6 < tau < 13.6]
    good = [f for tau, f in frames_with_tau if 6.0 < tau < 8.5 or tau > 14.8]
    assert len(denied) >= 6 and len(good) >= 5
    assert {f["position_source"] for f in denied} == {"local_position"}
    assert {f["position_source"] for f in good} == {"gps_3d"}
    assert all(f.get("lat_deg") is not None for f in denied)


def test_local_position_geotags_stay_accurate(flight: Flight) -> None:
    result = evaluate(flight.scenario, read_frames(flight.mcap), read_truth(flight.truth_exposures))
    assert result["exposures_missing_from_log"] == 0
    assert result["geotag_error_unflagged_cm"]["p95"] < 30.0


def test_with_pps_mid_exposure_utc_comes_from_the_edges_to_microseconds(flight: Flight) -> None:
    truth = {int(t["start_device_us"]): t for t in read_truth(flight.truth_exposures)}
    sources: dict[str, int] = {}
    pps_errors_us: list[float] = []
    for f in read_frames(flight.mcap):
        t = truth.get(int(f["start_device_us"]))
        if t is None or f.get("mid_utc_us") is None:
            continue
        sources[f["time_source"]] = sources.get(f["time_source"], 0) + 1
        if f["time_source"] == "pps":
            pps_errors_us.append(abs(int(f["mid_utc_us"]) - int(t["mid_utc_us"])))
            assert f["mid_utc_uncertainty_us"] <= 10
    # Every frame once the edges are locked (a few seconds in); the rest say where their UTC came from.
    assert len(pps_errors_us) >= 0.7 * sum(sources.values()), sources
    assert max(pps_errors_us) <= 5.0, sorted(pps_errors_us)[-5:]


def test_recomputing_the_flight_reproduces_every_frame_exactly(flight: Flight) -> None:
    assert_replay_reproduces_every_frame(flight.mcap)
