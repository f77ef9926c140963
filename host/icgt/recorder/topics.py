"""How messages become MCAP records: payloads and self-describing schemas of the raw streams, Foxglove views.

Raw device messages and raw MAVLink messages are recorded as they came, one topic per
message type, so poses can be recomputed later without re-flying. Their JSON Schemas are
derived from the protocol table (device) and from pymavlink's field lists (MAVLink). The Foxglove views
of frames and telemetry are `icgt.recording.views`.
"""

from __future__ import annotations

import base64
import math
from binascii import b2a_base64
from dataclasses import fields
from typing import Any

import msgspec

from icgt.mavlink.frames import UndecodedBatch, UndecodedFrame, message_name
from icgt.protocol import Message
from icgt.protocol.messages import FIELD_TYPES

# Topic names live in the log layout (one declaration for the writer and every reader).
from icgt.recording.layout import (
    CAMERA_FRAME,
    CLOCK_AUTOPILOT,
    CLOCK_AUTOPILOT_REQUESTS,
    CLOCK_DEVICE,
    CLOCK_DEVICE_EXCHANGES,
    CLOCK_UTC,
    COUNTERS,
    FRAMES,
    FRAMES_LOCATION,
    FRAMES_POSE,
    LINK_EVENTS,
    LOG,
    TF,
    WORLD_FRAME,
    device_topic,
    mavlink_topic,
)

__all__ = [
    "CAMERA_FRAME",
    "CLOCK_AUTOPILOT",
    "CLOCK_AUTOPILOT_REQUESTS",
    "CLOCK_DEVICE",
    "CLOCK_DEVICE_EXCHANGES",
    "CLOCK_UTC",
    "COUNTERS",
    "FRAMES",
    "FRAMES_LOCATION",
    "FRAMES_POSE",
    "LINK_EVENTS",
    "LOG",
    "TF",
    "WORLD_FRAME",
    "device_payload",
    "device_payload_json",
    "device_schema",
    "device_topic",
    "mavlink_payload",
    "mavlink_raw_payload",
    "mavlink_raw_payloads",
    "mavlink_schema",
    "mavlink_topic",
]

_DEVICE_JSON_TYPES = {"f32": "number", "f64": "number"}


def device_schema(cls: type[Message]) -> dict[str, Any]:
    """JSON Schema of a raw device message topic: its fields (units from the table) plus the header."""
    props: dict[str, Any] = {
        "seq": {"type": "integer", "description": "device frame sequence number"},
        "frame_flags": {"type": "integer", "description": "frame header flags"},
        "host_rx_ns": {"type": "integer", "description": "host CLOCK_MONOTONIC when the bytes arrived [ns]"},
    }
    for name, wire in FIELD_TYPES[cls.NAME]:
        kind = "string" if wire.startswith(("char", "str")) else _DEVICE_JSON_TYPES.get(wire, "integer")
        props[name] = {"type": kind, "description": f"{wire} [{cls.UNITS[name]}]"}
    required = [k for k, v in props.items() if v["type"] != "number"]
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"icgt.device.{cls.NAME}",
        "description": (cls.__doc__ or "").strip(),
        "type": "object",
        "properties": props,
        "required": required,
    }


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


def device_payload(msg: Message, seq: int, frame_flags: int, host_rx_ns: int) -> dict[str, Any]:
    """A device message as a JSON object; non-finite floats are left out (JSON has none)."""
    cls = type(msg)
    names = _FIELD_NAMES.get(cls)
    if names is None:
        names = _FIELD_NAMES[cls] = tuple(f.name for f in fields(msg))  # type: ignore[arg-type]
    out: dict[str, Any] = {"seq": seq, "frame_flags": frame_flags, "host_rx_ns": host_rx_ns}
    isfinite = math.isfinite
    for name in names:
        v = getattr(msg, name)
        if v.__class__ is float and not isfinite(v):
            continue
        out[name] = v
    return out


_JSON = msgspec.json.Encoder().encode


def device_payload_json(msg: Message, seq: int, frame_flags: int, host_rx_ns: int) -> bytes:
    """`device_payload` as compact JSON, byte for byte what encoding that mapping gives, at half the cost:
    the message (a dataclass) is encoded directly and the header fields put in front. A message with a
    non-finite float (msgspec writes null, the mapping leaves the field out) or no fields takes the mapping."""
    body = _JSON(msg)
    if len(body) <= 2 or b"null" in body:
        return _JSON(device_payload(msg, seq, frame_flags, host_rx_ns))
    return b'{"seq":%d,"frame_flags":%d,"host_rx_ns":%d,' % (seq, frame_flags, host_rx_ns) + body[1:]


def _mavlink_json_type(fieldtype: str) -> dict[str, Any]:
    base = fieldtype.split("[")[0]
    if base == "char":
        return {"type": "string"}
    scalar = {"type": "number"} if base in ("float", "double") else {"type": "integer"}
    if "[" in fieldtype:
        return {"type": "array", "items": scalar}
    return scalar


def mavlink_schema(msg: Any) -> dict[str, Any]:
    """JSON Schema of a raw MAVLink topic, from pymavlink's field names and C types."""
    props: dict[str, Any] = {
        "src_system": {"type": "integer"},
        "src_component": {"type": "integer"},
        "host_rx_ns": {"type": "integer", "description": "host CLOCK_MONOTONIC at receipt [ns]"},
        "raw": {"type": "string", "contentEncoding": "base64", "description": "the MAVLink frame as received"},
        "signed": {"type": "boolean", "description": "present (true) when its signature was valid with our key"},
    }
    for name, ftype in zip(msg.fieldnames, msg.fieldtypes, strict=True):
        props[name] = {**_mavlink_json_type(ftype), "description": ftype}
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": f"mavlink.{msg.get_type()}",
        "type": "object",
        "properties": props,
    }


def mavlink_payload(msg: Any, host_rx_ns: int) -> dict[str, Any]:
    out: dict[str, Any] = {
        "src_system": msg.get_srcSystem(),
        "src_component": msg.get_srcComponent(),
        "host_rx_ns": host_rx_ns,
        "raw": base64.b64encode(bytes(msg.get_msgbuf())).decode(),
    }
    if msg.get_signed():  # checked with the key, which the log does not hold: the recompute reads it here
        out["signed"] = True
    for name in msg.fieldnames:
        v = getattr(msg, name)
        if isinstance(v, bytes):
            v = v.decode("utf-8", "replace").rstrip("\0")
        elif isinstance(v, float) and not math.isfinite(v):
            continue
        elif isinstance(v, list):
            v = [x for x in v if not (isinstance(x, float) and not math.isfinite(x))]
        out[name] = v
    return out


def mavlink_raw_payload(msg: Any, host_rx_ns: int) -> dict[str, Any]:
    """A MAVLink message kept raw: its type, ids, receive time and frame bytes (no field expansion)."""
    if msg.__class__ is UndecodedFrame:  # most of them, and all of a flood: its fields directly
        return {
            "msg_type": msg.get_type(),
            "src_system": msg.src_system,
            "src_component": msg.src_component,
            "host_rx_ns": host_rx_ns,
            "raw": b2a_base64(msg.buf, newline=False).decode(),
        }
    return {
        "msg_type": msg.get_type(),
        "src_system": msg.get_srcSystem(),
        "src_component": msg.get_srcComponent(),
        "host_rx_ns": host_rx_ns,
        "raw": base64.b64encode(bytes(msg.get_msgbuf())).decode(),
    }


def mavlink_raw_payloads(batch: UndecodedBatch) -> list[dict[str, Any]]:
    """`mavlink_raw_payload` of each frame of a batch, in order (the same records, made in one pass)."""
    name = message_name
    return [
        {
            "msg_type": name(mid),
            "src_system": sysid,
            "src_component": compid,
            "host_rx_ns": rx_ns,
            "raw": b2a_base64(buf, newline=False).decode(),
        }
        for buf, sysid, compid, mid, rx_ns in batch.frames
    ]
