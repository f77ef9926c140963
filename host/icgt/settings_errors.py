"""msgspec's validation errors of a settings file in a user's words: the dotted key, the value found there, the rule.

The recorder's configuration (icgt.recorder.config) and the simulator's scenario files (icgt.sim.scenario) are
declared as msgspec Structs. msgspec checks types, ranges and unknown keys, and says what failed as ``Expected
`int` <= 6 - at `$.gps.fix_type```; a user who typed the file wants ``gps.fix_type = 9: must be <= 6``. msgspec
has no hook for its wording, so the translation is written here, once for both readers.

A Struct's ``__post_init__`` that refuses a combination raises ``ValueError("key: why")`` naming the key inside
that Struct; `explain` then puts the key after the Struct's own path.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import msgspec

__all__ = ["Explained", "error_at", "explain", "first_non_finite", "lookup"]

_AT = re.compile(r"^(?P<why>.*?)(?: - at `\$(?P<path>[^`]*)`)?$", re.DOTALL)
_FIELD = re.compile(r"^Object (?P<what>contains unknown|missing required) field `(?P<key>[^`]+)`$")
_BOUND = re.compile(r"^Expected `(?:int|float)` (?P<op>[<>]=?) (?P<limit>\S+)$")
_TYPE = re.compile(r"^Expected `(?P<want>[a-z]+)`(?: of length (?P<n>\d+))?(?:, got (?P<got>.*))?$")
_CHOICE = re.compile(r"^Invalid (?:enum )?value (?P<value>.+)$")
_OWN = re.compile(r"^(?P<key>[A-Za-z_][A-Za-z0-9_]*(?:\[\d+\])?(?:\.[A-Za-z_][A-Za-z0-9_]*)*): (?P<why>.+)$", re.DOTALL)
_WANTS = {
    "int": "expected an integer",
    "float": "expected a number",
    "bool": "expected true or false",
    "str": "expected a string",
    "object": "expected a table",
    "array": "expected an array",
}


def error_at(exc: msgspec.ValidationError) -> tuple[str, str]:
    """(msgspec's reason, its path such as ``.gps.outages_s[0]``; "" at the top)."""
    m = _AT.match(str(exc))
    if m is None:  # pragma: no cover - the pattern matches any text
        return str(exc), ""
    return m.group("why"), m.group("path") or ""


def lookup(data: Any, path: str) -> tuple[bool, Any]:
    """The raw value at a msgspec error path such as `.capture.interval_s` or `.camera.lever_arm_body_m[1]`."""
    value = data
    for part in re.findall(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]", path):
        key, index = part
        try:
            value = value[key] if key else value[int(index)]
        except (KeyError, IndexError, TypeError):
            return False, None
    return True, value


@dataclass(frozen=True)
class Explained:
    key: str
    """Dotted, with indices: ``gps.outages_s[0]``; "" for the file as a whole."""
    why: str
    """The rule, in words; ends with the value found when there was one (``..., got 9``)."""


def _dotted(path: str) -> str:
    return path[1:] if path.startswith(".") else path


def explain(exc: msgspec.ValidationError, data: Any, root: type | None = None) -> Explained:
    """The key and the rule of a failed `msgspec.convert(data, root)`; `root` lists a Literal's choices."""
    why, path = error_at(exc)
    m = _FIELD.match(why)
    if m:
        key = f"{path}.{m.group('key')}"
        return Explained(
            _dotted(key), "unknown key (a typo?)" if "unknown" in m.group("what") else "missing (required)"
        )
    m = _OWN.match(why)
    if m and not why.startswith("Expected"):
        return Explained(_dotted(f"{path}.{m.group('key')}"), m.group("why"))
    found, value = lookup(data, path)
    got = f", got {value!r}" if found and not isinstance(value, Mapping) else ""
    if m := _BOUND.match(why):
        return Explained(_dotted(path), f"must be {m.group('op')} {m.group('limit')}{got}")
    if m := _CHOICE.match(why):
        choices = _choices(root, path) if root is not None else None
        listed = f"must be one of {', '.join(repr(c) for c in choices)}" if choices else "not an allowed value"
        return Explained(_dotted(path), f"{listed}, got {m.group('value')}")
    if m := _TYPE.match(why):
        want = _WANTS.get(m.group("want"), f"expected {m.group('want')}")
        if m.group("n"):
            want = f"expected an array of {m.group('n')} values"
        return Explained(_dotted(path), f"{want}{got}")
    return Explained(_dotted(path), f"{why[:1].lower()}{why[1:]}{got}")


def _member(info: Any, name: str) -> Any:
    """The type of field `name` in a Struct type (or in any Struct of a union); None if there is none."""
    members = info.types if isinstance(info, msgspec.inspect.UnionType) else (info,)
    for t in members:
        if isinstance(t, msgspec.inspect.StructType):
            for f in t.fields:
                if f.encode_name == name:
                    return f.type
    return None


def _choices(root: type, path: str) -> Sequence[Any] | None:
    """The allowed values of the Literal (or of a tagged union's tag) at `path` in `root`."""
    info: Any = msgspec.inspect.type_info(root)
    parts = re.findall(r"\.([A-Za-z_][A-Za-z0-9_]*)|\[(\d+)\]", path)
    for i, (name, index) in enumerate(parts):
        if isinstance(info, msgspec.inspect.UnionType):
            structs = [t for t in info.types if isinstance(t, msgspec.inspect.StructType)]
            if i == len(parts) - 1 and structs and all(t.tag_field == name for t in structs):
                return [t.tag for t in structs]
        if index:
            item = getattr(info, "item_type", None)
            if item is None:
                items = getattr(info, "item_types", ())
                item = items[int(index)] if int(index) < len(items) else None
            info = item
        else:
            info = _member(info, name)
        if info is None:
            return None
    types = info.types if isinstance(info, msgspec.inspect.UnionType) else (info,)
    for t in types:
        if isinstance(t, msgspec.inspect.LiteralType):
            return list(t.values)
    return None


def first_non_finite(data: Any, path: str = "") -> str | None:
    """The dotted key of the first NaN or infinity in parsed TOML `data` (TOML has them; no setting takes one)."""
    if isinstance(data, float) and not math.isfinite(data):
        return path
    if isinstance(data, Mapping):
        for k, v in data.items():
            found = first_non_finite(v, f"{path}.{k}" if path else str(k))
            if found is not None:
                return found
    elif isinstance(data, list | tuple):
        for i, v in enumerate(data):
            found = first_non_finite(v, f"{path}[{i}]")
            if found is not None:
                return found
    return None
