"""CameraComponent on a real MavlinkLink, driven by a pymavlink "ground station" and "autopilot" over UDP."""

from __future__ import annotations

import logging
import math
import threading
import time

import pytest
from mavlink_peers import AutopilotPeer, Peer, free_udp_port, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.camera import (
    CameraComponent,
    CameraConfig,
    CameraError,
    CameraInfo,
    CapturedImage,
    CommandRecord,
    CommandResult,
    HandlerResult,
    RejectedCommand,
)
from icgt.mavlink.link import LinkConfig, MavlinkLink

M = mavlink2
ACCEPTED = M.MAV_RESULT_ACCEPTED


class FakeRecorder:
    def __init__(self):
        self.calls: list[tuple] = []
        self.lock = threading.Lock()
        self.next_result: CommandResult | HandlerResult | Exception = CommandResult.ACCEPTED

    def _answer(self, call):
        with self.lock:
            self.calls.append(call)
        if isinstance(self.next_result, Exception):
            raise self.next_result
        return self.next_result

    def start(self, interval_s, count):
        return self._answer(("start", interval_s, count))

    def stop(self):
        return self._answer(("stop",))

    def shoot(self):
        return self._answer(("shoot",))

    def count(self, name):
        with self.lock:
            return sum(1 for c in self.calls if c[0] == name)


class Rig:
    def __init__(self, tmp_path):
        self.port = free_udp_port()
        self.link = MavlinkLink(LinkConfig(f"udpin:127.0.0.1:{self.port}", request_rates=False, timesync=False))
        self.recorder = FakeRecorder()
        self.rejected: list[RejectedCommand] = []
        self.records: list[CommandRecord] = []
        info = CameraInfo(
            vendor="Sony",
            model="ILX-LR1",
            firmware_version=(1, 2, 3, 4),
            focal_length_mm=24.0,
            sensor_size_h_mm=35.7,
            sensor_size_v_mm=23.8,
            resolution_h=9504,
            resolution_v=6336,
        )
        self.camera = CameraComponent(
            self.link,
            CameraConfig(
                output_dir=tmp_path / "images",
                info=info,
                status_hz=5.0,
                heartbeat_hz=10.0,
                retransmit_window_s=0.5,
                log_period_s=0.5,
            ),
            self.recorder,
            on_rejected=self.rejected.append,
            on_command=self.records.append,
        )
        self.link.start()
        self.camera.start()
        self.gcs = Peer(255, 190, self.port)
        self.ap = AutopilotPeer(self.port)
        # udpin links answer whoever has spoken to them: both peers say hello first
        self.gcs.send(self.gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))
        self.ap.heartbeat()
        assert wait_until(lambda: len(self.link._conn.clients) == 2)

    def command(self, command, *params, target=(1, 100), confirmation=0, peer=None):
        peer = peer or self.gcs
        since = peer.mark()
        peer.command_long(target[0], target[1], command, *params, confirmation=confirmation)
        return since

    def ack(self, command, since, peer=None, timeout=2.0):
        peer = peer or self.gcs
        # Every peer hears every answer: only an ack addressed to this peer is its own (an intruder's refusal,
        # read late on a loaded machine, was taken for the ground station's answer)
        return peer.wait_for(
            "COMMAND_ACK",
            lambda m: m.command == command and getattr(m, "target_system", 0) in (0, peer.system),
            timeout=timeout,
            since=since,
        )

    def close(self):
        self.gcs.close()
        self.ap.close()
        self.camera.stop()
        self.link.stop()


@pytest.fixture
def rig(tmp_path):
    r = Rig(tmp_path)
    yield r
    r.close()


def from_camera(m) -> bool:
    return (m.get_srcSystem(), m.get_srcComponent()) == (1, 100)


def test_heartbeat_announces_a_camera(rig):
    hb = rig.gcs.wait_for("HEARTBEAT", from_camera)
    assert hb.type == M.MAV_TYPE_CAMERA and hb.autopilot == M.MAV_AUTOPILOT_INVALID
    assert hb.get_srcComponent() == M.MAV_COMP_ID_CAMERA == 100


def test_request_message_camera_information(rig):
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    ack = rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since)
    assert ack.result == ACCEPTED and (ack.target_system, ack.target_component) == (255, 190)
    info = rig.gcs.wait_for("CAMERA_INFORMATION", from_camera, since=since)
    assert bytes(info.vendor_name).rstrip(b"\0") == b"Sony" and bytes(info.model_name).rstrip(b"\0") == b"ILX-LR1"
    assert info.firmware_version == (4 << 24) | (3 << 16) | (2 << 8) | 1
    assert info.focal_length == pytest.approx(24.0) and info.sensor_size_h == pytest.approx(35.7)
    assert (info.resolution_h, info.resolution_v) == (9504, 6336)
    assert info.flags & M.CAMERA_CAP_FLAGS_CAPTURE_IMAGE


def test_qgroundcontrol_4_discovery_sequence(rig):
    """The legacy requests QGC 4.x sends after the camera's first heartbeat, each with COMMAND_ACK."""
    since = rig.gcs.mark()
    rig.command(M.MAV_CMD_REQUEST_CAMERA_INFORMATION, 1)
    rig.command(M.MAV_CMD_REQUEST_CAMERA_SETTINGS, 1)
    rig.command(M.MAV_CMD_REQUEST_STORAGE_INFORMATION, 0, 1)
    rig.command(M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS, 1)
    for cmd in (
        M.MAV_CMD_REQUEST_CAMERA_INFORMATION,
        M.MAV_CMD_REQUEST_CAMERA_SETTINGS,
        M.MAV_CMD_REQUEST_STORAGE_INFORMATION,
        M.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS,
    ):
        assert rig.ack(cmd, since).result == ACCEPTED
    rig.gcs.wait_for("CAMERA_INFORMATION", from_camera, since=since)
    settings = rig.gcs.wait_for("CAMERA_SETTINGS", from_camera, since=since)
    assert settings.mode_id == M.CAMERA_MODE_IMAGE
    storage = rig.gcs.wait_for("STORAGE_INFORMATION", from_camera, since=since)
    assert storage.status == M.STORAGE_STATUS_READY and storage.total_capacity > 0
    assert 0 < storage.available_capacity <= storage.total_capacity
    status = rig.gcs.wait_for("CAMERA_CAPTURE_STATUS", from_camera, since=since)
    assert status.image_status == 0 and status.available_capacity > 0
    # QGC's single photo: IMAGE_START_CAPTURE(0, 0 s, 1 image)
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1)
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == ACCEPTED
    assert rig.recorder.calls == [("shoot",)]


def test_interval_capture_start_status_and_stop(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0.5, 0)
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == ACCEPTED
    assert rig.recorder.calls == [("start", 0.5, 0)]
    st = rig.gcs.wait_for("CAMERA_CAPTURE_STATUS", lambda m: m.image_status == 3, since=since)
    assert st.image_interval == pytest.approx(0.5)
    # repeated while capturing (5 Hz in this rig)
    n = len(rig.gcs.messages("CAMERA_CAPTURE_STATUS", since))
    assert wait_until(lambda: len(rig.gcs.messages("CAMERA_CAPTURE_STATUS", since)) >= n + 2)
    since = rig.command(M.MAV_CMD_IMAGE_STOP_CAPTURE, 0)
    assert rig.ack(M.MAV_CMD_IMAGE_STOP_CAPTURE, since).result == ACCEPTED
    assert rig.recorder.calls[-1] == ("stop",)
    rig.gcs.wait_for("CAMERA_CAPTURE_STATUS", lambda m: m.image_status == 0, since=since)
    assert rig.camera.capture_status.image_status == 0


def test_duplicate_single_shot_sequence_is_acked_but_not_executed_twice(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 7)
    rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 7)  # re-sent, same sequence
    assert wait_until(lambda: len(rig.gcs.messages("COMMAND_ACK", since)) == 2)
    assert all(a.result == ACCEPTED for a in rig.gcs.messages("COMMAND_ACK", since))
    assert rig.recorder.count("shoot") == 1
    assert wait_until(lambda: [r.duplicate for r in rig.records][-2:] == [False, True])
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 8)  # next sequence: a new shot
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert rig.recorder.count("shoot") == 2


def test_reused_sequence_number_from_a_restarted_client_is_a_new_photo(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1)
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, confirmation=1)  # its retransmission
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert rig.recorder.count("shoot") == 1
    time.sleep(0.7)  # past the retransmit window (0.5 s in this rig), within the 10 s memory
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1)  # a restarted client counts from 1 again
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == ACCEPTED
    assert rig.recorder.count("shoot") == 2
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, confirmation=2)  # a late resend of it
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert rig.recorder.count("shoot") == 2


def test_retransmission_without_sequence_is_not_executed_twice(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 0)
    rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 0, confirmation=1)  # QGC's resend
    assert wait_until(lambda: len(rig.gcs.messages("COMMAND_ACK", since)) == 2)
    assert rig.recorder.count("shoot") == 1
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 0)  # pressed again: a new first transmission
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert rig.recorder.count("shoot") == 2


def test_do_digicam_control_shoot_and_command_identity(rig):
    since = rig.command(M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 1, 3, 0)
    assert rig.ack(M.MAV_CMD_DO_DIGICAM_CONTROL, since).result == ACCEPTED
    since = rig.command(M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 1, 3, 0)  # same identity
    assert rig.ack(M.MAV_CMD_DO_DIGICAM_CONTROL, since).result == ACCEPTED
    assert rig.recorder.count("shoot") == 1
    since = rig.command(M.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 0, 0, 0)  # not a shot
    assert rig.ack(M.MAV_CMD_DO_DIGICAM_CONTROL, since).result == M.MAV_RESULT_UNSUPPORTED
    assert rig.recorder.count("shoot") == 1


def test_autopilot_may_command_the_camera(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, peer=rig.ap)
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since, peer=rig.ap).result == ACCEPTED
    assert rig.recorder.count("shoot") == 1


def test_foreign_system_is_denied_and_reported(rig):
    intruder = Peer(42, 190, rig.port)
    try:
        since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 1.0, 0, peer=intruder)
        ack = rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since, peer=intruder)
        assert ack.result == M.MAV_RESULT_DENIED and (ack.target_system, ack.target_component) == (42, 190)
        assert rig.recorder.calls == []
        rej = rig.rejected[0]
        assert (rej.src_system, rej.src_component, rej.command) == (42, 190, M.MAV_CMD_IMAGE_START_CAPTURE)
        assert "not an allowed ground station" in rej.reason
        c = rig.camera.counters
        assert c["rejected_commands"] == c["denied_systems"] == c["refusal_acks_sent"] == 1
    finally:
        intruder.close()


def test_mavsdk_system_id_is_allowed_by_default(rig):
    mavsdk = Peer(245, 190, rig.port)
    try:
        since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 1, peer=mavsdk)
        assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since, peer=mavsdk).result == ACCEPTED
        assert rig.recorder.count("shoot") == 1
    finally:
        mavsdk.close()


def test_refusal_flood_is_rate_limited_logged_in_summaries_and_does_not_delay_a_command(rig, caplog):
    intruder = Peer(42, 190, rig.port)
    try:
        with caplog.at_level("WARNING", logger="icgt.mavlink.camera"):
            since = intruder.mark()
            for i in range(400):
                intruder.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, i + 1)
            t0 = time.monotonic()
            gsince = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 77)
            assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, gsince).result == ACCEPTED
            assert time.monotonic() - t0 < 1.0  # generous: the refusals never queue ahead of it
            assert wait_until(lambda: rig.camera.counters["denied_systems"] == 400)
            time.sleep(0.7)  # past the log period: the pending summary is written
        acks = [a for a in intruder.messages("COMMAND_ACK", since) if a.target_system == 42]  # all peers hear all
        c = rig.camera.counters
        assert 1 <= len(acks) <= 20 and all(a.result == M.MAV_RESULT_DENIED for a in acks)
        assert c["refusal_acks_sent"] + c["refusal_acks_suppressed"] == 400
        lines = [r.getMessage() for r in caplog.records if "denied commands" in r.getMessage()]
        assert 2 <= len(lines) <= 5
        assert "400 in total" in lines[-1]
        assert rig.recorder.count("shoot") == 1
    finally:
        intruder.close()


def test_queue_overflow_is_answered_temporarily_rejected_and_counted(tmp_path):
    gate = threading.Event()

    class Slow(FakeRecorder):
        def shoot(self):
            gate.wait(5)
            return super().shoot()

    port = free_udp_port()
    link = MavlinkLink(LinkConfig(f"udpin:127.0.0.1:{port}", request_rates=False, timesync=False))
    camera = CameraComponent(link, CameraConfig(output_dir=tmp_path, command_queue=2, log_period_s=0.2), Slow())
    link.start()
    camera.start()
    gcs = Peer(255, 190, port)
    try:
        gcs.send(gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))
        assert wait_until(lambda: len(link._conn.clients) == 1)
        since = gcs.mark()
        for i in range(8):
            gcs.command_long(1, 100, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, i + 1)

        def busy():
            return [a for a in gcs.messages("COMMAND_ACK", since) if a.result == M.MAV_RESULT_TEMPORARILY_REJECTED]

        assert wait_until(lambda: camera.counters["queue_overflows"] >= 4)
        assert wait_until(lambda: len(busy()) == camera.counters["refusal_acks_sent"])
        c = camera.counters
        assert c["refusal_acks_sent"] + c["refusal_acks_suppressed"] == c["queue_overflows"] == c["rejected_commands"]
        gate.set()
        answered = 8 - c["refusal_acks_suppressed"]  # past the ACK rate limit: counted, not answered
        assert wait_until(lambda: len(gcs.messages("COMMAND_ACK", since)) == answered, timeout=5)
    finally:
        gate.set()
        gcs.close()
        camera.stop()
        link.stop()


def test_commands_for_other_components_or_systems_are_ignored(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 5, target=(1, 1))  # for the autopilot
    rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 6, target=(2, 100))  # another vehicle's camera
    rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION, target=(1, 101))
    time.sleep(0.3)
    assert rig.gcs.messages("COMMAND_ACK", since) == [] and rig.recorder.calls == [] and rig.rejected == []
    # broadcast target component 0 is ours too
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 9, target=(0, 0))
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == ACCEPTED


def test_unknown_commands_targeted_unsupported_broadcast_silent(rig):
    since = rig.command(M.MAV_CMD_DO_SET_MODE, 1, 4, target=(1, 100))
    assert rig.ack(M.MAV_CMD_DO_SET_MODE, since).result == M.MAV_RESULT_UNSUPPORTED
    since = rig.command(M.MAV_CMD_DO_SET_MODE, 1, 4, target=(1, 0))
    rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, target=(1, 0))
    time.sleep(0.3)
    assert rig.gcs.messages("COMMAND_ACK", since) == []


def test_repeated_broadcast_we_do_not_implement_is_ignored_quietly(rig, caplog):
    """MAVProxy asks for the home position with a broadcast GET_HOME_POSITION every few seconds: not the
    camera's business. No ACK, no command record, nothing at INFO or above, one debug line in all."""
    with caplog.at_level(logging.DEBUG, logger="icgt.mavlink.camera"):
        since = rig.gcs.mark()
        for target in ((0, 0), (1, 0), (0, 0), (1, 0), (0, 0)):
            rig.command(M.MAV_CMD_GET_HOME_POSITION, target=target)
        assert wait_until(lambda: rig.camera.counters["broadcasts_ignored"] == 5, timeout=5.0)
        # a command we do answer, sent after them, shows they have all been handled
        assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, rig.command(M.MAV_CMD_REQUEST_MESSAGE, 259)).result == ACCEPTED
    acks = [a for a in rig.gcs.messages("COMMAND_ACK", since) if a.command == M.MAV_CMD_GET_HOME_POSITION]
    assert acks == []
    assert [r for r in rig.records if r.command == M.MAV_CMD_GET_HOME_POSITION] == []
    mentions = [r for r in caplog.records if f"command {M.MAV_CMD_GET_HOME_POSITION} " in r.getMessage()]
    assert len(mentions) == 1 and mentions[0].levelno == logging.DEBUG, [r.getMessage() for r in mentions]
    assert rig.camera.counters["rejected_commands"] == 0


def test_handler_results_map_to_acks(rig):
    rig.recorder.next_result = HandlerResult(CommandResult.DENIED, "no camera connected", progress=1, result_param2=7)
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 1.0, 0)
    ack = rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert (ack.result, ack.progress, ack.result_param2) == (M.MAV_RESULT_DENIED, 1, 7)
    assert rig.camera.capture_status.image_status == 0
    rig.recorder.next_result = CommandResult.TEMPORARILY_REJECTED
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 1.0, 0)
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == M.MAV_RESULT_TEMPORARILY_REJECTED
    rig.recorder.next_result = RuntimeError("board unplugged")
    since = rig.command(M.MAV_CMD_IMAGE_STOP_CAPTURE, 0)
    assert rig.ack(M.MAV_CMD_IMAGE_STOP_CAPTURE, since).result == M.MAV_RESULT_FAILED
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0)  # interval 0 and unlimited count
    assert rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since).result == M.MAV_RESULT_DENIED
    assert rig.recorder.count("start") == 2  # the invalid one never reached the handler


def image(index, **kw):
    values = dict(
        time_boot_ms=123_456,
        time_utc_us=1_700_000_000_123_456,
        lat_deg=47.3977419,
        lon_deg=-122.0840575,
        alt_msl_m=488.1234,
        relative_alt_m=30.25,
        q_wxyz=(math.sqrt(0.5), 0.0, 0.0, math.sqrt(0.5)),
        capture_result=True,
        file_url=f"file:///data/IMG_{index:05d}.JPG",
        camera_id=1,
    )
    values.update(kw)
    return CapturedImage(**values)


def test_camera_image_captured_round_trip_and_re_request(rig):
    since = rig.gcs.mark()
    for i in range(3):
        assert rig.camera.publish_image_captured(image(i)).image_index == i
    got = rig.gcs.wait_for("CAMERA_IMAGE_CAPTURED", lambda m: m.image_index == 2, since=since)
    assert from_camera(got)
    assert got.lat == 473_977_419 and got.lon == -1_220_840_575
    assert got.alt == 488_123 and got.relative_alt == 30_250
    assert list(got.q) == pytest.approx([math.sqrt(0.5), 0, 0, math.sqrt(0.5)])
    assert got.time_boot_ms == 123_456 and got.time_utc == 1_700_000_000_123_456
    assert got.capture_result == 1 and got.camera_id == 1
    assert got.file_url == "file:///data/IMG_00002.JPG"
    # re-request image 1 by index (MAV_CMD_REQUEST_MESSAGE p2) and by the legacy command
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 1)
    assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == ACCEPTED
    again = rig.gcs.wait_for("CAMERA_IMAGE_CAPTURED", since=since)
    assert again.image_index == 1 and again.lat == 473_977_419
    since = rig.command(M.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE, 0)
    assert rig.gcs.wait_for("CAMERA_IMAGE_CAPTURED", since=since).image_index == 0
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 99)
    assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == M.MAV_RESULT_DENIED
    # all (-1), a range (param3 = last index) and "this and every later one" (param3 = -1)
    for p2, p3, want in ((-1, 0, [0, 1, 2]), (0, 1, [0, 1]), (1, -1, [1, 2])):
        since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, p2, p3)
        assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == ACCEPTED
        assert wait_until(lambda: len(rig.gcs.messages("CAMERA_IMAGE_CAPTURED", since)) == len(want))  # noqa: B023
        time.sleep(0.1)
        assert [m.image_index for m in rig.gcs.messages("CAMERA_IMAGE_CAPTURED", since)] == want
    # no position (no 3D fix): zeros and NaN attitude, result unchanged
    since = rig.gcs.mark()
    rig.camera.publish_image_captured(image(3, lat_deg=None, lon_deg=None, alt_msl_m=None, q_wxyz=None))
    nofix = rig.gcs.wait_for("CAMERA_IMAGE_CAPTURED", since=since)
    assert (nofix.lat, nofix.lon, nofix.alt) == (0, 0, 0) and all(math.isnan(c) for c in nofix.q)
    with pytest.raises(CameraError):
        rig.camera.publish_image_captured(image(4, lat_deg=91.0))


def test_a_request_without_index_from_a_new_client_brings_every_image_it_lacks(rig):
    """MAVSDK asks REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED) with param2 = param3 = 0 for whatever index it misses
    (icgt.mavlink.camera_clients): a client that discovered the camera after images 0..4 gets all five, and
    the same request afterwards only image 0 (by the protocol's letter). An explicit index stays exact."""
    for i in range(5):
        rig.camera.publish_image_captured(image(i))
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    rig.gcs.wait_for("CAMERA_INFORMATION", since=since)
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 0, 0)
    assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == ACCEPTED
    assert wait_until(lambda: len(rig.gcs.messages("CAMERA_IMAGE_CAPTURED", since)) >= 5, timeout=5.0)
    assert sorted({m.image_index for m in rig.gcs.messages("CAMERA_IMAGE_CAPTURED", since)}) == [0, 1, 2, 3, 4]
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, 0, 0)
    assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == ACCEPTED
    time.sleep(0.3)
    assert [m.image_index for m in rig.gcs.messages("CAMERA_IMAGE_CAPTURED", since)] == [0]
    since = rig.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED, math.nan, math.nan)
    assert rig.ack(M.MAV_CMD_REQUEST_MESSAGE, since).result == M.MAV_RESULT_DENIED  # nothing named, nothing lacking


def test_count_limited_capture_returns_to_idle(rig):
    since = rig.command(M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0.1, 2)
    rig.ack(M.MAV_CMD_IMAGE_START_CAPTURE, since)
    assert rig.camera.capture_status.image_status == 3
    rig.camera.publish_image_captured(image(0))
    rig.camera.publish_image_captured(image(1))
    assert rig.camera.capture_status == type(rig.camera.capture_status)(0, 0.0, 2)  # image_count = last index + 1
    rig.gcs.wait_for("CAMERA_CAPTURE_STATUS", lambda m: m.image_status == 0 and m.image_count == 2, since=since)


def test_stop_leaves_no_threads(tmp_path):
    before = [t.name for t in threading.enumerate() if t.name.startswith("icgt-")]
    r = Rig(tmp_path)
    assert len([t for t in threading.enumerate() if t.name.startswith("icgt-")]) == len(before) + 3
    r.close()
    assert [t.name for t in threading.enumerate() if t.name.startswith("icgt-")] == before
