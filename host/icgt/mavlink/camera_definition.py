"""The camera's settings as a MAVLink camera definition file, and their values as PARAM_EXT bytes.

A camera definition file (the XML schema of https://mavlink.io/en/services/camera_def.html, parsed by
QGroundControl and MAVSDK) lists the parameters a ground station may read and set with the extended
parameter protocol (PARAM_EXT_*): name (at most 16 characters), type, default, a range (min, max, step)
or a list of options, and a description. `definition_xml` writes it for a list of `CameraParam`;
`definition_version` is the number CAMERA_INFORMATION announces with it, derived from the file's bytes,
so a client that caches definitions by model, vendor and version (MAVSDK does, in ~/.cache/mavsdk) never
reads an older file for a changed one.

PARAM_EXT values are the value's bytes (little-endian) at the start of a 128-byte field. pymavlink
decodes that field as a NUL-terminated string, which loses a float whose first byte is 0 (0.5 is
00 00 00 3f), so `value_from_payload` reads it from the message's raw frame instead (MAVLink 2 drops the payload's
trailing zeros: they are put back).
"""

from __future__ import annotations

import dataclasses
import math
import struct
import zlib
from collections.abc import Sequence
from typing import Literal
from xml.etree import ElementTree as ET

from icgt.errors import IcgtError

__all__ = [
    "PARAM_ID_LEN",
    "CameraParam",
    "ParamError",
    "decode_value",
    "definition_version",
    "definition_xml",
    "encode_value",
    "value_from_payload",
]

PARAM_ID_LEN = 16
MAV_PARAM_EXT_TYPE = {"uint32": 5, "float": 9}
_FORMAT = {"uint32": "<I", "float": "<f"}
_VALUE_OFFSET = {"PARAM_EXT_SET": 18, "PARAM_EXT_VALUE": 20, "PARAM_EXT_ACK": 16}  # wire offset of param_value


class ParamError(IcgtError):
    """A camera parameter or value that cannot be announced or taken (named in the message)."""


@dataclasses.dataclass(frozen=True, slots=True)
class CameraParam:
    """One setting: ``options`` (label, value) for a choice, else ``minimum`` .. ``maximum`` by ``step``.
    ``unit`` is said in the description (the schema has no unit attribute)."""

    name: str
    type: Literal["uint32", "float"]
    description: str
    default: float
    unit: str = ""
    minimum: float | None = None
    maximum: float | None = None
    step: float | None = None
    options: tuple[tuple[str, int], ...] = ()
    control: bool = True  # False: a ground station keeps track of it but shows no control for it

    def __post_init__(self) -> None:
        if not self.name or len(self.name.encode("ascii")) > PARAM_ID_LEN:
            raise ParamError(f"parameter name {self.name!r}: 1 to {PARAM_ID_LEN} ASCII characters")
        if self.type not in MAV_PARAM_EXT_TYPE:
            raise ParamError(f"parameter {self.name}: type {self.type!r} is not one of {sorted(MAV_PARAM_EXT_TYPE)}")
        if not self.options and (self.minimum is None or self.maximum is None):
            raise ParamError(f"parameter {self.name}: needs options or a minimum and a maximum")

    @property
    def mav_type(self) -> int:
        return MAV_PARAM_EXT_TYPE[self.type]

    def check(self, value: float) -> float:
        """The value as this parameter holds it (a uint32 as an integer); ParamError if it is not allowed."""
        if not math.isfinite(value):
            raise ParamError(f"{self.name}: {value} is not a number")
        if self.type == "uint32":
            if value != int(value):
                raise ParamError(f"{self.name}: {value} is not an integer")
            value = int(value)
        if self.options and value not in {v for _, v in self.options}:
            allowed = ", ".join(f"{v} ({label})" for label, v in self.options)
            raise ParamError(f"{self.name}: {value:g} is not one of {allowed}")
        if self.minimum is not None and value < self.minimum - 1e-9:
            raise ParamError(f"{self.name}: {value:g} {self.unit} is below the minimum {self.minimum:g}".strip())
        if self.maximum is not None and value > self.maximum + 1e-9:
            raise ParamError(f"{self.name}: {value:g} {self.unit} is above the maximum {self.maximum:g}".strip())
        return value


def _text(value: float, kind: str) -> str:
    return str(int(value)) if kind == "uint32" else repr(float(value))  # a client parses it as float32


def definition_xml(model: str, vendor: str, params: Sequence[CameraParam], version: int = 1) -> bytes:
    """The camera definition file (UTF-8 XML) for these parameters."""
    root = ET.Element("mavlinkcamera")
    definition = ET.SubElement(root, "definition", version=str(version))
    ET.SubElement(definition, "model").text = model
    ET.SubElement(definition, "vendor").text = vendor
    parameters = ET.SubElement(root, "parameters")
    for p in params:
        attrs = {"name": p.name, "type": p.type, "default": _text(p.default, p.type)}
        if not p.options:
            assert p.minimum is not None and p.maximum is not None
            attrs["min"] = _text(p.minimum, p.type)
            attrs["max"] = _text(p.maximum, p.type)
            if p.step is not None:
                attrs["step"] = _text(p.step, p.type)
        if not p.control:
            attrs["control"] = "0"
        el = ET.SubElement(parameters, "parameter", attrs)
        ET.SubElement(el, "description").text = f"{p.description} [{p.unit}]" if p.unit else p.description
        if p.options:
            opts = ET.SubElement(el, "options")
            for label, value in p.options:
                ET.SubElement(opts, "option", name=label, value=str(value))
    ET.indent(root)
    body = bytes(ET.tostring(root, encoding="utf-8"))
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + body + b"\n"


def definition_version(xml: bytes) -> int:
    """CAMERA_INFORMATION.cam_definition_version for this file: 1 .. 65535, from its CRC-32."""
    return zlib.crc32(xml) % 65535 + 1


def encode_value(param: CameraParam, value: float) -> bytes:
    """The PARAM_EXT param_value bytes of a value (its little-endian bytes; the field is NUL-padded)."""
    return struct.pack(_FORMAT[param.type], int(value) if param.type == "uint32" else float(value))


def decode_value(param_type: int, raw: bytes) -> float:
    """A value from PARAM_EXT param_value bytes of the given MAV_PARAM_EXT_TYPE; ParamError for other types."""
    for kind, code in MAV_PARAM_EXT_TYPE.items():
        if code == param_type:
            fmt = _FORMAT[kind]
            return float(struct.unpack(fmt, raw.ljust(struct.calcsize(fmt), b"\0")[: struct.calcsize(fmt)])[0])
    raise ParamError(f"MAV_PARAM_EXT_TYPE {param_type} is not a type of this camera's parameters")


def value_from_payload(msg: object, message_type: str) -> bytes:
    """The 128 param_value bytes of a decoded PARAM_EXT_SET / _VALUE / _ACK, read from its raw payload."""
    buf = bytes(getattr(msg, "get_msgbuf")())  # noqa: B009 (pymavlink's untyped message)
    header = 10 if buf[:1] == b"\xfd" else 6  # MAVLink 2 / 1; the payload's length is the header's 2nd byte
    payload = buf[header : header + buf[1]] if len(buf) > 1 else b""
    start = _VALUE_OFFSET[message_type]
    return payload[start : start + 128].ljust(128, b"\0")
