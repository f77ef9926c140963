"""Typed access to a scenario file's TOML tables, and the simulator's errors.

`TableReader` reads one table: typed values with their bounds, the keys read remembered so that a key
nobody read (a typo) is reported with the file and its place. `icgt.sim.scenario` and the scenario's
`[surface]` table (`icgt.sim.surface`) read through it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, NoReturn, TypeAlias

from icgt.errors import IcgtError

__all__ = ["ScenarioError", "SimError", "TableReader", "Vec3", "Window"]

Vec3: TypeAlias = tuple[float, float, float]
Window: TypeAlias = tuple[float, float]


class SimError(IcgtError):
    """A problem in the simulator (scenario, truth files, simulated devices)."""


class ScenarioError(SimError):
    """A scenario file that cannot be used; the message names the file and the key."""


_MISSING: Any = object()


class TableReader:
    """Typed access to one TOML table, remembering which keys were read so typos are reported."""

    def __init__(self, data: Mapping[str, Any], source: str, prefix: str = "") -> None:
        self.data = data
        self.source = source
        self.prefix = prefix
        self.used: set[str] = set()

    def fail(self, key: str, message: str) -> NoReturn:
        raise ScenarioError(f"{self.source}: {self.prefix}{key}: {message}")

    def _get(self, key: str, default: Any) -> Any:
        self.used.add(key)
        if key in self.data:
            return self.data[key]
        if default is _MISSING:
            self.fail(key, "missing (required)")
        return default

    def has(self, key: str) -> bool:
        return key in self.data

    def number(
        self,
        key: str,
        default: Any = _MISSING,
        *,
        min_value: float | None = None,
        max_value: float | None = None,
        positive: bool = False,
    ) -> float:
        value = self._get(key, default)
        return self._check_number(key, value, min_value, max_value, positive)

    def _check_number(
        self, key: str, value: Any, min_value: float | None, max_value: float | None, positive: bool
    ) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            self.fail(key, f"expected a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            self.fail(key, f"expected a finite number, got {value!r}")
        if positive and v <= 0.0:
            self.fail(key, f"must be > 0, got {value!r}")
        if min_value is not None and v < min_value:
            self.fail(key, f"must be >= {min_value:g}, got {value!r}")
        if max_value is not None and v > max_value:
            self.fail(key, f"must be <= {max_value:g}, got {value!r}")
        return v

    def optional_number(self, key: str, **kw: Any) -> float | None:
        if key not in self.data:
            self.used.add(key)
            return None
        return self.number(key, **kw)

    def integer(
        self, key: str, default: Any = _MISSING, *, min_value: int | None = None, max_value: int | None = None
    ) -> int:
        value = self._get(key, default)
        if isinstance(value, bool) or not isinstance(value, int):
            self.fail(key, f"expected an integer, got {value!r}")
        if min_value is not None and value < min_value:
            self.fail(key, f"must be >= {min_value}, got {value!r}")
        if max_value is not None and value > max_value:
            self.fail(key, f"must be <= {max_value}, got {value!r}")
        return value

    def string(self, key: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None) -> str:
        value = self._get(key, default)
        if not isinstance(value, str):
            self.fail(key, f"expected a string, got {value!r}")
        if choices is not None and value not in choices:
            self.fail(key, f"must be one of {', '.join(repr(c) for c in choices)}, got {value!r}")
        return value

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        value = self._get(key, default)
        if not isinstance(value, bool):
            self.fail(key, f"expected true or false, got {value!r}")
        return value

    def vec3(self, key: str, default: Any = _MISSING) -> Vec3:
        value = self._get(key, default)
        if not isinstance(value, list | tuple) or len(value) != 3:
            self.fail(key, f"expected [x, y, z], got {value!r}")
        x, y, z = (self._check_number(key, v, None, None, False) for v in value)
        return (x, y, z)

    def pairs(self, key: str, *, second_after_first: bool) -> tuple[Window, ...]:
        value = self._get(key, [])
        if not isinstance(value, list):
            self.fail(key, f"expected a list of [a, b] pairs, got {value!r}")
        out: list[Window] = []
        for i, pair in enumerate(value):
            if not isinstance(pair, list) or len(pair) != 2:
                self.fail(f"{key}[{i}]", f"expected [a, b], got {pair!r}")
            a = self._check_number(f"{key}[{i}]", pair[0], 0.0, None, False)
            b = self._check_number(f"{key}[{i}]", pair[1], 0.0, None, False)
            if second_after_first and b <= a:
                self.fail(f"{key}[{i}]", f"end {b:g} must be after start {a:g}")
            if not second_after_first and b <= 0.0:
                self.fail(f"{key}[{i}]", f"duration must be > 0, got {b:g}")
            out.append((a, b))
        return tuple(out)

    def numbers(self, key: str, *, min_value: float | None = None) -> tuple[float, ...]:
        value = self._get(key, [])
        if not isinstance(value, list):
            self.fail(key, f"expected a list of numbers, got {value!r}")
        return tuple(self._check_number(f"{key}[{i}]", v, min_value, None, False) for i, v in enumerate(value))

    def integers(self, key: str, *, min_value: int | None = None) -> tuple[int, ...]:
        value = self._get(key, [])
        if not isinstance(value, list):
            self.fail(key, f"expected a list of integers, got {value!r}")
        out: list[int] = []
        for i, v in enumerate(value):
            if isinstance(v, bool) or not isinstance(v, int):
                self.fail(f"{key}[{i}]", f"expected an integer, got {v!r}")
            if min_value is not None and v < min_value:
                self.fail(f"{key}[{i}]", f"must be >= {min_value}, got {v!r}")
            out.append(v)
        return tuple(out)

    def strings(self, key: str) -> tuple[str, ...]:
        value = self._get(key, [])
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            self.fail(key, f"expected a list of strings, got {value!r}")
        return tuple(value)

    def table(self, key: str, *, required: bool = False) -> TableReader:
        value = self._get(key, _MISSING if required else {})
        if not isinstance(value, dict):
            self.fail(key, f"expected a table, got {value!r}")
        return TableReader(value, self.source, f"{self.prefix}{key}.")

    def finish(self) -> None:
        unknown = sorted(set(self.data) - self.used)
        if unknown:
            self.fail(unknown[0], "unknown key (a typo?)")
