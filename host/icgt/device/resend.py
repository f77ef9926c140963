"""Retransmission on the host: find every gap in the device's sequence numbers, ask RESEND for it,
take the frames that come back (flagged retransmit, with their original seq) and count exactly,
by kind, what the device could no longer send (its RESEND_LOST answers, SPEC.md §3).

`ResendTracker` runs on the device link's reader thread: `observe` for every frame decoded
(it says whether the frame is new and must be delivered, or a duplicate), `tick` a few times a
second (it sends the requests and notices unanswered ones). Sequence numbers are unwrapped to a
64-bit count so ranges never straddle the 2^32 wrap in the bookkeeping.

Accounting: a gap is open until every sequence number in it either came back or was covered by
the device's RESEND_LOST for a request naming it. When the device says fewer frames are gone
than are still missing, some resent frames were themselves lost on the way: the missing runs are
asked again (a few attempts), and whatever stays missing beyond the device's count is counted
`unknown`. A device reboot (its sequence restarts) ends every open gap as `unknown`: its history
is gone with it.
"""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

from icgt.protocol import Received
from icgt.protocol.messages import FrameFlags, Message, Resend, ResendLost

_RETRANSMIT = int(FrameFlags.RETRANSMIT)  # an int: IntFlag's & costs a microsecond per frame

MAX_REQUEST = 0xFFFF  # RESEND.count is a u16
MAX_IN_FLIGHT = 4  # the device queues 8 requests; keep well inside it
REQUEST_TIMEOUT_NS = 2_000_000_000  # no RESEND_LOST by then (plus 1 ms per 10 frames asked): ask again
MAX_ATTEMPTS = 4
MAX_RETRY_RUNS = 32  # missing runs of one request asked again one by one, at most
_WRAP = 1 << 32
_HALF = 1 << 31


def _signed(d: int) -> int:
    d &= 0xFFFFFFFF
    return d - _WRAP if d >= _HALF else d


@dataclass
class _Request:
    first: int  # unwrapped
    count: int
    attempt: int
    sent_ns: int = 0


@dataclass
class LossReport:
    """What one request's answer said could not be recovered (first/last: device sequence numbers)."""

    first_seq: int
    count: int
    resent: int
    exposures: int
    pps: int
    samples: int
    other: int
    unknown: int

    @property
    def lost(self) -> int:
        return self.exposures + self.pps + self.samples + self.other + self.unknown


@dataclass
class ResendCounters:
    """Cumulative, for the log's counters and `icgt info`."""

    gaps: int = 0  # gaps found (each asked for)
    missing: int = 0  # sequence numbers found missing
    requests: int = 0  # RESEND requests sent (attempts included)
    recovered: int = 0  # frames that came back
    duplicates: int = 0  # retransmits of frames already held (dropped, not delivered)
    lost_exposures: int = 0
    lost_pps: int = 0
    lost_samples: int = 0
    lost_other: int = 0  # STATUS, ACK, LOG, ...: never kept by the device, cumulative or stale
    lost_unknown: int = 0
    unanswered: int = 0  # requests that timed out
    history_lost: list[LossReport] = field(default_factory=list)

    def as_dict(self) -> dict[str, int]:
        return {
            "resend_gaps": self.gaps,
            "resend_missing": self.missing,
            "resend_requests": self.requests,
            "resend_recovered": self.recovered,
            "resend_duplicates": self.duplicates,
            "resend_unanswered": self.unanswered,
            "lost_exposures": self.lost_exposures,
            "lost_pps": self.lost_pps,
            "lost_samples": self.lost_samples,
            "lost_other": self.lost_other,
            "lost_unknown": self.lost_unknown,
        }


class _Missing:
    """Disjoint sorted half-open intervals of unwrapped sequence numbers."""

    def __init__(self) -> None:
        self.starts: list[int] = []
        self.ends: list[int] = []

    def add(self, a: int, b: int) -> None:
        if a >= b:
            return
        i = bisect.bisect_left(self.ends, a)
        j = bisect.bisect_right(self.starts, b)
        if i < j:
            a = min(a, self.starts[i])
            b = max(b, self.ends[j - 1])
        self.starts[i:j] = [a]
        self.ends[i:j] = [b]

    def remove_point(self, s: int) -> bool:
        i = bisect.bisect_right(self.starts, s) - 1
        if i < 0 or s >= self.ends[i]:
            return False
        a, b = self.starts[i], self.ends[i]
        new_s, new_e = [], []
        if a < s:
            new_s.append(a)
            new_e.append(s)
        if s + 1 < b:
            new_s.append(s + 1)
            new_e.append(b)
        self.starts[i : i + 1] = new_s
        self.ends[i : i + 1] = new_e
        return True

    def runs_in(self, a: int, b: int) -> list[tuple[int, int]]:
        out = []
        i = max(0, bisect.bisect_right(self.starts, a) - 1)
        while i < len(self.starts) and self.starts[i] < b:
            lo, hi = max(a, self.starts[i]), min(b, self.ends[i])
            if lo < hi:
                out.append((lo, hi))
            i += 1
        return out

    def remove_range(self, a: int, b: int) -> None:
        for lo, hi in self.runs_in(a, b):
            i = bisect.bisect_right(self.starts, lo) - 1
            s0, e0 = self.starts[i], self.ends[i]
            new_s, new_e = [], []
            if s0 < lo:
                new_s.append(s0)
                new_e.append(lo)
            if hi < e0:
                new_s.append(hi)
                new_e.append(e0)
            self.starts[i : i + 1] = new_s
            self.ends[i : i + 1] = new_e

    def first(self) -> int | None:
        return self.starts[0] if self.starts else None

    def total(self) -> int:
        return sum(e - s for s, e in zip(self.starts, self.ends, strict=True))

    def clear(self) -> None:
        self.starts.clear()
        self.ends.clear()


class ResendTracker:
    """Gap bookkeeping and RESEND requests for one device link (thread-safe; meant for its reader thread)."""

    def __init__(
        self,
        send: Callable[[Message], object],
        *,
        on_loss: Callable[[LossReport], None] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
        timeout_ns: int = REQUEST_TIMEOUT_NS,
    ) -> None:
        self._send = send
        self._on_loss = on_loss
        self._clock = clock
        self._timeout_ns = timeout_ns
        self._lock = threading.Lock()
        self._missing = _Missing()
        self._queue: deque[_Request] = deque()
        self._in_flight: dict[tuple[int, int], _Request] = {}  # (wire first_seq, count) -> request
        self._last_wire: int | None = None  # the last live seq, and its unwrapped value
        self._last_u = 0
        self._first_u: int | None = None  # the first live frame's unwrapped seq
        self.counters = ResendCounters()

    # ------------------------------------------------------------------ frames in
    def _unwrap(self, seq: int) -> int:
        assert self._last_wire is not None
        return self._last_u + _signed(seq - self._last_wire)

    def observe(self, received: Received) -> bool:
        """One decoded frame; False if it is a retransmit of something already held (drop it)."""
        with self._lock:
            seq = received.seq
            if received.flags & _RETRANSMIT:
                if self._last_wire is None:
                    self.counters.duplicates += 1
                    return False
                if self._missing.remove_point(self._unwrap(seq)):
                    self.counters.recovered += 1
                    return True
                self.counters.duplicates += 1
                return False
            if self._last_wire is None:
                self._last_wire, self._last_u = seq, seq + _WRAP
                self._first_u = self._last_u
            else:
                d = (seq - self._last_wire - 1) & 0xFFFFFFFF
                if d >= _HALF:  # from the past: the device rebooted, its history went with it
                    self._device_restarted()
                    self._last_wire, self._last_u = seq, seq + _WRAP
                    self._first_u = self._last_u
                else:
                    u = self._last_u + 1 + d
                    if d:
                        self._add_gap(self._last_u + 1, u)
                    self._last_wire, self._last_u = seq, u
            if isinstance(received.message, ResendLost):
                self._answered(received.message)
            return True

    def recover_from(self, seq: int) -> int:
        """Ask for everything from device seq `seq` up to the first frame this link saw (a restarted host:
        DEVICE_STATE.host_received_seq). Returns how many sequence numbers that is (0: nothing to ask)."""
        with self._lock:
            if self._first_u is None or self._last_wire is None:
                return 0
            first_wire = (self._first_u - _WRAP) & 0xFFFFFFFF
            d = (first_wire - seq) & 0xFFFFFFFF
            if d == 0 or d >= _HALF:
                return 0
            self._add_gap(self._first_u - d, self._first_u)
            return d

    # ------------------------------------------------------------------ requests out
    def tick(self) -> None:
        """Send queued requests (a few in flight at a time) and requeue those left unanswered."""
        with self._lock:
            now = self._clock()
            for key, req in list(self._in_flight.items()):
                if now - req.sent_ns > self._timeout_ns + req.count * 100_000:
                    del self._in_flight[key]
                    self.counters.unanswered += 1
                    self._retry_or_give_up(req, None)
            while self._queue and len(self._in_flight) < MAX_IN_FLIGHT:
                req = self._queue.popleft()
                if not self._missing.runs_in(req.first, req.first + req.count):
                    continue  # everything in it came back already
                wire = req.first & 0xFFFFFFFF
                try:
                    self._send(Resend(first_seq=wire, count=req.count))
                except Exception:  # the link is down: ask again when it is back
                    self._queue.appendleft(req)
                    return
                req.sent_ns = now
                self.counters.requests += 1
                self._in_flight[(wire, req.count)] = req

    def link_restored(self) -> None:
        """The port was reopened: the device forgot the requests it had; ask them again."""
        with self._lock:
            for req in self._in_flight.values():
                self._queue.appendleft(_Request(req.first, req.count, req.attempt))
            self._in_flight.clear()

    def received_through(self) -> int | None:
        """The device seq before which every frame is held or accounted for (HOST_RECEIVED), if any."""
        with self._lock:
            if self._last_wire is None:
                return None
            first = self._missing.first()
            u = first if first is not None else self._last_u + 1
            return (u - _WRAP) & 0xFFFFFFFF

    @property
    def missing_now(self) -> int:
        with self._lock:
            return self._missing.total()

    def counter_dict(self) -> dict[str, int]:
        with self._lock:
            return self.counters.as_dict() | {"resend_missing_now": self._missing.total()}

    # ------------------------------------------------------------------ internals
    def _add_gap(self, a: int, b: int) -> None:
        self.counters.gaps += 1
        self.counters.missing += b - a
        self._missing.add(a, b)
        for s in range(a, b, MAX_REQUEST):
            self._queue.append(_Request(s, min(MAX_REQUEST, b - s), 0))

    def _answered(self, msg: ResendLost) -> None:
        req = self._in_flight.pop((msg.first_seq, msg.count), None)
        if req is None:
            return  # an answer to a request already given up (or not ours)
        lost = msg.exposures + msg.pps + msg.samples + msg.other + msg.unknown
        self._retry_or_give_up(req, msg, lost)

    def _retry_or_give_up(self, req: _Request, msg: ResendLost | None, lost: int = 0) -> None:
        a, b = req.first, req.first + req.count
        runs = self._missing.runs_in(a, b)
        still = sum(hi - lo for lo, hi in runs)
        if still == 0 and msg is None:
            return
        if msg is not None and still <= lost:
            self._account(a, req.count, msg, extra_unknown=0)
            self._missing.remove_range(a, b)
            return
        if req.attempt + 1 < MAX_ATTEMPTS and len(runs) <= MAX_RETRY_RUNS:
            for lo, hi in runs:  # exactly what is still missing: the new answers count only that
                self._queue.append(_Request(lo, hi - lo, req.attempt + 1))
            return
        if msg is None:
            msg = ResendLost(first_seq=a & 0xFFFFFFFF, count=req.count)
            lost = 0
        self._account(a, req.count, msg, extra_unknown=still - lost)
        self._missing.remove_range(a, b)

    def _account(self, a: int, count: int, msg: ResendLost, *, extra_unknown: int) -> None:
        c = self.counters
        c.lost_exposures += msg.exposures
        c.lost_pps += msg.pps
        c.lost_samples += msg.samples
        c.lost_other += msg.other
        c.lost_unknown += msg.unknown + extra_unknown
        report = LossReport(
            a & 0xFFFFFFFF,
            count,
            msg.resent,
            msg.exposures,
            msg.pps,
            msg.samples,
            msg.other,
            msg.unknown + extra_unknown,
        )
        if report.lost and self._on_loss is not None:
            self._on_loss(report)

    def _device_restarted(self) -> None:
        still = self._missing.total()
        if still:
            self.counters.lost_unknown += still
            if self._on_loss is not None:
                first = self._missing.first() or 0
                self._on_loss(LossReport(first & 0xFFFFFFFF, still, 0, 0, 0, 0, 0, still))
        self._missing.clear()
        self._queue.clear()
        self._in_flight.clear()
