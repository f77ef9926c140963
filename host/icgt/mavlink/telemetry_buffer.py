"""A bounded buffer of one telemetry stream's samples, sorted by the autopilot's boot clock, to interpolate from.

`TelemetryStore` (`icgt.mavlink.telemetry`) keeps one per stream; the geotagger brackets a mid-exposure in it.
"""

from __future__ import annotations

import bisect
from array import array
from typing import Any, Generic, Protocol, TypeVar

from icgt.mavlink.sample_codec import SampleCodec

__all__ = ["TelemetryBuffer"]


class _Stamped(Protocol):
    @property
    def boot_us(self) -> int: ...


S = TypeVar("S", bound=_Stamped)


def _check_bounds(capacity: int, retain_us: int | None) -> None:
    if capacity < 2:
        raise ValueError("capacity must be at least 2")
    if retain_us is not None and retain_us <= 0:
        raise ValueError("retain_us must be positive")


class TelemetryBuffer(Generic[S]):
    """A bounded buffer of one stream's samples kept sorted by ``boot_us`` (one thread: the synchroniser's).

    Pushing is amortised O(1) for samples in order (O(n) for the rare late one); `bracket` is O(log n).
    When a stamp goes back by more than ``reboot_backstep_us`` the autopilot rebooted and its boot clock
    restarted: the buffer is cleared (counted in ``resets``). A sample with the stamp of one already held
    replaces it (the same message arriving twice through two routes).

    Two bounds, both kept: at most ``capacity`` samples, and (when ``retain_us`` is set) only samples
    stamped within ``retain_us`` of the newest one. Samples past either bound are counted in ``expired``.
    """

    def __init__(
        self,
        capacity: int = 4096,
        *,
        reboot_backstep_us: int = 2_000_000,
        retain_us: int | None = None,
        codec: SampleCodec[S] | None = None,
    ) -> None:
        _check_bounds(capacity, retain_us)
        self.capacity = capacity
        self.retain_us = retain_us
        self.expired = 0
        self._backstep = reboot_backstep_us
        self._keys = array("q")  # boot_us of each entry, sorted: 8 bytes each (a list of ints takes 36)
        self._items: list[Any] = []  # the samples, or their bytes with a codec
        self._codec = codec
        self._head = 0  # entries before it are dropped (deleted in batches)
        self.resets = 0
        self.late = 0
        self.replaced = 0

    def __len__(self) -> int:
        return len(self._keys) - self._head

    @property
    def held(self) -> int:
        """Entries held in memory: the samples kept and the trimmed ones not deleted yet (see _trim)."""
        return len(self._keys)

    def _out(self, item: Any) -> S:
        codec = self._codec
        return item if codec is None else codec.decode(item)

    def push(self, sample: S) -> None:
        key = sample.boot_us
        item: Any = sample if self._codec is None else self._codec.encode(sample)
        keys, items = self._keys, self._items
        if len(keys) > self._head:
            last = keys[-1]
            if key < last:
                if key + self._backstep < last:
                    self._clear_all()
                    self.resets += 1
                else:
                    self._insert_late(key, item)
                    return
            elif key == last:
                items[-1] = item
                self.replaced += 1
                return
        keys.append(key)
        items.append(item)
        if len(keys) - self._head > self.capacity or (
            self.retain_us is not None and keys[self._head] < key - self.retain_us
        ):  # the only ways the head moves (see _trim)
            self._trim()

    def _insert_late(self, key: int, item: Any) -> None:
        i = bisect.bisect_left(self._keys, key, lo=self._head)
        if i < len(self._keys) and self._keys[i] == key:
            self._items[i] = item
            self.replaced += 1
            return
        too_old = self.retain_us is not None and key < self._keys[-1] - self.retain_us
        if too_old or (i == self._head and len(self._keys) - self._head >= self.capacity):
            self.expired += 1  # older than everything kept in a full buffer, or than the retention
            return
        self._keys.insert(i, key)
        self._items.insert(i, item)
        self.late += 1
        self._trim()

    def _trim(self) -> None:
        excess = len(self._keys) - self._head - self.capacity
        if self.retain_us is not None and len(self._keys) > self._head:
            expired = bisect.bisect_left(self._keys, self._keys[-1] - self.retain_us, lo=self._head) - self._head
            excess = max(excess, expired)
        if excess > 0:
            self._head += excess
            self.expired += excess
        # Deleted in batches of a quarter of what is kept (amortised O(1) per push), not of the capacity:
        # a stream slower than MAX_STREAM_RATE_HZ never fills a quarter of it (GPS at 10 Hz would hold 31 min
        # beyond its 12 min retention, SYSTEM_TIME at 2 Hz hours; issue 30's soak).
        if self._head >= max(64, (len(self._keys) - self._head) // 4):
            del self._keys[: self._head]
            del self._items[: self._head]
            self._head = 0

    def _clear_all(self) -> None:
        del self._keys[:]
        self._items.clear()
        self._head = 0

    def clear(self) -> None:
        self._clear_all()

    def set_bounds(self, capacity: int, retain_us: int | None) -> None:
        """Change both bounds (a longer retention keeps what is held; a shorter one trims at once)."""
        _check_bounds(capacity, retain_us)
        self.capacity = capacity
        self.retain_us = retain_us
        self._trim()

    def bracket(self, t_us: int) -> tuple[S | None, S | None]:
        """(latest sample with boot_us <= t_us, earliest sample with boot_us >= t_us).

        Both are the same sample when one is stamped exactly ``t_us``; either is None past the ends."""
        keys = self._keys
        i = bisect.bisect_right(keys, t_us, lo=self._head)
        before = self._items[i - 1] if i > self._head else None
        if before is not None and keys[i - 1] == t_us:
            same = self._out(before)
            return same, same
        after = self._items[i] if i < len(keys) else None
        return (
            None if before is None else self._out(before),
            None if after is None else self._out(after),
        )

    def latest(self) -> S | None:
        item = self._items[-1] if len(self._items) > self._head else None
        return None if item is None else self._out(item)

    def oldest(self) -> S | None:
        item = self._items[self._head] if len(self._items) > self._head else None
        return None if item is None else self._out(item)

    def samples(self) -> list[S]:
        """A copy of the samples held, oldest first."""
        items = self._items[self._head :]
        return items if self._codec is None else [self._out(it) for it in items]

    def between(self, t0_us: int, t1_us: int) -> list[S]:
        """Samples with t0_us <= boot_us <= t1_us, oldest first."""
        lo = bisect.bisect_left(self._keys, t0_us, lo=self._head)
        hi = bisect.bisect_right(self._keys, t1_us, lo=self._head)
        items = self._items[lo:hi]
        return items if self._codec is None else [self._out(it) for it in items]
