"""JSON Schemas and JSON encoders for the self-describing MCAP topics, derived from dataclasses.

A record type is defined once, as a dataclass whose every field carries a description and,
where it has one, a unit::

    @dataclass(frozen=True)
    class RangeSample:
        \"\"\"One LiDAR-Lite distance measurement.\"\"\"

        t_device_us: Annotated[int, Doc("acquisition start on the device clock", unit="us")]
        distance_m: Annotated[float, Doc("distance to the surface", unit="m", minimum=0.0)]

`json_schema(RangeSample)` is the JSON Schema stored in the MCAP Schema record (encoding
"jsonschema"), and `json_encoder(RangeSample)` turns instances into the compact JSON bytes of the
Message records (encoding "json"), in exactly the shape the schema describes.

The schemas keep to what Foxglove's JSON Schema reader understands: every property has one `type`
(object, array, string, number, integer, boolean), objects list their properties, arrays have one
item type. Hence no `null`, no unions and no free-form maps. Mapping of Python types:
bool -> boolean; int, IntEnum, IntFlag -> integer; float -> number; str, str enums, Literal -> string
or integer with `enum`; bytes -> base64 string (`contentEncoding: base64`, Foxglove's convention);
`list[X]`, `tuple[X, ...]` -> array; `tuple[X, X, X]` -> array of exactly 3; a nested dataclass ->
object. A value that can be missing is `X | None`: the key is left out when it is None. A float
that is not finite (NaN, infinity: JSON has neither) is left out too, so float fields are not
"required"; every other field is. Floats inside arrays must be finite (the encoder raises).
"""

from __future__ import annotations

import base64
import dataclasses
import enum
import json
import math
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import msgspec

from icgt.errors import IcgtError
from icgt.field_doc import Doc

JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"

Encoder = Callable[[Any], bytes]
_Convert = Callable[[Any], Any]
_Keep = Callable[[Any], bool]  # False: leave the key out of the JSON object


class SchemaError(IcgtError):
    """A record type cannot be described as a JSON Schema (an undocumented field, an unsupported type)."""


def schema_name(cls: type) -> str:
    """The MCAP schema name of a record type: `__schema_name__` if the class sets one, else icgt.<ClassName>."""
    name = getattr(cls, "__schema_name__", None)
    return name if isinstance(name, str) else f"icgt.{cls.__name__}"


def json_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a dataclass record type; raises SchemaError if it cannot be described."""
    schema = _object_schema(cls, stack=())
    return {"$schema": JSON_SCHEMA_DIALECT, "title": schema_name(cls), **schema}


def json_schema_bytes(cls: type) -> bytes:
    """`json_schema(cls)` as the UTF-8 bytes stored in an MCAP Schema record (keys sorted: stable across runs)."""
    return json.dumps(json_schema(cls), sort_keys=True, separators=(",", ":")).encode()


def encode_json(value: Any) -> bytes:
    """Compact JSON bytes of a dataclass instance (through its cached `json_encoder`)."""
    return json_encoder(type(value))(value)


_ENCODERS: dict[type, Encoder] = {}


def json_encoder(cls: type) -> Encoder:
    """A function turning instances of the dataclass `cls` into compact JSON bytes matching `json_schema(cls)`.

    Built once per type: per field, only the conversions its declared type needs are applied.
    Raises ValueError for a non-finite float inside an array.
    """
    cached = _ENCODERS.get(cls)
    if cached is None:
        json_schema(cls)  # refuse a type the schema cannot describe before its first message, not at it
        to_plain = _dataclass_converter(cls)
        dumps = msgspec.json.Encoder(enc_hook=_numpy_scalar).encode

        def cached(value: Any) -> bytes:
            return dumps(to_plain(value))

        _ENCODERS[cls] = cached  # a race builds it twice, harmlessly
    return cached


def _numpy_scalar(value: Any) -> Any:
    """The encoder's fallback for numbers that are not int or float subclasses (numpy.int64, numpy.float32...)."""
    if hasattr(value, "__index__"):
        return int(value.__index__())
    if hasattr(value, "__float__"):
        return float(value)
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


# --- reading a dataclass --------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Field:
    name: str
    hint: Any  # the type with Annotated and `| None` removed
    optional: bool  # declared `X | None`
    doc: Doc | None


def _fields(cls: type) -> list[_Field]:
    if not (isinstance(cls, type) and dataclasses.is_dataclass(cls)):
        raise SchemaError(f"{cls!r} is not a dataclass type")
    try:
        hints = typing.get_type_hints(cls, include_extras=True)
    except (NameError, TypeError) as exc:
        raise SchemaError(f"cannot resolve the field types of {cls.__name__}: {exc}") from exc
    result = []
    for f in dataclasses.fields(cls):
        doc = f.metadata.get("doc")
        hint, annotated_doc = _strip_annotated(hints[f.name])
        hint, optional = _strip_optional(hint, where=f"{cls.__name__}.{f.name}")
        hint, inner_doc = _strip_annotated(hint)
        doc = inner_doc or annotated_doc or doc
        result.append(_Field(f.name, hint, optional, doc if isinstance(doc, Doc) else None))
    return result


def _strip_annotated(hint: Any) -> tuple[Any, Doc | None]:
    if typing.get_origin(hint) is not typing.Annotated:
        return hint, None
    base, *extras = typing.get_args(hint)
    return base, next((e for e in extras if isinstance(e, Doc)), None)


def _strip_optional(hint: Any, where: str) -> tuple[Any, bool]:
    if typing.get_origin(hint) not in (typing.Union, types.UnionType):
        return hint, False
    members = [a for a in typing.get_args(hint) if a is not type(None)]
    if len(members) != 1:
        raise SchemaError(f"{where}: Foxglove reads one type per field; only `X | None` unions are supported")
    return members[0], True


# --- schema -----------------------------------------------------------------------------------------


def _object_schema(cls: type, stack: tuple[type, ...]) -> dict[str, Any]:
    if cls in stack:
        raise SchemaError(f"{cls.__name__} contains itself: recursive records are not supported")
    properties: dict[str, Any] = {}
    required: list[str] = []
    for f in _fields(cls):
        where = f"{cls.__name__}.{f.name}"
        if f.doc is None:
            raise SchemaError(f"{where} has no Doc(description, unit): every field must be described")
        prop = _value_schema(f.hint, (*stack, cls), where, in_array=False)
        prop["description"] = f.doc.text()
        if f.doc.minimum is not None:
            prop["minimum"] = f.doc.minimum
        if f.doc.maximum is not None:
            prop["maximum"] = f.doc.maximum
        if f.optional:
            prop["$comment"] = "absent when there is no value"
        elif f.hint is float:
            prop["$comment"] = "absent when the value is not finite (NaN or infinity)"
        else:
            required.append(f.name)
        properties[f.name] = prop
    schema: dict[str, Any] = {"type": "object", "properties": properties, "required": required}
    schema["additionalProperties"] = False
    if cls.__doc__ and not cls.__doc__.startswith(f"{cls.__name__}("):  # skip the dataclass auto-docstring
        schema["description"] = " ".join(cls.__doc__.split())
    return schema


def _value_schema(hint: Any, stack: tuple[type, ...], where: str, *, in_array: bool) -> dict[str, Any]:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if origin is typing.Annotated or origin in (typing.Union, types.UnionType):
        raise SchemaError(f"{where}: only a whole field may be `X | None` or carry a Doc, not {hint}")
    if origin is typing.Literal:
        kinds = {type(a) for a in args}
        if kinds == {str}:
            return {"type": "string", "enum": list(args)}
        if kinds == {int}:
            return {"type": "integer", "enum": list(args)}
        raise SchemaError(f"{where}: Literal values must be all str or all int")
    if origin in (list, tuple) or hint in (list, tuple):
        if in_array:
            raise SchemaError(f"{where}: Foxglove reads no arrays of arrays: wrap the inner one in a dataclass")
        return _array_schema(hint, stack, where)
    if isinstance(hint, type):
        if hint is bytes and in_array:
            raise SchemaError(f"{where}: Foxglove reads no arrays of bytes: wrap them in a dataclass")
        return _class_schema(hint, stack, where)
    raise SchemaError(f"{where}: unsupported type {hint!r}")


def _array_schema(hint: Any, stack: tuple[type, ...], where: str) -> dict[str, Any]:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if not args:
        raise SchemaError(f"{where}: give the element type (list[float], tuple[float, ...])")
    if origin is tuple and args[-1] is not Ellipsis:
        if len(set(args)) != 1:
            raise SchemaError(f"{where}: tuple items must all have one type (Foxglove reads one item type)")
        items = _value_schema(args[0], stack, where, in_array=True)
        return {"type": "array", "items": items, "minItems": len(args), "maxItems": len(args)}
    return {"type": "array", "items": _value_schema(args[0], stack, where, in_array=True)}


def _class_schema(hint: type, stack: tuple[type, ...], where: str) -> dict[str, Any]:
    if dataclasses.is_dataclass(hint):
        return _object_schema(hint, stack)
    if issubclass(hint, enum.Enum):
        values = [m.value for m in hint]
        if all(isinstance(v, int) for v in values):
            if issubclass(hint, enum.Flag):  # a combination of bits, not one of the listed values
                bits = ", ".join(f"{m.name}={m.value}" for m in hint)
                return {"type": "integer", "minimum": 0, "$comment": f"bit flags: {bits}"}
            names = ", ".join(f"{m.value}={m.name}" for m in hint)
            return {"type": "integer", "enum": values, "$comment": names}
        if all(isinstance(v, str) for v in values):
            return {"type": "string", "enum": values}
        raise SchemaError(f"{where}: enum {hint.__name__} mixes value types")
    simple = {bool: "boolean", int: "integer", float: "number", str: "string"}
    if hint in simple:
        return {"type": simple[hint]}
    if hint is bytes:
        return {"type": "string", "contentEncoding": "base64"}
    raise SchemaError(f"{where}: unsupported type {hint.__name__} (use a dataclass for structured values)")


# --- encoding -----------------------------------------------------------------------------------------


def _b64(value: Any) -> Any:
    return base64.b64encode(value).decode("ascii")


def _enum_value(value: Any) -> Any:
    return value.value if isinstance(value, enum.Enum) else value


def _is_value(value: Any) -> bool:
    return value is not None


def _finite_list(values: Any) -> list[Any]:
    out = list(values)
    for x in out:
        if not math.isfinite(x):
            raise ValueError(f"non-finite float {x!r} in an array (JSON has none)")
    return out


def _is_finite(value: Any) -> bool:
    return value is not None and math.isfinite(value)


def _converter(hint: Any) -> _Convert | None:
    """The conversion a value of type `hint` needs before JSON encoding, or None when it needs none."""
    origin = typing.get_origin(hint)
    if origin in (list, tuple):
        inner = typing.get_args(hint)[0]
        if inner is float:
            return _finite_list
        item = _converter(inner)
        return list if item is None else (lambda v: [item(x) for x in v])
    if isinstance(hint, type):
        if dataclasses.is_dataclass(hint):
            return _dataclass_converter(hint)
        if issubclass(hint, enum.Enum):
            return _enum_value
        if hint is bytes:
            return _b64
    return None


def _dataclass_converter(cls: type) -> _Convert:
    plan: list[tuple[str, _Convert | None, _Keep | None]] = []
    for f in _fields(cls):
        keep = _is_finite if f.hint is float else (_is_value if f.optional else None)  # float | None: finite too
        plan.append((f.name, _converter(f.hint), keep))

    def to_plain(value: Any) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name, convert, keep in plan:
            field_value = getattr(value, name)
            if keep is not None and not keep(field_value):
                continue
            out[name] = field_value if convert is None else convert(field_value)
        return out

    return to_plain
