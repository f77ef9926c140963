"""The device's history horizon as the host computes it (`icgt.device.history`), against the firmware's rings.

The ring sizes are read from firmware/lib/core/history.hpp, so a firmware that keeps less (or more) fails
here until the host's mirror follows it."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from icgt.device.history import (
    EVENT_SLOTS,
    KIND_ENTRIES,
    NOMINAL_RATES,
    RESEND_MARGIN_S,
    DeviceRates,
    history_horizon_s,
    telemetry_retention_s,
)

HEADER = Path(__file__).resolve().parents[2] / "firmware" / "lib" / "core" / "history.hpp"


def _teensy41_sizes() -> tuple[int, int]:
    text = HEADER.read_text()
    m = re.search(r"kTeensy41History\{(\d+), (\d+), (\d+), std::size_t\{1\} << (\d+)\}", text)
    assert m is not None, "kTeensy41History not found in history.hpp"
    return int(m.group(1)), 1 << int(m.group(4))


def test_the_ring_sizes_are_the_firmwares() -> None:
    assert _teensy41_sizes() == (EVENT_SLOTS, KIND_ENTRIES)


def test_at_5_fps_the_event_ring_decides_11_minutes() -> None:
    # 4096 slots at 5 exposures + 1 PPS a second; the kind ring (2^18 frames at ~218/s) reaches 20 min
    assert history_horizon_s(NOMINAL_RATES) == pytest.approx(4096 / 6)
    assert telemetry_retention_s(NOMINAL_RATES) == pytest.approx(4096 / 6 + RESEND_MARGIN_S)


def test_at_a_slow_capture_with_fast_sensors_the_kind_ring_decides() -> None:
    rates = DeviceRates(exposure_hz=0.5, imu_hz=100.0, range_hz=500.0)
    assert history_horizon_s(rates) == pytest.approx(KIND_ENTRIES / (1.5 + 600.0 + 12.0))
    assert history_horizon_s(rates) < EVENT_SLOTS / 1.5
