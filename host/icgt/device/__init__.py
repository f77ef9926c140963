"""The host's side of the device link: serial connection, handshake, commands, time sync."""

from icgt.device.link import (
    CommandRefusedError,
    DeviceAbsentError,
    DeviceBusyError,
    DeviceLink,
    DeviceLinkError,
    DeviceLinkEvent,
    TimeSyncSample,
)

__all__ = [
    "CommandRefusedError",
    "DeviceAbsentError",
    "DeviceBusyError",
    "DeviceLink",
    "DeviceLinkError",
    "DeviceLinkEvent",
    "TimeSyncSample",
]
