"""The capture a recording runs: the commands that start and stop it, and what the recorder knows of it.

`CaptureControl` is the one owner of the capture state: whether the device is capturing, at what interval,
with which sensors (what CONFIGURE left in force) and trigger settings (a ground station may change them, from
the next start). It changes only through its methods:
- `start` / `stop`: `icgt start` / `icgt stop` on the control socket, or the camera component's commands
  through `CaptureHandler` (MAV_CMD_IMAGE_START_CAPTURE and the rest), which also turns a refusal into the
  answer the ground station gets;
- `adopt`: a capture that was already running when the recorder started, taken over (`icgt.recorder.resync`);
- `device_stopped_itself`: `DeviceInput` saw the device stop this recording's capture by itself (its host went
  silent), so nothing is left to stop.
Each change is passed on to the camera component (what it tells the ground station), and a capture started
gives the worker its cadence (`cadence_hint`), so that its step schedule expects the frames.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import msgspec

from icgt.device import CommandRefusedError, DeviceLinkError
from icgt.device.limits import BoardLimits, LimitError, for_board
from icgt.mavlink.camera import CommandResult, HandlerResult
from icgt.protocol.messages import Hello, StopCapture
from icgt.recorder import capture
from icgt.recorder.config import CaptureSection, RecorderConfig
from icgt.recorder.links import Links

__all__ = ["CaptureControl", "CaptureHandler"]

log = logging.getLogger("icgt.recorder")


class CaptureControl:
    """The recording's capture: its commands and its state. `wake`: nudges the worker (a capture started)."""

    def __init__(self, config: RecorderConfig, links: Links, wake: Callable[[], None]) -> None:
        self._config = config
        self._links = links
        self._wake = wake
        self.hello: Hello | None = None  # the device's, once it answered (its board's limits)
        self.capturing = False
        self.interval_s: float | None = None  # of the capture running (what an outage took)
        self.cadence_hint = (0, 0)  # (captures started, the last one's interval [ns]), for the worker
        self.sensors = config.sensors  # what the device was configured with (a sensor that does not answer: off)
        self.settings = config.capture  # the trigger settings in force (a ground station may change them)

    def limits(self) -> BoardLimits:
        return for_board(self.hello.board if self.hello is not None else None)

    def configured(self) -> RecorderConfig:
        """The configuration with the sensors the device was configured with."""
        return msgspec.structs.replace(self._config, sensors=self.sensors)

    def set_settings(self, section: CaptureSection) -> None:
        """A ground station's capture settings (icgt.recorder.camera_settings): from the next capture start."""
        self.settings = section

    def start(self, interval_s: float | None = None, count: int = 0) -> None:
        """Start triggering: `count` 0 runs until stopped, 1 is a single shot, N stops after N.

        Raises CaptureRequestError (naming the limit) for a value the device would refuse, before
        anything is sent."""
        device = self._links.device
        assert device is not None
        c = self.settings
        interval_s, count = capture.check_capture_request(interval_s, count, c.shutter_pulse_s)
        config = msgspec.structs.replace(self._config, sensors=self.sensors, capture=c)
        cmd, mode = capture.start_command(config, interval_s, count, self.limits())  # LimitError: nothing sent
        interval_us = cmd.interval_us
        device.command(cmd)
        self.capturing = count != 1
        self.interval_s = interval_us / 1e6
        if self.capturing:  # the worker gives it to its step schedule (which is its own)
            self.cadence_hint = (self.cadence_hint[0] + 1, interval_us * 1000)
            self._wake()  # its first exposure is a shutter lag away: the worker's eager steps start now
        self._tell_camera(interval_us / 1e6)
        log.info("capture started: %s, interval %.3f s, count %d", mode.name.lower(), interval_us / 1e6, count)

    def stop(self) -> None:
        device = self._links.device
        assert device is not None
        device.command(StopCapture())
        self.capturing = False
        self._tell_camera()
        log.info("capture stopped")

    def adopt(self, interval_s: float) -> None:
        """A capture already running on the device when the recorder started, taken over as this one's."""
        self.capturing = True
        self.interval_s = interval_s
        self._tell_camera(interval_s)

    def device_stopped_itself(self) -> None:
        """The device stopped this recording's capture by itself (its host went silent): nothing left to stop."""
        self.capturing = False
        self._tell_camera()

    def _tell_camera(self, interval_s: float = 0.0) -> None:
        if self._links.camera is not None:
            self._links.camera.set_capturing(self.capturing, interval_s)

    def handler_result(self, action: Callable[[], Any]) -> CommandResult | HandlerResult:
        """A ground station's command done: its COMMAND_ACK result (a broken limit also said as STATUSTEXT)."""
        try:
            action()
        except LimitError as exc:  # CaptureRequestError too
            log.warning("%s", exc)
            if self._links.mavlink is not None:
                capture.announce(self._links.mavlink, exc)
            return capture.denied(exc)
        except CommandRefusedError as exc:
            log.warning("%s", exc)
            return CommandResult.DENIED
        except DeviceLinkError as exc:
            log.error("%s", exc)
            return CommandResult.FAILED
        return CommandResult.ACCEPTED


class CaptureHandler:
    """The camera component's CaptureHandler: ground-station commands become device commands."""

    def __init__(self, control: CaptureControl) -> None:
        self._c = control

    def start(self, interval_s: float, count: int) -> CommandResult | HandlerResult:
        # MAV_CMD_IMAGE_START_CAPTURE: interval 0 asks for the camera's own (the configured one).
        interval = None if interval_s == 0 else interval_s
        return self._c.handler_result(lambda: self._c.start(interval, count))

    def stop(self) -> CommandResult | HandlerResult:
        return self._c.handler_result(self._c.stop)

    def shoot(self) -> CommandResult | HandlerResult:
        return self._c.handler_result(lambda: self._c.start(None, 1))
