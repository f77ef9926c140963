"""The recorder end to end through the simulator: one flight with every fault, checked many ways.

The flight (short_flight.toml): a ground station starts 5 fps capture over MAVLink (routed by
the simulated autopilot to the recorder's camera component) and stops it later; meanwhile the
camera ignores trigger 7, someone presses the shutter by hand, the device's USB cable is pulled
for 1.5 s and the autopilot link is gone for 4 s. Everything runs for real: the firmware core
behind a pty, pymavlink over UDP, `icgt record` as its own process, MCAP read back with the
official reader.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory
from pymavlink import mavutil
from replay_check import assert_replay_reproduces_every_frame

from icgt.demo import Flight, fly
from icgt.geotag.bounds import AXIS_95, RADIAL_95
from icgt.sim.evaluate import evaluate, read_frames, read_truth
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("short_flight.toml")


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return fly(load_scenario(SCENARIO), tmp_path_factory.mktemp("flight"))


@pytest.fixture(scope="module")
def frames(flight: Flight) -> list[dict[str, Any]]:
    return read_frames(flight.mcap)


@pytest.fixture(scope="module")
def result(flight: Flight, frames: list[dict[str, Any]]) -> dict[str, Any]:
    return evaluate(flight.scenario, frames, read_truth(flight.truth_exposures))


def messages(flight: Flight, topic: str) -> list[dict[str, Any]]:
    with flight.mcap.open("rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]


def test_every_exposure_is_recorded_exactly_once(result: dict[str, Any]) -> None:
    assert result["true_exposures"] >= 60
    assert result["matched"] == result["true_exposures"]
    assert result["exposures_missing_from_log"] == 0


def test_the_ignored_trigger_and_the_manual_shot_are_recorded_and_flagged(frames: list[dict[str, Any]]) -> None:
    missing = [f for f in frames if "feedback_missing" in f["flags"]]
    manual = [f for f in frames if "unsolicited" in f["flags"]]
    assert [f["image_index"] for f in missing] == [7]
    assert len(manual) == 1 and manual[0]["image_index"] == 0


def test_ground_station_starts_and_stops_capture_and_sees_the_images(flight: Flight, frames: list[Any]) -> None:
    acks = flight.gcs.acks
    assert acks[mavutil.mavlink.MAV_CMD_IMAGE_START_CAPTURE] == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert acks[mavutil.mavlink.MAV_CMD_IMAGE_STOP_CAPTURE] == mavutil.mavlink.MAV_RESULT_ACCEPTED
    assert flight.gcs.camera_seen and flight.gcs.camera_info is not None
    # MAVLink image indices count every image from 0 (the manual shot too); /camera/images maps them to frames.
    published = {r["image_index"]: r for r in messages(flight, "/camera/images")}
    assert sorted(published) == list(range(len(frames)))
    by_seq = {f["frame_seq"]: f for f in frames}
    images = [m for m in flight.gcs.images if m.image_index in published]
    # Images published while the autopilot link was down (4 s of 13) never reach the ground station.
    assert len(images) >= len(frames) - 25
    for m in images:
        record = published[m.image_index]
        f = by_seq[record["frame_seq"]]
        assert record["device_image_index"] == f["image_index"]
        assert bool(m.capture_result) == record["capture_result"]
        if record["position_published"]:
            assert abs(m.lat / 1e7 - f["lat_deg"]) < 2e-7
            assert abs(m.lon / 1e7 - f["lon_deg"]) < 2e-7
        else:  # a poor pose: nothing a ground station could take for a fix
            assert (m.lat, m.lon, m.alt, m.relative_alt) == (0, 0, 0, 0) and m.capture_result == 0


def test_unplugged_device_is_reconnected_and_the_outage_recorded(flight: Flight) -> None:
    events = [e for e in messages(flight, "/icgt/link_events") if e["link"] == "device"]
    kinds = [e["kind"] for e in events]
    assert "disconnected" in kinds and "connected" in kinds
    back = next(e for e in events if e["kind"] == "connected")
    assert 1.0e9 <= back["outage_ns"] <= 3.0e9


def test_autopilot_link_loss_is_recorded_and_frames_still_geotagged_or_flagged(
    flight: Flight, frames: list[dict[str, Any]]
) -> None:
    events = messages(flight, "/icgt/link_events")
    kinds = [e["kind"] for e in events if e["link"] == "mavlink"]
    # the one 4 s link loss is one outage, told once (the synchroniser's account, under "mavlink")
    presence = [e["kind"] for e in events if e["kind"] in ("autopilot_lost", "autopilot_back", "autopilot_rebooted")]
    assert presence == ["autopilot_lost", "autopilot_back"], presence
    assert "autopilot_lost" in kinds and "autopilot_back" in kinds
    assert [e["kind"] for e in events].count("autopilot_seen") == 1
    for f in frames:
        if f.get("lat_deg") is None:
            assert {"no_fix", "no_pose", "no_attitude"} & set(f["flags"]), f
        elif "pose_gap_after_ms" not in f:  # nothing after mid-exposure was used (JSON has no infinity)
            assert "pose_extrapolated" in f["flags"], f
        elif "stale_pose" not in f["flags"] and f.get("h_acc_m") and f.get("v_acc_m"):
            # not stale: beyond the receiver's accuracy, the bound holds at most the recorder's default
            # max_position_error_m (0.10 m) of motion, plus the clock and lever-arm parts (centimetres)
            source = math.hypot(RADIAL_95 * f["h_acc_m"], AXIS_95 * f["v_acc_m"])
            assert f["position_error_bound_m"] <= source + 0.10 + 0.05, f


def test_geotags_are_accurate_and_timing_error_is_negligible(result: dict[str, Any]) -> None:
    assert result["frames_with_position"] >= result["matched"] - 25
    # Frames whose pose is not flagged: the autopilot's fused estimate (a few cm) is the limit.
    assert result["geotag_error_unflagged_cm"]["p95"] < 25.0
    assert result["geotag_error_unflagged_cm"]["n"] >= result["matched"] - 25
    assert result["timing_part_of_geotag_error_cm"]["p95"] < 2.0


def test_every_topic_has_a_schema_and_every_message_decodes(flight: Flight) -> None:
    decoders = DecoderFactory()
    topics: dict[str, int] = {}
    with flight.mcap.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "the file is complete: it has a summary and an index"
        for schema, channel, message in reader.iter_messages():
            assert schema is not None, channel.topic
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                json.loads(message.data)
            else:
                decoder = decoders.decoder_for(channel.message_encoding, schema)
                assert decoder is not None, channel.topic
                decoder(message.data)
            topics[channel.topic] = topics.get(channel.topic, 0) + 1
        names = {m.name for m in reader.iter_metadata()}
    for topic in (
        "/frames",
        "/frames/location",
        "/frames/pose",
        "/tf",
        "/icgt/log",
        "/device/exposure",
        "/device/imu",
        "/device/range",
        "/device/status",
        "/clock/device",
        "/clock/device/exchanges",
        "/mavlink/global_position_int",
        "/mavlink/attitude_quaternion",
    ):
        assert topics.get(topic, 0) > 0, topic
    assert {"icgt.device", "icgt.config", "icgt.calibration"} <= names


def test_the_recorder_logged_no_error(flight: Flight) -> None:
    log = flight.recorder_log.read_text()
    assert "Traceback" not in log and " ERROR " not in log and " CRITICAL " not in log


def test_recomputing_the_flight_reproduces_every_frame_exactly(flight: Flight) -> None:
    assert_replay_reproduces_every_frame(flight.mcap)
