"""Telemetry samples packed into bytes while they wait in a `TelemetryBuffer`: about a quarter of the memory.

The synchroniser keeps the autopilot's telemetry for the device's history horizon (about 12 min at 5 fps,
some 130 000 samples in the simulated flights) so that a frame resent that late is still posed. Held as
slotted dataclasses, each float boxed, a sample takes 500-650 bytes (86 MiB at the horizon, issue 30's soak);
packed with `struct` it takes the payload plus one bytes object (`PACKED_SAMPLE_BYTES`).

Written here because the sample types are our own frozen dataclasses and nothing in the standard library or
numpy packs an optional field: a numpy structured array would also need a None convention, and would not
keep the cheap sorted insert of a late sample that the buffer relies on. `struct` does the byte layout; this
module only maps each field to a format code, with a presence bit for ``X | None`` fields and a small table
for the few strings (``AttitudeSample.source``).
"""

from __future__ import annotations

import dataclasses
import struct
import types
import typing
from typing import Any, Generic, TypeVar, Union

__all__ = ["PACKED_SAMPLE_BYTES", "SampleCodec"]

PACKED_SAMPLE_BYTES = 224
"""Memory per packed sample held [bytes]: the bytes object (33 B header + 97-157 B payload for the MAVLink
sample types, rounded up to the allocator's 16 B), its list slot and its int64 key. Measured with tracemalloc
on CPython 3.11: GPS_RAW_INT 207, GLOBAL_POSITION_INT 159, ATTITUDE 151 (as dataclasses: 477-640);
tests/mavlink/test_sample_codec.py checks it."""

T = TypeVar("T")

_SCALAR_CODES = {int: "q", float: "d", bool: "?"}
_MAX_STRINGS = 255


@dataclasses.dataclass(frozen=True)
class _Slot:
    kind: str  # "scalar", "tuple" or "str"
    optional: bool
    width: int  # values it takes in the struct (a tuple's length, else 1)


def _slot(name: str, hint: Any) -> tuple[_Slot, str]:
    optional = False
    origin = typing.get_origin(hint)
    if origin in (Union, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        if len(args) != 1 or len(typing.get_args(hint)) != 2:  # X | None only
            raise TypeError(f"field {name}: only X | None unions pack, not {hint}")
        optional, hint, origin = True, args[0], typing.get_origin(args[0])
    if hint in _SCALAR_CODES:
        return _Slot("scalar", optional, 1), _SCALAR_CODES[hint]
    if hint is str:
        return _Slot("str", optional, 1), "B"
    if origin is tuple:
        members = typing.get_args(hint)
        if not members or Ellipsis in members or any(a not in _SCALAR_CODES for a in members):
            raise TypeError(f"field {name}: only fixed-length tuples of int/float/bool pack, not {hint}")
        return _Slot("tuple", optional, len(members)), "".join(_SCALAR_CODES[a] for a in members)
    raise TypeError(f"field {name}: {hint} does not pack")


class SampleCodec(Generic[T]):
    """Packs one frozen dataclass type to bytes and back, exactly (floats as IEEE doubles, ints as int64).

    Raises TypeError at construction for a field type it cannot pack, and `struct.error` from `encode` for
    an int outside int64 (no sample type here holds one)."""

    def __init__(self, cls: type[T]) -> None:
        if not dataclasses.is_dataclass(cls):
            raise TypeError(f"{cls.__name__} is not a dataclass")
        hints = typing.get_type_hints(cls)
        fields = dataclasses.fields(cls)
        slots, codes = zip(*(_slot(f.name, hints[f.name]) for f in fields), strict=True)
        self.cls = cls
        self._names = tuple(f.name for f in fields)
        self._slots: tuple[_Slot, ...] = slots
        n_optional = sum(s.optional for s in slots)
        if n_optional > 32:  # the presence word has 32 bits
            raise TypeError(f"{cls.__name__}: more than 32 optional fields")
        self._struct = struct.Struct("<I" + "".join(codes))
        self._plain = not any(s.optional or s.kind != "scalar" for s in slots)  # a dataclass of scalars only
        self._strings: list[str] = []
        self._string_ids: dict[str, int] = {}

    @property
    def size(self) -> int:
        """Payload bytes per sample."""
        return self._struct.size

    def _string_id(self, value: str) -> int:
        sid = self._string_ids.get(value)
        if sid is None:
            if len(self._strings) >= _MAX_STRINGS:
                raise ValueError(f"{self.cls.__name__}: more than {_MAX_STRINGS} distinct strings to pack")
            sid = self._string_ids[value] = len(self._strings)
            self._strings.append(value)
        return sid

    def encode(self, sample: T) -> bytes:
        if self._plain:
            return self._struct.pack(0, *(getattr(sample, n) for n in self._names))
        present = 0
        bit = 1
        out: list[Any] = []
        for name, slot in zip(self._names, self._slots, strict=True):
            value = getattr(sample, name)
            if slot.optional:
                if value is not None:
                    present |= bit
                bit <<= 1
            if slot.kind == "tuple":
                out.extend((0,) * slot.width if value is None else value)
            elif slot.kind == "str":
                out.append(0 if value is None else self._string_id(value))
            else:
                out.append(0 if value is None else value)
        return self._struct.pack(present, *out)

    def decode(self, data: bytes) -> T:
        values = self._struct.unpack(data)
        if self._plain:
            return self.cls(*values[1:])
        present = values[0]
        bit = 1
        i = 1
        args: list[Any] = []
        for slot in self._slots:
            if slot.kind == "tuple":
                value: Any = tuple(values[i : i + slot.width])
            elif slot.kind == "str":
                value = self._strings[values[i]]
            else:
                value = values[i]
            i += slot.width
            if slot.optional:
                if not present & bit:
                    value = None
                bit <<= 1
            args.append(value)
        return self.cls(*args)
