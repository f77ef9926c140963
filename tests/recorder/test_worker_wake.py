"""The recorder worker's sleep: a nudge from another thread, the links' input while watching, the timer."""

from __future__ import annotations

import os
import threading
import time

from icgt.recorder.worker_wake import WorkerWake


def test_a_nudge_set_before_the_wait_ends_it_at_once_and_clear_resets_it() -> None:
    wake = WorkerWake()
    try:
        wake.set()
        wake.set()  # twice: still one wake
        t0 = time.monotonic()
        assert wake.wait(5.0) is False  # a nudge, not input
        assert time.monotonic() - t0 < 2.0
        wake.clear()
        t0 = time.monotonic()
        wake.wait(0.05)
        assert time.monotonic() - t0 >= 0.04  # cleared: the timer ends this one
    finally:
        wake.close()


def test_input_on_a_watched_descriptor_ends_the_wait_after_the_minimum_gap() -> None:
    wake = WorkerWake()
    r, w = os.pipe()
    try:
        os.write(w, b"x")  # already readable: the wait still lasts the minimum gap
        t0 = time.monotonic()
        assert wake.wait(5.0, [r], min_gap_s=0.03) is True
        elapsed = time.monotonic() - t0
        assert 0.025 <= elapsed < 2.0
        os.read(r, 1)
        # Not watched: the same input does not end the wait.
        os.write(w, b"x")
        t0 = time.monotonic()
        assert wake.wait(0.05) is False
        assert time.monotonic() - t0 >= 0.04
    finally:
        wake.close()
        os.close(r)
        os.close(w)


def test_a_nudge_from_another_thread_ends_a_watching_wait() -> None:
    wake = WorkerWake()
    r, w = os.pipe()
    try:
        threading.Timer(0.05, wake.set).start()
        t0 = time.monotonic()
        assert wake.wait(10.0, [r]) is False
        assert time.monotonic() - t0 < 5.0
    finally:
        wake.close()
        os.close(r)
        os.close(w)


def test_a_descriptor_closed_by_its_link_leaves_the_timer_and_the_nudge() -> None:
    wake = WorkerWake()
    r, w = os.pipe()
    os.close(r)
    os.close(w)
    try:
        t0 = time.monotonic()
        assert wake.wait(0.05, [r]) is False  # EBADF: waited out on the nudge alone, no error
        assert time.monotonic() - t0 >= 0.04
    finally:
        wake.close()
    wake.set()  # after close: nothing written anywhere, no error
    wake.close()


def test_thread_input_ends_a_wait_that_watches_it_after_the_minimum_gap() -> None:
    """A MAVLink link read by its own thread (serial, TCP) hands a message over: the worker watching for a
    frame's telemetry wakes for it, as it does for a datagram on the UDP socket it pumps."""
    wake = WorkerWake()
    try:
        wake.watch_thread_input = True
        threading.Timer(0.05, wake.thread_input).start()
        t0 = time.monotonic()
        assert wake.wait(10.0, [wake.thread_input_fd], min_gap_s=0.01) is True
        assert time.monotonic() - t0 < 5.0
        wake.clear()  # the signal is reset with the nudge
        t0 = time.monotonic()
        assert wake.wait(0.05, [wake.thread_input_fd]) is False
        assert time.monotonic() - t0 >= 0.04
    finally:
        wake.close()


def test_thread_input_is_not_signalled_while_not_watched() -> None:
    """Between frames the reader thread's messages cost no system call and leave nothing that would end the
    next watching wait at once."""
    wake = WorkerWake()
    try:
        for _ in range(100):
            wake.thread_input()  # not watched: nothing written
        wake.watch_thread_input = True
        t0 = time.monotonic()
        assert wake.wait(0.05, [wake.thread_input_fd]) is False
        assert time.monotonic() - t0 >= 0.04
    finally:
        wake.close()
    wake.watch_thread_input = True
    wake.thread_input()  # after close(): ignored, no write to a reused descriptor number
