"""The camera's settings for ground stations: its definition file over MAVLink FTP, its values over PARAM_EXT.

`CameraSettings` is what the recorder offers (the parameters, their current values, how one is set);
`SettingsService` runs them on the camera's link, on the camera component's worker thread:

* CAMERA_INFORMATION announces ``cam_definition_uri = "mftp://icgt_camera.xml"`` and a version derived from
  the file (`icgt.mavlink.camera_definition`); the file is served read-only by `icgt.mavlink.ftp_server`
  to whoever asks the camera's component (FILE_TRANSFER_PROTOCOL addressed to it).
* PARAM_EXT_REQUEST_LIST (every parameter, index and count), PARAM_EXT_REQUEST_READ (by name, or by index
  when the name is empty) are answered with PARAM_EXT_VALUE; an unknown name gets no answer (the protocol's
  rule: the client times out).
* PARAM_EXT_SET from a system that may command the camera (the ground stations and the autopilot): the value
  is checked against the definition (`CameraParam.check`), then by the recorder (``CameraSettings.set``, which
  raises ParamError for a combination the device would refuse); PARAM_EXT_ACK ACCEPTED with the value now in
  force, or VALUE_UNSUPPORTED (outside the definition) / FAILED (refused by the recorder) with the value kept.
  With signing required, a PARAM_EXT_SET without a valid signature is not answered (as for commands).
  Every outcome is logged and counted (``settings_set``, ``settings_refused``, ``settings_untrusted``).
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Callable, Sequence

from icgt.mavlink.camera_definition import (
    PARAM_ID_LEN,
    CameraParam,
    ParamError,
    decode_value,
    definition_version,
    definition_xml,
    encode_value,
    value_from_payload,
)
from icgt.mavlink.ftp_server import FtpServer, pack
from icgt.mavlink.link import MavlinkLink, MavlinkMessage, mavlink2

__all__ = ["DEFINITION_FILE", "SETTINGS_MESSAGES", "CameraSettings", "SettingsService"]

log = logging.getLogger(__name__)

DEFINITION_FILE = "icgt_camera.xml"
SETTINGS_MESSAGES = ("FILE_TRANSFER_PROTOCOL", "PARAM_EXT_REQUEST_LIST", "PARAM_EXT_REQUEST_READ", "PARAM_EXT_SET")


@dataclasses.dataclass(frozen=True, slots=True)
class CameraSettings:
    """The settings a ground station may read and change. ``values()``: every parameter's value now;
    ``set(name, value)``: apply one (already checked against its definition), ParamError if refused."""

    params: tuple[CameraParam, ...]
    values: Callable[[], dict[str, float]]
    set: Callable[[str, float], None]


def _param_id(msg: object) -> str:
    raw = getattr(msg, "param_id", b"")
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0][:PARAM_ID_LEN]


class SettingsService:
    """The definition file and the PARAM_EXT parameters of one camera component (worker thread only)."""

    def __init__(
        self,
        link: MavlinkLink,
        settings: CameraSettings,
        *,
        model: str,
        vendor: str,
        allowed_systems: frozenset[int],
        require_signing: bool,
    ) -> None:
        self.link = link
        self.settings = settings
        self._params = {p.name: p for p in settings.params}
        self._order: Sequence[CameraParam] = settings.params
        self._allowed = allowed_systems
        self._require_signing = require_signing
        self.xml = definition_xml(model, vendor, settings.params)
        self.version = definition_version(self.xml)
        self.uri = f"mftp://{DEFINITION_FILE}"
        self.ftp = FtpServer({DEFINITION_FILE: self.xml})
        self._component = link.config.component_id
        self.counts = {"settings_set": 0, "settings_refused": 0, "settings_untrusted": 0}

    @property
    def counters(self) -> dict[str, int]:
        return {**self.counts, **self.ftp.counts}

    def for_us(self, rec: MavlinkMessage) -> bool:
        """Whether a message of `SETTINGS_MESSAGES` is addressed to this component (checked on the reader)."""
        msg = rec.msg
        system = int(getattr(msg, "target_system", 0))
        component = int(getattr(msg, "target_component", 0))
        if system not in (0, self.link.config.system_id):
            return False
        if rec.type in ("FILE_TRANSFER_PROTOCOL", "PARAM_EXT_SET"):
            return component == self._component  # never a broadcast: the autopilot answers those
        return component in (0, self._component)

    def handle(self, rec: MavlinkMessage) -> None:
        msg = rec.msg
        client = (rec.src_system, rec.src_component)
        if rec.type == "FILE_TRANSFER_PROTOCOL":
            for reply in self.ftp.handle(client, list(msg.payload)):
                self.link.send(self.link.mav.file_transfer_protocol_encode(0, client[0], client[1], pack(reply)))
        elif rec.type == "PARAM_EXT_REQUEST_LIST":
            for index in range(len(self._order)):
                self._send_value(index)
        elif rec.type == "PARAM_EXT_REQUEST_READ":
            name, index = _param_id(msg), int(msg.param_index)
            if name:
                index = next((i for i, p in enumerate(self._order) if p.name == name), -1)
            if 0 <= index < len(self._order):
                self._send_value(index)
        elif rec.type == "PARAM_EXT_SET":
            self._set(rec)

    # ------------------------------------------------------------------ PARAM_EXT
    def _send_value(self, index: int) -> None:
        p = self._order[index]
        value = self.settings.values()[p.name]
        self.link.send(
            self.link.mav.param_ext_value_encode(
                p.name.encode("ascii"), encode_value(p, value), p.mav_type, len(self._order), index
            )
        )

    def _ack(self, p: CameraParam, result: int) -> None:
        value = self.settings.values()[p.name]
        raw = encode_value(p, value)
        self.link.send(self.link.mav.param_ext_ack_encode(p.name.encode("ascii"), raw, p.mav_type, result))

    def _set(self, rec: MavlinkMessage) -> None:
        msg = rec.msg
        name, who = _param_id(msg), f"{rec.src_system}:{rec.src_component}"
        if self._require_signing and not msg.get_signed():
            self.counts["settings_untrusted"] += 1
            log.warning("camera setting %s from %s ignored: no valid signature", name, who)
            return
        p = self._params.get(name)
        if p is None:
            log.warning("camera setting %s from %s: no such parameter (not answered)", name, who)
            return
        if rec.src_system not in self._allowed:
            self.counts["settings_refused"] += 1
            log.warning("camera setting %s from %s refused: system %d may not command the camera (add it to "
                        "[mavlink] ground_station_systems)", name, who, rec.src_system)  # fmt: skip
            self._ack(p, mavlink2.PARAM_ACK_FAILED)
            return
        try:
            if int(msg.param_type) != p.mav_type:
                raise ParamError(f"{name}: sent as MAV_PARAM_EXT_TYPE {int(msg.param_type)}, it is {p.mav_type}")
            value = p.check(decode_value(int(msg.param_type), value_from_payload(msg, "PARAM_EXT_SET")))
        except ParamError as exc:
            self.counts["settings_refused"] += 1
            log.warning("camera setting from %s refused: %s", who, exc)
            self._ack(p, mavlink2.PARAM_ACK_VALUE_UNSUPPORTED)
            return
        try:
            self.settings.set(name, value)
        except ParamError as exc:
            self.counts["settings_refused"] += 1
            log.warning("camera setting from %s refused: %s", who, exc)
            self._ack(p, mavlink2.PARAM_ACK_FAILED)
            return
        self.counts["settings_set"] += 1
        unit = f" {p.unit}" if p.unit else ""
        log.info("camera setting %s = %g%s from %s (in force from the next capture start)", name, value, unit, who)
        self._ack(p, mavlink2.PARAM_ACK_ACCEPTED)
