"""The control socket's requests (`icgt status`, `icgt start`, `icgt stop`) answered for one recording.

`ControlRequests.handle` is the `icgt.control.ControlServer`'s handler: status comes from the recorder's
health report; start and stop go to `CaptureControl`, but not while the recorder is still starting (waiting
for, or configuring, the device: a capture started then would make the device refuse its CONFIGURE), for
which they wait up to CONTROL_READY_WAIT_S.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import asdict

from icgt.control import Reply, Request
from icgt.recorder.capture_control import CaptureControl
from icgt.recorder.health import RecorderStatus

__all__ = ["CONTROL_READY_WAIT_S", "ControlRequests"]

CONTROL_READY_WAIT_S = 4.0  # how long a start/stop on the control socket waits for a recorder still starting [s]


class ControlRequests:
    """`starting`: set while the recorder's start() runs; `waiting_for_device`: whether it waits for the device."""

    def __init__(
        self,
        capture: CaptureControl,
        status: Callable[[], RecorderStatus],
        starting: threading.Event,
        waiting_for_device: Callable[[], bool],
    ) -> None:
        self._capture = capture
        self._status = status
        self._starting = starting
        self._waiting_for_device = waiting_for_device

    def handle(self, request: Request) -> Reply:
        command = request.get("command")
        if command == "status":
            return {"ok": True, "status": asdict(self._status())}
        if command in ("start", "stop") and not _wait_clear(self._starting, CONTROL_READY_WAIT_S):
            # The control socket is up while the recorder still waits for, or configures, the device: a capture
            # started then would make the device refuse its CONFIGURE (busy capturing) and fail the start.
            what = "waiting for the device" if self._waiting_for_device() else "connecting and configuring"
            return {"error": f"the recorder is still starting ({what}): {command} not done; try again once "
                    "`icgt status` answers with the recording"}  # fmt: skip
        if command == "start":
            self._capture.start(request.get("interval_s"), request.get("count", 0))
            return {"ok": True}
        if command == "stop":
            self._capture.stop()
            return {"ok": True}
        return {"error": f"unknown command {command!r} (start, stop, status)"}


def _wait_clear(flag: threading.Event, timeout_s: float) -> bool:
    """True once `flag` is clear (within timeout_s)."""
    deadline = time.monotonic() + timeout_s
    while flag.is_set():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True
