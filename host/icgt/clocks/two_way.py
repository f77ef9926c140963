"""The two-way clock engine: a remote clock against the host clock from request/reply exchanges.

Used by the device filter (TIME_SYNC, `icgt.clocks.device_clock`) and the autopilot filter (MAVLink
TIMESYNC, `icgt.clocks.autopilot_clock`).

Clocks
------
- host clock: ``time.monotonic_ns()`` on the companion computer [ns].
- device clock: the firmware's 64-bit microsecond counter [us] (never adjusted; restarts at 0 on boot).

Method (why not "lowest RTT, then least squares")
-------------------------------------------------
One exchange gives two causality constraints on the true line ``host = f(device)``:

- request:  ``f(device_rx) >= host_tx``  (the request cannot arrive before it was sent),
- reply:    ``f(device_tx) <= host_rx``  (the reply cannot arrive before it was sent).

In the (device, host) plane the request points lie below the true line and the reply points
above it, each at a distance equal to that direction's one-way delay. Over USB full speed the
delays are dominated by the wait for a 1 ms frame. Picking the lowest-RTT exchange and halving
it needs *both* directions near their floor in the same exchange (error falls like 1/sqrt(N));
the envelope of each direction separately reaches its floor much faster. So the filter keeps
the upper convex hull of the request points and the lower convex hull of the reply points over
a bounded window and places the line midway between the two envelopes (equal clearance, i.e.
equal path floors assumed, or a configured ``path_asymmetry_ns``). Delay spikes never touch an
envelope, so they are harmless (those above ``rtt_limit_ns`` are not even stored).

The slope is not taken from the two or three extreme points that hold the widest separating
band (one unlucky point near the end of the window would tilt it) but from the envelope points
of equal time buckets, each side weighted by how sharp its floor is (``bucket_slope``), always
clipped to the slopes that violate no exchange.

Frame-synchronous links. A USB host polls the device on its frame grid (1 ms full speed,
125 us high speed) and requests reach the device at one phase of it, so a reply sent at once
would always wait most of a frame for the next poll and never reach its path's floor (a bias
of about half a frame). The firmware therefore holds each reply a random 0..1 ms before
sending it (``firmware/lib/core/time_sync_responder.hpp``, SPEC.md): some replies then leave
just before a poll and both envelopes reach their floors. Nothing here models the frames.

Uncertainty (a worst-case bound, not a sigma)
----------------------------------------------
Every line that violates no exchange's constraint is a possible truth. The reported
``uncertainty_ns`` at a device time is the largest distance from the estimate to any such line
there whose slope is also within 4 standard errors of the estimated drift (a small LP over the
same hulls, solved exactly: the extreme line at a point rests on the hull edge over that point,
see ``bound_ns``), plus the 1 us stamp resolution, plus an allowance for the crystal's frequency wander
(``wander_ppm``) for queries outside the window (extrapolation across an unplug grows linearly).
It holds whatever the path asymmetry is, provided the clock is linear over the window; so it
includes the constant asymmetry of the two paths' floors that no two-way method can observe
(about half the lowest round trip), and is typically several times the actual error.

The window is trimmed by age and count (bounded memory for hours of flight), but old samples
are only dropped once newer ones span half the window, so after a long gap the drift measured
before it still carries across. If the window cannot be fitted by any line (the crystal's
frequency changed too much), the oldest samples are dropped until it can.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from enum import Enum

from icgt.clocks.hull_geometry import (
    Hull,
    bucket_slope,
    concave_argmax,
    level_crossing,
    lower_hull,
    support_slope,
    upper_hull,
)
from icgt.errors import IcgtError

__all__ = [
    "ClockError",
    "ClockEstimate",
    "ClockNotSyncedError",
    "ExchangeStatus",
    "ResetReason",
]

_REORDER_US = 100_000.0  # a remote clock that went back by less than this is a reordered reply, not a reboot


class ClockError(IcgtError):
    """A clock mapping problem."""


class ClockNotSyncedError(ClockError):
    """A mapping was asked for before any exchange (or PPS edge) was accepted."""


class ExchangeStatus(Enum):
    """What ``add_exchange`` did with one exchange."""

    ACCEPTED = "accepted"
    REJECTED_RTT = "rejected_rtt"  # round trip above rtt_limit_ns: a delay spike
    REJECTED_INVALID = "rejected_invalid"  # impossible stamps (reply before request, negative RTT, out of order)
    RESET_REBOOT = "reset_reboot"  # the remote clock went backwards: rebooted; accepted as the first of a new window
    RESET_JUMP = "reset_jump"  # the exchange contradicts the current line by far more than its bound


class ResetReason(Enum):
    """Why a filter dropped its window (``last_reset_reason``)."""

    NONE = "none"
    REBOOT = "reboot"
    JUMP = "jump"
    CALLER = "caller"


@dataclass(frozen=True, slots=True)
class ClockEstimate:
    """The current line ``host_ns = ref_host_ns + (clock_us - ref_clock_us) * 1000 / (1 + drift_ppm * 1e-6)``.

    ``clock`` is the remote clock: the device clock [us] for DeviceClockFilter, the autopilot
    boot clock [us] for AutopilotClockFilter. ``drift_ppm`` is how fast the remote clock runs
    relative to the host clock (+50 = it gains 50 us per host second). ``uncertainty_ns`` is a
    worst-case bound (see the module docstring) on the error of the mapping at ``ref_clock_us``,
    the remote time of the newest exchange used, whose host receive time is ``t_host_ns``.
    """

    valid: bool
    settled: bool
    n_used: int
    ref_clock_us: float
    ref_host_ns: int
    drift_ppm: float
    uncertainty_ns: int
    t_host_ns: int
    min_rtt_ns: int
    span_s: float
    resets: int

    @property
    def offset_ns(self) -> float:
        """host_ns - clock_us * 1000 at the reference [ns]."""
        return self.ref_host_ns - self.ref_clock_us * 1000.0

    def to_dict(self) -> dict[str, float | int | bool]:
        """Flat record for the log (so frames can be re-timed offline)."""
        d: dict[str, float | int | bool] = asdict(self)
        d["offset_ns"] = self.offset_ns
        return d


_INVALID = ClockEstimate(False, False, 0, 0.0, 0, 0.0, 0, 0, 0, 0.0, 0)


@dataclass(frozen=True, slots=True)
class _Sample:
    host_tx_ns: int
    rx: float  # remote clock [us], centred on its resolution step
    tx: float
    host_rx_ns: int


@dataclass(frozen=True, slots=True)
class _Fit:
    ref_x: float  # remote clock [us] of the reference (newest sample's receive stamp)
    ref_host_ns: int  # host stamp the relative coordinates are measured from
    a: float  # line: u = a + s * x, with x = (remote - ref_x) * 1000 [ns], u = host - ref_host - x [ns]
    s: float
    s_lo: float  # feasible slope interval (all lines consistent with the window)
    s_hi: float
    b_lo: float  # slopes the uncertainty bound considers (feasible and statistically plausible)
    b_hi: float
    hull_a: Hull  # upper hull of request points (x, u): lines pass above
    hull_b: Hull  # lower hull of reply points: lines pass below
    x_min: float
    x_max: float
    n: int
    min_rtt_ns: int
    t_host_ns: int


_REFIT_LAZY_AFTER = 64  # exchanges in the window before refits may be spaced out (refit_interval_ns)


class _TwoWayLine:
    """Shared engine: a remote clock [us] against the host clock [ns] from two-way exchanges.

    The remote stamps of one exchange may be two (receive, transmit: the Teensy) or one
    (MAVLink TIMESYNC's tc1: pass it as both).
    """

    def __init__(
        self,
        *,
        resolution_us: float,
        window_s: float,
        max_samples: int,
        min_span_s: float,
        max_drift_ppm: float,
        rtt_limit_ns: int,
        rtt_limit_inclusive: bool,
        wander_ppm: float,
        prior_drift_uncertainty_ppm: float,
        path_asymmetry_ns: float,
        jump_margin_ns: int,
        refit_interval_ns: int = 0,
    ) -> None:
        if window_s <= 0 or max_samples < 2 or min_span_s < 0 or max_drift_ppm <= 0 or rtt_limit_ns <= 0:
            raise ValueError(
                "need window_s > 0, max_samples >= 2, min_span_s >= 0, max_drift_ppm > 0, rtt_limit_ns > 0"
            )
        self._half_res = 0.5 * resolution_us
        self._window_ns = int(window_s * 1e9)
        self._max_samples = max_samples
        self._min_span_ns = int(min_span_s * 1e9)
        self._s_max = max_drift_ppm * 1e-6
        self._rtt_limit_ns = rtt_limit_ns
        self._rtt_inclusive = rtt_limit_inclusive
        self._wander = wander_ppm * 1e-6
        self._prior_unc = prior_drift_uncertainty_ppm * 1e-6
        self._asym = float(path_asymmetry_ns)
        self._jump_margin_ns = jump_margin_ns
        self._refit_ns = refit_interval_ns
        self._fit_newest_ns = 0  # host receive time of the newest exchange in the current fit
        self._samples: deque[_Sample] = deque()
        self._fit: _Fit | None = None
        self._dirty = False
        self._prior_s: float | None = None
        self.resets = 0
        self.last_reset_reason = ResetReason.NONE
        self.rejected_rtt = 0
        self.rejected_invalid = 0
        self.accepted = 0
        self.samples_since_reset = 0
        self.samples_since_gap = 0
        self.last_host_rx_ns: int | None = None

    # -- input ------------------------------------------------------------------------------

    def add(self, host_tx_ns: int, remote_rx_us: float, remote_tx_us: float, host_rx_ns: int) -> ExchangeStatus:
        host_tx_ns, host_rx_ns = int(host_tx_ns), int(host_rx_ns)
        rx = float(remote_rx_us) + self._half_res  # stamps truncate: the true instant is half a step later on average
        tx = float(remote_tx_us) + self._half_res
        slack_ns = 2000.0 * self._half_res
        turnaround_ns = (tx - rx) * 1000.0
        net_rtt = (host_rx_ns - host_tx_ns) - turnaround_ns
        if host_rx_ns < host_tx_ns or turnaround_ns < 0.0 or net_rtt < -slack_ns:
            self.rejected_invalid += 1
            return ExchangeStatus.REJECTED_INVALID
        if net_rtt > self._rtt_limit_ns or (self._rtt_inclusive and net_rtt >= self._rtt_limit_ns):
            self.rejected_rtt += 1
            return ExchangeStatus.REJECTED_RTT

        status = ExchangeStatus.ACCEPTED
        if self._samples and rx < self._samples[-1].tx - self._half_res * 2.0:
            if rx > self._samples[-1].tx - _REORDER_US:
                # A little back: a reply overtaken by a newer one (UDP), not a reboot.
                self.rejected_invalid += 1
                return ExchangeStatus.REJECTED_INVALID
            self.reset(ResetReason.REBOOT)
            status = ExchangeStatus.RESET_REBOOT
        elif self._samples and self._contradicts(host_tx_ns, rx, tx, host_rx_ns):
            self.reset(ResetReason.JUMP)
            status = ExchangeStatus.RESET_JUMP

        if self.last_host_rx_ns is not None and host_rx_ns - self.last_host_rx_ns > 5_000_000_000:
            self.samples_since_gap = 0
        self.last_host_rx_ns = host_rx_ns
        self._samples.append(_Sample(host_tx_ns, rx, tx, host_rx_ns))
        self.accepted += 1
        self.samples_since_reset += 1
        self.samples_since_gap += 1
        self._trim_by_age()
        self._dirty = True
        return status

    def reset(self, reason: ResetReason) -> None:
        """Forget the window; keep the last drift as a prior (the crystal is the same after a reboot)."""
        fit = self.fit()
        if fit is not None and fit.x_max - fit.x_min >= self._min_span_ns:
            self._prior_s = fit.s
        self._samples.clear()
        self._fit = None
        self._dirty = False
        self.resets += 1
        self.last_reset_reason = reason
        self.samples_since_reset = 0
        self.samples_since_gap = 0

    def _contradicts(self, host_tx_ns: int, rx: float, tx: float, host_rx_ns: int) -> bool:
        """True if the exchange needs a negative one-way delay far beyond the current bound: a clock step."""
        fit = self.fit()
        if fit is None:
            return False
        out_delay = self._host_ns_f(fit, rx) - host_tx_ns
        in_delay = host_rx_ns - self._host_ns_f(fit, tx)
        bound = max(self.bound_ns(fit, rx), self.bound_ns(fit, tx))
        return min(out_delay, in_delay) < -(bound + self._jump_margin_ns)

    def _trim_by_age(self) -> None:
        newest = self._samples[-1].host_rx_ns
        while len(self._samples) > self._max_samples:
            self._samples.popleft()
        # Drop samples older than the window only once the samples inside it span half the window:
        # after a long gap (unplug) those from before it stay and carry the drift measured there
        # (bounded by max_samples anyway).
        horizon = newest - self._window_ns
        inside = next((smp.host_rx_ns for smp in self._samples if smp.host_rx_ns >= horizon), newest)
        if newest - inside < max(self._min_span_ns, self._window_ns // 2):
            return
        while len(self._samples) > 2 and self._samples[0].host_rx_ns < horizon:
            self._samples.popleft()

    # -- fitting ----------------------------------------------------------------------------

    def fit(self) -> _Fit | None:
        if (
            self._dirty
            and self._fit is not None
            and len(self._samples) >= _REFIT_LAZY_AFTER
            and self._samples[-1].host_rx_ns - self._fit_newest_ns < self._refit_ns
        ):
            # Settled, and the fit is younger than the refit interval: the newest exchanges change the line
            # by far less than its bound (the window holds minutes); refit at most every interval.
            return self._fit
        if self._dirty:
            self._fit_newest_ns = self._samples[-1].host_rx_ns if self._samples else 0
            self._fit = self._compute_fit()
            while self._fit is not None and self._fit.s_lo > self._fit.s_hi and len(self._samples) > 1:
                # No line fits the whole window: the frequency moved more than the delays allow. Drop
                # the oldest quarter and refit (cheap; rare).
                for _ in range(max(1, len(self._samples) // 4)):
                    if len(self._samples) > 1:
                        self._samples.popleft()
                self._fit = self._compute_fit()
            self._dirty = False
        return self._fit

    def _compute_fit(self) -> _Fit | None:
        """The line midway between the two envelopes over the window, its feasible slopes and hulls."""
        if not self._samples:
            return None
        newest = self._samples[-1]
        ref_x, ref_h = newest.rx, newest.host_rx_ns
        pts_a: list[tuple[float, float]] = []
        pts_b: list[tuple[float, float]] = []
        min_rtt = math.inf
        for smp in self._samples:
            xa = (smp.rx - ref_x) * 1000.0
            pts_a.append((xa, float(smp.host_tx_ns - ref_h) - xa))
            xb = (smp.tx - ref_x) * 1000.0
            pts_b.append((xb, float(smp.host_rx_ns - ref_h) - xb))
            min_rtt = min(min_rtt, (smp.host_rx_ns - smp.host_tx_ns) - (smp.tx - smp.rx) * 1000.0)
        hull_a = upper_hull(pts_a)
        hull_b = lower_hull(pts_b)
        hulls = (Hull.of(hull_a), Hull.of(hull_b))
        # margin(s) is concave and linear between the hulls' edge slopes (where either side's supporting
        # point changes): its maximum and its level crossings are found exactly among them.
        knots = sorted(hulls[0].slopes + hulls[1].slopes)
        x_min = min(hull_a[0][0], hull_b[0][0])
        x_max = max(hull_a[-1][0], hull_b[-1][0])
        slack = 2000.0 * self._half_res

        def lower(s: float) -> float:  # lowest intercept a line of slope s may have (above every request)
            return max(u - s * x for x, u in hull_a)

        def upper(s: float) -> float:  # highest intercept (below every reply)
            return min(u - s * x for x, u in hull_b)

        def margin(s: float) -> float:
            return upper(s) - lower(s)

        lo, hi = -self._s_max, self._s_max
        span_ok = x_max - x_min >= self._min_span_ns
        if not span_ok and self._prior_s is not None:
            # Short span after a reset: the drift measured before it bounds the slope (same crystal).
            lo = max(lo, self._prior_s - self._prior_unc)
            hi = min(hi, self._prior_s + self._prior_unc)
        s_best = concave_argmax(margin, knots, lo, hi)
        if margin(s_best) < -slack and (lo, hi) != (-self._s_max, self._s_max):
            lo, hi = -self._s_max, self._s_max  # the prior is wrong (temperature moved): let the data speak
            s_best = concave_argmax(margin, knots, lo, hi)
        if margin(s_best) < -slack:
            return _Fit(ref_x, ref_h, 0.0, s_best, 1.0, -1.0, 1.0, -1.0, *hulls, x_min, x_max, 0, 0, 0)

        s_lo = lo if margin(lo) >= -slack else level_crossing(margin, knots, s_best, lo, -slack)
        s_hi = hi if margin(hi) >= -slack else level_crossing(margin, knots, s_best, hi, -slack)
        b_lo, b_hi = s_lo, s_hi
        if span_ok:
            s_bucket, sigma = bucket_slope(pts_a, pts_b, 0.5 * (lower(s_best) + upper(s_best)), s_best)
            s = min(max(s_bucket, s_lo), s_hi)
            # The bound considers the lines whose slope is within 4 standard errors of ours (and feasible):
            # every feasible slope would be a pure worst case, several times wider than the slope's real error.
            b_lo, b_hi = max(s_lo, s - 4.0 * sigma), min(s_hi, s + 4.0 * sigma)
        else:
            # Too short a span to measure the drift: use the prior (or none) within what the data allow.
            s = min(max(self._prior_s if self._prior_s is not None else 0.0, s_lo), s_hi)
        a = 0.5 * (lower(s) + upper(s)) + 0.5 * self._asym
        return _Fit(
            ref_x,
            ref_h,
            a,
            s,
            s_lo,
            s_hi,
            b_lo,
            b_hi,
            *hulls,
            x_min,
            x_max,
            len(self._samples),
            int(min_rtt),
            newest.host_rx_ns,
        )

    # -- queries ----------------------------------------------------------------------------

    @staticmethod
    def _host_ns_f(fit: _Fit, remote_us: float) -> float:
        """Host time [ns] relative to nothing (absolute), as float, of a remote time [us]."""
        x = (remote_us - fit.ref_x) * 1000.0
        return fit.ref_host_ns + fit.a + (1.0 + fit.s) * x

    def host_ns(self, remote_us: float) -> int:
        fit = self._require()
        x = (float(remote_us) - fit.ref_x) * 1000.0
        return fit.ref_host_ns + round(fit.a + (1.0 + fit.s) * x)

    def remote_us(self, host_ns: int) -> float:
        fit = self._require()
        u = float(int(host_ns) - fit.ref_host_ns)
        x = (u - fit.a) / (1.0 + fit.s)
        return fit.ref_x + x / 1000.0

    def bound_ns(self, fit: _Fit, remote_us: float) -> float:
        """Worst-case error [ns] of the estimate at a remote time: extreme consistent lines + wander."""
        x = (float(remote_us) - fit.ref_x) * 1000.0
        est = fit.a + fit.s * x

        # The highest line below every reply point, at x, is concave in its slope s and its derivative is
        # x minus the x of the supporting hull vertex: the best slope is that of the lower hull's edge over
        # x (-inf left of the hull, +inf right of it), clipped to [b_lo, b_hi] (a concave function of one
        # variable peaks on an interval at its unconstrained peak, clipped). Likewise the lowest line above
        # every request point, with the upper hull's edge (whose slopes fall with x). Exact, and O(hull).
        inf = math.inf
        s_top = min(max(support_slope(fit.hull_b, x, -inf, inf), fit.b_lo), fit.b_hi)
        s_bot = min(max(support_slope(fit.hull_a, x, inf, -inf), fit.b_lo), fit.b_hi)
        top = min(u + s_top * (x - xb) for xb, u in fit.hull_b.points)  # highest consistent line of slope s_top, at x
        bottom = max(u + s_bot * (x - xa) for xa, u in fit.hull_a.points)
        spread = max(top - est, est - bottom, 0.0)
        outside = max(x - fit.x_max, fit.x_min - x, 0.0)
        return spread + 2000.0 * self._half_res + abs(0.5 * self._asym) + self._wander * outside

    def uncertainty_ns(self, remote_us: float) -> int:
        return math.ceil(self.bound_ns(self._require(), remote_us))

    def _require(self) -> _Fit:
        fit = self.fit()
        if fit is None or fit.n == 0:
            raise ClockNotSyncedError("no clock exchange accepted yet")
        return fit

    def estimate(self, settled: bool) -> ClockEstimate:
        fit = self.fit()
        if fit is None or fit.n == 0:
            return _INVALID
        return ClockEstimate(
            valid=True,
            settled=settled,
            n_used=fit.n,
            ref_clock_us=fit.ref_x,
            ref_host_ns=fit.ref_host_ns + round(fit.a),
            drift_ppm=(1.0 / (1.0 + fit.s) - 1.0) * 1e6,
            uncertainty_ns=math.ceil(self.bound_ns(fit, fit.ref_x)),
            t_host_ns=fit.t_host_ns,
            min_rtt_ns=fit.min_rtt_ns,
            span_s=(fit.x_max - fit.x_min) * 1e-9,
            resets=self.resets,
        )

    def counters(self) -> dict[str, int]:
        """Accepted / rejected / reset counts since construction, and the samples in the window."""
        return {
            "accepted": self.accepted,
            "rejected_rtt": self.rejected_rtt,
            "rejected_invalid": self.rejected_invalid,
            "resets": self.resets,
            "in_window": len(self),
        }

    def span_ns(self) -> float:
        fit = self.fit()
        return 0.0 if fit is None else fit.x_max - fit.x_min

    def __len__(self) -> int:
        return len(self._samples)


class _TwoWayClock:
    """What both two-way clock filters expose from their line: the estimate, a reset and the counts.

    Subclasses set ``self._line`` and say when they are ``settled`` (when to drop to the slow rate).
    """

    _line: _TwoWayLine

    @property
    def settled(self) -> bool:
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the window (the remote rebooted); the last drift is kept as a prior (same crystal)."""
        self._line.reset(ResetReason.CALLER)

    def estimate(self) -> ClockEstimate:
        """The current line and its worst-case bound at the newest exchange (``valid`` False before any)."""
        return self._line.estimate(self.settled)

    @property
    def resets(self) -> int:
        return self._line.resets

    @property
    def last_reset_reason(self) -> ResetReason:
        return self._line.last_reset_reason

    @property
    def counters(self) -> dict[str, int]:
        """Accepted / rejected / reset counts since construction, and the samples in the window."""
        return self._line.counters()
