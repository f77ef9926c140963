"""The C heap trim (icgt.recorder.native_heap): free memory held in a thread's malloc arena goes back."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
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


_ARENA_PROBE = """
import ctypes, os, sys, tempfile, threading
from icgt.recorder.native_heap import limit_malloc_arenas
if sys.argv[1] == "limit":
    assert limit_malloc_arenas(1) is True
libc = ctypes.CDLL(None)
libc.malloc.restype = ctypes.c_void_p
libc.malloc.argtypes = [ctypes.c_size_t]
libc.free.argtypes = [ctypes.c_void_p]
libc.fopen.restype = ctypes.c_void_p
libc.fopen.argtypes = [ctypes.c_char_p, ctypes.c_char_p]
libc.malloc_info.argtypes = [ctypes.c_int, ctypes.c_void_p]
libc.fclose.argtypes = [ctypes.c_void_p]
go = threading.Barrier(4)
def work():
    go.wait()
    blocks = [libc.malloc(4096) for _ in range(200)]
    for b in blocks:
        libc.free(b)
threads = [threading.Thread(target=work) for _ in range(4)]
for t in threads:
    t.start()
for t in threads:
    t.join()
path = os.path.join(tempfile.mkdtemp(), "malloc_info.xml")
f = libc.fopen(path.encode(), b"w")
libc.malloc_info(0, f)
libc.fclose(f)
print(open(path).read().count("<heap nr="))
"""


def test_the_recorder_s_threads_share_one_malloc_arena() -> None:
    """limit_malloc_arenas(1) (the recorder's start): threads started after it allocate from one arena, where
    by default each new thread gets its own (whose small free chunks the trim cannot give back)."""
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_ARENA_MAX"}

    def heaps(mode: str) -> int:
        out = subprocess.run([sys.executable, "-c", _ARENA_PROBE, mode], env=env, capture_output=True, text=True)
        assert out.returncode == 0, out.stderr
        return int(out.stdout.strip())

    assert heaps("default") > 1  # the control: glibc gives the threads arenas of their own
    assert heaps("limit") == 1
