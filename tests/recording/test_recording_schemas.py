"""JSON Schemas from dataclasses: every field described, Foxglove-readable, and the encoder matches the schema."""

from __future__ import annotations

import base64
import enum
import json
import math
from dataclasses import dataclass, field
from typing import Annotated, Any, Literal

import pytest
from hypothesis import given
from hypothesis import strategies as st
from recording_checks import foxglove_compatible, validate

from icgt.recording import Doc, SchemaError, encode_json, json_schema, schema_name


class PoseSource(enum.IntEnum):
    NONE = 0
    FIX_3D = 3
    RTK = 4


class Flag(enum.IntFlag):
    NO_FIX = 1
    STALE_POSE = 2


@dataclass(frozen=True)
class Enu:
    """A local position."""

    east_m: Annotated[float, Doc("east", unit="m")]
    north_m: Annotated[float, Doc("north", unit="m")]


@dataclass(frozen=True)
class Sample:
    """Every supported field kind."""

    seq: Annotated[int, Doc("sequence number")]
    ok: Annotated[bool, Doc("valid")]
    range_m: Annotated[float, Doc("range", unit="m", minimum=0.0)]
    camera: Annotated[str, Doc("camera id")]
    raw: Annotated[bytes, Doc("raw bytes")]
    source: Annotated[PoseSource, Doc("pose source")]
    flags: Annotated[Flag, Doc("quality flags")]
    mode: Annotated[Literal["auto", "manual"], Doc("mode")]
    quat: Annotated[tuple[float, float, float, float], Doc("quaternion w, x, y, z")]
    history_m: Annotated[list[float], Doc("recent ranges", unit="m")]
    position: Annotated[Enu, Doc("position")]
    track: Annotated[list[Enu], Doc("recent positions")]
    age_ms: Annotated[float | None, Doc("age of the range", unit="ms")]
    fix: Annotated[Enu | None, Doc("the fix, if any")]
    note: str = field(default="", metadata={"doc": Doc("free text")})


def _sample(**changes: Any) -> Sample:
    base: dict[str, Any] = dict(
        seq=1, ok=True, range_m=5.0, camera="cam0", raw=b"\x00\xff", source=PoseSource.RTK,
        flags=Flag.NO_FIX | Flag.STALE_POSE, mode="auto", quat=(1.0, 0.0, 0.0, 0.0), history_m=[1.0, 2.0],
        position=Enu(1.0, 2.0), track=[Enu(0.0, 0.0)], age_ms=3.0, fix=None,
    )  # fmt: skip
    base.update(changes)
    return Sample(**base)


def test_schema_describes_every_field_with_units_and_is_foxglove_readable() -> None:
    schema = json_schema(Sample)
    assert schema["title"] == "icgt.Sample" == schema_name(Sample)
    assert schema["description"] == "Every supported field kind."
    props = schema["properties"]
    assert props["range_m"]["description"] == "range [m]" and props["range_m"]["minimum"] == 0.0
    assert props["raw"] == {"type": "string", "contentEncoding": "base64", "description": "raw bytes"}
    assert props["source"]["enum"] == [0, 3, 4]
    assert props["quat"]["minItems"] == props["quat"]["maxItems"] == 4
    assert props["position"]["properties"]["north_m"]["description"] == "north [m]"
    assert all(p["description"] for p in props.values())
    # floats and optionals may be left out; everything else is always there
    assert set(schema["required"]) == set(props) - {"range_m", "age_ms", "fix"}
    assert foxglove_compatible(schema) == []


def test_encoded_record_validates_and_round_trips() -> None:
    value = _sample()
    decoded = json.loads(encode_json(value))
    assert validate(decoded, json_schema(Sample)) == []
    assert base64.b64decode(decoded["raw"]) == b"\x00\xff"
    assert decoded["source"] == 4 and decoded["flags"] == 3 and "fix" not in decoded
    assert decoded["position"] == {"east_m": 1.0, "north_m": 2.0}


def test_missing_values_are_left_out_not_null() -> None:
    decoded = json.loads(encode_json(_sample(range_m=math.nan, age_ms=None, fix=Enu(math.inf, 1.0))))
    assert "range_m" not in decoded and "age_ms" not in decoded
    assert decoded["fix"] == {"north_m": 1.0}
    assert validate(decoded, json_schema(Sample)) == []


def test_non_finite_float_inside_an_array_is_refused() -> None:
    with pytest.raises(ValueError):
        encode_json(_sample(history_m=[1.0, math.nan]))


@given(
    seq=st.integers(min_value=-(2**63), max_value=2**64 - 1),
    range_m=st.floats(min_value=0.0) | st.sampled_from([math.nan, math.inf, -math.inf]),
    camera=st.text(),
    raw=st.binary(max_size=64),
    history=st.lists(st.floats(allow_nan=False, allow_infinity=False), max_size=5),
    age_ms=st.none() | st.floats(),
)
def test_any_value_encodes_to_json_that_validates(
    seq: int, range_m: float, camera: str, raw: bytes, history: list[float], age_ms: float | None
) -> None:
    value = _sample(seq=seq, range_m=range_m, camera=camera, raw=raw, history_m=history, age_ms=age_ms)
    decoded = json.loads(encode_json(value))
    assert validate(decoded, json_schema(Sample)) == []
    assert decoded["seq"] == seq and decoded["camera"] == camera and base64.b64decode(decoded["raw"]) == raw


@dataclass
class Undocumented:
    x: int


@dataclass
class WithDict:
    m: Annotated[dict[str, int], Doc("a map")]


@dataclass
class WithUnion:
    u: Annotated[int | str, Doc("either")]


@dataclass
class WithNestedList:
    grid: Annotated[list[list[float]], Doc("a grid")]


@dataclass
class WithBytesList:
    blobs: Annotated[list[bytes], Doc("blobs")]


@pytest.mark.parametrize("record_type", [Undocumented, WithDict, WithUnion, WithNestedList, WithBytesList, int])
def test_what_foxglove_cannot_read_is_refused(record_type: type) -> None:
    with pytest.raises(SchemaError):
        json_schema(record_type)


def test_schema_name_can_be_set_by_the_class() -> None:
    @dataclass
    class Named:
        __schema_name__ = "icgt.FrameRecord"
        x: Annotated[int, Doc("x")]

    assert json_schema(Named)["title"] == "icgt.FrameRecord"
