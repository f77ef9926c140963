"""What the links' threads hand to the recorder's worker, in arrival order, and where each kind goes.

The links call these callbacks from whichever thread reads them (the worker's own when it pumps a link, a
link's reader thread otherwise). Each input is appended to one deque (`deque.append` is atomic) tagged by its
kind and its arrival stamp; only the worker empties it (`handle`), giving each input to `DeviceInput` or
`MavlinkInput`, which log it and feed it to the synchroniser in that order: the order the log keeps, and
that the offline recompute replays.

An exposure record read by another thread than the worker's, and MAVLink input handed over by a link's
reader thread, wake the worker (`WorkerWake`): the frame they complete would otherwise wait for its next
timed step.
"""

from __future__ import annotations

import threading
from collections import deque
from typing import Any

from icgt.device import DeviceLinkEvent, TimeSyncSample
from icgt.mavlink.frames import UndecodedBatch
from icgt.mavlink.link import MavlinkEvent, MavlinkMessage
from icgt.protocol import Received as DeviceReceived
from icgt.recorder.device_input import DeviceInput
from icgt.recorder.mavlink_input import MavlinkInput
from icgt.recorder.worker_wake import WorkerWake

__all__ = ["DEVICE", "DEVICE_EVENT", "EXCHANGE", "MAVLINK", "MAVLINK_EVENT", "TIMESYNC_SENT", "Inbox"]

# Inputs from the reader threads to the worker, tagged by kind.
DEVICE, EXCHANGE, DEVICE_EVENT, MAVLINK, MAVLINK_EVENT, TIMESYNC_SENT = range(6)


class Inbox:
    """The links' inputs, filled by any thread and emptied by the worker only."""

    def __init__(self, device_input: DeviceInput, mavlink_input: MavlinkInput, wake: WorkerWake) -> None:
        self._device = device_input
        self._mavlink = mavlink_input
        self._wake = wake
        self.items: deque[tuple[int, Any, int]] = deque()
        self.worker_ident = 0  # the worker thread's ident once it runs

    # ------------------------------------------------------------ the links' callbacks (any thread)
    def device_message(self, received: DeviceReceived, rx_ns: int) -> None:
        """An exposure record that the device reader read (it reads the whole stream while a TIME_SYNC answer
        is awaited) wakes the worker: its frame waits for the worker's next step otherwise, which the worker,
        finding nothing on the port, would not take before the base period."""
        self.items.append((DEVICE, received, rx_ns))
        if received.message.NAME == "EXPOSURE" and threading.get_ident() != self.worker_ident:
            self._wake.set()

    def device_event(self, event: DeviceLinkEvent) -> None:
        self.items.append((DEVICE_EVENT, event, event.host_ns))

    def time_sync(self, sample: TimeSyncSample) -> None:
        self.items.append((EXCHANGE, sample, sample.host_rx_ns))

    def mavlink_message(self, rec: MavlinkMessage | UndecodedBatch) -> None:
        """The worker's thread when it pumps the link, else the link's reader thread, which then wakes a worker
        that watches for the telemetry of an expected frame (`Worker.input_fds`)."""
        self.items.append((MAVLINK, rec, rec.rx_ns))
        self._wake.thread_input()

    def mavlink_event(self, event: MavlinkEvent) -> None:
        self.items.append((MAVLINK_EVENT, event, event.host_ns))

    def timesync_sent(self, tx_ns: int) -> None:
        self.items.append((TIMESYNC_SENT, tx_ns, tx_ns))

    # ------------------------------------------------------------ the worker's side
    def handle(self, limit: int | None) -> None:
        """Up to `limit` inputs (None: all), oldest first, each to its side's input handler."""
        items = self.items
        n = 0
        while items and (limit is None or n < limit):
            self.dispatch(items.popleft())
            n += 1
        if self._mavlink.holds_other_systems:
            self._mavlink.flush_other_systems()

    def dispatch(self, item: tuple[int, Any, int]) -> None:
        kind, payload, rx_ns = item
        if kind == DEVICE:
            self._device.on_message(payload, rx_ns)
        elif kind == MAVLINK:
            self._mavlink.on_message(payload)
        elif kind == EXCHANGE:
            self._device.on_time_sync(payload)
        elif kind == TIMESYNC_SENT:
            self._mavlink.on_timesync_sent(payload)
        elif kind == DEVICE_EVENT:
            self._device.on_link_event(payload)
        elif kind == MAVLINK_EVENT:
            self._mavlink.on_event(payload)
