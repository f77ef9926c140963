"""PpsUtcMapper: device clock -> UTC from GPS PPS edges (sub-microsecond, glitches, lock, labels)."""

from __future__ import annotations

import numpy as np
import pytest

from icgt.clocks import ClockNotSyncedError, PpsStatus, PpsUtcMapper
from icgt.clocks.simulate import RemoteClockTruth, simulate_pps


def coarse(truth: RemoteClockTruth, device_us: int, error_us: float = 0.0) -> float:
    """A coarse UTC of a device instant (what the host's UTC estimate or the RTC anchor would give)."""
    return truth.utc_us(truth.host_ns(device_us)) + error_us


def utc_error_ns(mapper: PpsUtcMapper, truth: RemoteClockTruth, utc_us: float) -> int:
    dev = truth.remote_us(truth.host_t0_ns + (utc_us - truth.utc0_us) * 1000.0)
    return mapper.device_to_utc_ns(dev) - round(utc_us * 1000.0)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_sub_microsecond_mapping(seed: int) -> None:
    rng = np.random.default_rng(seed)
    truth = RemoteClockTruth(offset_us=float(rng.uniform(1e6, 1e9)), drift_ppm=float(rng.uniform(-60, 60)))
    edges = simulate_pps(truth, 60, rng)
    mapper = PpsUtcMapper()
    worst = 0
    for edge in edges:
        status = mapper.add_pps(edge.device_us, edge.pps_count, coarse(truth, edge.device_us, 40_000.0), 100_000.0)
        assert status is PpsStatus.ACCEPTED
        if not mapper.locked():
            continue
        # Between this edge and the next, before the next edge is known (the real-time case).
        for frac in np.linspace(0.0, 0.999, 9):
            err = utc_error_ns(mapper, truth, edge.utc_us + frac * 1e6)
            worst = max(worst, abs(err))
            assert abs(err) <= mapper.uncertainty_us(truth.remote_us(truth.host_ns(edge.device_us))) * 1000 + 1000
    assert worst <= 1000, worst
    est = mapper.estimate()
    assert est.locked and est.labelled
    assert est.drift_ppm == pytest.approx(truth.drift_ppm, abs=0.05)
    assert est.uncertainty_us < 1.0


def test_lock_needs_three_edges_and_is_lost_without_edges() -> None:
    rng = np.random.default_rng(3)
    truth = RemoteClockTruth()
    edges = simulate_pps(truth, 5, rng)
    mapper = PpsUtcMapper()
    mapper.add_pps(edges[0].device_us, 1, coarse(truth, edges[0].device_us))
    mapper.add_pps(edges[1].device_us, 2, coarse(truth, edges[1].device_us))
    assert not mapper.locked()
    mapper.add_pps(edges[2].device_us, 3, coarse(truth, edges[2].device_us))
    assert mapper.locked()
    assert mapper.locked(edges[2].device_us + 1_000_000)
    assert not mapper.locked(edges[2].device_us + 3_000_000)  # no edge for 3 s: lock lost


def test_glitch_edge_rejected_and_missing_edge_tolerated() -> None:
    rng = np.random.default_rng(4)
    truth = RemoteClockTruth()
    edges = simulate_pps(truth, 12, rng)
    mapper = PpsUtcMapper()
    count = 0
    for i, edge in enumerate(edges):
        if i == 6:
            continue  # a missed pulse: the next edge comes 2 s later
        count += 1
        if i == 8:
            # Noise on the line half a second after an edge: the firmware counted it too.
            assert mapper.add_pps(edge.device_us - 500_000, count) is PpsStatus.REJECTED_INTERVAL
            count += 1
        assert mapper.add_pps(edge.device_us, count, coarse(truth, edge.device_us)) is PpsStatus.ACCEPTED
    assert mapper.rejected == 1
    assert mapper.locked()
    assert abs(utc_error_ns(mapper, truth, edges[-1].utc_us + 300_000.0)) <= 1000


def test_edges_not_one_second_apart_are_rejected() -> None:
    mapper = PpsUtcMapper()
    assert mapper.add_pps(10_000_000, 1) is PpsStatus.ACCEPTED
    assert mapper.add_pps(11_000_900, 2) is PpsStatus.REJECTED_INTERVAL  # 900 us off: not a PPS
    assert mapper.add_pps(11_000_020, 3) is PpsStatus.ACCEPTED


def test_reboot_resets() -> None:
    mapper = PpsUtcMapper()
    for k in range(4):
        mapper.add_pps(50_000_000 + k * 1_000_000, k + 1, 1.7e15 + k * 1e6)
    assert mapper.locked()
    assert mapper.add_pps(1_200_000, 1) is PpsStatus.RESET_REBOOT
    assert not mapper.locked()
    with pytest.raises(ClockNotSyncedError):
        mapper.device_to_utc_us(1_300_000)


def test_label_needs_coarse_utc_and_is_corrected_by_consistent_coarse_values() -> None:
    rng = np.random.default_rng(6)
    truth = RemoteClockTruth()
    edges = simulate_pps(truth, 10, rng)
    mapper = PpsUtcMapper()
    mapper.add_pps(edges[0].device_us, 1)  # no coarse UTC: fits, but cannot name the second
    mapper.add_pps(edges[1].device_us, 2, coarse(truth, edges[1].device_us), 900_000.0)  # too vague to use
    assert not mapper.labelled
    # The first usable coarse UTC is 1 s off (e.g. a wrong RTC), later ones are right.
    mapper.add_pps(edges[2].device_us, 3, coarse(truth, edges[2].device_us, 1_000_000.0))
    assert mapper.labelled
    assert abs(utc_error_ns(mapper, truth, edges[2].utc_us) - 1_000_000_000) <= 1000
    for i in range(3, 10):
        mapper.add_pps(edges[i].device_us, i + 1, coarse(truth, edges[i].device_us, 300_000.0))
    assert mapper.relabelled == 1
    assert abs(utc_error_ns(mapper, truth, edges[-1].utc_us + 500_000.0)) <= 1000


def test_utc_to_device_inverts() -> None:
    mapper = PpsUtcMapper()
    for k in range(5):
        mapper.add_pps(3_000_000 + k * 1_000_050, k + 1, 1_750_000_000e6 + k * 1e6)
    dev = 5_500_000.0
    assert mapper.utc_to_device_us(mapper.device_to_utc_ns(dev) / 1000.0) == pytest.approx(dev, abs=0.3)
    assert mapper.estimate().to_dict()["locked"] is True
