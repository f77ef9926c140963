"""A recording's frame records: one decoded from its /frames JSON, and all of them as numpy columns (`FrameTable`).

The columns follow `icgt.geotag.record.FrameRecord` field by field (read from its type hints), so a field added
there is a column here without a change to this module.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Iterable, Mapping
from typing import Any, cast

import numpy as np

from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.ingest.errors import IngestError

__all__ = ["FIELD_NAMES", "FLAG_BITS", "INT_MISSING", "FrameTable", "decode_frame"]

INT_MISSING = -1
"""Value of an optional integer column (mid_utc_us, satellites, imu_calib_*) where the frame has none."""

FLAG_BITS: dict[str, int] = {flag.value: 1 << i for i, flag in enumerate(FrameFlag)}
"""Bit of each FrameFlag value in `FrameTable["flags"]`; a flag this version does not know sets bit 31."""
_UNKNOWN_FLAG_BIT = 1 << 31


@dataclasses.dataclass(frozen=True)
class _FieldKind:
    name: str
    base: type  # int, float, bool, str or list (flags)
    optional: bool


def _field_kinds() -> tuple[_FieldKind, ...]:
    hints = typing.get_type_hints(FrameRecord)
    out: list[_FieldKind] = []
    for f in dataclasses.fields(FrameRecord):
        hint = hints[f.name]
        optional = False
        if isinstance(hint, types.UnionType):
            args = [a for a in typing.get_args(hint) if a is not type(None)]
            optional = len(args) < len(typing.get_args(hint))
            hint = args[0]
        base = typing.get_origin(hint) or hint
        if base not in (int, float, bool, str, list):
            raise TypeError(f"FrameRecord.{f.name}: unsupported type {hint!r}")
        out.append(_FieldKind(f.name, cast(type, base), optional))
    return tuple(out)


_KINDS = _field_kinds()
FIELD_NAMES: tuple[str, ...] = tuple(k.name for k in _KINDS)


def decode_frame(data: Mapping[str, Any]) -> FrameRecord:
    """A FrameRecord from its JSON object on /frames.

    The recorder leaves out None values and non-finite floats (JSON has neither): a missing optional
    field is None, a missing required float (the pose gaps) is +infinity, the geotagger's "no sample".
    Keys this version does not know are ignored.
    """
    kwargs: dict[str, Any] = {}
    for k in _KINDS:
        value = data.get(k.name)
        if value is None:
            if k.optional:
                continue
            if k.base is float:
                value = math.inf
            else:
                raise IngestError(
                    f"a frame record without {k.name!r}: not an ICGT recording, or one of an icgt version "
                    "this one cannot read"
                )
        kwargs[k.name] = value
    try:
        return FrameRecord(**kwargs)
    except TypeError as exc:
        raise IngestError(f"a frame record this version cannot read: {exc}") from None


def _flag_mask(flags: Iterable[str]) -> int:
    mask = 0
    for f in flags:
        mask |= FLAG_BITS.get(f, _UNKNOWN_FLAG_BIT)
    return mask


class FrameTable:
    """The frames of a recording as columns: one numpy array per FrameRecord field, all of equal length.

    Column dtypes: integers int64, floats float64, bools bool, strings numpy unicode. Missing values:
    NaN in float columns, `INT_MISSING` (-1) in optional integer columns (`valid(name)` gives the
    mask of present values). Column ``flags`` is a uint32 bitmask per frame (bits: `FLAG_BITS`);
    `has_flag(flag)` gives a boolean column and `flag_list(i)` the names for one frame.
    """

    def __init__(self, columns: dict[str, np.ndarray[Any, Any]]) -> None:
        lengths = {len(v) for v in columns.values()}
        if len(lengths) > 1:
            raise IngestError(f"frame table columns of unequal lengths {sorted(lengths)}")
        self.columns = columns
        self._n = lengths.pop() if lengths else 0
        self._valid: dict[str, np.ndarray[Any, np.dtype[np.bool_]]] = {}

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, name: str) -> np.ndarray[Any, Any]:
        try:
            return self.columns[name]
        except KeyError:
            raise KeyError(f"no column {name!r}; columns: {', '.join(self.columns)}") from None

    def __contains__(self, name: object) -> bool:
        return name in self.columns

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(self.columns)

    def valid(self, name: str) -> np.ndarray[Any, np.dtype[np.bool_]]:
        """True where the frame has a value in column `name` (not NaN, not INT_MISSING)."""
        mask = self._valid.get(name)
        if mask is not None:
            return mask
        col = self[name]
        if col.dtype.kind == "f":
            mask = ~np.isnan(col)
        elif col.dtype.kind == "i" and any(k.name == name and k.optional for k in _KINDS):
            mask = col != INT_MISSING
        else:
            mask = np.ones(len(col), dtype=bool)
        self._valid[name] = mask
        return mask

    def has_flag(self, flag: FrameFlag | str) -> np.ndarray[Any, np.dtype[np.bool_]]:
        bit = FLAG_BITS[FrameFlag(flag).value]
        flags: np.ndarray[Any, Any] = self.columns["flags"]
        return cast("np.ndarray[Any, np.dtype[np.bool_]]", (flags & bit) != 0)

    def flag_list(self, i: int) -> list[str]:
        mask = int(self.columns["flags"][i])
        return [name for name, bit in FLAG_BITS.items() if mask & bit]

    @classmethod
    def from_frames(cls, frames: Iterable[FrameRecord]) -> FrameTable:
        lists: dict[str, list[Any]] = {k.name: [] for k in _KINDS}
        for f in frames:
            for k in _KINDS:
                lists[k.name].append(getattr(f, k.name))
        columns: dict[str, np.ndarray[Any, Any]] = {}
        for k in _KINDS:
            values = lists.pop(k.name)
            if k.base is list:
                columns[k.name] = np.fromiter((_flag_mask(v) for v in values), dtype=np.uint32, count=len(values))
            elif k.base is float:
                columns[k.name] = np.array([math.nan if v is None else v for v in values], dtype=np.float64)
            elif k.base is bool:
                columns[k.name] = np.array(values, dtype=bool)
            elif k.base is int:
                columns[k.name] = np.array([INT_MISSING if v is None else v for v in values], dtype=np.int64)
            else:
                columns[k.name] = np.array(values, dtype=np.str_) if values else np.array([], dtype="<U1")
        return cls(columns)
