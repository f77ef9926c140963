"""Which MAVLink messages come from the autopilot, and when it (re)appeared: the rules, in one place.

Used by the live link (to schedule stream-rate requests) and by the synchroniser (to decide which
TIMESYNC replies and telemetry it takes), so the recorder and the offline recompute apply the same
rules to the same messages. Pure functions and a small state machine over (message, arrival time):
no I/O, no threads.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = [
    "BOOT_CLOCK_TYPES",
    "REBOOT_BACKSTEP_MS",
    "AutopilotPresence",
    "Freshness",
    "is_autopilot_heartbeat",
]

REBOOT_BACKSTEP_MS = 2000  # a boot stamp going back more than this means the autopilot rebooted
BOOT_CLOCK_TYPES = frozenset(
    {"SYSTEM_TIME", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"}
)
_NOT_AUTOPILOT_TYPES = frozenset(
    {
        mavlink2.MAV_TYPE_GCS,
        mavlink2.MAV_TYPE_CAMERA,
        mavlink2.MAV_TYPE_GIMBAL,
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
    }
)


def is_autopilot_heartbeat(msg: Any) -> bool:
    """A HEARTBEAT from a flight controller (not a GCS, camera, gimbal or companion computer)."""
    return int(msg.autopilot) != mavlink2.MAV_AUTOPILOT_INVALID and int(msg.type) not in _NOT_AUTOPILOT_TYPES


class Freshness(enum.Enum):
    """What one autopilot message says about the autopilot's presence."""

    SAME = "same"  # nothing new
    SEEN = "autopilot_seen"  # the first message ever
    BACK = "autopilot_back"  # the first after a silence longer than the timeout
    REBOOTED = "autopilot_rebooted"  # its boot clock went back


@dataclass
class AutopilotPresence:
    """Tracks one autopilot (system id given, component learnt from its first HEARTBEAT) over its messages.

    `observe` returns None for messages from anyone else, else how the message changes what is known
    (first seen, back after ``timeout_ns`` of silence, rebooted). ``component`` None means: learn it.
    """

    system: int
    component: int | None = None
    timeout_ns: int = 3_000_000_000
    last_rx_ns: int | None = None
    last_boot_ms: int | None = None
    detail: str = ""

    def observe(self, msg: Any, mtype: str, rx_ns: int) -> Freshness | None:
        if int(msg.get_srcSystem()) != self.system:
            return None
        comp = int(msg.get_srcComponent())
        if self.component is None:
            if mtype != "HEARTBEAT" or not is_autopilot_heartbeat(msg):
                return None
            self.component = comp
        if comp != self.component:
            return None
        fresh = Freshness.SAME
        if self.last_rx_ns is None:
            fresh, self.detail = Freshness.SEEN, f"first {mtype}"
        elif rx_ns - self.last_rx_ns > self.timeout_ns:
            fresh, self.detail = Freshness.BACK, f"back after {(rx_ns - self.last_rx_ns) / 1e9:.3f} s"
        self.last_rx_ns = rx_ns
        boot_ms = getattr(msg, "time_boot_ms", None) if mtype in BOOT_CLOCK_TYPES else None
        if isinstance(boot_ms, int):
            last, self.last_boot_ms = self.last_boot_ms, boot_ms
            if last is not None and boot_ms + REBOOT_BACKSTEP_MS < last:
                fresh, self.detail = Freshness.REBOOTED, f"{mtype}.time_boot_ms went from {last} to {boot_ms}"
        return fresh
