"""The device side of a recording: what the device link hands over, logged and fed to the synchroniser in order.

`DeviceInput` takes each input of the device link from the worker's inbox (`icgt.recorder.inbox`): a device
message goes to its topic and to the synchroniser (an exposure is counted, the device's log lines go to the
host's log and the live view, a DEVICE_STATE saying the device stopped capturing by itself is said once); a
TIME_SYNC exchange is fed to the clock filter and written with its verdict; the link's own events go on
/icgt/link_events.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from icgt.device import DeviceLinkEvent, TimeSyncSample
from icgt.protocol import Received as DeviceReceived
from icgt.protocol.messages import DeviceState, FrameFlags, Log, LogLevel
from icgt.recorder import topics
from icgt.recorder.device_stop import SelfStopWatch
from icgt.recorder.log_file import RecorderLog
from icgt.recording import layout
from icgt.recording.views import FoxgloveViews
from icgt.sync import Synchroniser

__all__ = ["DeviceInput"]

log = logging.getLogger("icgt.recorder")

_RETRANSMIT = int(FrameFlags.RETRANSMIT)
_DEVICE_LOG_LEVELS: dict[int, int] = {
    LogLevel.DEBUG: logging.DEBUG,
    LogLevel.INFO: logging.INFO,
    LogLevel.WARNING: logging.WARNING,
    LogLevel.ERROR: logging.ERROR,
    LogLevel.FATAL: logging.CRITICAL,
}


class DeviceInput:
    """Every device input of one recording, on the worker's thread. ``on_self_stop``: called when the device
    says it stopped this recording's capture by itself (its host went silent): nothing is left to stop."""

    def __init__(
        self, sync: Synchroniser, log_file: RecorderLog, views: FoxgloveViews, on_self_stop: Callable[[], None]
    ) -> None:
        self._sync = sync
        self._log = log_file
        self._views = views
        self._on_self_stop = on_self_stop
        self._self_stops = SelfStopWatch()
        self.exposures = 0

    def on_message(self, received: DeviceReceived, host_rx_ns: int) -> None:
        msg = received.message
        if self._log.mcap is not None:
            data = topics.device_payload_json(msg, received.seq, received.flags, host_rx_ns)
            self._log.write_encoded(topics.device_topic(msg.NAME), data, host_rx_ns)
        self._sync.on_device(msg, host_rx_ns, retransmitted=bool(received.flags & _RETRANSMIT))
        if msg.NAME == "EXPOSURE":
            self.exposures += 1
        elif isinstance(msg, DeviceState):
            self._on_state(msg, host_rx_ns)
        elif isinstance(msg, Log):
            self._views.on_device_log(msg.level, msg.text, host_rx_ns)
            log.log(_DEVICE_LOG_LEVELS.get(msg.level, logging.INFO), "device: %s", msg.text)

    def _on_state(self, state: DeviceState, host_rx_ns: int) -> None:
        """A DEVICE_STATE saying the device stopped a capture by itself (its host went silent): said once."""
        news = self._self_stops.observe(state)
        if news is None:
            return
        stop, before = news
        if before:  # a capture of an earlier flight, before this recorder started
            log.warning(
                "%s, before this recording (the last host's log: recording id 0x%08X); what that flight's "
                "outage left in the device's history: icgt recover-device --flight LOG",
                stop.detail,
                stop.recording_id,
            )
            return
        self._on_self_stop()
        log.warning("%s", stop.detail)
        self._log.link_event("device", "device_stopped_itself", stop.detail, host_rx_ns, stop.triggers_fired)

    def on_link_event(self, event: DeviceLinkEvent) -> None:
        level = logging.INFO if event.kind == "connected" else logging.WARNING
        log.log(level, "device link: %s", event.detail)
        self._log.link_event("device", event.kind, event.detail, event.host_ns, event.count, event.outage_ns)

    def on_time_sync(self, sample: TimeSyncSample) -> None:
        status = self._sync.on_exchange(sample.host_tx_ns, sample.device_rx_us, sample.device_tx_us, sample.host_rx_ns)
        # Written after it was fed only because the status is part of the record; the recompute refits
        # from these records in file order, which is the order they were fed.
        self._log.write(
            layout.CLOCK_DEVICE_EXCHANGES,
            {
                "host_tx_ns": sample.host_tx_ns,
                "device_rx_us": sample.device_rx_us,
                "device_tx_us": sample.device_tx_us,
                "host_rx_ns": sample.host_rx_ns,
                "status": status.value,
            },
            sample.host_rx_ns,
        )
