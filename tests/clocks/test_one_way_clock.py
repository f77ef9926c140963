"""The one-way autopilot clock: boot time -> host time from arrival times alone (no TIMESYNC answers).

Sequences shaped like real links: ArduPilot's millisecond stamps, a companion UART/UDP path with a floor
of about 0.3 ms and exponential queueing delays on top, a crystal 40 ppm off, bursts delayed by tens of
milliseconds; and an autopilot reboot.
"""

from __future__ import annotations

import numpy as np
import pytest

from icgt.clocks.autopilot_clock import AutopilotClockFilter
from icgt.clocks.autopilot_time import AutopilotClockMethod, AutopilotTimeMap
from icgt.clocks.device_clock import ClockNotSyncedError
from icgt.clocks.one_way import OneWayClock

BOOT0_HOST_NS = 5_000_000_000_000  # host time of the autopilot's boot


def _true_host_ns(boot_us: np.ndarray, drift_ppm: float) -> np.ndarray:
    return BOOT0_HOST_NS + boot_us * 1000.0 * (1.0 + drift_ppm * 1e-6)


def _feed(clock: OneWayClock, seconds: float, rate_hz: float, drift_ppm: float, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t_ms = np.arange(1_000.0, 1_000.0 + seconds * 1000.0, 1000.0 / rate_hz)
    stamp_ms = np.floor(t_ms)  # time_boot_ms truncates
    delay_ns = 300_000 + rng.exponential(2_000_000, t_ms.size)  # floor 0.3 ms, queueing 2 ms mean
    burst = rng.random(t_ms.size) < 0.05
    delay_ns[burst] += rng.uniform(10e6, 40e6, burst.sum())  # a radio or a busy router holds some
    rx = _true_host_ns(t_ms * 1000.0, drift_ppm) + delay_ns
    for s, r in zip(stamp_ms, rx, strict=True):
        clock.add(s * 1000.0 + 500.0, int(r))
    return t_ms


def test_nothing_before_the_first_message() -> None:
    c = OneWayClock()
    assert not c.synced
    with pytest.raises(ClockNotSyncedError):
        c.host_to_autopilot_us(BOOT0_HOST_NS)


@pytest.mark.parametrize("drift_ppm", [0.0, 40.0, -120.0])
def test_maps_boot_time_to_host_time_within_the_link_floor(drift_ppm: float) -> None:
    c = OneWayClock()
    t_ms = _feed(c, 120.0, 50.0, drift_ppm, seed=3)
    for boot_ms in (t_ms[len(t_ms) // 2], t_ms[-1]):
        truth = _true_host_ns(np.array([boot_ms * 1000.0]), drift_ppm)[0]
        err_ns = c.autopilot_to_host_ns(boot_ms * 1000.0) - truth
        # the envelope sits the link's floor (0.3 ms) above the truth, plus the stamp's half millisecond
        assert 0.0 <= err_ns + 600_000 <= 1_500_000, err_ns
        assert abs(err_ns) <= c.uncertainty_ns(boot_ms * 1000.0)
    f = c.fit()
    assert f.rate == pytest.approx(1.0 + drift_ppm * 1e-6, abs=5e-6)


def test_inverse_mapping_round_trips() -> None:
    c = OneWayClock()
    _feed(c, 60.0, 10.0, 25.0, seed=5)
    host = BOOT0_HOST_NS + 30_000_000_000
    assert c.autopilot_to_host_ns(c.host_to_autopilot_us(host)) == pytest.approx(host, abs=2)


def test_a_reboot_starts_the_envelope_again() -> None:
    c = OneWayClock()
    _feed(c, 30.0, 10.0, 0.0, seed=1)
    before = c.resets
    c.add(600.0, BOOT0_HOST_NS + 40_000_000_000)  # the boot clock went back from ~31 s to 0.6 ms
    assert c.resets == before + 1
    assert c.autopilot_to_host_ns(600.0) == BOOT0_HOST_NS + 40_000_000_000  # only the new point counts


def test_the_map_prefers_timesync_and_says_which_it_used() -> None:
    ts = AutopilotClockFilter()
    ow = OneWayClock()
    m = AutopilotTimeMap(ts, ow)
    assert m.method() is AutopilotClockMethod.NONE and not m.synced
    _feed(ow, 10.0, 10.0, 0.0, seed=2)
    assert m.method() is AutopilotClockMethod.ARRIVAL
    one_way = m.host_to_autopilot_us(BOOT0_HOST_NS + 5_000_000_000)
    ts.add_timesync(BOOT0_HOST_NS + 5_000_000_000, 5_000_000_000 + 250_000, BOOT0_HOST_NS + 5_000_500_000)
    assert m.method() is AutopilotClockMethod.TIMESYNC
    two_way = m.host_to_autopilot_us(BOOT0_HOST_NS + 5_000_250_000)
    assert abs(two_way - one_way) < 5_000  # both near 5 s of boot time
    assert m.uncertainty_ns(two_way) < ow.uncertainty_ns(two_way)
