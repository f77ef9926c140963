"""Rate limits for what a flood of bad input would otherwise multiply: replies and log lines.

`TokenBucket` bounds how often something may happen (COMMAND_ACKs to commands we refuse). `ThrottledLog`
logs the first occurrence of a kind of event at once and then at most one line per period that says how
many more there were since the last line and in total, with the latest detail: nothing is dropped
silently, and a flood of a thousand refused commands costs a handful of log lines.
"""

from __future__ import annotations

import logging
import threading

__all__ = ["ThrottledLog", "TokenBucket"]


class TokenBucket:
    """At most ``rate_hz`` events per second on average, ``burst`` at once. Thread-safe."""

    def __init__(self, rate_hz: float, burst: int) -> None:
        if rate_hz <= 0 or burst < 1:
            raise ValueError(f"rate_hz {rate_hz} must be > 0 and burst {burst} >= 1")
        self._rate_per_ns = rate_hz / 1e9
        self._burst = float(burst)
        self._tokens = float(burst)
        self._last_ns: int | None = None
        self._lock = threading.Lock()

    def allow(self, now_ns: int) -> bool:
        with self._lock:
            if self._last_ns is not None:
                self._tokens = min(self._burst, self._tokens + (now_ns - self._last_ns) * self._rate_per_ns)
            self._last_ns = now_ns
            if self._tokens >= 1.0:
                self._tokens -= 1.0
                return True
            return False


class ThrottledLog:
    """One kind of event (``what``), logged at once the first time, then summarised every ``period_s``.

    `report` from any thread; `tick` (periodically, e.g. from a worker) writes a pending summary when the
    events have stopped coming; `total` counts every event."""

    def __init__(
        self, logger: logging.Logger, what: str, *, period_s: float = 5.0, level: int = logging.WARNING
    ) -> None:
        self._log = logger
        self._what = what
        self._period_ns = int(period_s * 1e9)
        self._level = level
        self._lock = threading.Lock()
        self.total = 0
        self._pending = 0
        self._pending_detail = ""
        self._last_line_ns: int | None = None

    def report(self, now_ns: int, detail: str) -> None:
        with self._lock:
            self.total += 1
            if self._last_line_ns is None or now_ns - self._last_line_ns >= self._period_ns:
                pending, self._pending = self._pending, 0
                self._last_line_ns = now_ns
                line = self._line(detail, pending + 1)
            else:
                self._pending += 1
                self._pending_detail = detail
                return
        self._log.log(self._level, "%s", line)

    def tick(self, now_ns: int) -> None:
        with self._lock:
            if not self._pending or self._last_line_ns is None or now_ns - self._last_line_ns < self._period_ns:
                return
            line = self._line(self._pending_detail, self._pending)
            self._pending = 0
            self._last_line_ns = now_ns
        self._log.log(self._level, "%s", line)

    def flush(self) -> None:
        """Write what is pending now (at shutdown)."""
        with self._lock:
            if not self._pending:
                return
            line = self._line(self._pending_detail, self._pending)
            self._pending = 0
        self._log.log(self._level, "%s", line)

    def _line(self, detail: str, n: int) -> str:
        if self.total == 1:
            return f"{self._what}: {detail}"
        return f"{self._what}: {n} since the last report ({self.total} in total), latest: {detail}"
