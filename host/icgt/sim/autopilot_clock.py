"""The simulated autopilot's "now": scenario time (tau) and its boot clock, read from the clock maps.

Every part of the autopilot reads the maps through one `AutopilotClock`, so that when the session
replaces them (releasing a held scenario: `SimAutopilot.clocks`) they all follow at once. Split from
`icgt.sim.autopilot`.
"""

from __future__ import annotations

import math
import time

from icgt.sim.truth import ClockMaps

__all__ = ["AutopilotClock"]


class AutopilotClock:
    """The clock maps in force (``maps``, replaceable) and the autopilot's readings of them now."""

    def __init__(self, maps: ClockMaps) -> None:
        self.maps = maps

    def tau_now(self) -> float:
        return self.maps.host_ns_to_tau(time.monotonic_ns())

    def ap_now_us(self) -> int:
        return math.floor(float(self.maps.tau_to_autopilot_us(self.tau_now())))
