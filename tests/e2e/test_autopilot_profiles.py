"""Whole flights against each simulated autopilot profile (icgt.sim.profiles), scored against truth.

One 20 s deck pass at 10 m/s per case (tests/e2e/profiles/*.toml): the ideal autopilot, ArduPilot at
the 4 Hz a ground station asks for with SET_MESSAGE_INTERVAL unanswered (with and without TIMESYNC
answers, with an EKF origin reset, a parameter download, ground stations 245/250/255, vehicle system
id 42, a second camera at component 100), and PX4 with its onboard-link defaults and an origin reset.
Checked per case (issue 9): every frame with a 3D fix has a pose; none is labelled `vio` while GPS
samples bracket it; the geotag error p95 / max; the timing part of the error (the whole chain device
-> host -> autopilot clock, times the true speed) p95 <= 2 cm with TIMESYNC, <= 5 cm without; the
autopilot clock method each frame used; the replay reproduces every frame.
"""

from __future__ import annotations

import bisect
import json
from pathlib import Path
from typing import Any

import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.demo import Flight, fly
from icgt.ingest.reader import read
from icgt.sim.evaluate import (
    autopilot_timing,
    evaluate,
    pose_report,
    read_frames,
    read_truth,
    replayed_autopilot_times,
)
from icgt.sim.scenario import load_scenario

PROFILE_DIR = Path(__file__).with_name("profiles")
CASES = ["ideal", "ardupilot", "ardupilot_no_timesync", "px4"]
MAX_GPS_GAP_S = 1.5  # the host's rule for interpolating between GPS samples (icgt.geotag.position)
CAPTURE_SETTLE_S = 4.0  # frames before this scenario time may come before the clocks have data


class Scored:
    def __init__(self, flight: Flight) -> None:
        self.flight = flight
        self.sc = flight.scenario
        self.frames = read_frames(flight.mcap)
        self.truth = read_truth(flight.truth_exposures)
        self.result = evaluate(self.sc, self.frames, self.truth)
        self.mapped = replayed_autopilot_times(flight.mcap)
        self.timing = autopilot_timing(self.sc, self.frames, self.truth, self.mapped, flight.clocks)
        self.poses = pose_report(self.frames)
        by_start = {int(t["start_device_us"]): t for t in self.truth}
        self.tau = {fr["frame_seq"]: float(by_start[int(fr["start_device_us"])]["mid_tau_s"]) for fr in self.frames
                    if int(fr["start_device_us"]) in by_start}  # fmt: skip
        self.settled = [fr for fr in self.frames if self.tau.get(fr["frame_seq"], 0.0) >= CAPTURE_SETTLE_S]
        print(
            f"\n{self.sc.name}: " + json.dumps({**self.poses, **self.timing, "geotag": self.result["geotag_error_cm"]})
        )

    @property
    def timesync(self) -> bool:
        return self.sc.autopilot.answer_timesync


_FLOWN: dict[str, Scored] = {}


def flown(case: str, tmp_path_factory: pytest.TempPathFactory) -> Scored:
    """Each case is flown once per session, whichever test asks first."""
    if case not in _FLOWN:
        sc = load_scenario(PROFILE_DIR / f"{case}.toml")
        _FLOWN[case] = Scored(fly(sc, tmp_path_factory.mktemp(f"profile_{case}")))
    return _FLOWN[case]


@pytest.fixture(scope="module", params=CASES)
def scored(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Scored:
    return flown(str(request.param), tmp_path_factory)


def _in_param_burst(scored: Scored, tau_s: float) -> bool:
    ap = scored.sc.autopilot
    return any(t <= tau_s < t + ap.param_burst_duration_s + 1.0 for t in ap.param_bursts_s)


def test_every_frame_with_a_fix_has_a_pose(scored: Scored) -> None:
    assert scored.result["exposures_missing_from_log"] == 0
    assert len(scored.settled) >= 30
    without = [(fr["frame_seq"], fr["flags"]) for fr in scored.settled if fr.get("lat_deg") is None]
    assert not without, (scored.poses, without[:5])
    assert all(fr["fix_type"] >= 3 for fr in scored.settled)


def test_the_clock_method_is_recorded(scored: Scored) -> None:
    want = "timesync" if scored.timesync else "arrival"
    assert {fr["autopilot_clock"] for fr in scored.settled} == {want}, scored.poses
    assert all(fr["autopilot_clock_uncertainty_us"] is not None for fr in scored.settled)


def _gps_stamps_us(mcap: Path, system_id: int) -> list[int]:
    out: list[int] = []
    for _, d in read(mcap).messages("/mavlink/global_position_int"):
        msg: dict[str, Any] = d.get("msg", d)
        if d.get("src_system", system_id) == system_id and msg.get("lat", 0) != 0:
            out.append(int(msg["time_boot_ms"]) * 1000)
    return sorted(out)


def _vio_between_gps(scored: Scored, *, in_bursts: bool) -> list[tuple[int, int, float, int]]:
    """Frames labelled vio although GPS samples at most MAX_GPS_GAP_S apart bracket their mid-exposure."""
    stamps = _gps_stamps_us(scored.flight.mcap, scored.sc.autopilot.system_id)
    assert len(stamps) > 20
    wrong = []
    for fr in scored.frames:
        if fr["position_source"] != "local_position":
            continue
        if _in_param_burst(scored, scored.tau.get(fr["frame_seq"], 0.0)) != in_bursts:
            continue
        mid = scored.mapped.get(int(fr["mid_host_ns"]))
        assert mid is not None
        i = bisect.bisect_right(stamps, mid)
        if 0 < i < len(stamps) and stamps[i] - stamps[i - 1] <= MAX_GPS_GAP_S * 1e6:
            wrong.append((fr["frame_seq"], stamps[i - 1], mid, stamps[i]))
    return wrong


def test_no_frame_labelled_vio_while_gps_samples_bracket_it(scored: Scored) -> None:
    """Outside parameter downloads (those are the test below)."""
    wrong = _vio_between_gps(scored, in_bursts=False)
    assert not wrong, wrong[:5]
    outside = {
        fr["position_source"] for fr in scored.settled if not _in_param_burst(scored, scored.tau[fr["frame_seq"]])
    }
    assert outside == {"gps_3d"}, scored.poses


def test_no_frame_labelled_vio_during_a_parameter_download(
    tmp_path_factory: pytest.TempPathFactory,
) -> None:
    """ArduPilot slows its 4 Hz streams to 1 Hz while sending parameters (tests/geotag/test_slow_gps_streams.py)."""
    scored = flown("ardupilot", tmp_path_factory)
    assert scored.sc.autopilot.param_bursts_s and scored.sc.autopilot.param_burst_stream_divisor == 4
    wrong = _vio_between_gps(scored, in_bursts=True)
    assert not wrong, wrong[:5]


def test_geotag_error_against_truth(scored: Scored) -> None:
    geo = scored.result["geotag_error_cm"]
    assert geo["n"] >= 30
    # The fused estimate's noise (3 cm horizontal, 5 cm vertical, 1 sigma) dominates; interpolating
    # 4 Hz samples at 10 m/s with 3.3 m/s^2 ramps adds < 1 cm; an origin reset must add nothing.
    assert geo["p95"] < 25.0, geo
    assert geo["max"] < 50.0, geo


def test_timing_part_of_the_error(scored: Scored) -> None:
    part = scored.timing["timing_part_cm"]
    assert part["n"] >= 30
    limit_cm = 2.0 if scored.timesync else 5.0  # issue 9's targets at 10 m/s
    assert part["p95"] <= limit_cm, scored.timing


def test_recomputing_the_flight_reproduces_every_frame_exactly(scored: Scored) -> None:
    assert_replay_reproduces_every_frame(scored.flight.mcap)


def test_a_foreign_camera_at_component_100_is_logged_loudly(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Issue 9: a second device at component 100 of the vehicle must be detected and said, not dropped as an echo."""
    scored = flown("ardupilot_no_timesync", tmp_path_factory)
    assert scored.sc.autopilot.foreign_camera
    rec = read(scored.flight.mcap)
    loud = [
        d["message"]
        for _, d in rec.messages("/icgt/log")
        if d["level"] in ("WARNING", "ERROR", "CRITICAL") and "100" in d["message"]
    ]
    loud += [d["detail"] for _, d in rec.messages("/icgt/link_events") if "100" in str(d.get("detail", ""))]
    assert loud, "nothing in /icgt/log (WARNING or above) or /icgt/link_events names component 100"
