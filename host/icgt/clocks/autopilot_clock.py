"""Autopilot boot clock -> host clock (MAVLink TIMESYNC), and host clock -> UTC (SYSTEM_TIME, GPS time).

Clocks
------
- host clock: ``time.monotonic_ns()`` [ns].
- autopilot boot clock: what ``time_boot_ms`` / ``time_usec`` (GPS_RAW_INT, ...) count [us]; TIMESYNC's
  ``tc1`` carries it in ns (1 us steps on PX4 and ArduPilot).
- UTC: microseconds since the Unix epoch [us].

TIMESYNC: the host sends ``tc1 = 0, ts1 = host_tx_ns``; the autopilot answers ``tc1 = its boot time [ns]``,
``ts1`` echoed; the host stamps the reply's arrival. One remote stamp per exchange, so the same
envelope engine as the device filter runs with receive = transmit = tc1 (see device_clock's
module docstring for the method and for what ``uncertainty_ns`` means: a worst-case bound).
Like PX4, exchanges with a round trip of 10 ms or more are dropped.

UTC: SYSTEM_TIME pairs ``time_unix_usec`` (0 until the autopilot has GPS time: ignored, as is
anything before 2020) with ``time_boot_ms``; a GPS time (week, time of week) can be paired with an
autopilot boot time the same way. UTC is fitted as a line of the autopilot boot clock (its drift
against true time shows in the slope) and chained with the TIMESYNC mapping, so host -> UTC =
UTC(autopilot(host)). Without any of that, the host's own CLOCK_REALTIME (sampled by the caller
next to CLOCK_MONOTONIC) is used, flagged as a fallback.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from enum import Enum
from typing import Protocol

from icgt.clocks.two_way import ClockNotSyncedError, ExchangeStatus, _TwoWayClock, _TwoWayLine

__all__ = [
    "AutopilotClockFilter",
    "UtcEstimate",
    "UtcMapper",
    "UtcSource",
    "gps_to_utc_us",
]

MIN_VALID_UTC_US = 1_577_836_800_000_000  # 2020-01-01T00:00:00Z: anything earlier is an unset clock
MAX_VALID_UTC_US = 4_102_444_800_000_000  # 2100-01-01T00:00:00Z: anything later is a broken clock (SITL: 2908)
GPS_EPOCH_UNIX_S = 315_964_800  # 1980-01-06T00:00:00Z
GPS_UTC_LEAP_S = 18  # GPS - UTC since 2017-01-01 (no leap second announced since)


def gps_to_utc_us(week: int, time_of_week_ms: float, leap_seconds: int = GPS_UTC_LEAP_S) -> float:
    """UTC [us since the Unix epoch] of a GPS week and time of week [ms] (GPS time runs ahead by the leap seconds)."""
    return (GPS_EPOCH_UNIX_S + week * 604_800 - leap_seconds) * 1e6 + time_of_week_ms * 1e3


class AutopilotClockFilter(_TwoWayClock):
    """Autopilot boot clock [us] -> host monotonic clock [ns] from MAVLink TIMESYNC round trips.

    Feed only replies to this host's own requests (``ts1`` equal to a value it sent, ``tc1 != 0``).
    """

    def __init__(
        self,
        *,
        window_s: float = 300.0,
        max_samples: int = 512,
        min_span_s: float = 30.0,
        max_drift_ppm: float = 1000.0,
        rtt_limit_ns: int = 10_000_000,
        wander_ppm: float = 1.0,
        prior_drift_uncertainty_ppm: float = 5.0,
        path_asymmetry_ns: float = 0.0,
        jump_margin_ns: int = 50_000_000,
        fast_interval_s: float = 0.2,
        slow_interval_s: float = 1.0,
        settle_min_samples: int = 10,
    ) -> None:
        """``rtt_limit_ns``: round trips >= this are dropped (PX4 uses 10 ms). Other arguments as DeviceClockFilter.

        ``min_span_s`` is longer than the device's: with millisecond delays a few seconds of replies say
        nothing useful about the drift, so until then the slope is the nominal rate (or the last drift).
        """
        self._line = _TwoWayLine(
            resolution_us=1.0,
            window_s=window_s,
            max_samples=max_samples,
            min_span_s=min_span_s,
            max_drift_ppm=max_drift_ppm,
            rtt_limit_ns=rtt_limit_ns,
            rtt_limit_inclusive=True,
            wander_ppm=wander_ppm,
            prior_drift_uncertainty_ppm=prior_drift_uncertainty_ppm,
            path_asymmetry_ns=path_asymmetry_ns,
            jump_margin_ns=jump_margin_ns,
        )
        self._fast = fast_interval_s
        self._slow = slow_interval_s
        self._settle_n = settle_min_samples

    def add_timesync(self, ts1_ns: int, tc1_ns: int, host_rx_ns: int) -> ExchangeStatus:
        """One TIMESYNC reply: ts1 = our send time [ns, host], tc1 = autopilot boot [ns], our receive [ns, host]."""
        if tc1_ns <= 0:
            self._line.rejected_invalid += 1  # tc1 = 0 is a request, not a reply
            return ExchangeStatus.REJECTED_INVALID
        remote_us = tc1_ns / 1000.0
        # tc1 is a whole microsecond: floor it so the engine's half-step centring is right.
        return self._line.add(ts1_ns, math.floor(remote_us), math.floor(remote_us), host_rx_ns)

    @property
    def settled(self) -> bool:
        return self._line.samples_since_reset >= self._settle_n and len(self._line) > 0

    @property
    def synced(self) -> bool:
        """At least one reply is in the window (the mappings can be asked for)."""
        return len(self._line) > 0

    def autopilot_to_host_ns(self, boot_us: float) -> int:
        """Host monotonic time [ns] of an autopilot boot time [us]. Raises ClockNotSyncedError before any reply."""
        return self._line.host_ns(boot_us)

    def host_to_autopilot_us(self, host_ns: int) -> float:
        """Autopilot boot time [us] of a host monotonic time [ns]."""
        return self._line.remote_us(host_ns)

    def uncertainty_ns(self, boot_us: float) -> int:
        """Worst-case error bound [ns] of ``autopilot_to_host_ns(boot_us)``."""
        return self._line.uncertainty_ns(boot_us)

    def next_exchange_interval_s(self) -> float:
        """Seconds until the next TIMESYNC request: fast until settled, then slow."""
        return self._slow if self.settled else self._fast


class AutopilotMapping(Protocol):
    """What the UTC mapper needs of an autopilot clock mapping (AutopilotClockFilter, AutopilotTimeMap)."""

    @property
    def resets(self) -> int: ...
    @property
    def synced(self) -> bool: ...
    def host_to_autopilot_us(self, host_ns: int) -> float: ...
    def uncertainty_ns(self, boot_us: float) -> int: ...


class UtcSource(Enum):
    """Where a UTC value came from, best first."""

    GPS_TIME = "gps_time"  # a GPS week / time of week paired with an autopilot boot time
    SYSTEM_TIME = "system_time"  # the autopilot's SYSTEM_TIME (its GPS-set clock)
    HOST_REALTIME = "host_realtime"  # fallback: the companion computer's CLOCK_REALTIME
    NONE = "none"


@dataclass(frozen=True, slots=True)
class UtcEstimate:
    """UTC [us since the Unix epoch] of one instant, with a bound [us] and its source.

    ``uncertainty_us`` for GPS sources is about a 95 % bound (fit + the TIMESYNC mapping's worst-case
    bound + the autopilot's own UTC accuracy allowance); for the host fallback it is what the caller
    said the host clock is good to. ``fallback`` is True when it is the host's CLOCK_REALTIME.
    """

    valid: bool
    utc_us: float
    uncertainty_us: float
    source: UtcSource
    fallback: bool

    def to_dict(self) -> dict[str, float | bool | str]:
        d = asdict(self)
        d["source"] = self.source.value
        return d


@dataclass(frozen=True, slots=True)
class _UtcFit:
    ref_boot_us: float
    ref_utc_us: float
    slope: float  # UTC us per boot us
    sigma_us: float
    n: int
    sxx: float
    mean_x: float
    newest_boot_us: float
    source: UtcSource


_NO_UTC = UtcEstimate(False, 0.0, math.inf, UtcSource.NONE, False)


class UtcMapper:
    """Host monotonic clock [ns] -> UTC [us] via the autopilot: UTC = fit(boot), boot = TIMESYNC(host).

    Samples are (autopilot boot time [us], UTC [us]) pairs; a least-squares line over the last
    ``max_samples`` (both clocks are good crystals or GPS, so a line is right for many minutes).
    SYSTEM_TIME's ``time_boot_ms`` is truncated to the millisecond, so it is centred (+0.5 ms) and
    its +-0.5 ms spread averages out in the fit. ``autopilot_utc_allowance_us`` covers how far the
    autopilot's own UTC may be from true UTC (PX4 sets its clock from GPS only when it drifts off
    by a threshold); a sample that disagrees with the fit by more than ``step_threshold_us`` three
    times in a row means the autopilot's UTC stepped: the fit restarts from those samples.
    """

    def __init__(
        self,
        autopilot: AutopilotMapping,
        *,
        max_samples: int = 120,
        autopilot_utc_allowance_us: float = 1000.0,
        step_threshold_us: float = 5000.0,
    ) -> None:
        self._ap = autopilot
        self._max = max_samples
        self._allowance = autopilot_utc_allowance_us
        self._step = step_threshold_us
        self._samples: deque[tuple[float, float, float]] = deque()  # (boot us, utc us, sample spread us)
        self._source = UtcSource.NONE
        self._fit: _UtcFit | None = None
        self._outliers: list[tuple[float, float, float]] = []
        self._ap_resets = autopilot.resets
        self._realtime: tuple[int, int, float] | None = None  # (mono ns, realtime ns, uncertainty us)
        self.ignored_unset = 0
        self.ignored_implausible = 0
        self.steps = 0

    # -- inputs -------------------------------------------------------------------------------

    def add_system_time(self, time_unix_usec: int, time_boot_ms: int) -> bool:
        """SYSTEM_TIME. Returns False (and ignores it) while ``time_unix_usec`` is 0 / before 2020 (no GPS time),
        and for a clock past 2100 (a simulator's or a corrupt one)."""
        if time_unix_usec < MIN_VALID_UTC_US:
            self.ignored_unset += 1
            return False
        if time_unix_usec >= MAX_VALID_UTC_US:
            self.ignored_implausible += 1
            return False
        if self._source is UtcSource.GPS_TIME:
            return False  # a better source is already in use
        self._add(time_boot_ms * 1000.0 + 500.0, float(time_unix_usec), 500.0 / math.sqrt(3.0), UtcSource.SYSTEM_TIME)
        return True

    def add_gps_time(
        self, gps_week: int, time_of_week_ms: float, autopilot_boot_us: float, leap_seconds: int = GPS_UTC_LEAP_S
    ) -> bool:
        """A GPS time [week, ms of week] valid at an autopilot boot time [us]."""
        if gps_week <= 0:
            return False
        utc = gps_to_utc_us(gps_week, time_of_week_ms, leap_seconds)
        if utc < MIN_VALID_UTC_US:
            self.ignored_unset += 1
            return False
        if utc >= MAX_VALID_UTC_US:
            self.ignored_implausible += 1
            return False
        if self._source is not UtcSource.GPS_TIME:
            self._samples.clear()  # switch to the better source
            self._fit = None
        self._add(float(autopilot_boot_us), utc, 1.0, UtcSource.GPS_TIME)
        return True

    def add_host_realtime(self, host_ns: int, realtime_ns: int, uncertainty_us: float = 50_000.0) -> None:
        """The host's CLOCK_REALTIME [ns] sampled next to CLOCK_MONOTONIC [ns]; used only while no GPS UTC exists.

        ``uncertainty_us``: how good the host clock is believed to be (NTP-synced: a few ms; never synced: unknown).
        """
        self._realtime = (int(host_ns), int(realtime_ns), float(uncertainty_us))

    def _add(self, boot_us: float, utc_us: float, spread_us: float, source: UtcSource) -> None:
        if self._ap.resets != self._ap_resets or (self._samples and boot_us < self._samples[-1][0]):
            # The autopilot rebooted: its boot clock restarted, the old pairs mean nothing now.
            self._ap_resets = self._ap.resets
            self._samples.clear()
            self._fit = None
            self._outliers.clear()
        self._source = source
        fit = self._fit
        if fit is not None and fit.n >= 3:
            predicted = fit.ref_utc_us + (boot_us - fit.ref_boot_us) * fit.slope
            if abs(utc_us - predicted) > max(self._step, 5.0 * fit.sigma_us):
                self._outliers.append((boot_us, utc_us, spread_us))
                if len(self._outliers) < 3:
                    return
                offsets = [u - (fit.ref_utc_us + (b - fit.ref_boot_us) * fit.slope) for b, u, _ in self._outliers]
                if max(offsets) - min(offsets) > self._step:
                    self._outliers = self._outliers[-1:]  # not one consistent step: keep waiting
                    return
                self._samples.clear()
                self._samples.extend(self._outliers)
                self._outliers.clear()
                self.steps += 1
                self._refit()
                return
        self._outliers.clear()
        self._samples.append((boot_us, utc_us, spread_us))
        while len(self._samples) > self._max:
            self._samples.popleft()
        self._refit()

    def _refit(self) -> None:
        n = len(self._samples)
        if n == 0:
            self._fit = None
            return
        ref_b, ref_u, spread = self._samples[-1]
        xs = [b - ref_b for b, _, _ in self._samples]
        ys = [u - ref_u for _, u, _ in self._samples]
        mx = sum(xs) / n
        my = sum(ys) / n
        sxx = sum((x - mx) ** 2 for x in xs)
        # Below ~10 s of span the slope is noise: assume the boot clock runs at UTC rate (error <= 1000 ppm * span).
        if n >= 3 and (max(xs) - min(xs)) >= 10e6 and sxx > 0:
            slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
        else:
            slope = 1.0
        intercept = my - slope * mx
        res = [y - intercept - slope * x for x, y in zip(xs, ys, strict=True)]
        sigma = math.sqrt(sum(r * r for r in res) / (n - 2)) if n > 2 else spread
        self._fit = _UtcFit(
            ref_b,
            ref_u + intercept,
            slope,
            max(sigma, spread),
            n,
            sxx,
            mx,
            max(b for b, _, _ in self._samples),
            self._source,
        )

    # -- queries ------------------------------------------------------------------------------

    def autopilot_to_utc(self, boot_us: float) -> UtcEstimate:
        """UTC [us] of an autopilot boot time [us], from GPS sources only (not valid without them)."""
        fit = self._fit
        if fit is None or self._ap.resets != self._ap_resets:
            return _NO_UTC
        x = boot_us - fit.ref_boot_us
        utc = fit.ref_utc_us + x * fit.slope
        lever = 1.0 / fit.n + ((x - fit.mean_x) ** 2 / fit.sxx if fit.sxx > 0 else 0.0)
        beyond = max(0.0, boot_us - fit.newest_boot_us)
        unc = 2.0 * fit.sigma_us * math.sqrt(lever) + self._allowance + 1e-6 * beyond  # 1 ppm past the data
        return UtcEstimate(True, utc, unc, fit.source, False)

    def host_to_utc(self, host_ns: int) -> UtcEstimate:
        """UTC [us] of a host monotonic time [ns]: via the autopilot if it has GPS time, else the host's clock."""
        via = self._via_autopilot(host_ns)
        if via is not None:
            return via
        if self._realtime is not None:
            mono, real, unc = self._realtime
            return UtcEstimate(True, (real + (int(host_ns) - mono)) / 1000.0, unc, UtcSource.HOST_REALTIME, True)
        return _NO_UTC

    def host_realtime_utc_us(self, host_ns: int) -> float | None:
        """UTC [us] of a host monotonic time by the host's own clock alone (None without a sample)."""
        if self._realtime is None:
            return None
        mono, real, _ = self._realtime
        return (real + (int(host_ns) - mono)) / 1000.0

    def _via_autopilot(self, host_ns: int) -> UtcEstimate | None:
        if self._fit is None:
            return None
        try:
            boot = self._ap.host_to_autopilot_us(host_ns)
            map_unc_us = self._ap.uncertainty_ns(boot) / 1000.0
        except ClockNotSyncedError:
            return None
        est = self.autopilot_to_utc(boot)
        if not est.valid:
            return None
        return UtcEstimate(True, est.utc_us, est.uncertainty_us + map_unc_us, est.source, False)

    def host_to_utc_us(self, host_ns: int) -> float:
        """UTC [us] of a host monotonic time [ns]; raises ClockNotSyncedError if there is no source at all."""
        est = self.host_to_utc(host_ns)
        if not est.valid:
            raise ClockNotSyncedError("no UTC source yet (no GPS time from the autopilot, no host realtime sample)")
        return est.utc_us

    @property
    def source(self) -> UtcSource:
        """The source host_to_utc would use now (without a TIMESYNC mapping the GPS fit cannot be reached)."""
        if self._fit is not None and self._ap.synced:
            return self._fit.source
        return UtcSource.HOST_REALTIME if self._realtime is not None else UtcSource.NONE
