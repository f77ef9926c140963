"""What the device link reports and raises: its errors, its events, a TIME_SYNC exchange, its callbacks.

Shared by the transport (`icgt.device.link`, `icgt.device.port`) and the protocol session over it
(`icgt.device.session`); importers take them from `icgt.device`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from icgt.device.limits import describe_refusal
from icgt.errors import ProtocolError
from icgt.protocol import Received

__all__ = [
    "CommandRefusedError",
    "DeviceAbsentError",
    "DeviceBusyError",
    "DeviceLinkError",
    "DeviceLinkEvent",
    "EventCallback",
    "MessageCallback",
    "TimeSyncCallback",
    "TimeSyncSample",
]


class DeviceLinkError(ProtocolError):
    """The device cannot be reached, or did not answer."""


class DeviceAbsentError(DeviceLinkError):
    """The device's port does not exist (yet): not plugged in, or not enumerated."""


class DeviceBusyError(DeviceLinkError):
    """Another program holds the device's port."""


class CommandRefusedError(DeviceLinkError):
    """The device refused a command (NACK) and changed nothing."""

    def __init__(self, command: str, code: int, detail: int) -> None:
        # ACK.detail names the limit broken (protocol Limit); describe_refusal says it in words.
        super().__init__(f"device refused {command}: {describe_refusal(code, detail)}")
        self.command = command
        self.code = code
        self.detail = detail


@dataclass(frozen=True, slots=True)
class TimeSyncSample:
    """One NTP-style exchange: host send/receive [ns, host monotonic], device receive/transmit [us]."""

    host_tx_ns: int
    device_rx_us: int
    device_tx_us: int
    host_rx_ns: int

    @property
    def round_trip_ns(self) -> int:
        return (self.host_rx_ns - self.host_tx_ns) - (self.device_tx_us - self.device_rx_us) * 1000


@dataclass(frozen=True, slots=True)
class DeviceLinkEvent:
    """Something about the link itself, for the log: kind is one of 'connected', 'disconnected',
    'sequence_gap', 'frames_rejected', 'table_hash_mismatch', 'history_lost' (frames the device could no
    longer send: count = exposures + PPS + samples, detail by kind)."""

    kind: str
    host_ns: int
    detail: str
    count: int = 0
    outage_ns: int = 0


MessageCallback = Callable[[Received, int], None]
EventCallback = Callable[[DeviceLinkEvent], None]
TimeSyncCallback = Callable[[TimeSyncSample], None]
