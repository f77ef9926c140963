"""Autopilot boot clock -> host clock from arrival times alone, for autopilots that never answer TIMESYNC.

A telemetry radio or router that drops TIMESYNC, older firmware, or a replayed log: the autopilot's
messages still carry its boot time (``time_boot_ms``, ``time_usec``) and the host stamps their arrival.
Every arrival is later than the stamp by the link's delay, which is never negative, so the points
(boot time, arrival) lie on or above the true line ``host = offset + boot * rate``; the lower envelope
of many points, where delays were smallest, is that line shifted up by the link's minimum delay. This
is the one-way method of convex-hull time translators: the estimate is the edge of the lower convex
hull under the window's centre (the supporting line that leaves the least total delay above it),
fitted over a sliding window so that the crystal's drift shows in the slope.

What one-way timing cannot see is the minimum delay itself (a UDP link on the same computer: well
under a millisecond; a 57600-baud radio: the serialisation time of the shortest message, several
milliseconds). ``min_delay_allowance_s`` is the bound the caller states for it; ``uncertainty_ns``
is that allowance plus ``time_boot_ms``'s millisecond truncation plus drift past the data. With
TIMESYNC answered, the two-way filter (`AutopilotClockFilter`) is used instead: it measures the delay.

Points are bucketed (the smallest delay per ``bucket_s``), so memory and the fit's cost stay bounded
at any message rate.
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import dataclass

from icgt.clocks.device_clock import ClockNotSyncedError

__all__ = ["OneWayClock", "OneWayFit"]


@dataclass(frozen=True, slots=True)
class OneWayFit:
    ref_boot_us: float
    ref_host_ns: float
    rate: float  # host ns per boot us / 1000 (1.0 = nominal)
    span_s: float
    n: int
    newest_boot_us: float


def _lower_hull(points: list[tuple[float, float]]) -> list[tuple[float, float]]:
    hull: list[tuple[float, float]] = []
    for p in points:
        while len(hull) >= 2:
            (ox, oy), (ax, ay) = hull[-2], hull[-1]
            if (ax - ox) * (p[1] - oy) - (ay - oy) * (p[0] - ox) <= 0:
                hull.pop()
            else:
                break
        hull.append(p)
    return hull


class OneWayClock:
    """Boot time [us] <-> host CLOCK_MONOTONIC [ns] from (stamp, arrival) pairs of the autopilot's messages."""

    def __init__(
        self,
        *,
        window_s: float = 120.0,
        bucket_s: float = 0.5,
        min_span_s: float = 20.0,
        max_drift_ppm: float = 500.0,
        stamp_resolution_us: float = 1000.0,
        min_delay_allowance_s: float = 0.002,
    ) -> None:
        self._window_us = window_s * 1e6
        self._bucket_us = bucket_s * 1e6
        self._min_span_us = min_span_s * 1e6
        self._max_drift = max_drift_ppm * 1e-6
        self._resolution_us = stamp_resolution_us
        self._allowance_ns = min_delay_allowance_s * 1e9
        self._buckets: deque[tuple[float, float]] = deque()  # (boot us, arrival - boot*1000 [ns]) minima
        self._bucket_key: int | None = None
        self._fit: OneWayFit | None = None
        self._dirty = False
        self.points = 0
        self.resets = 0

    def reset(self) -> None:
        """The autopilot rebooted (its boot clock restarted): forget every point."""
        self._buckets.clear()
        self._bucket_key = None
        self._fit = None
        self.resets += 1

    def add(self, boot_us: float, host_rx_ns: int) -> None:
        """One message: its boot stamp [us] (time_boot_ms * 1000 + 500 centres a millisecond stamp) and arrival."""
        excess = host_rx_ns - boot_us * 1000.0
        if self._buckets and boot_us + 2e6 < self._buckets[-1][0]:
            self.reset()  # a stamp seconds behind the newest: the boot clock restarted
        self.points += 1
        key = math.floor(boot_us / self._bucket_us)
        if self._bucket_key == key and self._buckets:
            _, e = self._buckets[-1]
            if excess < e:
                self._buckets[-1] = (boot_us, excess)
                self._dirty = True
        elif self._bucket_key is None or key > self._bucket_key:
            self._bucket_key = key
            self._buckets.append((boot_us, excess))
            while self._buckets and boot_us - self._buckets[0][0] > self._window_us:
                self._buckets.popleft()
            self._dirty = True
        # a late, out-of-order stamp in an older bucket carries nothing the envelope needs

    @property
    def synced(self) -> bool:
        return bool(self._buckets)

    def fit(self) -> OneWayFit:
        if not self._buckets:
            raise ClockNotSyncedError("no autopilot message with a boot time yet")
        if self._fit is None or self._dirty:
            self._fit = self._compute()
            self._dirty = False
        return self._fit

    def _compute(self) -> OneWayFit:
        pts = list(self._buckets)
        newest = pts[-1][0]
        span = pts[-1][0] - pts[0][0]
        if len(pts) < 3 or span < self._min_span_us:
            b, e = min(pts, key=lambda p: p[1])
            return OneWayFit(b, b * 1000.0 + e, 1.0, span / 1e6, len(pts), newest)
        hull = _lower_hull(pts)
        centre = sum(p[0] for p in pts) / len(pts)
        edge = (hull[0], hull[-1])
        for a, c in itertools.pairwise(hull):
            if a[0] <= centre <= c[0]:
                edge = (a, c)
                break
        (xa, ya), (xc, yc) = edge
        slope = (yc - ya) / (xc - xa) if xc > xa else 0.0  # excess ns per boot us
        slope = max(-self._max_drift * 1000.0, min(self._max_drift * 1000.0, slope))
        ref_boot = xa
        return OneWayFit(ref_boot, ref_boot * 1000.0 + ya, 1.0 + slope / 1000.0, span / 1e6, len(pts), newest)

    def autopilot_to_host_ns(self, boot_us: float) -> int:
        f = self.fit()
        return round(f.ref_host_ns + (boot_us - f.ref_boot_us) * 1000.0 * f.rate)

    def host_to_autopilot_us(self, host_ns: int) -> float:
        f = self.fit()
        return f.ref_boot_us + (host_ns - f.ref_host_ns) / (1000.0 * f.rate)

    def uncertainty_ns(self, boot_us: float) -> int:
        """Bound [ns]: the stated minimum-delay allowance, the stamp resolution, drift beyond the data."""
        f = self.fit()
        beyond_us = abs(boot_us - f.newest_boot_us)
        drift_ns = (self._max_drift if f.span_s * 1e6 < self._min_span_us else 20e-6) * beyond_us * 1000.0
        return int(self._allowance_ns + self._resolution_us * 1000.0 + drift_ns)
