"""The camera's definition file over MAVLink FTP and its settings over PARAM_EXT (issue 33), on a real
CameraComponent and MavlinkLink driven by a pymavlink ground station over UDP, with the recorder's capture
settings behind them (`icgt.recorder.camera_settings`). MAVSDK's own client: tests/e2e/test_mavsdk_settings.py.

FTP: CAMERA_INFORMATION names the file and its version; the file read in 239-byte chunks, by burst, listed and
CRC'd is the definition; a lost reply (the same request again) brings the same reply; reads past the end, an
unknown file or session and writes are refused with the protocol's errors. PARAM_EXT: the list carries every
parameter's value and type; a set applies, or is refused with the value kept: outside the definition
(VALUE_UNSUPPORTED), against the device's rules (FAILED), from a system that may not command the camera (FAILED).
"""

from __future__ import annotations

import struct
import xml.etree.ElementTree as ET
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import msgspec
import pytest
from mavlink_peers import Peer, free_udp_port, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.device.limits import CORE
from icgt.mavlink.camera import CameraComponent, CameraConfig, CameraInfo, CommandResult
from icgt.mavlink.camera_definition import decode_value, definition_version, value_from_payload
from icgt.mavlink.ftp_server import MAX_DATA, FtpError, FtpOpcode, FtpReply, pack, unpack
from icgt.mavlink.link import LinkConfig, MavlinkLink
from icgt.recorder.camera_settings import capture_settings
from icgt.recorder.config import CaptureSection, RecorderConfig

M = mavlink2
CAMERA = 100
FILE = "icgt_camera.xml"


class Handler:
    def start(self, interval_s: float, count: int) -> CommandResult:
        return CommandResult.ACCEPTED

    def stop(self) -> CommandResult:
        return CommandResult.ACCEPTED

    def shoot(self) -> CommandResult:
        return CommandResult.ACCEPTED


class Rig:
    def __init__(self, tmp_path: Path) -> None:
        self.port = free_udp_port()
        self.link = MavlinkLink(LinkConfig(f"udpin:127.0.0.1:{self.port}", request_rates=False, timesync=False))
        self.config = RecorderConfig(capture=CaptureSection(interval_s=0.5, shutter_pulse_s=0.02, burst_s=2.0))
        self.capture = self.config.capture
        settings = capture_settings(lambda: self.capture, self._put, lambda: self.config, lambda: CORE)
        info = CameraInfo()
        self.camera = CameraComponent(
            self.link, CameraConfig(output_dir=tmp_path, info=info, settings=settings), Handler()
        )
        self.link.start()
        self.camera.start()
        self.gcs = Peer(255, 190, self.port)
        self.intruder = Peer(42, 190, self.port)
        for peer in (self.gcs, self.intruder):
            peer.send(peer.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))
        assert wait_until(lambda: len(self.link._conn.clients) == 2)
        self.seq = 0

    def _put(self, section: CaptureSection) -> None:
        self.capture = section

    def ftp(self, opcode: int, *, session: int = 0, offset: int = 0, data: bytes = b"", seq: int | None = None,
            replies: int = 1) -> list[FtpReply]:  # fmt: skip
        if seq is None:
            self.seq += 1
            seq = self.seq
        since = self.gcs.mark()
        request = FtpReply(seq, session, opcode, 0, offset, data)
        self.gcs.send(self.gcs.mav.file_transfer_protocol_encode(0, 1, CAMERA, pack(request)))
        assert wait_until(lambda: len(self.gcs.messages("FILE_TRANSFER_PROTOCOL", since)) >= replies, 2.0)
        return [unpack(m.payload) for m in self.gcs.messages("FILE_TRANSFER_PROTOCOL", since)]

    def download(self) -> bytes:
        (opened,) = self.ftp(FtpOpcode.OPEN_FILE_RO, data=FILE.encode() + b"\0")
        assert opened.opcode == FtpOpcode.ACK and opened.req_opcode == FtpOpcode.OPEN_FILE_RO
        size = struct.unpack("<I", opened.data)[0]
        out = b""
        while len(out) < size:
            (chunk,) = self.ftp(FtpOpcode.READ_FILE, session=opened.session, offset=len(out), data=bytes(MAX_DATA))
            assert chunk.opcode == FtpOpcode.ACK and chunk.offset == len(out), chunk
            out += chunk.data
        (done,) = self.ftp(FtpOpcode.TERMINATE_SESSION, session=opened.session)
        assert done.opcode == FtpOpcode.ACK
        return out

    def close(self) -> None:
        self.gcs.close()
        self.intruder.close()
        self.camera.stop()
        self.link.stop()


@pytest.fixture
def rig(tmp_path: Path) -> Iterator[Rig]:
    r = Rig(tmp_path)
    yield r
    r.close()


def _information(rig: Rig) -> Any:
    since = rig.gcs.mark()
    rig.gcs.command_long(1, CAMERA, M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_CAMERA_INFORMATION)
    return rig.gcs.wait_for("CAMERA_INFORMATION", since=since)


def test_the_definition_file_comes_over_mavlink_ftp_as_camera_information_names_it(rig: Rig) -> None:
    info = _information(rig)
    uri = info.cam_definition_uri
    uri = uri.decode() if isinstance(uri, bytes) else uri
    assert uri == f"mftp://{FILE}"
    xml = rig.download()
    assert info.cam_definition_version == definition_version(xml) and len(xml) > 2 * MAX_DATA
    root = ET.fromstring(xml)
    assert root.tag == "mavlinkcamera" and root.findtext("definition/model") == CameraInfo().model
    params = {p.get("name"): p for p in root.iter("parameter")}
    assert set(params) == {"CAM_MODE", "ICGT_TRIG_MODE", "ICGT_INTERVAL", "ICGT_FOCUS_LEAD", "ICGT_BURST",
                           "ICGT_SHUTTER_PW"}  # fmt: skip
    assert params["ICGT_INTERVAL"].attrib == {"name": "ICGT_INTERVAL", "type": "float", "default": "0.5",
                                              "min": "0.05", "max": "3600.0", "step": "0.01"}  # fmt: skip
    assert [o.get("value") for o in params["ICGT_TRIG_MODE"].iter("option")] == ["0", "1"]
    assert params["CAM_MODE"].get("control") == "0"
    # the same file by burst (QGroundControl's way), in the listing, and its CRC
    (opened,) = rig.ftp(FtpOpcode.OPEN_FILE_RO, data=b"/" + FILE.encode() + b"\0")
    burst = rig.ftp(FtpOpcode.BURST_READ_FILE, session=opened.session, replies=-(-len(xml) // MAX_DATA))
    assert b"".join(b.data for b in burst) == xml and burst[-1].burst_complete
    assert [b.seq for b in burst] == list(range(rig.seq + 1, rig.seq + 1 + len(burst)))
    (listing,) = rig.ftp(FtpOpcode.LIST_DIRECTORY, data=b"/\0")
    assert listing.data == f"F{FILE}\t{len(xml)}".encode() + b"\0"
    (crc,) = rig.ftp(FtpOpcode.CALC_FILE_CRC32, data=FILE.encode())
    assert struct.unpack("<I", crc.data)[0] == zlib.crc32(xml)
    assert rig.camera.counters["ftp_files_opened"] == 2


def test_ftp_errors_and_a_lost_reply(rig: Rig) -> None:
    (missing,) = rig.ftp(FtpOpcode.OPEN_FILE_RO, data=b"etc/passwd\0")
    assert (missing.opcode, missing.data) == (FtpOpcode.NAK, bytes([FtpError.FILE_NOT_FOUND]))
    (opened,) = rig.ftp(FtpOpcode.OPEN_FILE_RO, data=FILE.encode() + b"\0")
    size = struct.unpack("<I", opened.data)[0]
    (first,) = rig.ftp(FtpOpcode.READ_FILE, session=opened.session, data=bytes(MAX_DATA))
    (again,) = rig.ftp(FtpOpcode.READ_FILE, session=opened.session, data=bytes(MAX_DATA), seq=rig.seq)  # resent
    assert again == first and again.seq == rig.seq + 1
    assert rig.camera.counters["ftp_retransmissions"] == 1
    (eof,) = rig.ftp(FtpOpcode.READ_FILE, session=opened.session, offset=size, data=bytes(MAX_DATA))
    assert (eof.opcode, eof.data) == (FtpOpcode.NAK, bytes([FtpError.EOF]))
    (bad,) = rig.ftp(FtpOpcode.READ_FILE, session=opened.session + 1, data=bytes(MAX_DATA))
    assert bad.data == bytes([FtpError.INVALID_SESSION])
    for op in (FtpOpcode.CREATE_FILE, FtpOpcode.WRITE_FILE, FtpOpcode.REMOVE_FILE):
        (refused,) = rig.ftp(op, data=FILE.encode())
        assert (refused.opcode, refused.data) == (FtpOpcode.NAK, bytes([FtpError.FILE_PROTECTED]))
    (unknown,) = rig.ftp(99)
    assert unknown.data == bytes([FtpError.UNKNOWN_COMMAND])


def _values(rig: Rig) -> dict[str, tuple[float, int, int]]:
    since = rig.gcs.mark()
    rig.gcs.send(rig.gcs.mav.param_ext_request_list_encode(1, CAMERA))
    assert wait_until(lambda: len(rig.gcs.messages("PARAM_EXT_VALUE", since)) >= 6, 2.0)
    out = {}
    for m in rig.gcs.messages("PARAM_EXT_VALUE", since):
        raw = value_from_payload(m, "PARAM_EXT_VALUE")
        out[m.param_id] = (decode_value(m.param_type, raw), m.param_type, m.param_count)
    return out


def _set(rig: Rig, name: str, value: float, kind: int = M.MAV_PARAM_EXT_TYPE_REAL32, peer: Peer | None = None) -> Any:
    peer = peer or rig.gcs
    raw = struct.pack("<f" if kind == M.MAV_PARAM_EXT_TYPE_REAL32 else "<I", value)
    since = peer.mark()
    peer.send(peer.mav.param_ext_set_encode(1, CAMERA, name.encode(), raw, kind))
    ack = peer.wait_for("PARAM_EXT_ACK", lambda m: m.param_id == name, since=since)
    return ack, decode_value(ack.param_type, value_from_payload(ack, "PARAM_EXT_ACK"))


def test_param_ext_lists_sets_and_refuses(rig: Rig) -> None:
    values = _values(rig)
    assert values["ICGT_TRIG_MODE"] == (0.0, M.MAV_PARAM_EXT_TYPE_UINT32, 6)
    assert values["ICGT_INTERVAL"][:2] == (pytest.approx(0.5), M.MAV_PARAM_EXT_TYPE_REAL32)
    assert values["ICGT_FOCUS_LEAD"][0] == pytest.approx(0.5)  # 00 00 00 3f: a leading NUL byte, read right
    # accepted: in force for the next capture start
    ack, value = _set(rig, "ICGT_TRIG_MODE", 1, M.MAV_PARAM_EXT_TYPE_UINT32)
    assert (ack.param_result, value) == (M.PARAM_ACK_ACCEPTED, 1.0) and rig.capture.mode == "focus_burst"
    ack, value = _set(rig, "ICGT_BURST", 0.6)
    assert ack.param_result == M.PARAM_ACK_ACCEPTED and rig.capture.burst_s == 0.6 and value == pytest.approx(0.6)
    # the device's rule: a burst shorter than the interval -> FAILED, kept
    ack, value = _set(rig, "ICGT_BURST", 0.3)
    assert (ack.param_result, rig.capture.burst_s) == (M.PARAM_ACK_FAILED, 0.6) and value == pytest.approx(0.6)
    # outside the definition's range, or of another type -> VALUE_UNSUPPORTED, kept
    ack, _ = _set(rig, "ICGT_SHUTTER_PW", 2.0)
    assert (ack.param_result, rig.capture.shutter_pulse_s) == (M.PARAM_ACK_VALUE_UNSUPPORTED, 0.02)
    ack, _ = _set(rig, "ICGT_TRIG_MODE", 1.0)  # a float for the uint32
    assert ack.param_result == M.PARAM_ACK_VALUE_UNSUPPORTED
    # a system that may not command the camera -> FAILED, kept
    ack, _ = _set(rig, "ICGT_INTERVAL", 1.0, peer=rig.intruder)
    assert (ack.param_result, rig.capture.interval_s) == (M.PARAM_ACK_FAILED, 0.5)
    counters = rig.camera.counters
    assert (counters["settings_set"], counters["settings_refused"]) == (2, 4)
    assert _values(rig)["ICGT_BURST"][0] == pytest.approx(0.6)


def test_the_recorders_capture_command_follows_the_settings() -> None:
    """What the recorder sends the device at the next start (START_CAPTURE) is built from the settings in force."""
    from icgt.recorder.capture import start_command

    config = RecorderConfig(capture=CaptureSection(interval_s=0.5))
    current = [config.capture]
    settings = capture_settings(lambda: current[0], lambda c: current.__setitem__(0, c), lambda: config, lambda: CORE)
    for name, value in (("ICGT_TRIG_MODE", 1), ("ICGT_BURST", 0.6), ("ICGT_FOCUS_LEAD", 0.4),
                        ("ICGT_SHUTTER_PW", 0.05)):  # fmt: skip
        settings.set(name, value)
    cmd, mode = start_command(msgspec.structs.replace(config, capture=current[0]), 0.2, 0, CORE)
    assert (cmd.mode, cmd.interval_us, cmd.burst_us, cmd.focus_lead_us, cmd.shutter_pulse_us) == (
        int(mode), 200_000, 600_000, 400_000, 50_000)  # fmt: skip
    assert mode.name == "FOCUS_BURST"
