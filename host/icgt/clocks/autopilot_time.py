"""Autopilot boot time <-> host time by the best method available: TIMESYNC round trips, else arrival times.

`AutopilotTimeMap` is what the geotagger and the UTC mapper ask. It answers from the two-way TIMESYNC
filter once that has a reply in its window (the delay is measured: sub-millisecond on a companion
link), and otherwise from the one-way arrival-time envelope (`OneWayClock`: no answer needed, the
link's minimum delay is an allowance). `method()` says which one a given answer came from; frames
record it.
"""

from __future__ import annotations

import enum

from icgt.clocks.autopilot_clock import AutopilotClockFilter
from icgt.clocks.device_clock import ClockNotSyncedError
from icgt.clocks.one_way import OneWayClock

__all__ = ["AutopilotClockMethod", "AutopilotTimeMap"]


class AutopilotClockMethod(enum.StrEnum):
    TIMESYNC = "timesync"  # two-way MAVLink TIMESYNC
    ARRIVAL = "arrival"  # one-way: lower envelope of message arrival times
    NONE = "none"


class AutopilotTimeMap:
    """The autopilot clock mapping with a TIMESYNC filter first and a one-way fallback."""

    def __init__(self, timesync: AutopilotClockFilter, one_way: OneWayClock) -> None:
        self.timesync = timesync
        self.one_way = one_way

    def method(self) -> AutopilotClockMethod:
        if self.timesync.synced:
            return AutopilotClockMethod.TIMESYNC
        if self.one_way.synced:
            return AutopilotClockMethod.ARRIVAL
        return AutopilotClockMethod.NONE

    @property
    def resets(self) -> int:
        """Changes whenever either mapping restarts (the UTC fit must then restart too)."""
        return self.timesync.resets + self.one_way.resets

    @property
    def synced(self) -> bool:
        return self.timesync.synced or self.one_way.synced

    def host_to_autopilot_us(self, host_ns: int) -> float:
        if self.timesync.synced:
            return self.timesync.host_to_autopilot_us(host_ns)
        if self.one_way.synced:
            return self.one_way.host_to_autopilot_us(host_ns)
        raise ClockNotSyncedError("no autopilot clock mapping yet (no TIMESYNC reply, no stamped message)")

    def autopilot_to_host_ns(self, boot_us: float) -> int:
        if self.timesync.synced:
            return self.timesync.autopilot_to_host_ns(boot_us)
        return self.one_way.autopilot_to_host_ns(boot_us)

    def uncertainty_ns(self, boot_us: float) -> int:
        if self.timesync.synced:
            return self.timesync.uncertainty_ns(boot_us)
        return self.one_way.uncertainty_ns(boot_us)
