"""The height of home above mean sea level, from the autopilot's GLOBAL_POSITION_INT.

GLOBAL_POSITION_INT carries both ``alt`` (above MSL) and ``relative_alt`` (above home); their difference
is home's altitude. A camera position's height above home is its MSL altitude minus home's altitude at
that instant, interpolated between the samples around it: the same as interpolating ``relative_alt`` to
the instant, but it applies to the camera (lever arm included) rather than to the vehicle's reference
point. Samples without a position (lat = lon = 0: no fix yet) are ignored. A home reset (a new home set
in flight) moves the difference; the samples around an exposure say which home applied then.
"""

from __future__ import annotations

import bisect
from collections import deque
from typing import Any

__all__ = ["HomeAltitude"]


class HomeAltitude:
    """Home's MSL altitude over host time, from GLOBAL_POSITION_INT. Not thread-safe (one feeder)."""

    def __init__(self, keep_s: float = 30.0) -> None:
        self._keep_ns = int(keep_s * 1e9)
        self._t: deque[int] = deque()
        self._home_m: deque[float] = deque()

    def on_global_position(self, msg: Any, host_ns: int) -> None:
        if int(msg.lat) == 0 and int(msg.lon) == 0:
            return
        if self._t and host_ns < self._t[-1]:
            return  # out of order: the series stays sorted
        self._t.append(host_ns)
        self._home_m.append((int(msg.alt) - int(msg.relative_alt)) / 1000.0)
        while self._t and self._t[0] < host_ns - self._keep_ns:
            self._t.popleft()
            self._home_m.popleft()

    def home_alt_msl_m(self, host_ns: int) -> float | None:
        """Home's MSL altitude at ``host_ns`` (interpolated; the nearest end outside the samples), None if none."""
        if not self._t:
            return None
        i = bisect.bisect_left(self._t, host_ns)
        if i == 0:
            return self._home_m[0]
        if i >= len(self._t):
            return self._home_m[-1]
        t0, t1 = self._t[i - 1], self._t[i]
        h0, h1 = self._home_m[i - 1], self._home_m[i]
        if t1 == t0:
            return h1
        return h0 + (h1 - h0) * (host_ns - t0) / (t1 - t0)

    def relative_alt_m(self, alt_msl_m: float | None, host_ns: int) -> float | None:
        """Height above home of a position at ``alt_msl_m`` at ``host_ns``; None if either is unknown."""
        home = self.home_alt_msl_m(host_ns)
        if alt_msl_m is None or home is None:
            return None
        return alt_msl_m - home
