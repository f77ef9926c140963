"""Busy-loop processes that keep every core loaded: the 'loaded machine' of the kill -9 and flood checks.

Each burner is a separate Python process spinning at normal priority (not threads: the GIL would make
them one core). With one burner per core plus the code under test, the machine's load is cores + 1:
the code under test gets about half a core per runnable thread, as on a companion computer whose
cores are busy with other work.
"""

from __future__ import annotations

import os
import subprocess
import sys
from types import TracebackType

_SPIN = "while True: pass"


class CpuBurners:
    """`with CpuBurners():` one busy-loop process per core (or `count`), ended (by pid) on exit."""

    def __init__(self, count: int | None = None) -> None:
        self.count = count if count is not None else os.cpu_count() or 1
        self._procs: list[subprocess.Popen[bytes]] = []

    @property
    def pids(self) -> list[int]:
        """The running burners' process ids (to pin them: os.sched_setaffinity)."""
        return [proc.pid for proc in self._procs]

    def __enter__(self) -> CpuBurners:
        for _ in range(self.count):
            self._procs.append(subprocess.Popen([sys.executable, "-c", _SPIN]))
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        for proc in self._procs:
            proc.kill()
        for proc in self._procs:
            proc.wait()
        self._procs = []
