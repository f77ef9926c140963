"""The device's part of a recording's start: connect (waiting for it to appear), configure, describe.

`DeviceConnector.connect` opens the device link and completes the handshake, trying again for up to
[device] wait_s while the port does not exist (`waiting` says so meanwhile, for `icgt status`).
`configure_device` sends CONFIGURE, going on without a sensor that does not answer (said loudly) and refusing
to start otherwise, and sets the device's clock when asked to. `record_hello` stores what the device said of
itself in the log's metadata.
"""

from __future__ import annotations

import logging
import threading
import time

from icgt.device import CommandRefusedError, DeviceAbsentError, DeviceLink
from icgt.device.limits import BoardLimits
from icgt.protocol.messages import Hello, SetTime
from icgt.recorder import capture
from icgt.recorder.config import RecorderConfig, SensorsSection
from icgt.recorder.inbox import Inbox
from icgt.recorder.links import Links
from icgt.recorder.log_file import board_name, device_metadata
from icgt.recording import McapRecorder

__all__ = ["READ_BATCH_S", "DeviceConnector", "configure_device", "record_hello"]

log = logging.getLogger("icgt.recorder")

# The device reader sleeps this long between reads [s] when no stamp depends on it (DeviceLink batch_s: not
# while a reply is awaited) until the worker pumps the link, and again after: one wake-up per pause, not per USB
# frame. (A UDP MAVLink link is read by the worker; a serial or TCP one's reader reads each chunk as it comes.)
READ_BATCH_S = 0.02


class DeviceConnector:
    """Opens the recording's device link (into `links.device`), its input going to `inbox`."""

    def __init__(self, config: RecorderConfig, links: Links, inbox: Inbox, stopping: threading.Event) -> None:
        self._config = config.device
        self._links = links
        self._inbox = inbox
        self._stopping = stopping
        self.waiting = False  # started, the device not there yet ([device] wait_s)

    def connect(self) -> Hello:
        """Open the device and complete the handshake, waiting up to [device] wait_s for it to appear."""
        cfg = self._config
        inbox = self._inbox
        deadline = time.monotonic() + cfg.wait_s
        next_note = 0.0
        while True:
            self._links.device = device = DeviceLink(
                cfg.url,
                on_message=inbox.device_message,
                on_event=inbox.device_event,
                on_time_sync=inbox.time_sync,
                batch_s=READ_BATCH_S,
            )
            try:
                return device.start()
            except DeviceAbsentError as exc:
                now = time.monotonic()
                if now >= deadline or self._stopping.is_set():
                    raise DeviceAbsentError(f"{exc} (waited {cfg.wait_s:g} s: [device] wait_s)") from None
                if now >= next_note:
                    log.warning("waiting for the device: %s", exc)
                    next_note = now + 10.0
                self.waiting = True
                self._stopping.wait(0.5)
            finally:
                self.waiting = False


def configure_device(device: DeviceLink, config: RecorderConfig, limits: BoardLimits) -> SensorsSection:
    """CONFIGURE sent; returns the sensors the device was configured with (without one that does not answer)."""
    sensors = config.sensors
    for _ in range(3):  # at most: without the IMU, then without the LiDAR
        try:
            device.command(capture.configure_command(sensors, limits))
            break
        except CommandRefusedError as exc:
            # Never record with the device's old settings: go on only without a sensor that does not
            # answer (said loudly), refuse to start otherwise.
            sensors = capture.configure_refused(sensors, exc.code, exc.detail, str(exc))
            log.warning("%s: recording without it", exc)
    if config.device.set_rtc:
        try:
            device.command(SetTime(utc_us=time.time_ns() // 1000))
            log.info("device RTC set from the host clock")
        except CommandRefusedError as exc:
            log.warning("device RTC not set: %s", exc)
    return sensors


def record_hello(mcap: McapRecorder, hello: Hello, config: RecorderConfig) -> None:
    """The device's HELLO (board, firmware, serial number) in the log's metadata, and said."""
    for name, values in device_metadata(hello, config.device.url, config.camera).items():
        mcap.add_metadata(name, values)
    log.info(
        "device: %s on %s, firmware %s, serial %s",
        board_name(hello.board),
        config.device.url,
        hello.firmware_version,
        hello.serial_number,
    )
