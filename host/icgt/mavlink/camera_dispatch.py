"""What each command the camera component executes does, on its worker thread.

IMAGE_START_CAPTURE / IMAGE_STOP_CAPTURE / DO_DIGICAM_CONTROL through the recorder's `CaptureHandler`
(and the capture state they change), SET_CAMERA_MODE and RESET_CAMERA_SETTINGS, and the information
requests (MAV_CMD_REQUEST_MESSAGE and the older MAV_CMD_REQUEST_CAMERA_INFORMATION & co.), whose message
is sent after the COMMAND_ACK. Each gives an `Outcome`; result None for a broadcast that is not ours to
answer. Split from `icgt.mavlink.camera`.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
from collections import deque
from collections.abc import Callable

from icgt.mavlink.camera_clients import ClientTracker, is_unspecified_image_request
from icgt.mavlink.camera_commands import Command, Outcome
from icgt.mavlink.camera_images import ImageHistory, image_range
from icgt.mavlink.camera_status import IMAGE_STATUS_IDLE, CaptureState
from icgt.mavlink.camera_types import CaptureHandler, CommandResult, HandlerResult
from icgt.mavlink.link import mavlink2

__all__ = ["CommandDispatcher", "InformationSenders"]

log = logging.getLogger("icgt.mavlink.camera")  # the camera component's log lines keep its logger's name


@dataclasses.dataclass(frozen=True, slots=True)
class InformationSenders:
    """The component's senders of the messages a command may request."""

    camera_information: Callable[[], None]
    camera_settings: Callable[[], None]
    storage_information: Callable[[], None]
    capture_status: Callable[[], None]


class CommandDispatcher:
    """Executes one command for the component (its handler, capture state, images and senders)."""

    def __init__(
        self,
        handler: CaptureHandler,
        state: CaptureState,
        lock: threading.Lock,
        images: ImageHistory,
        clients: ClientTracker,
        resend: deque[range],
        senders: InformationSenders,
        *,
        component: int,
    ) -> None:
        self.handler = handler
        self._state = state
        self._lock = lock  # the component's: it guards the capture state
        self.images = images
        self.clients = clients
        self._resend = resend  # re-requested images still to send (the component's worker sends them)
        self._senders = senders
        self._component = component

    def dispatch(self, cmd: Command) -> Outcome:
        c = cmd.command
        p = cmd.params
        if c == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(cmd, int(p[0]) if math.isfinite(p[0]) else -1, p[1], p[2])
        legacy = {
            mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION: mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION,
            mavlink2.MAV_CMD_REQUEST_CAMERA_SETTINGS: mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS,
            mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION: mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION,
            mavlink2.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
            mavlink2.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE: mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED,
        }
        if c in legacy:
            # 525 carries the storage id in param1, 2002 the image index in param1
            return self._request_message(cmd, legacy[c], p[0])
        if c == mavlink2.MAV_CMD_IMAGE_START_CAPTURE:
            return self._start_capture(p)
        if c == mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE:
            outcome = self._call("stop", self.handler.stop)
            if outcome.result == CommandResult.ACCEPTED:
                with self._lock:
                    self._state.set_locked(IMAGE_STATUS_IDLE, 0.0)
            return outcome
        if c == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL:
            if p[4] == 1:
                return self._call("shoot", self.handler.shoot)
            return Outcome(int(CommandResult.UNSUPPORTED), reason="DO_DIGICAM_CONTROL without shoot (param5 != 1)")
        if c == mavlink2.MAV_CMD_SET_CAMERA_MODE:
            if p[1] == mavlink2.CAMERA_MODE_IMAGE:
                return Outcome(int(CommandResult.ACCEPTED), reason="image mode (the only mode)")
            return Outcome(int(CommandResult.DENIED), reason="only image mode is supported")
        if c == mavlink2.MAV_CMD_RESET_CAMERA_SETTINGS:
            return Outcome(int(CommandResult.ACCEPTED), reason="no settings to reset")
        if cmd.broadcast:
            return Outcome(None, reason="broadcast command not implemented here")
        return Outcome(int(CommandResult.UNSUPPORTED), reason="command not supported by this camera")

    def _start_capture(self, p: tuple[float, ...]) -> Outcome:
        target_camera, interval, count_f = p[0], p[1], p[2]
        if math.isfinite(target_camera) and int(target_camera) not in (0, 1, self._component):
            return Outcome(int(CommandResult.DENIED), reason=f"param1 names camera {int(target_camera)}, not this one")
        if not math.isfinite(count_f) or count_f < 0 or count_f != int(count_f):
            return Outcome(int(CommandResult.DENIED), reason=f"invalid image count {count_f}")
        count = int(count_f)
        if count == 1:
            return self._call("shoot", self.handler.shoot)
        if not math.isfinite(interval) or interval <= 0:
            return Outcome(int(CommandResult.DENIED), reason=f"invalid interval {interval} s for {count} images")
        outcome = self._call(f"start({interval:g} s, {count})", lambda: self.handler.start(interval, count))
        if outcome.result == CommandResult.ACCEPTED:
            with self._lock:
                self._state.start_interval_locked(interval, count)
        return outcome

    def _call(self, what: str, fn: Callable[[], CommandResult | HandlerResult]) -> Outcome:
        try:
            answer = fn()
        except Exception as exc:
            log.exception("capture handler %s raised", what)
            return Outcome(int(CommandResult.FAILED), reason=f"{what} raised {exc!r}")
        if isinstance(answer, HandlerResult):
            return Outcome(int(answer.result), answer.progress, answer.result_param2, f"{what}: {answer.reason}")
        if isinstance(answer, CommandResult):
            return Outcome(int(answer), reason=what)
        return Outcome(int(CommandResult.FAILED), reason=f"{what} returned {answer!r}")

    def _request_message(self, cmd: Command, msg_id: int, arg: float, last: float = 0.0) -> Outcome:
        send: Callable[[], None]
        if msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self.clients.discovered((cmd.src_system, cmd.src_component), cmd.rx_ns)
            send = self._senders.camera_information
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            send = self._senders.camera_settings
        elif msg_id == mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            storage = int(arg) if math.isfinite(arg) else -1
            if storage not in (0, 1):
                return Outcome(int(CommandResult.DENIED), reason=f"no storage {storage}")
            send = self._senders.storage_information
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            send = self._senders.capture_status
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            spans: list[range] = []
            if cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE and is_unspecified_image_request(arg, last):
                # MAVSDK's form, whatever it misses (icgt.mavlink.camera_clients): what it names, and the rest
                wanted, why = image_range(0.0, 0.0, len(self.images)) if arg == 0 else (range(0), "param2 unset")
                spans = self.clients.take_undelivered((cmd.src_system, cmd.src_component))
                if wanted and not any(wanted.start in r for r in spans):
                    spans.insert(0, wanted)
            else:
                wanted, why = image_range(arg, last, len(self.images))
                spans = [wanted] if wanted else []
            if not spans:
                return Outcome(int(CommandResult.DENIED), reason=why)

            def send() -> None:
                self._resend.extend(spans)
        else:
            if cmd.broadcast:
                return Outcome(None, reason=f"message {msg_id} not provided here")
            return Outcome(int(CommandResult.UNSUPPORTED), reason=f"message {msg_id} not provided")
        return Outcome(int(CommandResult.ACCEPTED), reason=f"message {msg_id}", after=send)
