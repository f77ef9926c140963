"""Synthetic clocks and links for the clock filters' tests and benchmark (no I/O; seeded numpy RNG).

Axes (as in hil_sim/README.md): the host monotonic clock [ns] is the truth of time here; UTC [us]
= ``utc0_us + (host_ns - host_t0_ns) / 1000``; a remote clock (the device's microsecond counter or
the autopilot's boot clock) [us] = ``offset_us + tau * 1e6 + drift_ppm * tau + 0.5 * rate * tau**2``
with ``tau`` the host seconds since ``host_t0_ns`` and ``rate`` the drift's change in ppm per
second (a crystal warming up). Remote stamps are truncated to whole microseconds, as the
firmware's counter and the autopilots' ``hrt_absolute_time`` / ``micros64`` are.

USB full speed (the device link): a request waits for the next 1 ms frame of the host's
controller (the frame grid is fixed in host time), then reaches the device after a small
uniform jitter; the device holds its reply a random 0..1 ms (as the firmware does), then it
leaves with the host's next IN poll (the next frame boundary) and reaches the reading thread
after a floor, a uniform jitter and an exponential scheduler tail.
The two directions have different floors (an asymmetry no two-way method can observe: it
appears as a bias of half the difference) and different jitter shapes. Occasional spikes of
milliseconds to tens of milliseconds hit one direction.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "MavlinkLinkModel",
    "RemoteClockTruth",
    "SimExchange",
    "SimPpsEdge",
    "SimSystemTime",
    "SimTimesync",
    "UsbLinkModel",
    "exchange_schedule",
    "simulate_exchanges",
    "simulate_pps",
    "simulate_system_time",
    "simulate_timesync",
]


@dataclass(frozen=True, slots=True)
class RemoteClockTruth:
    """The true relation of a remote clock [us] to the host monotonic clock [ns]."""

    offset_us: float = 12_345_678.25  # remote clock at host_t0_ns
    drift_ppm: float = 50.0  # + = the remote clock gains on the host
    drift_rate_ppm_per_s: float = 0.0  # thermal change of the drift
    host_t0_ns: int = 1_000_000_000_000
    utc0_us: int = 1_750_000_000_000_000  # UTC at host_t0_ns (2025-06-15)

    def remote_us(self, host_ns: float) -> float:
        """Remote clock [us] (continuous, before truncation) at a host time [ns]."""
        tau = (host_ns - self.host_t0_ns) * 1e-9
        return self.offset_us + tau * 1e6 + self.drift_ppm * tau + 0.5 * self.drift_rate_ppm_per_s * tau * tau

    def host_ns(self, remote_us: float) -> float:
        """Host time [ns] at which the remote clock reads ``remote_us`` (Newton on the quadratic)."""
        tau = (remote_us - self.offset_us) / (1e6 + self.drift_ppm)
        for _ in range(4):
            f = self.offset_us + tau * 1e6 + self.drift_ppm * tau + 0.5 * self.drift_rate_ppm_per_s * tau * tau
            df = 1e6 + self.drift_ppm + self.drift_rate_ppm_per_s * tau
            tau -= (f - remote_us) / df
        return self.host_t0_ns + tau * 1e9

    def utc_us(self, host_ns: float) -> float:
        """True UTC [us] at a host time [ns]."""
        return self.utc0_us + (host_ns - self.host_t0_ns) / 1000.0


@dataclass(frozen=True, slots=True)
class UsbLinkModel:
    """USB full-speed CDC link, both directions quantised to the host controller's 1 ms frames. Times in us."""

    frame_us: float = 1000.0
    frame_phase_us: float = 317.0  # where the frame grid sits relative to host_t0_ns
    out_on_frames: bool = True  # False: requests go out at once (bulk OUT on a real controller), replies still wait
    out_floor_us: float = 20.0  # request: write() to the controller
    out_jitter_us: float = 50.0  # uniform 0..this after the frame
    in_floor_us: float = 45.0  # reply: controller interrupt -> tty layer -> reading thread
    in_jitter_us: float = 50.0
    in_tail_us: float = 30.0  # exponential mean: the reading thread's wake-up
    turnaround_min_us: float = 5.0  # device: request received -> reply framed, if sent at once
    reply_hold_max_us: float = 1000.0  # the firmware holds each reply uniform 0..this (TimeSyncResponder)
    spike_probability: float = 0.02
    spike_min_us: float = 2_000.0
    spike_max_us: float = 40_000.0


@dataclass(frozen=True, slots=True)
class MavlinkLinkModel:
    """Serial / radio MAVLink link for TIMESYNC (the autopilot stamps tc1 when it handles the request). Times in us."""

    out_floor_us: float = 800.0
    out_jitter_us: float = 3_000.0  # uniform
    in_floor_us: float = 1_200.0  # reply waits for the autopilot's send loop, then the wire
    in_jitter_us: float = 6_000.0
    in_tail_us: float = 2_000.0  # exponential mean
    spike_probability: float = 0.05
    spike_min_us: float = 5_000.0
    spike_max_us: float = 50_000.0


@dataclass(frozen=True, slots=True)
class SimExchange:
    """One TIME_SYNC exchange as the host would see it, plus truth for diagnostics."""

    host_tx_ns: int
    device_rx_us: int
    device_tx_us: int
    host_rx_ns: int
    spike: bool


@dataclass(frozen=True, slots=True)
class SimTimesync:
    """One MAVLink TIMESYNC round trip: ts1 (host send, echoed) [ns], tc1 (autopilot boot) [ns], host receive [ns]."""

    ts1_ns: int
    tc1_ns: int
    host_rx_ns: int


@dataclass(frozen=True, slots=True)
class SimPpsEdge:
    device_us: int
    pps_count: int
    utc_us: int  # the whole second it marks


@dataclass(frozen=True, slots=True)
class SimSystemTime:
    """SYSTEM_TIME as sent (time_unix_usec 0 before the GPS fix), and the host time it arrives."""

    time_unix_usec: int
    time_boot_ms: int
    host_rx_ns: int


def exchange_schedule(
    duration_s: float,
    rng: np.random.Generator,
    *,
    start_ns: int = 1_000_000_000_000,
    warmup_s: float = 5.0,
    warmup_hz: float = 5.0,
    steady_hz: float = 1.0,
    dither: float = 0.1,
    gaps: Sequence[tuple[float, float]] = (),
) -> list[int]:
    """Host send times [ns]: ``warmup_hz`` for ``warmup_s``, then ``steady_hz``; intervals dithered by +-dither.

    ``gaps``: (start_s, length_s) windows with no exchanges (an unplugged cable).
    """
    out: list[int] = []
    t = 0.0
    while t < duration_s:
        if not any(g0 <= t < g0 + gl for g0, gl in gaps):
            out.append(start_ns + round(t * 1e9))
        rate = warmup_hz if t < warmup_s else steady_hz
        t += (1.0 / rate) * (1.0 + dither * (2.0 * float(rng.random()) - 1.0))
    return out


def _next_boundary_ns(t_ns: float, phase_ns: float, frame_ns: float) -> float:
    if frame_ns <= 0.0:
        return t_ns
    return phase_ns + (math.floor((t_ns - phase_ns) / frame_ns) + 1.0) * frame_ns


def simulate_exchanges(
    send_times_ns: Sequence[int], truth: RemoteClockTruth, link: UsbLinkModel, rng: np.random.Generator
) -> list[SimExchange]:
    """Device TIME_SYNC exchanges for the given host send times [ns]."""
    frame_ns = link.frame_us * 1000.0
    phase_ns = truth.host_t0_ns + link.frame_phase_us * 1000.0
    out: list[SimExchange] = []
    for host_tx in send_times_ns:
        spike = float(rng.random()) < link.spike_probability
        spike_ns = float(rng.uniform(link.spike_min_us, link.spike_max_us)) * 1000.0 if spike else 0.0
        spike_out = spike and float(rng.random()) < 0.5
        t = host_tx + link.out_floor_us * 1000.0 + (spike_ns if spike_out else 0.0)
        sent = _next_boundary_ns(t, phase_ns, frame_ns) if link.out_on_frames else t
        arrive = sent + float(rng.uniform(0.0, link.out_jitter_us)) * 1000.0
        rx_true = truth.remote_us(arrive)
        tx_true = rx_true + link.turnaround_min_us + float(rng.uniform(0.0, link.reply_hold_max_us))
        leave = _next_boundary_ns(truth.host_ns(tx_true), phase_ns, frame_ns)
        host_rx = (
            leave
            + link.in_floor_us * 1000.0
            + float(rng.uniform(0.0, link.in_jitter_us)) * 1000.0
            + (float(rng.exponential(link.in_tail_us)) * 1000.0 if link.in_tail_us > 0 else 0.0)
            + (spike_ns if spike and not spike_out else 0.0)
        )
        out.append(SimExchange(host_tx, math.floor(rx_true), math.floor(tx_true), math.ceil(host_rx), spike))
    return out


def simulate_timesync(
    send_times_ns: Sequence[int], truth: RemoteClockTruth, link: MavlinkLinkModel, rng: np.random.Generator
) -> list[SimTimesync]:
    """MAVLink TIMESYNC round trips for the given host send times [ns]; tc1 has 1 us steps like PX4 / ArduPilot."""
    out: list[SimTimesync] = []
    for ts1 in send_times_ns:
        spike = float(rng.random()) < link.spike_probability
        spike_ns = float(rng.uniform(link.spike_min_us, link.spike_max_us)) * 1000.0 if spike else 0.0
        spike_out = spike and float(rng.random()) < 0.5
        handled = ts1 + (link.out_floor_us + float(rng.uniform(0.0, link.out_jitter_us))) * 1000.0
        handled += spike_ns if spike_out else 0.0
        boot_us = truth.remote_us(handled)
        host_rx = (
            handled
            + (link.in_floor_us + float(rng.uniform(0.0, link.in_jitter_us))) * 1000.0
            + float(rng.exponential(link.in_tail_us)) * 1000.0
            + (spike_ns if spike and not spike_out else 0.0)
        )
        out.append(SimTimesync(ts1, math.floor(boot_us) * 1000, math.ceil(host_rx)))
    return out


def simulate_pps(
    truth: RemoteClockTruth,
    n_edges: int,
    rng: np.random.Generator,
    *,
    first_utc_s: int | None = None,
    isr_jitter_ns: float = 300.0,
    first_count: int = 1,
) -> list[SimPpsEdge]:
    """PPS edges at whole UTC seconds, stamped on the device clock (interrupt latency 0..isr_jitter_ns, truncated)."""
    if first_utc_s is None:
        first_utc_s = truth.utc0_us // 1_000_000 + 1
    out: list[SimPpsEdge] = []
    for i in range(n_edges):
        utc_us = (first_utc_s + i) * 1_000_000
        host_ns = truth.host_t0_ns + (utc_us - truth.utc0_us) * 1000.0
        dev = truth.remote_us(host_ns) + float(rng.uniform(0.0, isr_jitter_ns)) / 1000.0
        out.append(SimPpsEdge(math.floor(dev), first_count + i, utc_us))
    return out


def simulate_system_time(
    truth: RemoteClockTruth,
    host_times_ns: Sequence[int],
    rng: np.random.Generator,
    *,
    fix_after_s: float = 10.0,
    latency_us: float = 3_000.0,
) -> list[SimSystemTime]:
    """SYSTEM_TIME from an autopilot whose boot clock is ``truth``: UTC 0 until the GPS fix, ms boot stamps."""
    out: list[SimSystemTime] = []
    for h in host_times_ns:
        boot_us = truth.remote_us(h)
        fixed = (h - truth.host_t0_ns) * 1e-9 >= fix_after_s
        unix = math.floor(truth.utc_us(h)) if fixed else 0
        rx = h + float(rng.uniform(0.5, 1.0)) * latency_us * 1000.0
        out.append(SimSystemTime(unix, math.floor(boot_us / 1000.0), math.ceil(rx)))
    return out
