"""Retransmission end to end: one flight through the simulator with every fault of issue 12, 0 exposures lost.

The real firmware core behind the simulator's pty, `icgt record` as a subprocess: a 30 s USB unplug, three
3 s unplugs, bit flips at 1e-3 per byte for 10 s, a kill -9 of the recorder and a restart during capture
(the new recorder adopts the running capture and asks back what no recorder heard). Every exposure the
camera made is in a recording (the killed recorder's file recovered), each fault's exposures included, and
the recordings' own loss count agrees (0). Beyond the ring (minutes of outage) the loss count is checked on
the simulated board in virtual time (firmware/test/history, AppResend.BeyondTheRingTheLossIsCountedExactly)
and against a model device (tests/device/test_resend_tracker.py)."""

from __future__ import annotations

from pathlib import Path

import pytest
from replay_check import assert_replay_reproduces_every_frame

from icgt.sim.fault_flight import Fault, FaultPlan, FlightResult, fly_faults
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("resend_flight.toml")
PLAN = FaultPlan(
    capture_start_s=5.0,
    capture_stop_s=75.0,
    faults=(
        Fault("30 s unplug", "unplug", 8.0, 30.0),
        Fault("3 s unplug #1", "unplug", 41.0, 3.0),
        Fault("3 s unplug #2", "unplug", 47.0, 3.0),
        Fault("3 s unplug #3", "unplug", 53.0, 3.0),
        Fault("bit flips 1e-3 for 10 s", "flips", 58.0, 10.0, flip_probability=1e-3),
        Fault("recorder kill -9 + restart", "kill", 69.0, 2.0),
    ),
)

pytestmark = pytest.mark.timeout(300)


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> FlightResult:
    return fly_faults(load_scenario(SCENARIO), PLAN, tmp_path_factory.mktemp("resend"))


def test_no_exposure_is_lost_in_any_fault(flight: FlightResult) -> None:
    for c in flight.faults:
        assert c.exposures >= 8, f"{c.name}: the camera made only {c.exposures} exposures in its window"
        assert c.recorded == c.exposures, f"{c.name}: {c.exposures - c.recorded} of {c.exposures} exposures lost"
    # >= 150: a loaded machine starts the recorder (and so the capture) late; 350 when it is not loaded
    assert flight.recorded_exposures == flight.true_exposures >= 150


def test_the_long_unplug_came_back_through_resend(flight: FlightResult) -> None:
    (long_unplug,) = [c for c in flight.faults if c.name == "30 s unplug"]
    assert long_unplug.recovered >= long_unplug.exposures - 10  # all but the last second's come as resends


def test_the_logs_loss_count_is_the_true_loss(flight: FlightResult) -> None:
    assert flight.reported_lost_exposures == flight.true_exposures - flight.recorded_exposures == 0
    assert flight.link_summary.get("lost_exposures") == "0"
    assert int(flight.link_summary.get("resend_recovered", "0")) > 0


def test_the_restarted_recorder_wrote_its_own_file(flight: FlightResult) -> None:
    assert len(flight.recordings) == 2


def test_live_equals_replay_with_resent_frames_in_the_log(flight: FlightResult) -> None:
    # The restarted recorder's log holds the frames asked back from the history, late and out of order.
    assert assert_replay_reproduces_every_frame(flight.recordings[-1]) > 0
