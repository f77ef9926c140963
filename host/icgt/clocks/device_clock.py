"""Device clock [us] -> host clock [ns] from the firmware's NTP-style TIME_SYNC exchanges.

The method (two envelopes of causality constraints, a worst-case bound) is the shared two-way engine's,
described in `icgt.clocks.two_way`; this module sets it up for the device (two stamps per exchange,
1 us resolution, USB delays) and schedules the exchanges. PPS -> UTC lives in `icgt.clocks.pps`; both
names are re-exported here for older imports.
"""

from __future__ import annotations

import random

from icgt.clocks.pps import PpsEstimate, PpsStatus, PpsUtcMapper
from icgt.clocks.two_way import (
    ClockError,
    ClockEstimate,
    ClockNotSyncedError,
    ExchangeStatus,
    ResetReason,
    _TwoWayClock,
    _TwoWayLine,
)

__all__ = [
    "ClockError",
    "ClockEstimate",
    "ClockNotSyncedError",
    "DeviceClockFilter",
    "ExchangeStatus",
    "PpsEstimate",
    "PpsStatus",
    "PpsUtcMapper",
    "ResetReason",
]


class DeviceClockFilter(_TwoWayClock):
    """Device clock [us] -> host monotonic clock [ns] from TIME_SYNC / TIME_SYNC_REPLY exchanges.

    Feed it every reply with ``add_exchange``; ask ``next_exchange_interval_s`` when to send the
    next request. Pure computation: the caller stamps ``host_tx_ns`` just before writing the
    request and ``host_rx_ns`` as soon as the reply is read, both with ``time.monotonic_ns()``.

    Defaults suit USB full speed: window 120 s / 512 exchanges (a line over 2 minutes follows a
    crystal warming up by a few ppm without bending), drift up to +-1000 ppm, RTTs above 10 ms
    not stored (spikes), 0.5 ppm frequency wander allowed for when extrapolating.
    """

    def __init__(
        self,
        *,
        window_s: float = 120.0,
        max_samples: int = 512,
        min_span_s: float = 2.0,
        max_drift_ppm: float = 1000.0,
        rtt_limit_ns: int = 10_000_000,
        wander_ppm: float = 0.5,
        prior_drift_uncertainty_ppm: float = 5.0,
        path_asymmetry_ns: float = 0.0,
        jump_margin_ns: int = 2_000_000,
        fast_interval_s: float = 0.2,
        slow_interval_s: float = 1.0,
        settle_min_samples: int = 20,
        settle_min_span_s: float = 4.0,
        dither: float = 0.1,
        seed: int = 0,
        refit_interval_s: float = 0.0,
    ) -> None:
        """``path_asymmetry_ns``: known (request floor - reply floor) one-way delay difference, if calibrated.

        ``refit_interval_s``: once the window holds enough exchanges, refit the line at most this often
        (host time of the exchanges, so a replay refits at the same points); 0 refits on every query
        after a new exchange. The recorder uses 0.5 s: each fit is a hull and a slope search over the window.

        ``dither``: the schedule hint varies by +-this fraction, so requests do not stay phase-locked
        to the 1 ms USB frames (a fixed phase would be a fixed, unobservable bias).
        """
        self._line = _TwoWayLine(
            resolution_us=1.0,
            window_s=window_s,
            max_samples=max_samples,
            min_span_s=min_span_s,
            max_drift_ppm=max_drift_ppm,
            rtt_limit_ns=rtt_limit_ns,
            rtt_limit_inclusive=False,
            wander_ppm=wander_ppm,
            prior_drift_uncertainty_ppm=prior_drift_uncertainty_ppm,
            path_asymmetry_ns=path_asymmetry_ns,
            jump_margin_ns=jump_margin_ns,
            refit_interval_ns=int(refit_interval_s * 1e9),
        )
        self._fast = fast_interval_s
        self._slow = slow_interval_s
        self._settle_n = settle_min_samples
        self._settle_span_ns = settle_min_span_s * 1e9
        self._dither = dither
        self._rng = random.Random(seed)

    def add_exchange(self, host_tx_ns: int, device_rx_us: int, device_tx_us: int, host_rx_ns: int) -> ExchangeStatus:
        """One exchange: host send [ns, host], device receive and transmit [us, device], host receive [ns, host]."""
        return self._line.add(host_tx_ns, device_rx_us, device_tx_us, host_rx_ns)

    @property
    def settled(self) -> bool:
        """Enough exchanges over enough time since the last reset or gap to drop to the slow rate."""
        ln = self._line
        return (
            ln.samples_since_reset >= self._settle_n
            and ln.samples_since_gap >= 5
            and ln.span_ns() >= self._settle_span_ns
            and len(ln) > 0
        )

    def device_to_host_ns(self, device_us: float) -> int:
        """Host monotonic time [ns] of a device time [us]. Raises ClockNotSyncedError before any exchange."""
        return self._line.host_ns(device_us)

    def host_to_device_us(self, host_ns: int) -> float:
        """Device time [us] of a host monotonic time [ns]."""
        return self._line.remote_us(host_ns)

    def uncertainty_ns(self, device_us: float) -> int:
        """Worst-case error bound [ns] of ``device_to_host_ns(device_us)`` (grows outside the window)."""
        return self._line.uncertainty_ns(device_us)

    def next_exchange_interval_s(self) -> float:
        """Seconds until the next TIME_SYNC: fast until settled (and after a reset or a gap), then slow; dithered."""
        base = self._slow if self.settled else self._fast
        return base * (1.0 + self._dither * (2.0 * self._rng.random() - 1.0))


# ---------------------------------------------------------------------------------------------
# GPS PPS: device clock -> UTC directly
