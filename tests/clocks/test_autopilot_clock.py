"""AutopilotClockFilter (MAVLink TIMESYNC) and UtcMapper (SYSTEM_TIME / GPS time / host fallback)."""

from __future__ import annotations

import numpy as np
import pytest

from icgt.clocks import AutopilotClockFilter, ClockNotSyncedError, ExchangeStatus, UtcMapper, UtcSource, gps_to_utc_us
from icgt.clocks.simulate import (
    MavlinkLinkModel,
    RemoteClockTruth,
    exchange_schedule,
    simulate_system_time,
    simulate_timesync,
)


def synced_autopilot(seed: int, duration_s: float = 600.0) -> tuple[AutopilotClockFilter, RemoteClockTruth, list]:
    rng = np.random.default_rng(seed)
    truth = RemoteClockTruth(offset_us=float(rng.uniform(1e6, 1e9)), drift_ppm=float(rng.uniform(-40, 40)))
    replies = simulate_timesync(exchange_schedule(duration_s, rng), truth, MavlinkLinkModel(), rng)
    return AutopilotClockFilter(), truth, replies


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_timesync_p95_within_1ms(seed: int) -> None:
    filt, truth, replies = synced_autopilot(seed)
    rtts_ms = np.array([(r.host_rx_ns - r.ts1_ns) / 1e6 for r in replies])
    assert rtts_ms.min() < 4.0 and np.percentile(rtts_ms, 99) > 20.0  # RTTs of 2-30 ms (and spikes)
    errors = []
    covered = []
    for r in replies:
        status = filt.add_timesync(r.ts1_ns, r.tc1_ns, r.host_rx_ns)
        assert (status is ExchangeStatus.REJECTED_RTT) == (r.host_rx_ns - r.ts1_ns >= 10_000_000)
        if r.host_rx_ns - truth.host_t0_ns < 5e9 or not filt.synced:
            continue
        boot = truth.remote_us(r.host_rx_ns)
        err = filt.autopilot_to_host_ns(boot) - r.host_rx_ns
        errors.append(err)
        covered.append(abs(err) <= filt.uncertainty_ns(boot))
    assert np.percentile(np.abs(errors), 95) <= 1_000_000
    assert np.mean(covered) >= 0.95
    assert filt.counters["rejected_rtt"] > 0.2 * len(replies)
    assert filt.estimate().drift_ppm == pytest.approx(truth.drift_ppm, abs=5.0)


def test_rtt_limit_is_exclusive_at_10ms() -> None:
    filt = AutopilotClockFilter()
    assert filt.add_timesync(1_000_000_000, 5_000_000_000, 1_010_000_000) is ExchangeStatus.REJECTED_RTT
    assert filt.add_timesync(2_000_000_000, 6_000_000_000, 2_009_999_000) is ExchangeStatus.ACCEPTED
    assert filt.add_timesync(3_000_000_000, 0, 3_001_000_000) is ExchangeStatus.REJECTED_INVALID  # a request
    with pytest.raises(ClockNotSyncedError):
        AutopilotClockFilter().autopilot_to_host_ns(1_000)


def test_autopilot_reboot_resets() -> None:
    filt = AutopilotClockFilter()
    for k in range(20):
        filt.add_timesync(k * 10**9, 100 * 10**9 + k * 10**9 + 3_000_000, k * 10**9 + 5_000_000)
    assert filt.add_timesync(21 * 10**9, 2 * 10**9, 21 * 10**9 + 5_000_000) is ExchangeStatus.RESET_REBOOT
    assert filt.resets == 1


def test_gps_week_conversion() -> None:
    # GPS week 2000 started 2018-05-06T00:00:00 GPS = 2018-05-05T23:59:42 UTC.
    assert gps_to_utc_us(2000, 0.0) == 1_525_564_782_000_000
    assert gps_to_utc_us(2000, 1500.0) == 1_525_564_783_500_000


def test_utc_ignores_unset_time_and_falls_back_to_host_clock() -> None:
    filt, truth, replies = synced_autopilot(4, duration_s=120.0)
    utc = UtcMapper(filt)
    assert not utc.host_to_utc(truth.host_t0_ns).valid
    with pytest.raises(ClockNotSyncedError):
        utc.host_to_utc_us(truth.host_t0_ns)
    # The host's CLOCK_REALTIME, 20 ms off, sampled with CLOCK_MONOTONIC by the caller.
    utc.add_host_realtime(truth.host_t0_ns, int(truth.utc0_us * 1000 + 20_000_000), uncertainty_us=50_000.0)
    fallback = utc.host_to_utc(truth.host_t0_ns + 1_000_000_000)
    assert fallback.valid and fallback.fallback and fallback.source is UtcSource.HOST_REALTIME
    assert fallback.utc_us == pytest.approx(truth.utc0_us + 1_020_000.0)

    rng = np.random.default_rng(4)
    msgs = simulate_system_time(
        truth, [truth.host_t0_ns + k * 1_000_000_000 for k in range(120)], rng, fix_after_s=10.0
    )
    for r in replies:
        filt.add_timesync(r.ts1_ns, r.tc1_ns, r.host_rx_ns)
    accepted = [utc.add_system_time(m.time_unix_usec, m.time_boot_ms) for m in msgs]
    assert accepted[:10] == [False] * 10 and all(accepted[10:])
    assert utc.ignored_unset == 10
    assert utc.source is UtcSource.SYSTEM_TIME
    for k in (30, 60, 119):
        host = truth.host_t0_ns + k * 1_000_000_000 + 123_456_789
        est = utc.host_to_utc(host)
        assert not est.fallback and est.source is UtcSource.SYSTEM_TIME
        err_us = est.utc_us - truth.utc_us(host)
        assert abs(err_us) <= 1_500.0  # the TIMESYNC mapping (~0.5 ms) + the ms steps of time_boot_ms
        assert abs(err_us) <= est.uncertainty_us


def test_utc_restarts_when_autopilot_reboots_and_follows_steps() -> None:
    filt = AutopilotClockFilter()
    for k in range(30):
        filt.add_timesync(k * 10**9, 50 * 10**9 + k * 10**9, k * 10**9 + 2_000_000)
    utc = UtcMapper(filt)
    base = 1_750_000_000_000_000
    for k in range(10):
        utc.add_system_time(base + k * 1_000_000, 50_000 + k * 1000)
    assert utc.autopilot_to_utc(55_000_000.0).utc_us == pytest.approx(base + 5_000_000 - 500, abs=50)
    # The autopilot's clock steps by +2 s (it re-set itself from GPS): 3 consistent samples re-anchor the fit.
    for k in range(10, 13):
        utc.add_system_time(base + 2_000_000 + k * 1_000_000, 50_000 + k * 1000)
    assert utc.steps == 1
    assert utc.autopilot_to_utc(62_000_000.0).utc_us == pytest.approx(base + 2_000_000 + 12_000_000 - 500, abs=50)
    # Autopilot reboot: the TIMESYNC filter resets, the old (boot, UTC) pairs are dropped.
    filt.add_timesync(40 * 10**9, 10**9, 40 * 10**9 + 2_000_000)
    assert not utc.autopilot_to_utc(62_000_000.0).valid
    utc.add_system_time(base + 40_000_000, 1_000)
    assert utc.autopilot_to_utc(1_000_500.0).valid


def test_reordered_reply_is_not_a_reboot() -> None:
    filt = AutopilotClockFilter()
    for k in range(5):
        filt.add_timesync(k * 10**9, 100 * 10**9 + k * 10**9, k * 10**9 + 4_000_000)
    # The reply to a request sent 3 ms before the last one arrives after it (UDP reordering).
    assert filt.add_timesync(4 * 10**9 - 3_000_000, 104 * 10**9 - 2_000_000, 4 * 10**9 + 5_000_000) is (
        ExchangeStatus.REJECTED_INVALID
    )
    assert filt.resets == 0


def test_gps_time_preferred_over_system_time() -> None:
    filt = AutopilotClockFilter()
    for k in range(40):
        filt.add_timesync(k * 10**9, 7 * 10**9 + k * 10**9, k * 10**9 + 2_000_000)
    utc = UtcMapper(filt)
    assert utc.add_system_time(1_750_000_000_000_000, 7_000)
    week, tow_ms = 2370, 100_000.0
    for k in range(5):
        assert utc.add_gps_time(week, tow_ms + k * 1000.0, 8_000_000.0 + k * 1e6)
    assert not utc.add_system_time(1_750_000_010_000_000, 17_000)  # ignored: GPS time is the better source
    est = utc.host_to_utc(3 * 10**9 + 1_000_000)  # the host time of autopilot boot 10 s
    assert est.source is UtcSource.GPS_TIME and not est.fallback
    assert est.utc_us == pytest.approx(gps_to_utc_us(week, tow_ms + 2000.0), abs=1500.0)
