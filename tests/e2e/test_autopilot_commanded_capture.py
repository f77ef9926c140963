"""Capture commanded by the autopilot itself, the way ArduPilot's camera backends send it (issue 29.2).

The simulated autopilot runs ArduPilot's AP_Camera logic (icgt.sim.camera_trigger): a time trigger and
then a distance trigger during a vertical scan, through CAM1_TYPE = MAVLinkCamV2 (one IMAGE_START_CAPTURE
per shot to component 100, sequence numbers 1, 2, ..., after it found the camera's HEARTBEAT and got its
CAMERA_INFORMATION) and through CAM1_TYPE = MAVLink (DO_DIGICAM_CONTROL broadcast, every shot the same
command), and the way PX4's MAVLink camera trigger sends it (CAMERA_TRIGGER, IMAGE_START_CAPTURE re-sent
until acknowledged, and DO_DIGICAM_CONTROL for the same shot: one picture). `icgt record` runs on the
flight with no ground station at all. Checked: every commanded image is
recorded exactly once (frames, true exposures), each command gets one COMMAND_ACK ACCEPTED back at the
autopilot, one CAMERA_IMAGE_CAPTURED per image with indices 0..N-1, each exposure follows its command, and
the triggers keep ArduPilot's rules (interval strictly exceeded, distance reached).
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from mcap.reader import make_reader
from pymavlink.dialects.v20 import common as mavlink2

from icgt.recording import layout
from icgt.sim.camera_trigger import read_trigger_log
from icgt.sim.evaluate import read_frames, read_truth
from icgt.sim.live_recorder import LiveRecorder
from icgt.sim.scenario import Scenario, load_scenario

BASE = load_scenario(Path(__file__).with_name("ardupilot_commanded.toml"))
PX4 = load_scenario(Path(__file__).with_name("px4_commanded.toml"))
MAX_COMMAND_TO_EXPOSURE_S = 1.5  # shutter latency 48 ms plus the recorder's queue on a loaded machine


def scenario(backend: str) -> Scenario:
    if backend == "px4":
        return PX4
    cam = msgspec.structs.replace(BASE.autopilot.camera, backend=backend)
    ap = msgspec.structs.replace(BASE.autopilot, camera=cam)
    return msgspec.structs.replace(BASE, name=f"{BASE.name}_{backend}", autopilot=ap)


class Flown:
    def __init__(self, sc: Scenario, out: Path) -> None:
        with LiveRecorder(sc, out) as live:
            assert live.session is not None
            live.session.wait_until(sc.duration_s)
            mcap = live.stop()
            files = live.session.files
        self.sc = sc
        self.recorder_log = live.recorder_log.read_text(encoding="utf-8")
        with mcap.open("rb") as f:
            topic = layout.mavlink_topic("GLOBAL_POSITION_INT")
            self.position_log_ns = [m.log_time for _, _, m in make_reader(f).iter_messages(topics=[topic])]
        self.log = read_trigger_log(files.autopilot_camera)
        self.frames = sorted(read_frames(mcap), key=lambda f: int(f["start_device_us"]))
        self.truth = sorted(read_truth(files.truth_exposures), key=lambda t: float(t["mid_tau_s"]))
        self.pictures: list[dict[str, Any]] = self.log["pictures"]
        # the pictures whose command went out (MAVLink backend: not before a component was heard)
        self.sent = [p for p in self.pictures if self.sc.autopilot.camera.backend != "mavlink" or p["acks"]]
        print(
            f"\n{sc.name}: {len(self.pictures)} pictures, {len(self.frames)} frames, {len(self.truth)} exposures, "
            f"{len(self.log['image_captured'])} CAMERA_IMAGE_CAPTURED, failed triggers {self.log['failed_triggers']}, "
            f"info requests {self.log['info_requests']}"
        )


@pytest.fixture(scope="module", params=["mavlink_camv2", "mavlink", "px4"])
def flown(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flown]:
    backend = str(request.param)
    yield Flown(scenario(backend), tmp_path_factory.mktemp(backend))


def test_both_triggers_commanded_pictures(flown: Flown) -> None:
    kinds = [p["trigger"] for p in flown.sent]
    # time trigger over 6 s at 0.5 s; distance trigger (horizontal, as ArduPilot) over the 1 m step at 0.25 m
    assert kinds.count("time") >= 6, kinds
    assert kinds.count("distance") >= 3, kinds
    assert [p["number"] for p in flown.pictures] == list(range(1, len(flown.pictures) + 1))


def test_every_commanded_image_recorded_exactly_once(flown: Flown) -> None:
    n = len(flown.sent)
    assert len(flown.truth) == n, "the camera exposed once per command"
    assert len(flown.frames) == n, "the log holds one frame per command"
    assert len({int(f["start_device_us"]) for f in flown.frames}) == n
    truth_starts = {int(t["start_device_us"]) for t in flown.truth}
    assert {int(f["start_device_us"]) for f in flown.frames} == truth_starts
    for pic, exposure in zip(flown.sent, flown.truth, strict=True):
        lag = float(exposure["mid_tau_s"]) - float(pic["tau_s"])
        assert 0.0 < lag < MAX_COMMAND_TO_EXPOSURE_S, (pic, exposure["mid_tau_s"])


def test_each_command_acknowledged_once_accepted(flown: Flown) -> None:
    for pic in flown.sent:
        # a PX4 command re-sent before its ACK came (a loaded machine) is answered once per transmission
        assert pic["acks"] == [mavlink2.MAV_RESULT_ACCEPTED] * (1 + pic["resends"]) or (
            pic["acks"] and pic["acks"][0] == mavlink2.MAV_RESULT_ACCEPTED and pic["resends"] > 0
        ), pic
    if not any(p["resends"] for p in flown.pictures):
        assert flown.log["unmatched_acks"] == []


def test_px4_second_command_of_a_shot_acknowledged_without_a_picture(flown: Flown) -> None:
    if flown.sc.autopilot.camera.backend != "px4":  # ArduPilot sends one command per shot and no CAMERA_TRIGGER
        assert flown.log["camera_trigger_seqs"] == [] and flown.log["companion_acks"] == []
        return
    assert flown.log["camera_trigger_seqs"] == list(range(len(flown.pictures)))
    # every DO_DIGICAM_CONTROL sent with an IMAGE_START_CAPTURE answered ACCEPTED, and no picture of its own
    assert flown.log["companion_acks"] == [mavlink2.MAV_RESULT_ACCEPTED] * len(flown.pictures)
    assert len(flown.truth) == len(flown.pictures)


def test_one_image_captured_per_image(flown: Flown) -> None:
    assert sorted(flown.log["image_captured"]) == list(range(len(flown.sent)))


def test_trigger_rules_as_ardupilot(flown: Flown) -> None:
    cam = flown.sc.autopilot.camera
    timed = [p for p in flown.sent if p["trigger"] == "time"]
    for a, b in itertools.pairwise(timed):
        gap_ms = b["boot_ms"] - a["boot_ms"]
        assert gap_ms > cam.interval_s * 1000, (a, b)  # "delta_ms > time_interval_ms": never at the interval
    dist = [p for p in flown.pictures if p["trigger"] == "distance"]
    for a, b in itertools.pairwise(dist):
        step = float(np.linalg.norm(np.subtract(b["position_enu_m"], a["position_enu_m"])))
        assert step >= cam.distance_m, (a, b)
    if cam.backend == "mavlink_camv2":
        assert flown.log["camera_found_tau_s"] is not None
        assert flown.log["info_requests"] >= 1


def test_streams_at_the_requested_rate_after_ardupilots_boot_reset(flown: Flown) -> None:
    """`stream_reset_s`: whether the recorder's requests came before the reset (then it must notice the
    4 Hz and ask again) or after, GLOBAL_POSITION_INT runs at the 50 Hz asked for when capture runs."""
    t = np.asarray(flown.position_log_ns, dtype=float) * 1e-9
    end = t.max()
    last = t[t > end - 8.0]
    assert len(last) / 8.0 > 25.0, (len(last), flown.recorder_log[-2000:])
