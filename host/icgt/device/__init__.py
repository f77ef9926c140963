"""The host's side of the device link: the transport (`link`, `port`), the protocol session over it (`session`), the
device's limits (`limits`) and the recovery of what it missed (`resend`, `history`)."""

from icgt.device.link import DeviceLink
from icgt.device.link_types import (
    CommandRefusedError,
    DeviceAbsentError,
    DeviceBusyError,
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
