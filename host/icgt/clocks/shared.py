"""Sharing a clock filter between threads.

The filters are plain computation and not thread-safe (a query refits the window the reader
thread is appending to). The recorder feeds them from the link readers and queries them from
its worker and the geotagger, so it wraps each in `Synchronized`.
"""

from __future__ import annotations

import functools
import threading
from typing import Any, Generic, TypeVar, cast

T = TypeVar("T")


class Synchronized(Generic[T]):
    """Every method call and attribute read of the wrapped object runs under one lock."""

    def __init__(self, target: T, lock: threading.RLock | None = None) -> None:
        object.__setattr__(self, "_target", target)
        object.__setattr__(self, "_lock", lock or threading.RLock())

    @property
    def lock(self) -> threading.RLock:
        return cast(threading.RLock, object.__getattribute__(self, "_lock"))

    def __getattr__(self, name: str) -> Any:
        target = object.__getattribute__(self, "_target")
        lock = object.__getattribute__(self, "_lock")
        with lock:
            value = getattr(target, name)  # properties are evaluated under the lock too
        if not callable(value):
            return value

        @functools.wraps(value)
        def locked(*args: Any, **kwargs: Any) -> Any:
            with lock:
                return value(*args, **kwargs)

        return locked

    def unwrap(self) -> T:
        return cast(T, object.__getattribute__(self, "_target"))
