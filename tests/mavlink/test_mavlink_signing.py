"""MAVLink 2 signing: the key file, a camera that refuses unsigned and wrongly signed commands, signs its own."""

from __future__ import annotations

import hashlib
import time

import pytest
from mavlink_peers import Peer, free_udp_port, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.camera import CameraComponent, CameraConfig, CameraError, CommandResult
from icgt.mavlink.link import LinkConfig, MavlinkLink
from icgt.mavlink.signing import SigningError, SigningState, key_from_passphrase, load_signing_key
from icgt.recorder.config import ConfigError, parse_config

M = mavlink2
KEY = key_from_passphrase("pier 7 inspection")


class Shots:
    def __init__(self):
        self.n = 0

    def start(self, interval_s, count):
        return CommandResult.ACCEPTED

    def stop(self):
        return CommandResult.ACCEPTED

    def shoot(self):
        self.n += 1
        return CommandResult.ACCEPTED


def test_key_is_the_sha256_of_the_passphrase_as_qgc_derives_it(tmp_path):
    f = tmp_path / "mavlink.key"
    f.write_text("pier 7 inspection\n")
    f.chmod(0o600)
    assert load_signing_key(f) == hashlib.sha256(b"pier 7 inspection").digest() == KEY
    assert "pier" not in repr(SigningState(KEY)) and KEY.hex() not in repr(LinkConfig("udpin:x:1", signing_key=KEY))


@pytest.mark.parametrize("content, why", [(b"", "empty"), (b"\n", "empty"), (b"\xff\xfe", "not UTF-8")])
def test_unusable_key_files_are_named(tmp_path, content, why):
    f = tmp_path / "k"
    f.write_bytes(content)
    with pytest.raises(SigningError, match=why) as exc:
        load_signing_key(f)
    assert "signing_key_file" in str(exc.value) and str(f) in str(exc.value)
    with pytest.raises(SigningError, match="cannot read"):
        load_signing_key(tmp_path / "missing")


def test_config_takes_a_key_file_path_and_the_default_ground_stations():
    cfg = parse_config({"mavlink": {"signing_key_file": "/etc/icgt/key"}}, "t.toml")
    assert str(cfg.mavlink.signing_key_file) == "/etc/icgt/key"
    assert set(cfg.mavlink.ground_station_systems) == {255, 245}
    with pytest.raises(ConfigError, match="signing_key_file"):
        parse_config({"mavlink": {"signing_key_file": ""}}, "t.toml")


def test_require_signing_needs_a_key_on_the_link(tmp_path):
    link = MavlinkLink(LinkConfig("udpin:127.0.0.1:1", request_rates=False, timesync=False))
    with pytest.raises(CameraError, match="signing"):
        CameraComponent(link, CameraConfig(output_dir=tmp_path, require_signing=True), Shots())


@pytest.fixture
def signed_camera(tmp_path):
    port = free_udp_port()
    link = MavlinkLink(LinkConfig(f"udpin:127.0.0.1:{port}", request_rates=False, timesync=False, signing_key=KEY))
    shots = Shots()
    camera = CameraComponent(
        link, CameraConfig(output_dir=tmp_path, require_signing=True, heartbeat_hz=10.0, log_period_s=0.2), shots
    )
    link.start()
    camera.start()
    peers: list[Peer] = []

    def peer(key: bytes | None, system: int = 255) -> Peer:
        p = Peer(system, 190, port)
        if key is not None:
            state = SigningState(key, link_id=1)
            state.attach_output(p.mav)
            state.attach_input(p._parser)
        peers.append(p)
        p.send(p.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))
        return p

    yield camera, shots, peer, link
    for p in peers:
        p.close()
    camera.stop()
    link.stop()


def test_signed_commands_work_and_our_replies_are_signed(signed_camera):
    _camera, shots, peer, _ = signed_camera
    gcs = peer(KEY)
    since = gcs.mark()
    gcs.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1)
    ack = gcs.wait_for("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_IMAGE_START_CAPTURE, since=since)
    assert ack.result == M.MAV_RESULT_ACCEPTED and ack.get_signed()  # verified with the key by the peer's parser
    hb = gcs.wait_for("HEARTBEAT", lambda m: m.get_srcComponent() == 100, since=since)
    assert hb.get_signed()
    assert shots.n == 1


def test_unsigned_and_wrongly_signed_commands_get_no_answer(signed_camera):
    camera, shots, peer, link = signed_camera
    plain = peer(None)
    wrong = peer(key_from_passphrase("guessed"))
    since_p, since_w = plain.mark(), wrong.mark()
    plain.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1)
    wrong.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 2)
    assert wait_until(lambda: camera.counters["rejected_commands"] == 2)
    time.sleep(0.3)
    assert plain.messages("COMMAND_ACK", since_p) == [] and wrong.messages("COMMAND_ACK", since_w) == []
    c = camera.counters
    assert (c["unsigned_commands"], c["badly_signed_commands"], c["refusal_acks_sent"]) == (1, 1, 0)
    assert shots.n == 0
    stats = link.stats()
    assert stats.signed_bad >= 1 and stats.unsigned >= 1


def test_a_replayed_signed_command_is_refused(signed_camera):
    camera, shots, peer, _ = signed_camera
    gcs = peer(KEY)
    msg = gcs.mav.command_long_encode(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 1, 5, 0, 0, 0)
    buf = bytes(msg.pack(gcs.mav))
    gcs.send_raw(buf)
    assert wait_until(lambda: shots.n == 1)
    gcs.send_raw(buf)  # the same frame again: its timestamp is not newer
    assert wait_until(lambda: camera.counters["badly_signed_commands"] == 1)
    assert shots.n == 1


def test_a_forged_frame_with_a_future_timestamp_does_not_block_the_genuine_stream(signed_camera):
    camera, shots, peer, _ = signed_camera
    gcs = peer(KEY)
    forger = peer(key_from_passphrase("guessed"))
    forger.mav.signing.link_id = gcs.mav.signing.link_id  # the same stream: link id, system, component
    forger.mav.signing.timestamp = gcs.mav.signing.timestamp + 10**9  # far ahead
    forger.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 9)
    assert wait_until(lambda: camera.counters["badly_signed_commands"] == 1)
    since = gcs.mark()
    gcs.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1)
    ack = gcs.wait_for("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_IMAGE_START_CAPTURE, since=since)
    assert ack.result == M.MAV_RESULT_ACCEPTED and shots.n == 1
