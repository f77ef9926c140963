"""How far back the device can resend: its history rings, in time, at the rates it runs.

The host's mirror of the ring sizes in ``firmware/lib/core/history.hpp`` (tests/device/test_history_horizon.py
reads that header and fails when a number here differs). The device keeps one event slot per EXPOSURE or
PPS edge and the kind of each of its last `KIND_ENTRIES` frames; RESEND brings back an exposure only while
both still hold it. So an exposure can come back at most `history_horizon_s` after it was made, and the
host keeps the autopilot's telemetry at least that long (`icgt.sync.synchroniser`), so that a frame that
comes back that late is posed from the telemetry that arrived on time.

The figures are the Teensy 4.1's, the larger board (a Teensy 3.6 keeps less): a host that keeps
telemetry for the 4.1's horizon keeps it for either board.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = [
    "EVENT_SLOTS",
    "KIND_ENTRIES",
    "NOMINAL_RATES",
    "OTHER_FRAMES_HZ",
    "RESEND_MARGIN_S",
    "DeviceRates",
    "history_horizon_s",
    "telemetry_retention_s",
]

EVENT_SLOTS = 4096  # kTeensy41History.event_slots: EXPOSURE and PPS frames kept
KIND_ENTRIES = 1 << 18  # kTeensy41History.kind_entries: sequence numbers whose kind the device knows
PPS_HZ = 1.0  # one PPS edge a second (a board without PPS keeps more exposures: the bound is safe)
# Frames the device sends besides events and samples (STATUS, TIME_SYNC_REPLY, ACK, LOG): at most this many
# a second in the kind ring. TIME_SYNC at up to 10 Hz while fitting, STATUS at 1 Hz, the rest rare.
OTHER_FRAMES_HZ = 12.0
# Kept beyond the horizon: the time a reconnect and its RESEND take, and the frame's own wait for its later
# pose sample, so that the oldest exposure the device still holds is not the one whose telemetry just went.
RESEND_MARGIN_S = 60.0


@dataclass(frozen=True)
class DeviceRates:
    """The rates the device runs at (DEVICE_STATE reports them): exposures [1/s], IMU and range [Hz]."""

    exposure_hz: float
    imu_hz: float
    range_hz: float


NOMINAL_RATES = DeviceRates(exposure_hz=5.0, imu_hz=100.0, range_hz=100.0)
"""5 fps with the sensors' default rates: the rates the default retention is sized for."""


def history_horizon_s(rates: DeviceRates) -> float:
    """How long [s] after an exposure the device can still resend it: the shorter of the event ring's reach
    (one slot per exposure and PPS edge) and the kind ring's (one entry per frame of any kind)."""
    events_hz = max(rates.exposure_hz, 0.0) + PPS_HZ
    frames_hz = events_hz + max(rates.imu_hz, 0.0) + max(rates.range_hz, 0.0) + OTHER_FRAMES_HZ
    return min(EVENT_SLOTS / events_hz, KIND_ENTRIES / frames_hz)


def telemetry_retention_s(rates: DeviceRates) -> float:
    """How long [s] the host keeps autopilot telemetry for a device at ``rates``: its horizon plus the margin."""
    return history_horizon_s(rates) + RESEND_MARGIN_S
