"""Pairing MAVLink TIMESYNC replies with this host's own requests (one rule, live and offline).

The host sends ``TIMESYNC(tc1=0, ts1=host_tx_ns)``; the autopilot answers ``tc1 = its boot time [ns]``
with ``ts1`` echoed. A reply is taken when it comes from the autopilot's component, has ``tc1 != 0``,
echoes a request this host sent (and that is still pending: each is used once), and arrives within
``timeout_ns`` of it. Requests are forgotten when the autopilot (re)appears or reboots (their answers
would mix two boot clocks) and after the timeout, where they count as unanswered.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

__all__ = ["TimesyncPairing", "TimesyncReply"]


class TimesyncReply(NamedTuple):
    """One TIMESYNC round trip: host send time [ns], the autopilot's boot clock [ns] when it answered, receipt [ns]."""

    host_tx_ns: int
    autopilot_tc1_ns: int
    host_rx_ns: int

    @property
    def rtt_ns(self) -> int:
        return self.host_rx_ns - self.host_tx_ns


@dataclass
class TimesyncPairing:
    """Pending requests and the counters of what became of them."""

    timeout_ns: int = 1_000_000_000
    pending: dict[int, int] = field(default_factory=dict)  # ts1 -> host send time (the same value)
    sent: int = 0
    answered: int = 0
    unanswered: int = 0
    foreign: int = 0  # replies to requests that are not ours (or no longer pending)

    def request_sent(self, ts1_ns: int) -> None:
        self.pending[ts1_ns] = ts1_ns
        self.sent += 1

    def forget(self) -> None:
        """The autopilot (re)appeared: requests sent before are not answered on the same clock."""
        self.unanswered += len(self.pending)
        self.pending.clear()

    def expire(self, now_ns: int) -> None:
        if not self.pending:
            return
        stale = [ts1 for ts1, tx in self.pending.items() if now_ns - tx > self.timeout_ns]
        for ts1 in stale:
            del self.pending[ts1]
        self.unanswered += len(stale)

    def reply(self, msg: Any, rx_ns: int) -> TimesyncReply | None:
        """The round trip if `msg` (a TIMESYNC from the autopilot) answers one of our pending requests."""
        tc1, ts1 = int(msg.tc1), int(msg.ts1)
        if tc1 == 0:
            return None  # the autopilot's own request, not an answer
        self.expire(rx_ns)
        tx = self.pending.pop(ts1, None)
        if tx is None or rx_ns < tx:
            self.foreign += 1
            return None
        self.answered += 1
        return TimesyncReply(tx, tc1, rx_ns)
