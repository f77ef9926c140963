"""The geotagger's views of the clock filters, shared by the live recorder and the offline recompute."""

from __future__ import annotations

from icgt.clocks.autopilot_clock import UtcMapper
from icgt.clocks.autopilot_time import AutopilotTimeMap
from icgt.clocks.device_clock import ClockNotSyncedError, DeviceClockFilter, PpsUtcMapper


class AutopilotClockView:
    """Host -> autopilot boot time, or None before any mapping exists (instead of an exception)."""

    def __init__(self, f: AutopilotTimeMap) -> None:
        self._f = f

    def host_to_autopilot_us(self, host_ns: int) -> float | None:
        if not self._f.synced:
            return None
        try:
            return self._f.host_to_autopilot_us(host_ns)
        except ClockNotSyncedError:
            return None

    def method(self) -> str:
        """Which mapping answers now: timesync, arrival or none."""
        return self._f.method().value

    def uncertainty_us(self, boot_us: float) -> float | None:
        try:
            return self._f.uncertainty_ns(boot_us) / 1000.0
        except ClockNotSyncedError:
            return None


class UtcView:
    """UTC of a device instant: PPS if locked, else via the autopilot's GPS time, else the host clock."""

    def __init__(self, pps: PpsUtcMapper, utc: UtcMapper) -> None:
        self._pps = pps
        self._utc = utc

    def utc_at(self, device_us: float, host_ns: int) -> tuple[int, float, str] | None:
        if self._pps.locked(device_us) and self._pps.labelled:
            return int(self._pps.device_to_utc_us(device_us)), self._pps.uncertainty_us(device_us), "pps"
        est = self._utc.host_to_utc(host_ns)
        if not est.valid:
            return None
        return int(est.utc_us), est.uncertainty_us, est.source.value


def add_pps_edge(pps: PpsUtcMapper, utc: UtcMapper, device_clock: DeviceClockFilter, t_us: int, count: int) -> None:
    """Feed one PPS edge, labelled with the coarse UTC of its second when the device clock is mapped."""
    coarse = None
    if device_clock.settled:
        est = utc.host_to_utc(device_clock.device_to_host_ns(t_us))
        coarse = est.utc_us if est.valid else None
    pps.add_pps(t_us, count, coarse)
