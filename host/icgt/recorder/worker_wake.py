"""The recorder worker's sleep between two steps, and what ends it early.

The worker sleeps until its next step time (`icgt.recorder.step_schedule`). Two things end the sleep early:
- a nudge from another thread (a capture started, the recorder stops): `set()`;
- while a frame is expected, input on the links the worker reads itself (the device's serial port, the
  MAVLink UDP socket): the exposure record or the telemetry sample after mid-exposure is handled when it
  arrives, not at the next timed retry (10 ms later). Never sooner than `min_gap_s` after the last step, so
  that a stream of small transfers (the device's 500 Hz range samples, 1 ms apart) wakes it a few times per
  frame, not once per transfer;
- while a frame is expected, input that a link's own reader thread handed over (a serial or TCP MAVLink
  link: `thread_input()`), on the same terms: the worker watches `thread_input_fd` like a link's descriptor.
  The reader signals only while `watch_thread_input` is set, so a link read by its thread costs no system
  call per message between frames.

A `threading.Event` cannot be waited on together with file descriptors, so the nudge is a non-blocking pipe
(the self-pipe pattern) and the sleep one `select()` over it and the links' descriptors.
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Sequence

__all__ = ["WorkerWake"]


class WorkerWake:
    """An event that the worker can wait on together with the links' file descriptors."""

    def __init__(self) -> None:
        self._r, self._w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self._in_r, self._in_w = os.pipe2(os.O_NONBLOCK | os.O_CLOEXEC)
        self.watch_thread_input = False
        """Set by the worker while it watches `thread_input_fd` (read by other threads without a lock: a stale
        value costs one spare byte in the pipe or one message handled at the timed step instead)."""
        self._closed = False
        self._lock = threading.Lock()  # a set() racing close() must not write to a reused descriptor number

    def set(self) -> None:
        """Wake the worker (from any thread); it stays woken until `clear()`."""
        with self._lock, contextlib.suppress(BlockingIOError):  # a full pipe is already set
            if not self._closed:
                os.write(self._w, b"\x01")

    @property
    def thread_input_fd(self) -> int:
        """The descriptor that `thread_input()` makes readable: the worker passes it to `wait()` as a link's."""
        return self._in_r

    def thread_input(self) -> None:
        """A link's reader thread handed input to the worker (any thread): ends a wait that watches
        `thread_input_fd`, after its minimum gap; nothing is done while `watch_thread_input` is not set."""
        if not self.watch_thread_input:
            return
        with self._lock, contextlib.suppress(BlockingIOError):
            if not self._closed:
                os.write(self._in_w, b"\x01")

    def clear(self) -> None:
        """Reset the nudge and the thread-input signal (the worker, after each wait)."""
        for fd in (self._r, self._in_r):
            with contextlib.suppress(BlockingIOError, OSError):
                while os.read(fd, 4096):
                    pass

    def wait(self, timeout_s: float, fds: Sequence[int] = (), min_gap_s: float = 0.0) -> bool:
        """Sleep up to `timeout_s`: until `set()`, or, after `min_gap_s`, one of `fds` is readable.

        Returns True when a descriptor in `fds` ended the sleep (the caller reads it), False on a nudge or
        the timeout. A descriptor closed meanwhile by its link (a reconnect) only makes the sleep wait on
        the nudge alone."""
        timeout_s = max(0.0, timeout_s)
        if not fds:
            self._select([self._r], timeout_s)
            return False
        gap = min(max(0.0, min_gap_s), timeout_s)
        start = time.monotonic()
        if gap > 0.0 and self._select([self._r], gap):
            return False
        remaining = max(0.0, timeout_s - (time.monotonic() - start))
        try:
            ready, _, _ = select.select([self._r, *fds], [], [], remaining)
        except (OSError, ValueError):  # a descriptor closed under us: the nudge and the timer only
            self._select([self._r], remaining)
            return False
        return any(fd != self._r for fd in ready)

    def _select(self, fds: list[int], timeout_s: float) -> bool:
        ready, _, _ = select.select(fds, [], [], timeout_s)
        return bool(ready)

    def close(self) -> None:
        """Release the pipe (after the worker's last wait)."""
        with self._lock:
            if not self._closed:
                self._closed = True
                for fd in (self._r, self._w, self._in_r, self._in_w):
                    os.close(fd)
