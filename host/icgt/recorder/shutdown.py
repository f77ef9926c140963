"""How a recording ends: the stop sequence, a start abandoned half-way, and a capture stop that cannot be delivered.

`Shutdown.run` is `Recorder.stop()`'s sequence, in an order that loses nothing: the capture is stopped (or,
the device unreachable, the log's last records say what that leaves unknown: `StopNotDeliveredError`), the
last exposures' feedback is waited for, the worker ends and the inbox is drained with every pending frame
emitted; then the links close, and what arrived while they closed is drained and logged too, before the
counters, the summary and the log's end. `Shutdown.abandon` undoes a start that failed after the log was
created: nothing is left on disk.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable
from pathlib import Path

from icgt.errors import IcgtError
from icgt.recorder.capture_control import CaptureControl
from icgt.recorder.config import RecorderConfig
from icgt.recorder.health import Health
from icgt.recorder.links import Links
from icgt.recorder.log_file import RecorderLog
from icgt.recorder.tuning import InterpreterTuning
from icgt.recorder.worker import Worker
from icgt.recorder.worker_wake import WorkerWake

__all__ = ["Shutdown", "StopNotDeliveredError"]

log = logging.getLogger("icgt.recorder")

LAST_FEEDBACK_WAIT_S = 0.3  # the last exposures' feedback and telemetry are still on their way [s]
WORKER_JOIN_TIMEOUT_S = 3.0


class StopNotDeliveredError(IcgtError):
    """The recording ended with capture running on a device the recorder could not reach to stop it."""


class Shutdown:
    """The end of one recording. `stop_control`: closes the control socket; `on_failure`: records what made the
    recording fail (the first failure counts)."""

    def __init__(
        self,
        *,
        config: RecorderConfig,
        links: Links,
        capture: CaptureControl,
        worker: Worker,
        wake: WorkerWake,
        log_file: RecorderLog,
        health: Health,
        tuning: InterpreterTuning,
        stop_control: Callable[[], None],
        on_failure: Callable[[IcgtError], None],
    ) -> None:
        self._config = config
        self._links = links
        self._capture = capture
        self._worker = worker
        self._wake = wake
        self._log = log_file
        self._health = health
        self._tuning = tuning
        self._stop_control = stop_control
        self._on_failure = on_failure

    def run(self) -> None:
        """Stop capture if running, emit every pending frame, close the links and the log."""
        links = self._links
        worker = self._worker
        self._wake.set()
        if links.device is not None:
            # The worker steps no more: the device reader reads the stream again (during the wait below)
            links.device.set_pumped(False)
        if self._capture.capturing and links.device is not None:
            try:
                self._capture.stop()
            except IcgtError as exc:
                self._stop_not_delivered(exc)
        time.sleep(LAST_FEEDBACK_WAIT_S)
        worker.join(WORKER_JOIN_TIMEOUT_S)
        if links.device is not None:
            links.device.time_sync_interval_s = None  # no exchange after the worker's last step
        worker.flush()
        self._stop_control()
        if links.camera is not None:
            links.camera.stop()
        if links.mavlink is not None:
            links.mavlink.stop()
        if links.device is not None:
            links.device.stop()
        worker.flush(counters=True)  # what arrived while the links closed is still logged
        self._health.record_summary()
        self.close_log()
        self._tuning.restore()
        if not worker.alive:
            self._wake.close()

    def abandon(self, path: Path) -> None:
        """A start that failed after the log was created: close everything and remove the file."""
        links = self._links
        if links.mavlink is not None:
            with contextlib.suppress(Exception):
                links.mavlink.stop()
        if links.device is not None:
            with contextlib.suppress(Exception):
                links.device.stop()
        self._stop_control()
        self.close_log()
        self._wake.close()
        with contextlib.suppress(FileNotFoundError):
            path.unlink()

    def close_log(self) -> None:
        failure = self._log.close()
        if failure is not None:
            self._on_failure(failure)

    def _stop_not_delivered(self, exc: IcgtError) -> None:
        """The recording ends with capture running on a device it cannot reach: the log's last records say so
        (event `unreachable_at_end` on /icgt/link_events: the exposures it was known to be taking, interval x
        outage, are unknown, not 0), and the recorder fails with the stop it could not deliver."""
        device = self._links.device
        assert device is not None
        now = time.monotonic_ns()
        down = device.down_since_ns
        outage_ns = 0 if down is None else now - down
        interval = self._capture.interval_s
        taken = int(outage_ns / 1e9 / interval) if interval and outage_ns else 0
        if taken:
            known = f"about {taken} exposures (every {interval:.3f} s for {outage_ns / 1e9:.1f} s)"
        else:
            known = "exposures at an unknown rate"
        timeout_s = self._config.capture.host_timeout_s
        after = (
            f"the device stops the capture by itself {timeout_s:g} s after it last heard from this recorder "
            "([capture] host_timeout_s)"
            if timeout_s
            else "the camera may still be shooting ([capture] host_timeout_s = 0: the device never stops by itself)"
        )
        detail = (
            f"capture stop not delivered ({exc}): the device was unreachable at the end and capturing; {known} "
            f"taken while unreachable are not in this log (unknown, device unreachable at the end); {after}; "
            "icgt recover-device --flight THIS_LOG fetches what its history still holds"
        )
        log.error("%s", detail)
        self._log.link_event("device", "unreachable_at_end", detail, now, taken, outage_ns)
        self._on_failure(
            StopNotDeliveredError(
                f"the capture stop could not be delivered to the device ({exc}): it may still be capturing; "
                f"{known} are not in the log"
            )
        )
