"""DeviceClockFilter against the synthetic USB link (icgt.clocks.simulate): accuracy, robustness, honesty."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from icgt.clocks import ClockNotSyncedError, DeviceClockFilter, ExchangeStatus, ResetReason
from icgt.clocks.simulate import RemoteClockTruth, SimExchange, UsbLinkModel, exchange_schedule, simulate_exchanges

EXCHANGE_HZ = 10.0  # the recorder's TIME_SYNC rate after the first seconds

CLEAN = UsbLinkModel(
    frame_us=0.0,
    out_floor_us=30.0,
    out_jitter_us=0.0,
    in_floor_us=30.0,
    in_jitter_us=0.0,
    in_tail_us=0.0,
    spike_probability=0.0,
)


def online_errors(
    exchanges: Sequence[SimExchange],
    truth: RemoteClockTruth,
    filt: DeviceClockFilter,
    *,
    after_s: float = 5.0,
    step_s: float = 0.25,
) -> tuple[np.ndarray, np.ndarray]:
    """Error [ns] of the online mapping at instants between exchanges, and the bound reported there."""
    errors: list[float] = []
    bounds: list[float] = []
    start = truth.host_t0_ns + after_s * 1e9
    for i, ex in enumerate(exchanges):
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
        end = exchanges[i + 1].host_rx_ns if i + 1 < len(exchanges) else ex.host_rx_ns + 1_000_000_000
        for q in np.arange(ex.host_rx_ns, end, step_s * 1e9):
            if q < start:
                continue
            dev = truth.remote_us(float(q))
            errors.append(filt.device_to_host_ns(dev) - float(q))
            bounds.append(filt.uncertainty_ns(dev))
    return np.array(errors), np.array(bounds)


def run(
    seed: int,
    duration_s: float = 600.0,
    link: UsbLinkModel | None = None,
    steady_hz: float = EXCHANGE_HZ,
    **truth_kw: float,
) -> tuple:
    rng = np.random.default_rng(seed)
    truth = RemoteClockTruth(**truth_kw)  # type: ignore[arg-type]
    schedule = exchange_schedule(duration_s, rng, steady_hz=steady_hz)
    exchanges = simulate_exchanges(schedule, truth, link or UsbLinkModel(), rng)
    filt = DeviceClockFilter()
    errors, bounds = online_errors(exchanges, truth, filt)
    return errors, bounds, filt


def test_not_synced_before_any_exchange() -> None:
    filt = DeviceClockFilter()
    assert not filt.estimate().valid
    with pytest.raises(ClockNotSyncedError):
        filt.device_to_host_ns(1_000)


def test_exact_recovery_without_jitter() -> None:
    errors, _, filt = run(1, duration_s=60.0, link=CLEAN, drift_ppm=50.0)
    # Only the 1 us truncation of the device stamps is left.
    assert np.max(np.abs(errors)) <= 1_000
    est = filt.estimate()
    assert est.drift_ppm == pytest.approx(50.0, abs=0.01)
    assert est.valid and est.settled


@settings(max_examples=20, deadline=None)
@given(
    offset_us=st.floats(0.0, 1e10),
    drift_ppm=st.floats(-300.0, 300.0),
    floor_us=st.floats(5.0, 2000.0),
    seed=st.integers(0, 2**16),
)
def test_exact_recovery_property(offset_us: float, drift_ppm: float, floor_us: float, seed: int) -> None:
    link = dataclasses.replace(CLEAN, out_floor_us=floor_us, in_floor_us=floor_us)
    rng = np.random.default_rng(seed)
    truth = RemoteClockTruth(offset_us=offset_us, drift_ppm=drift_ppm)
    exchanges = simulate_exchanges(exchange_schedule(12.0, rng, steady_hz=EXCHANGE_HZ), truth, link, rng)
    filt = DeviceClockFilter()
    for ex in exchanges:
        assert (
            filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns) is ExchangeStatus.ACCEPTED
        )
    q = exchanges[-1].host_rx_ns + 500_000_000
    dev = truth.remote_us(q)
    assert abs(filt.device_to_host_ns(dev) - q) <= 1_500
    # The inverse agrees with the forward mapping.
    assert filt.host_to_device_us(filt.device_to_host_ns(dev)) == pytest.approx(dev, abs=0.01)


@pytest.mark.parametrize("seed", [0, 1])
def test_p95_within_50us_usb_jitter_50ppm(seed: int) -> None:
    # 5 min: 5 Hz for 5 s, then 10 Hz as the recorder asks; USB full-speed frames both ways, jitter,
    # scheduler tail, 2 % spikes. (At 1 Hz a reply lands within a few us of a 1 ms frame's poll only
    # about once a minute, and p95 is ~100 us: the reason the recorder exchanges at 10 Hz.)
    errors, bounds, filt = run(seed, duration_s=300.0, drift_ppm=50.0)
    p95_us = np.percentile(np.abs(errors), 95) / 1000.0
    assert p95_us <= 50.0, p95_us
    assert filt.estimate().drift_ppm == pytest.approx(50.0, abs=0.5)
    # The reported bound is honest (it is a worst-case bound: it should essentially always hold).
    assert np.mean(np.abs(errors) <= bounds) >= 0.95


def test_outliers_rejected_and_harmless() -> None:
    link = dataclasses.replace(UsbLinkModel(), spike_probability=0.15, spike_min_us=12_000.0, spike_max_us=60_000.0)
    rng = np.random.default_rng(7)
    truth = RemoteClockTruth()
    exchanges = simulate_exchanges(exchange_schedule(300.0, rng, steady_hz=EXCHANGE_HZ), truth, link, rng)
    filt = DeviceClockFilter()
    errors, _ = online_errors(exchanges, truth, filt)
    spikes = sum(ex.spike for ex in exchanges)
    assert spikes > 20
    assert filt.counters["rejected_rtt"] == spikes  # every spike above the 10 ms limit, nothing else
    assert np.percentile(np.abs(errors), 95) <= 50_000


def test_sub_limit_spikes_do_not_move_the_estimate() -> None:
    # Spikes of 2-7 ms are stored (below the RTT limit) but never touch the envelopes.
    link = dataclasses.replace(UsbLinkModel(), spike_probability=0.3, spike_min_us=2_000.0, spike_max_us=7_000.0)
    errors, _, filt = run(3, duration_s=300.0, link=link)
    assert filt.counters["rejected_rtt"] == 0
    assert np.percentile(np.abs(errors), 95) <= 50_000


def test_invalid_exchange_rejected() -> None:
    filt = DeviceClockFilter()
    assert filt.add_exchange(2_000_000, 100, 100, 1_000_000) is ExchangeStatus.REJECTED_INVALID  # reply before send
    assert filt.add_exchange(1_000_000, 200, 100, 2_000_000) is ExchangeStatus.REJECTED_INVALID  # tx before rx
    assert filt.counters["rejected_invalid"] == 2
    assert not filt.estimate().valid


def test_reboot_detected_and_reconverges() -> None:
    rng = np.random.default_rng(11)
    before = RemoteClockTruth(offset_us=50_000_000.0, drift_ppm=40.0)
    # Reboot 60 s in: the device clock restarts near 0, same crystal.
    t_reboot = before.host_t0_ns + 60_000_000_000
    after = RemoteClockTruth(offset_us=-60e6 * (1 + 40e-6) + 1_500_000.0, drift_ppm=40.0)
    sched = exchange_schedule(180.0, rng, steady_hz=EXCHANGE_HZ)
    first = simulate_exchanges([t for t in sched if t < t_reboot], before, UsbLinkModel(), rng)
    second = simulate_exchanges([t for t in sched if t >= t_reboot], after, UsbLinkModel(), rng)
    filt = DeviceClockFilter()
    for ex in first:
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
    ex = second[0]
    assert (
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns) is ExchangeStatus.RESET_REBOOT
    )
    assert filt.resets == 1 and filt.last_reset_reason is ResetReason.REBOOT
    assert filt.estimate().n_used == 1
    assert filt.next_exchange_interval_s() < 0.5  # back to the fast rate
    errors, _ = online_errors(second[1:], after, filt, after_s=60.0 + 20.0)
    assert np.percentile(np.abs(errors), 95) <= 50_000
    assert filt.resets == 1


def test_forward_jump_detected() -> None:
    rng = np.random.default_rng(12)
    truth = RemoteClockTruth()
    exchanges = simulate_exchanges(exchange_schedule(30.0, rng, steady_hz=EXCHANGE_HZ), truth, UsbLinkModel(), rng)
    filt = DeviceClockFilter()
    for ex in exchanges[:-1]:
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
    last = exchanges[-1]
    jump = 5_000_000  # the device clock 5 s ahead (e.g. another board answering)
    status = filt.add_exchange(last.host_tx_ns, last.device_rx_us + jump, last.device_tx_us + jump, last.host_rx_ns)
    assert status is ExchangeStatus.RESET_JUMP
    assert filt.last_reset_reason is ResetReason.JUMP


def test_gap_extrapolation_with_honest_bound() -> None:
    hits = 0
    checks = 0
    for seed in range(6):
        rng = np.random.default_rng(100 + seed)
        truth = RemoteClockTruth(drift_ppm=float(rng.uniform(-80, 80)))
        sched = exchange_schedule(200.0, rng, steady_hz=EXCHANGE_HZ, gaps=[(120.0, 30.0)])
        exchanges = simulate_exchanges(sched, truth, UsbLinkModel(), rng)
        filt = DeviceClockFilter()
        before_gap = [ex for ex in exchanges if ex.host_tx_ns < truth.host_t0_ns + 120e9]
        for ex in before_gap:
            filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
        last_bound = 0
        for k in range(1, 31):  # 1 .. 30 s into the unplug
            q = before_gap[-1].host_rx_ns + k * 1_000_000_000
            dev = truth.remote_us(q)
            bound = filt.uncertainty_ns(dev)
            assert bound >= last_bound  # the bound grows while extrapolating
            last_bound = bound
            checks += 1
            hits += abs(filt.device_to_host_ns(dev) - q) <= bound
        assert last_bound < 200_000  # still a usable bound after 30 s
    assert hits / checks >= 0.95


def test_schedule_hint_fast_then_slow() -> None:
    rng = np.random.default_rng(5)
    truth = RemoteClockTruth()
    exchanges = simulate_exchanges(exchange_schedule(60.0, rng, steady_hz=EXCHANGE_HZ), truth, UsbLinkModel(), rng)
    filt = DeviceClockFilter(seed=1)
    assert 0.18 <= filt.next_exchange_interval_s() <= 0.22
    for ex in exchanges:
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
    intervals = [filt.next_exchange_interval_s() for _ in range(50)]
    assert all(0.9 <= x <= 1.1 for x in intervals)
    assert max(intervals) - min(intervals) > 0.05  # dithered, so requests do not phase-lock to USB frames
    filt.reset()
    assert filt.next_exchange_interval_s() < 0.25


def test_window_is_bounded() -> None:
    rng = np.random.default_rng(9)
    truth = RemoteClockTruth()
    sched = exchange_schedule(900.0, rng, steady_hz=EXCHANGE_HZ)
    exchanges = simulate_exchanges(sched, truth, UsbLinkModel(), rng)
    filt = DeviceClockFilter(window_s=30.0, max_samples=40)
    sizes = []
    for ex in exchanges:
        filt.add_exchange(ex.host_tx_ns, ex.device_rx_us, ex.device_tx_us, ex.host_rx_ns)
        sizes.append(filt.counters["in_window"])
    assert max(sizes) <= 40
    assert filt.estimate().span_s <= 31.0


def test_estimate_record_for_the_log() -> None:
    _, _, filt = run(2, duration_s=30.0)
    record = filt.estimate().to_dict()
    for key in (
        "valid",
        "n_used",
        "ref_clock_us",
        "ref_host_ns",
        "drift_ppm",
        "uncertainty_ns",
        "t_host_ns",
        "offset_ns",
    ):
        assert key in record


def test_async_request_link() -> None:
    # Requests that go out at once (real bulk OUT) and replies that wait for the frame.
    errors, _, _ = run(4, duration_s=300.0, link=dataclasses.replace(UsbLinkModel(), out_on_frames=False))
    assert np.percentile(np.abs(errors), 95) <= 80_000


def test_the_devices_random_reply_hold_is_what_removes_the_half_frame_bias() -> None:
    # A device that answered at once would always reply at the request's phase of the frame grid,
    # so its replies wait most of a frame for the next poll and never reach their floor.
    prompt = dataclasses.replace(UsbLinkModel(), reply_hold_max_us=0.0)
    at_once, _, _ = run(5, duration_s=300.0, link=prompt)
    held, _, _ = run(5, duration_s=300.0)
    assert np.median(at_once) >= 300_000  # the mapping lands late by about half of the 1 ms frame
    assert np.percentile(np.abs(held), 95) <= 50_000
