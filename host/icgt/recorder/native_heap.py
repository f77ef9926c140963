"""Gives the C heap's free pages back to the system now and then (glibc's malloc_trim), during a recording.

Why (issue 30's soak): with the telemetry retention shortened to 90 s so that the warm-up ends after 2 min,
the recorder's Python objects (sys.getallocatedblocks) and glibc's main arena stayed flat, but its RSS still
rose about 0.4 MiB/min: the per-thread malloc arenas of the reader and writer threads (buffers of the
serial and UDP reads, chunk compression) grew from 1-2 MiB to 3-4 MiB each, most of it free chunks that
glibc keeps (it gives a thread arena's memory back only from its top). ``malloc_trim(0)`` releases the free
pages of every arena (madvise), so the resident set follows what is in use. glibc has no setting that does
this by itself; the standard library does not call it; so it is called here through ctypes, once every
``interval_s`` (a few ms for the recorder's heap). Elsewhere than glibc (musl, macOS) it does nothing.

The trim releases whole free pages only. What it cannot release, free chunks smaller than a page between
used ones, still grew in the thread arenas after the warm-up (soak with the 90 s retention, 2026-12-07:
in use flat at 15.4 MB, free in the arenas 6.1 -> 7.0 MB over minutes 8-16, about 0.1 MiB/min; Python's
traced allocations +0.03 MB over 10 min). With one arena for every thread (`limit_malloc_arenas(1)`,
glibc's M_ARENA_MAX, as MALLOC_ARENA_MAX=1 would set) the free memory settled at 3.9-4.0 MB from minute
12 on. One arena means one lock for the threads' C allocations; most of the recorder's allocations are made
holding the GIL anyway, so they were serialised before (its latency with one arena: benchmarks/capture_rates.py).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os

__all__ = ["TRIM_INTERVAL_S", "NativeHeapTrimmer", "limit_malloc_arenas", "malloc_trim"]

log = logging.getLogger(__name__)

TRIM_INTERVAL_S = 30.0
"""How often the recorder trims the C heap [s]."""


def _glibc_function(name: str, argtypes: list[type], restype: type) -> ctypes._CFuncPtr | None:  # type: ignore[name-defined]
    """The C library's function `name`, typed; None where there is no C library or no such function."""
    lib = ctypes.util.find_library("c")
    if lib is None:
        return None
    try:
        func = getattr(ctypes.CDLL(lib), name)
    except (OSError, AttributeError):
        return None  # not glibc
    func.argtypes = argtypes
    func.restype = restype
    return func


_TRIM = _glibc_function("malloc_trim", [ctypes.c_size_t], ctypes.c_int)

_M_ARENA_MAX = -8  # glibc's malloc.h
# mallopt exists in musl too but ignores M_ARENA_MAX: taken only where malloc_trim (glibc's) is there.
_MALLOPT = _glibc_function("mallopt", [ctypes.c_int, ctypes.c_int], ctypes.c_int) if _TRIM is not None else None


def limit_malloc_arenas(count: int) -> bool | None:
    """At most `count` malloc arenas from now on (threads started later share them); call it before the
    threads start. True when glibc took it, None where unsupported; a MALLOC_ARENA_MAX set in the
    environment wins (the user's choice)."""
    if _MALLOPT is None:
        return None
    if os.environ.get("MALLOC_ARENA_MAX"):
        return False
    return bool(_MALLOPT(_M_ARENA_MAX, max(1, count)))


def malloc_trim() -> bool | None:
    """Releases the free memory of every malloc arena; True if some was released, None where unsupported."""
    if _TRIM is None:
        return None
    return bool(_TRIM(0))


class NativeHeapTrimmer:
    """Calls `malloc_trim` at most once every ``interval_s`` of the caller's clock [ns]."""

    def __init__(self, interval_s: float = TRIM_INTERVAL_S) -> None:
        self.interval_ns = int(interval_s * 1e9)
        self._next_ns: int | None = None
        self.trims = 0

    def maybe_trim(self, now_ns: int) -> None:
        if self._next_ns is None:
            self._next_ns = now_ns + self.interval_ns
            return
        if now_ns < self._next_ns:
            return
        self._next_ns = now_ns + self.interval_ns
        if malloc_trim() is not None:
            self.trims += 1
