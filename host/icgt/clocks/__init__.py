"""Clock mapping (pure computation, no I/O): device clock and autopilot boot clock -> host monotonic clock -> UTC.

- ``DeviceClockFilter``: Teensy microsecond clock [us] -> host ``time.monotonic_ns()`` [ns] from
  TIME_SYNC / TIME_SYNC_REPLY exchanges.
- ``PpsUtcMapper``: device clock [us] -> UTC [us] from GPS PPS edges.
- ``AutopilotClockFilter``: autopilot boot clock [us] -> host [ns] from MAVLink TIMESYNC.
- ``UtcMapper``: host [ns] -> UTC [us] from SYSTEM_TIME / GPS time via the autopilot, else the
  host's CLOCK_REALTIME (flagged as a fallback).

Every estimate has ``to_dict()`` for the log, so frames can be re-timed offline by feeding the
logged exchanges to a fresh filter.
"""

from icgt.clocks.autopilot_clock import AutopilotClockFilter, UtcEstimate, UtcMapper, UtcSource, gps_to_utc_us
from icgt.clocks.device_clock import (
    ClockError,
    ClockEstimate,
    ClockNotSyncedError,
    DeviceClockFilter,
    ExchangeStatus,
    PpsEstimate,
    PpsStatus,
    PpsUtcMapper,
    ResetReason,
)

__all__ = [
    "AutopilotClockFilter",
    "ClockError",
    "ClockEstimate",
    "ClockNotSyncedError",
    "DeviceClockFilter",
    "ExchangeStatus",
    "PpsEstimate",
    "PpsStatus",
    "PpsUtcMapper",
    "ResetReason",
    "UtcEstimate",
    "UtcMapper",
    "UtcSource",
    "gps_to_utc_us",
]
