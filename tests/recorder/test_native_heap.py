"""The C heap trim (icgt.recorder.native_heap): free memory held in a thread's malloc arena goes back."""

from __future__ import annotations

import ctypes
import threading
from pathlib import Path

from icgt.recorder.native_heap import NativeHeapTrimmer, malloc_trim

_LIBC = ctypes.CDLL(None)
_LIBC.malloc.restype = ctypes.c_void_p
_LIBC.malloc.argtypes = [ctypes.c_size_t]
_LIBC.free.argtypes = [ctypes.c_void_p]
_LIBC.memset.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_size_t]


def _anon_kib() -> int:
    for line in Path("/proc/self/smaps_rollup").read_text().splitlines():
        if line.startswith("Anonymous:"):
            return int(line.split()[1])
    raise AssertionError("no Anonymous line")


def _fill_and_free_in_thread(n: int, size: int, held: list[int]) -> None:
    """In a new thread (its own arena): n blocks written, all freed but the last (which pins the arena's top)."""

    def work() -> None:
        blocks = [_LIBC.malloc(size) for _ in range(n)]
        for b in blocks:
            _LIBC.memset(b, 1, size)
        for b in blocks[:-1]:
            _LIBC.free(b)
        held.append(blocks[-1])

    t = threading.Thread(target=work)
    t.start()
    t.join()


def test_trim_gives_back_a_thread_arenas_free_memory() -> None:
    malloc_trim()
    before = _anon_kib()
    held: list[int] = []
    _fill_and_free_in_thread(20_000, 2000, held)  # 38 MiB written, freed below a live block
    try:
        filled = _anon_kib()
        assert filled - before > 20_000, "the freed blocks stay resident (glibc keeps them in the arena)"
        malloc_trim()
        trimmed = _anon_kib()
        assert filled - trimmed > 20_000, f"trim released only {filled - trimmed} KiB"
    finally:
        for b in held:
            _LIBC.free(b)


def test_trimmer_waits_its_interval() -> None:
    trimmer = NativeHeapTrimmer(interval_s=30.0)
    trimmer.maybe_trim(0)
    trimmer.maybe_trim(29_000_000_000)
    assert trimmer.trims == 0
    trimmer.maybe_trim(30_000_000_000)
    trimmer.maybe_trim(31_000_000_000)
    expected = 0 if malloc_trim() is None else 1
    assert trimmer.trims == expected
