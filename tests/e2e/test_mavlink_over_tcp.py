"""The recorder reaching the autopilot over a byte stream (a serial port, ArduPilot SITL's TCP port), not UDP.

On a stream the recorder's MAVLink reader thread reads the link, not its worker: the worker learns of the
telemetry a waiting frame needs from the reader's thread-input signal (icgt.recorder.worker_wake). A short
flight through `icgt.sim.tcp_bridge` (the simulator's autopilot datagrams onto one TCP connection, the
recorder connecting with ``--mavlink tcp:...``): every exposure paired and posed, commands and
CAMERA_IMAGE_CAPTURED through the stream, and no frame emitted before its inputs were in. How soon after is a
timing figure: `benchmarks/capture_rates.py --mavlink-tcp`.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from icgt.demo import Flight, fly
from icgt.sim.evaluate import evaluate, read_frames, read_truth
from icgt.sim.latency import frame_timings
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("late_recorder.toml")  # hover, 5 fps for 5 s


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return fly(load_scenario(SCENARIO), tmp_path_factory.mktemp("mavlink_tcp"), mavlink_over_tcp=True)


def test_the_recorder_took_the_autopilot_over_tcp(flight: Flight) -> None:
    log = flight.recorder_log.read_text()
    assert "MAVLink link tcp:127.0.0.1:" in log  # the stream, not a UDP socket
    assert "MAV_RESULT_ACCEPTED" in log  # its stream-rate requests went through the stream and were answered
    assert flight.gcs.camera_seen  # the camera's HEARTBEAT reached the ground station through the stream


def test_every_exposure_is_paired_and_posed(flight: Flight) -> None:
    frames = read_frames(flight.mcap)
    result = evaluate(flight.scenario, frames, read_truth(flight.truth_exposures))
    assert result["matched"] == result["true_exposures"] >= 23
    assert result["exposures_missing_from_log"] == 0
    assert len(flight.gcs.images) == result["matched"]  # one CAMERA_IMAGE_CAPTURED per frame


def test_no_frame_is_emitted_before_its_inputs_are_in(flight: Flight) -> None:
    timings = frame_timings(flight.mcap)
    shares = [t.recorder_ms for t in timings]
    assert len(shares) >= 23
    assert all(math.isfinite(x) for x in shares), shares  # every frame's telemetry came through the stream
    assert min(shares) >= -1.0, shares  # 1 ms: the clock maps' error between the two links
