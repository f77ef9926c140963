"""Shared checks for the recording tests: a small JSON Schema validator and readers built on the official mcap reader.

The validator covers the keywords icgt.recording.schemas emits (type, properties, required,
additionalProperties, items, minItems, maxItems, enum, minimum, maximum, contentEncoding) and fails on
any other keyword, so a schema that grows a keyword it cannot check is noticed, not waved through.
"""

from __future__ import annotations

import base64
import binascii
import io
import json
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.data_stream import ReadDataStream
from mcap.exceptions import EndOfFile
from mcap.reader import NonSeekingReader, make_reader
from mcap.records import Chunk, ChunkIndex, Footer, Message, MessageIndex, SummaryOffset
from mcap.stream_reader import StreamReader, get_chunk_data_stream
from mcap_protobuf.decoder import DecoderFactory

KNOWN_KEYWORDS = {
    "$schema",
    "$comment",
    "title",
    "description",
    "type",
    "properties",
    "required",
    "additionalProperties",
    "items",
    "minItems",
    "maxItems",
    "enum",
    "minimum",
    "maximum",
    "contentEncoding",
}
FOXGLOVE_TYPES = {"object", "array", "string", "number", "integer", "boolean"}
_PY_TYPES: dict[str, Any] = {"object": dict, "array": list, "string": str, "boolean": bool}


def _type_ok(value: Any, kind: str) -> bool:
    if kind == "integer":
        return isinstance(value, int) and not isinstance(value, bool)
    if kind == "number":
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, _PY_TYPES[kind])


def validate(value: Any, schema: dict[str, Any], where: str = "$") -> list[str]:
    """Errors of `value` against `schema` (empty when valid)."""
    unknown = set(schema) - KNOWN_KEYWORDS
    if unknown:
        return [f"{where}: schema uses keywords this validator does not know: {sorted(unknown)}"]
    kind = schema.get("type")
    if not isinstance(kind, str) or kind not in FOXGLOVE_TYPES:
        return [f"{where}: schema type must be one of {sorted(FOXGLOVE_TYPES)}, not {kind!r}"]
    if not _type_ok(value, kind):
        return [f"{where}: {value!r} is not of type {kind}"]
    errors: list[str] = []
    if "enum" in schema and value not in schema["enum"]:
        errors.append(f"{where}: {value!r} not in {schema['enum']}")
    if "minimum" in schema and value < schema["minimum"]:
        errors.append(f"{where}: {value} < minimum {schema['minimum']}")
    if "maximum" in schema and value > schema["maximum"]:
        errors.append(f"{where}: {value} > maximum {schema['maximum']}")
    if schema.get("contentEncoding") == "base64":
        try:
            base64.b64decode(value, validate=True)
        except binascii.Error:
            errors.append(f"{where}: not base64")
    if kind == "object":
        properties = schema.get("properties", {})
        errors += [f"{where}: missing required {key}" for key in schema.get("required", []) if key not in value]
        if schema.get("additionalProperties") is False:
            errors += [f"{where}: unexpected key {key}" for key in value if key not in properties]
        for key, item in value.items():
            if key in properties:
                errors += validate(item, properties[key], f"{where}.{key}")
    if kind == "array":
        if "minItems" in schema and len(value) < schema["minItems"]:
            errors.append(f"{where}: fewer than {schema['minItems']} items")
        if "maxItems" in schema and len(value) > schema["maxItems"]:
            errors.append(f"{where}: more than {schema['maxItems']} items")
        for i, item in enumerate(value):
            errors += validate(item, schema["items"], f"{where}[{i}]")
    return errors


def foxglove_compatible(schema: dict[str, Any], where: str = "$") -> list[str]:
    """Structural rules of Foxglove's JSON Schema reader: one type per property, objects list properties,
    arrays have one item type that is not an array and not binary."""
    errors: list[str] = []
    if schema.get("type") != "object" or not isinstance(schema.get("properties"), dict):
        return [f"{where}: must be an object with properties"]
    for name, prop in schema["properties"].items():
        kind = prop.get("type")
        if kind not in FOXGLOVE_TYPES:
            errors.append(f"{where}.{name}: type {kind!r}")
        elif kind == "object":
            errors += foxglove_compatible(prop, f"{where}.{name}")
        elif kind == "array":
            items = prop.get("items")
            if not isinstance(items, dict) or items.get("type") not in FOXGLOVE_TYPES - {"array"}:
                errors.append(f"{where}.{name}: array items {items!r}")
            elif items.get("contentEncoding") is not None:
                errors.append(f"{where}.{name}: binary array items")
            elif items["type"] == "object":
                errors += foxglove_compatible(items, f"{where}.{name}[]")
    return errors


@dataclass
class ReadBack:
    """Everything in a finished file, read with the official seeking reader."""

    messages: list[tuple[str, int, int, Any]] = field(default_factory=list)  # topic, log time, sequence, decoded
    message_count_in_statistics: int = 0
    chunk_count: int = 0
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, bytes] = field(default_factory=dict)
    schemas: dict[str, tuple[str, bytes]] = field(default_factory=dict)  # name -> encoding, data


def read_complete(path: Path) -> ReadBack:
    """Reads a complete file: summary required; protobuf decoded by mcap-protobuf-support, JSON parsed
    and validated against its JSON Schema. Any problem raises AssertionError."""
    out = ReadBack()
    with path.open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None, f"{path} has no summary"
        assert summary.chunk_indexes, f"{path} has no chunk index"
        out.message_count_in_statistics = summary.statistics.message_count
        out.chunk_count = len(summary.chunk_indexes)
        for schema in summary.schemas.values():
            out.schemas[schema.name] = (schema.encoding, schema.data)
        factory = DecoderFactory()
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert schema is not None, f"{channel.topic} has no schema"
            if channel.message_encoding == "json":
                assert schema.encoding == "jsonschema"
                decoded = json.loads(message.data)
                json_schema = json.loads(schema.data)
                errors = validate(decoded, json_schema) + foxglove_compatible(json_schema)
                assert not errors, f"{channel.topic}: {errors}"
            else:
                assert channel.message_encoding == "protobuf" and schema.encoding == "protobuf"
                decoder = factory.decoder_for(channel.message_encoding, schema)
                assert decoder is not None, f"{channel.topic}: no protobuf decoder for {schema.name}"
                decoded = decoder(message.data)
            out.messages.append((channel.topic, message.log_time, message.sequence, decoded))
        out.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        out.attachments = {a.name: a.data for a in reader.iter_attachments()}
    assert len(out.messages) == out.message_count_in_statistics
    check_crcs_and_indexes(path)
    return out


def check_crcs_and_indexes(path: Path) -> None:
    """Checks what readers trust without re-deriving: chunk and data section CRCs (official reader), the
    summary CRC, every summary offset group, and every message index entry against the chunk it indexes."""
    data = path.read_bytes()
    with path.open("rb") as f:
        for _ in NonSeekingReader(f, validate_crcs=True).iter_messages(log_time_order=False):
            pass  # raises on a chunk or data section CRC mismatch
    footer = next(StreamReader(io.BytesIO(data[-(8 + 29) :]), skip_magic=True).records)
    assert isinstance(footer, Footer) and footer.summary_start > 0
    assert zlib.crc32(data[footer.summary_start : len(data) - 8 - 4]) == footer.summary_crc, "summary CRC"
    summary_records = list(
        StreamReader(io.BytesIO(data[footer.summary_start :]), skip_magic=True).records  # to the footer
    )
    offsets = [r for r in summary_records if isinstance(r, SummaryOffset)]
    assert offsets, "no summary offsets"
    for group in offsets:
        blob = data[group.group_start : group.group_start + group.group_length]
        opcodes = set()
        pos = 0
        while pos < len(blob):
            opcodes.add(blob[pos])
            pos += 9 + int.from_bytes(blob[pos + 1 : pos + 9], "little")
        assert pos == len(blob) and opcodes == {group.group_opcode}, f"summary offset group {group}"
    for index in (r for r in summary_records if isinstance(r, ChunkIndex)):
        raw = data[index.chunk_start_offset : index.chunk_start_offset + index.chunk_length]
        chunk = next(StreamReader(io.BytesIO(raw), skip_magic=True, emit_chunks=True).records)
        assert isinstance(chunk, Chunk) and len(raw) == index.chunk_length
        assert (chunk.message_start_time, chunk.message_end_time) == (index.message_start_time, index.message_end_time)
        records, _ = get_chunk_data_stream(chunk, validate_crc=True)
        inner = records.read(chunk.uncompressed_size)
        total = 0
        for channel_id, offset in index.message_index_offsets.items():
            head = data[offset : offset + 9]
            length = int.from_bytes(head[1:], "little")
            record = next(StreamReader(io.BytesIO(data[offset : offset + 9 + length]), skip_magic=True).records)
            assert isinstance(record, MessageIndex) and record.channel_id == channel_id
            for log_time, at in record.records:
                message = Message.read(
                    ReadDataStream(io.BytesIO(inner[at + 9 :])), int.from_bytes(inner[at + 1 : at + 9], "little")
                )
                assert inner[at] == 0x05 and message.channel_id == channel_id and message.log_time == log_time
            total += 9 + length
        assert total == index.message_index_length, "message index length"


def read_unfinished(path: Path) -> tuple[list[tuple[str, int]], Exception | None]:
    """(topic, log time) of every message the official stream-mode reader finds in a possibly unfinished
    file, and what stopped it: EndOfFile when the file ends after a complete record, another error
    when the last record was cut (kill -9 can cut a large write short)."""
    found: list[tuple[str, int]] = []
    with path.open("rb") as f:
        try:
            for _, channel, message in NonSeekingReader(f).iter_messages(log_time_order=False):
                found.append((channel.topic, message.log_time))
        except EndOfFile as exc:
            return found, exc
        except Exception as exc:  # a record cut by the crash; the caller checks it was the last one
            return found, exc
    return found, None
