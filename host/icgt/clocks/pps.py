"""Device clock [us] -> UTC [us] from the GPS receiver's PPS edges timestamped by the firmware."""

from __future__ import annotations

import math
from collections import deque
from dataclasses import asdict, dataclass
from enum import Enum

from icgt.clocks.two_way import ClockNotSyncedError

__all__ = ["PpsEstimate", "PpsStatus", "PpsUtcMapper"]


class PpsStatus(Enum):
    """What ``add_pps`` did with one edge."""

    ACCEPTED = "accepted"
    REJECTED_INTERVAL = "rejected_interval"  # not a whole number of seconds after the last good edge
    RESET_REBOOT = "reset_reboot"  # device clock or edge count went backwards
    RESET_RESTART = "reset_restart"  # edges consistent among themselves but not with the fit: re-locked


@dataclass(frozen=True, slots=True)
class PpsEstimate:
    """State of the PPS mapping. ``utc_label_s`` is the UTC second of the edge at ``ref_device_us`` (0 = unlabelled)."""

    locked: bool
    labelled: bool
    n_edges: int
    ref_device_us: float
    utc_label_s: int
    drift_ppm: float  # device clock rate relative to UTC (+ = device gains)
    residual_rms_us: float
    uncertainty_us: float
    rejected: int
    relabelled: int
    resets: int

    def to_dict(self) -> dict[str, float | int | bool]:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class _PpsLine:
    k_ref: int  # second index of the newest edge
    t_ref: float  # fitted device time [us] of that edge
    slope: float  # device us per UTC second
    rms: float  # residual rms [us]
    sxx: float  # sum of squared second offsets (for the line's leverage)
    mean_x: float  # mean second offset from k_ref


class PpsUtcMapper:
    """Device clock [us] -> UTC [us since the Unix epoch] from GPS PPS edges on the device clock.

    Each PPS edge marks a whole UTC second; which one comes from a coarse UTC (the host's UTC
    estimate mapped to the edge, or HELLO's ``rtc_utc_us_at_boot + t_us``) that must be right to
    within +-0.4 s. A line (least squares, device time against the edge's second index) over
    the last ``max_edges`` edges averages the 1 us stamp quantisation and the interrupt latency.
    Edges not a whole number of seconds after the last accepted edge (within ``tolerance_us``
    before the fit exists, ``locked_tolerance_us`` after) are rejected; ``lock_edges`` accepted
    edges give lock, lost when no edge came for ``lost_after_s`` (``locked(device_us)``).
    """

    def __init__(
        self,
        *,
        max_edges: int = 16,
        lock_edges: int = 3,
        tolerance_us: float = 500.0,
        locked_tolerance_us: float = 50.0,
        lost_after_s: float = 2.5,
        pps_offset_ns: float = 0.0,
        wander_ppm: float = 0.5,
        max_coarse_uncertainty_us: float = 400_000.0,
    ) -> None:
        """``pps_offset_ns``: known delay from the true second to the edge stamp (cable, receiver), subtracted."""
        if max_edges < 3 or lock_edges < 2:
            raise ValueError("max_edges >= 3 and lock_edges >= 2")
        self._max_edges = max_edges
        self._lock_edges = lock_edges
        self._tol = tolerance_us
        self._locked_tol = locked_tolerance_us
        self._lost_after_us = lost_after_s * 1e6
        self._offset_us = pps_offset_ns / 1000.0
        self._wander = wander_ppm * 1e-6
        self._max_coarse_unc = max_coarse_uncertainty_us
        self._edges: deque[tuple[int, float]] = deque()  # (second index since the first edge, device us centred)
        self._line: _PpsLine | None = None
        self._label0: int | None = None  # UTC second of index 0
        self._last_count: int | None = None
        self._run = 0  # accepted edges since the (re)start
        self._candidates: list[float] = []  # rejected edges that agree with each other
        self._relabel_votes: list[int] = []
        self.rejected = 0
        self.relabelled = 0
        self.resets = 0

    def add_pps(
        self,
        device_us: int,
        pps_count: int,
        coarse_utc_us: float | None = None,
        coarse_uncertainty_us: float = 0.0,
    ) -> PpsStatus:
        """One PPS message: edge [us, device clock], edges since boot, optional coarse UTC [us] of that instant.

        ``coarse_uncertainty_us`` above ``max_coarse_uncertainty_us`` means the coarse UTC cannot name
        the second: the edge still counts for the fit, the label waits for a better one.
        """
        t = float(device_us) + 0.5 - self._offset_us  # stamps truncate: centre; remove the known delay
        status = PpsStatus.ACCEPTED
        went_back = self._edges and t < self._edges[-1][1]
        if went_back or (self._last_count is not None and pps_count < self._last_count):
            self._reset()
            status = PpsStatus.RESET_REBOOT
        self._last_count = pps_count
        if not self._edges:
            self._edges.append((0, t))
            self._run = 1
            self._label(0, coarse_utc_us, coarse_uncertainty_us)
            return status
        k_last, t_last = self._edges[-1]
        rate = self._line.slope if self._line is not None else 1e6
        dt = t - t_last
        k = round(dt / rate)
        tol = self._locked_tol if self._line is not None and len(self._edges) >= self._lock_edges else self._tol
        if k < 1 or abs(dt - k * rate) > tol:
            # A glitch (noise edge, bounce) or the receiver re-acquired with another phase.
            self.rejected += 1
            if self._restart_if_consistent(t):
                self._label(len(self._edges) - 1, coarse_utc_us, coarse_uncertainty_us)
                return PpsStatus.RESET_RESTART
            return PpsStatus.REJECTED_INTERVAL
        self._candidates.clear()
        self._edges.append((k_last + k, t))
        while len(self._edges) > self._max_edges:
            self._edges.popleft()
        self._run += 1
        self._refit()
        self._label(k_last + k, coarse_utc_us, coarse_uncertainty_us)
        return status

    def _restart_if_consistent(self, t: float) -> bool:
        """Three rejected edges in a row, 1 s apart among themselves: restart the fit on them."""
        if self._candidates and abs(t - self._candidates[-1] - 1e6) > self._tol:
            self._candidates.clear()
        self._candidates.append(t)
        if len(self._candidates) < 3:
            return False
        cands = list(self._candidates)
        self._reset()
        for i, tc in enumerate(cands):
            self._edges.append((i, tc))
        self._run = len(cands)
        self._refit()
        return True

    def reset(self) -> None:
        """Forget every edge (e.g. HELLO says the device rebooted)."""
        self._reset()
        self._last_count = None

    def _reset(self) -> None:
        self._edges.clear()
        self._line = None
        self._label0 = None
        self._run = 0
        self._candidates.clear()
        self._relabel_votes.clear()
        self.resets += 1

    def _label(self, k: int, coarse_utc_us: float | None, unc_us: float) -> None:
        if coarse_utc_us is None or unc_us > self._max_coarse_unc:
            return
        label0 = round(coarse_utc_us / 1e6) - k  # the edge is at a whole second; the coarse UTC names it
        if self._label0 is None:
            self._label0 = label0
            return
        if label0 == self._label0:
            self._relabel_votes.clear()
            return
        # Three consistent disagreements in a row: the first label came from a bad coarse UTC.
        if self._relabel_votes and self._relabel_votes[-1] != label0:
            self._relabel_votes.clear()
        self._relabel_votes.append(label0)
        if len(self._relabel_votes) >= 3:
            self._label0 = label0
            self._relabel_votes.clear()
            self.relabelled += 1

    def _refit(self) -> None:
        n = len(self._edges)
        if n < 2:
            self._line = None
            return
        k_ref, t_last = self._edges[-1]
        xs = [float(k - k_ref) for k, _ in self._edges]
        ys = [t - t_last for _, t in self._edges]
        mx = sum(xs) / n
        my = sum(ys) / n
        sxx = sum((x - mx) ** 2 for x in xs)
        slope = sum((x - mx) * (y - my) for x, y in zip(xs, ys, strict=True)) / sxx
        intercept = my - slope * mx
        res = [y - (intercept + slope * x) for x, y in zip(xs, ys, strict=True)]
        rms = math.sqrt(sum(r * r for r in res) / (n - 2)) if n > 2 else 0.0
        self._line = _PpsLine(k_ref, t_last + intercept, slope, rms, sxx, mx)

    def locked(self, device_us: float | None = None) -> bool:
        """Lock: ``lock_edges`` good edges and, if ``device_us`` [device clock] is given, the last one recent."""
        if self._line is None or self._run < self._lock_edges:
            return False
        return device_us is None or float(device_us) - self._edges[-1][1] <= self._lost_after_us

    @property
    def labelled(self) -> bool:
        return self._label0 is not None

    def _require(self) -> tuple[_PpsLine, int]:
        if self._line is None or self._label0 is None:
            raise ClockNotSyncedError("no labelled PPS fit yet (needs two edges and a coarse UTC)")
        return self._line, self._label0

    def device_to_utc_us(self, device_us: float) -> float:
        """UTC [us since the Unix epoch] of a device time [us] (a float: ~0.25 us steps at today's epoch)."""
        return self.device_to_utc_ns(device_us) / 1000.0

    def device_to_utc_ns(self, device_us: float) -> int:
        """UTC [ns since the Unix epoch] of a device time [us], exact integer arithmetic for the seconds."""
        line, label0 = self._require()
        sec = (float(device_us) - line.t_ref) / line.slope  # UTC seconds after the newest edge
        whole = math.floor(sec)
        return (label0 + line.k_ref + whole) * 1_000_000_000 + round((sec - whole) * 1e9)

    def utc_to_device_us(self, utc_us: float) -> float:
        """Device time [us] of a UTC [us since the Unix epoch]."""
        line, label0 = self._require()
        sec = utc_us / 1e6 - (label0 + line.k_ref)
        return line.t_ref + sec * line.slope

    def uncertainty_us(self, device_us: float) -> float:
        """About a 95 % bound [us]: 2 sigma of the fitted line there, + 0.5 us stamp step, + wander past the edges."""
        line, _ = self._require()
        n = len(self._edges)
        sigma = max(line.rms, 0.29)  # never below the 1 us truncation's own spread (1/sqrt(12))
        x = (float(device_us) - line.t_ref) / line.slope
        lever = 1.0 / n + (x - line.mean_x) ** 2 / line.sxx
        outside = max(float(device_us) - self._edges[-1][1], self._edges[0][1] - float(device_us), 0.0)
        return 2.0 * sigma * math.sqrt(lever) + 0.5 + self._wander * outside

    def estimate(self) -> PpsEstimate:
        """State for the log."""
        if self._line is None:
            return PpsEstimate(
                False, False, len(self._edges), 0.0, 0, 0.0, 0.0, math.inf, self.rejected, self.relabelled, self.resets
            )
        line = self._line
        return PpsEstimate(
            locked=self.locked(),
            labelled=self._label0 is not None,
            n_edges=len(self._edges),
            ref_device_us=line.t_ref,
            utc_label_s=(self._label0 + line.k_ref) if self._label0 is not None else 0,
            drift_ppm=(line.slope / 1e6 - 1.0) * 1e6,
            residual_rms_us=line.rms,
            uncertainty_us=self.uncertainty_us(line.t_ref) if self._label0 is not None else math.inf,
            rejected=self.rejected,
            relabelled=self.relabelled,
            resets=self.resets,
        )
