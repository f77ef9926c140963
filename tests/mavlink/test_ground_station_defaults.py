"""Every ground station on its default MAVLink ids may drive the camera with every configuration we ship.

The configurations: the recorder's defaults (no file), `deploy/recorder.toml` (what a user copies to the
companion computer) and the one `icgt demo` / `icgt sim` write (`icgt.sim.recorder_setup`). The clients on
their out-of-the-box ids: MAVSDK as a ground station 245/190, QGroundControl 255/190, MAVProxy 255/230
(`--source-system` / `--source-component` defaults), Mission Planner 255/190. Each sends an
IMAGE_START_CAPTURE single shot to a camera built the way the recorder builds it (`build_camera`) and must
get COMMAND_ACK ACCEPTED and the shot executed; a system outside the list is DENIED and the log line names
the key that would allow it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
from mavlink_peers import Peer, free_udp_port, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.camera import CameraComponent, CommandResult
from icgt.mavlink.link import LinkConfig, MavlinkLink
from icgt.recorder.camera_link import build_camera
from icgt.recorder.config import RecorderConfig, load_config
from icgt.sim.recorder_setup import recorder_config_text
from icgt.sim.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[2]
M = mavlink2
GROUND_STATIONS = {
    "MAVSDK": (245, 190),
    "QGroundControl": (255, 190),
    "MAVProxy": (255, 230),
    "Mission Planner": (255, 190),
}


class Shooter:
    def __init__(self) -> None:
        self.shots = 0

    def start(self, interval_s: float, count: int) -> CommandResult:
        return CommandResult.ACCEPTED

    def stop(self) -> CommandResult:
        return CommandResult.ACCEPTED

    def shoot(self) -> CommandResult:
        self.shots += 1
        return CommandResult.ACCEPTED


def _shipped(name: str, tmp_path: Path) -> RecorderConfig:
    if name == "defaults":
        return load_config(None)
    if name == "deploy/recorder.toml":
        return load_config(ROOT / "deploy" / "recorder.toml")
    sc = load_scenario(ROOT / "hil_sim" / "scenarios" / "pier_scan.toml")
    path = tmp_path / "recorder.toml"
    path.write_text(recorder_config_text(sc, tmp_path / "out"))
    return load_config(path)


class _Camera:
    def __init__(self, config: RecorderConfig) -> None:
        self.port = free_udp_port()
        self.link = MavlinkLink(
            LinkConfig(
                f"udpin:127.0.0.1:{self.port}",
                system_id=config.mavlink.system_id,
                component_id=config.mavlink.component_id,
                request_rates=False,
                timesync=False,
            )
        )
        self.handler = Shooter()
        self.camera: CameraComponent = build_camera(config, self.link, self.handler)
        self.link.start()
        self.camera.start()

    def shoot_from(self, system: int, component: int, sequence: int) -> object:
        peer = Peer(system, component, self.port)
        try:
            peer.send(peer.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))
            since = peer.mark()
            sys_id, comp_id = self.link.config.system_id, self.link.config.component_id
            peer.command_long(sys_id, comp_id, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, sequence)
            ack = peer.wait_for(
                "COMMAND_ACK",
                lambda m: m.command == M.MAV_CMD_IMAGE_START_CAPTURE and m.target_system == system,
                timeout=10.0,
                since=since,
            )
            return ack.result if ack is not None else None
        finally:
            peer.close()

    def close(self) -> None:
        self.camera.stop()
        self.link.stop()


@pytest.mark.parametrize("shipped", ["defaults", "deploy/recorder.toml", "icgt sim / demo"])
@pytest.mark.parametrize("client", list(GROUND_STATIONS))
def test_every_ground_station_on_its_default_ids_is_accepted(shipped: str, client: str, tmp_path: Path) -> None:
    config = _shipped(shipped, tmp_path)
    camera = _Camera(config)
    try:
        system, component = GROUND_STATIONS[client]
        assert camera.shoot_from(system, component, 1) == M.MAV_RESULT_ACCEPTED, (client, shipped)
        assert wait_until(lambda: camera.handler.shots == 1, timeout=5.0)
        assert camera.camera.counters["denied_systems"] == 0
    finally:
        camera.close()


def test_a_denial_names_the_config_key(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    camera = _Camera(load_config(ROOT / "deploy" / "recorder.toml"))
    try:
        with caplog.at_level(logging.WARNING, logger="icgt.mavlink.camera"):
            assert camera.shoot_from(42, 190, 1) == M.MAV_RESULT_DENIED
            camera.camera.stop()  # flushes the throttled log
        lines = [r.getMessage() for r in caplog.records if "denied" in r.getMessage()]
        assert lines and all("[mavlink] ground_station_systems" in line for line in lines), lines
        assert any("add 42 to [mavlink] ground_station_systems" in line for line in lines), lines
        assert camera.handler.shots == 0
    finally:
        camera.close()
