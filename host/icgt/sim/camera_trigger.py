"""The simulated autopilot's camera trigger: commanded capture the way ArduPilot's AP_Camera sends it.

`[autopilot.camera] backend` picks one of ArduPilot's two MAVLink camera backends (CAM1_TYPE; facts from
ArduPilot/ardupilot libraries/AP_Camera, AP_Mission, GCS_MAVLink/MAVLink_routing.cpp, ArduCopter 4.7-dev):

- ``"mavlink_camv2"`` (CAM1_TYPE = 6, AP_Camera_MAVLinkCamV2): from 10 s after boot it looks in its routing
  table for a HEARTBEAT of MAV_TYPE_CAMERA from component 100 of its own system (a route is learnt per
  link from what arrives on it), then sends MAV_CMD_REQUEST_MESSAGE(CAMERA_INFORMATION) to it every 1 s
  until CAMERA_INFORMATION arrives; it triggers only if that says CAMERA_CAP_FLAGS_CAPTURE_IMAGE. Each
  picture is one COMMAND_LONG MAV_CMD_IMAGE_START_CAPTURE targeted at (its system, 100) on that link:
  param1 0, param2 0 (interval), param3 1 (one image), param4 = image number (1, 2, ...), confirmation 0,
  never re-sent; the COMMAND_ACK and CAMERA_IMAGE_CAPTURED that come back are not looked at (it routes
  CAMERA_IMAGE_CAPTURED on to the ground stations). A picture due before the camera is found fails
  (no number spent) and is retried at the next 50 Hz update.
- ``"mavlink"`` (CAM1_TYPE = 5, AP_Camera_MAVLink): each picture is COMMAND_LONG MAV_CMD_DO_DIGICAM_CONTROL
  with target system 0 and component 0 and only param5 = 1 (shoot; param6, the command identity, 0), sent
  once on every link where a component of its own system has been heard (`send_to_components`), nothing
  waited for. Every shot's command is identical: only the link's sequence number differs.

- ``"px4"`` (PX4 TRIG_INTERFACE = 3, MAVLink; src/modules/mavlink/streams/CAMERA_TRIGGER.hpp): per shot
  CAMERA_TRIGGER (time_usec = boot time, seq from 0), then COMMAND_LONG MAV_CMD_IMAGE_START_CAPTURE to
  (its system, 100) with param1 0, param2 0, param3 1, param4 its own count from 1, param5..7 NaN, sent
  through MavlinkCommandSender (re-sent every 0.5 s with confirmation 1, 2, 3 until a COMMAND_ACK that is
  not IN_PROGRESS), then COMMAND_LONG MAV_CMD_DO_DIGICAM_CONTROL to (0, 100) with param5 = 1 and every
  other parameter NaN, sent once. No camera discovery: it sends from the first trigger on. The trigger
  rules below (ArduPilot's) are kept for this backend too: PX4's time trigger fires at the interval and
  its distance trigger when the distance is reached, which on the simulator's 20 ms update grid differs
  from ArduPilot's by at most one update.

When (AP_Camera_Backend::update, 50 Hz): a time trigger (mission IMAGE_START_CAPTURE with an interval, or
the command) takes a picture when ``now_ms - last_picture_ms > interval_ms`` (strictly greater: on the
20 ms update grid an interval of 1000 ms gives 1020 ms between pictures); while one is active the distance
trigger is not looked at. The distance trigger (DO_SET_CAM_TRIGG_DIST, CAM1_TRIGG_DIST) takes one when the
AHRS position is at least the distance from where the last picture was taken, measured horizontally
(Location::get_distance: a vertical climb alone never triggers it; the first update only sets that
place). Both honour CAM1_INTRVAL_MIN (``min_interval_s``): a picture due sooner waits, pending.

The trigger keeps its own log (what ArduPilot's CAM messages hold): each picture's number, scenario time,
boot time and position, and the COMMAND_ACK and CAMERA_IMAGE_CAPTURED it heard back, for tests to check
that the recorder's log and the autopilot's agree on every image.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.sim.scenario import AutopilotCamera

UPDATE_PERIOD_S = 0.02
"""AP_Camera::update runs at 50 Hz in ArduCopter's scheduler."""
SEARCH_AFTER_BOOT_MS = 10_000
"""AP_Camera_MAVLinkCamV2::find_camera waits 10 s after boot (so the user sees the banner)."""
INFO_REQUEST_PERIOD_MS = 1000
CAMERA_COMPONENT = 100
PX4_RESEND_MS = 500
"""MavlinkCommandSender::TIMEOUT_US: a command not acknowledged is re-sent after this."""
PX4_RETRIES = 3
"""MavlinkCommandSender::RETRIES."""
NAN = float("nan")


@dataclass
class Picture:
    """One picture the autopilot took (ArduPilot's image_index after the increment: 1, 2, ...)."""

    number: int
    tau_s: float
    boot_ms: int
    trigger: str  # "time" or "distance"
    position_enu_m: tuple[float, float, float]
    acks: list[int] = field(default_factory=list)
    """COMMAND_ACK results heard for this picture's command (matched by order of the commands)."""
    resends: int = 0
    """px4: times its IMAGE_START_CAPTURE was re-sent for want of an ACK (confirmation 1, 2, 3)."""


@dataclass
class TriggerLog:
    backend: str
    pictures: list[Picture] = field(default_factory=list)
    failed_triggers: int = 0
    """Pictures due while the camera was not found yet (retried, no number spent)."""
    info_requests: int = 0
    camera_found_tau_s: float | None = None
    image_captured: list[int] = field(default_factory=list)
    """image_index of every CAMERA_IMAGE_CAPTURED heard from the camera, in order of arrival."""
    unmatched_acks: list[tuple[int, int]] = field(default_factory=list)
    """(command, result) of COMMAND_ACKs that fit no picture."""
    companion_acks: list[int] = field(default_factory=list)
    """px4: results of the COMMAND_ACKs to the DO_DIGICAM_CONTROL sent with each IMAGE_START_CAPTURE
    (PX4 does not look at them)."""
    camera_trigger_seqs: list[int] = field(default_factory=list)
    """px4: seq of every CAMERA_TRIGGER sent."""

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(asdict(self), indent=1) + "\n", encoding="utf-8")


def read_trigger_log(path: Path) -> dict[str, Any]:
    data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    return data


class CameraTrigger:
    """ArduPilot's camera backend in the simulated autopilot; `update` at 50 Hz, `on_message` for replies."""

    def __init__(
        self,
        config: AutopilotCamera,
        system_id: int,
        codec: Any,
        send: Callable[[Any], None],
        position_enu: Callable[[float], np.ndarray[Any, np.dtype[np.float64]]],
    ) -> None:
        self.config = config
        self.system_id = system_id
        self._codec = codec
        self._send = send
        self._position_enu = position_enu
        self.log = TriggerLog(config.backend)
        self._route = False  # a HEARTBEAT of MAV_TYPE_CAMERA from (system_id, 100) was heard on the link
        self._info = False
        self._last_info_request_ms: int | None = None
        self._last_picture_ms = 0
        self._last_place: np.ndarray[Any, np.dtype[np.float64]] | None = None
        self._pending = False
        self._awaiting_ack: list[Picture] = []
        self._last_sent_ms: dict[int, int] = {}  # px4: picture number -> boot time its command last went out

    # ------------------------------------------------------------------ what arrives on the companion link
    def on_message(self, msg: Any) -> None:
        if (msg.get_srcSystem(), msg.get_srcComponent()) != (self.system_id, CAMERA_COMPONENT):
            return
        mtype = msg.get_type()
        if mtype == "HEARTBEAT" and int(msg.type) == mavlink2.MAV_TYPE_CAMERA:
            self._route = True
        elif mtype == "CAMERA_INFORMATION":
            self._info = bool(int(msg.flags) & mavlink2.CAMERA_CAP_FLAGS_CAPTURE_IMAGE)
        elif mtype == "CAMERA_IMAGE_CAPTURED":
            self.log.image_captured.append(int(msg.image_index))
        elif mtype == "COMMAND_ACK":
            self._on_ack(int(msg.command), int(msg.result))

    def _on_ack(self, command: int, result: int) -> None:
        shot = {
            "mavlink_camv2": mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
            "mavlink": mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
            "px4": mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        }.get(self.config.backend)
        if command == shot and self._awaiting_ack and result != mavlink2.MAV_RESULT_IN_PROGRESS:
            self._awaiting_ack.pop(0).acks.append(result)
        elif self.config.backend == "px4" and command == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL:
            self.log.companion_acks.append(result)
        elif command != mavlink2.MAV_CMD_REQUEST_MESSAGE:
            self.log.unmatched_acks.append((command, result))

    # ------------------------------------------------------------------ the 50 Hz update
    def update(self, tau_s: float, boot_ms: int) -> None:
        c = self.config
        if c.backend == "mavlink_camv2" and not self._info:
            self._find_camera(tau_s, boot_ms)
        if c.backend == "px4":
            self._resend_unacknowledged(boot_ms)
        if self._pending:
            self._take_picture(tau_s, boot_ms, "pending")
        if c.interval_s > 0 and c.interval_window_s[0] <= tau_s < c.interval_window_s[1]:
            if boot_ms - self._last_picture_ms > round(c.interval_s * 1000):
                self._take_picture(tau_s, boot_ms, "time")
            return
        if not (c.distance_m > 0 and c.distance_window_s[0] <= tau_s < c.distance_window_s[1]):
            self._last_place = None
            return
        here = self._position_enu(tau_s)
        if self._last_place is None:
            self._last_place = here
            return
        if float(np.linalg.norm(here[:2] - self._last_place[:2])) < c.distance_m:  # Location::get_distance
            return
        self._take_picture(tau_s, boot_ms, "distance")

    def _resend_unacknowledged(self, boot_ms: int) -> None:
        for pic in list(self._awaiting_ack):
            if boot_ms - self._last_sent_ms.get(pic.number, boot_ms) < PX4_RESEND_MS:
                continue
            if pic.resends >= PX4_RETRIES:
                self._awaiting_ack.remove(pic)  # MavlinkCommandSender gives up: no ACK for this picture
            else:
                pic.resends += 1
                self._last_sent_ms[pic.number] = boot_ms
                self._send(self._px4_start_capture(pic.number, confirmation=pic.resends))

    def _px4_start_capture(self, number: int, confirmation: int) -> Any:
        return self._codec.command_long_encode(
            self.system_id, CAMERA_COMPONENT, mavlink2.MAV_CMD_IMAGE_START_CAPTURE, confirmation,
            0, 0, 1, float(number), NAN, NAN, NAN,
        )  # fmt: skip

    def _find_camera(self, tau_s: float, boot_ms: int) -> None:
        if boot_ms < SEARCH_AFTER_BOOT_MS or not self._route:
            return
        if self.log.camera_found_tau_s is None:
            self.log.camera_found_tau_s = tau_s
        last = self._last_info_request_ms
        if last is None or boot_ms - last > INFO_REQUEST_PERIOD_MS:
            self._last_info_request_ms = boot_ms
            self.log.info_requests += 1
            self._send(
                self._codec.command_long_encode(
                    self.system_id,
                    CAMERA_COMPONENT,
                    mavlink2.MAV_CMD_REQUEST_MESSAGE,
                    0,
                    float(mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION),
                    0,
                    0,
                    0,
                    0,
                    0,
                    0,
                )
            )

    def _take_picture(self, tau_s: float, boot_ms: int, why: str) -> bool:
        if boot_ms - self._last_picture_ms < round(self.config.min_interval_s * 1000):
            self._pending = True
            return False
        self._pending = False
        number = len(self.log.pictures) + 1
        sent = self._trigger(number, boot_ms)
        if sent is None:
            self.log.failed_triggers += 1
            return False
        here = self._position_enu(tau_s)
        trigger = why if why != "pending" else "distance" if self.config.distance_m > 0 else "time"
        pic = Picture(number, tau_s, boot_ms, trigger, (float(here[0]), float(here[1]), float(here[2])))
        self.log.pictures.append(pic)
        if sent:
            self._awaiting_ack.append(pic)
        self._last_picture_ms = boot_ms
        self._last_place = here
        return True

    def _trigger(self, number: int, boot_ms: int) -> bool | None:
        """Send picture `number`'s command: True sent, False not sent but the number spent, None failed."""
        if self.config.backend == "px4":
            seq = number - 1
            self.log.camera_trigger_seqs.append(seq)
            self._send(self._codec.camera_trigger_encode(boot_ms * 1000, seq))
            self._send(self._px4_start_capture(number, confirmation=0))
            self._last_sent_ms[number] = boot_ms
            self._send(
                self._codec.command_long_encode(
                    0, CAMERA_COMPONENT, mavlink2.MAV_CMD_DO_DIGICAM_CONTROL, 0, NAN, NAN, NAN, NAN, 1, NAN, NAN
                )
            )
            return True
        if self.config.backend == "mavlink_camv2":
            if not self._info:
                return None
            cmd = self._codec.command_long_encode(
                self.system_id,
                CAMERA_COMPONENT,
                mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
                0,
                0,
                0,
                1,
                float(number),
                0,
                0,
                0,
            )
        else:
            if not self._route:
                return False  # send_to_components finds no link: the number is spent all the same
            cmd = self._codec.command_long_encode(0, 0, mavlink2.MAV_CMD_DO_DIGICAM_CONTROL, 0, 0, 0, 0, 0, 1, 0, 0)
        self._send(cmd)
        return True


def trigger_due(config: AutopilotCamera) -> bool:
    """Whether the scenario asks the autopilot to command the camera at all."""
    return config.backend != "none" and (config.interval_s > 0 or config.distance_m > 0)
