#!/usr/bin/env python3
"""Generate the C++ and Python message definitions from protocol/messages.toml.

    python protocol/generate.py          # rewrite the generated files
    python protocol/generate.py --check  # exit 1 if a generated file is stale

Only the standard library is used so the generator runs before any venv exists.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tomllib
import zlib
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TABLE = ROOT / "protocol" / "messages.toml"
CPP_OUT = ROOT / "firmware" / "lib" / "protocol" / "messages.hpp"
PY_OUT = ROOT / "host" / "icgt" / "protocol" / "messages.py"

SCALARS: dict[str, tuple[int, str, str, str]] = {
    # type: (size, struct char, C++ type, Python annotation)
    "u8": (1, "B", "uint8_t", "int"),
    "u16": (2, "H", "uint16_t", "int"),
    "u32": (4, "I", "uint32_t", "int"),
    "u64": (8, "Q", "uint64_t", "int"),
    "i8": (1, "b", "int8_t", "int"),
    "i16": (2, "h", "int16_t", "int"),
    "i32": (4, "i", "int32_t", "int"),
    "i64": (8, "q", "int64_t", "int"),
    "f32": (4, "f", "float", "float"),
    "f64": (8, "d", "double", "float"),
}
SIZED = re.compile(r"^(char|str)\[(\d+)\]$")
DIRECTIONS = {"device_to_host": (0x01, 0x3F), "host_to_device": (0x40, 0x7F)}


class TableError(Exception):
    """The message table is inconsistent."""


@dataclass(frozen=True)
class Field:
    name: str
    type: str
    unit: str
    doc: str
    enum: str | None
    bits: str | None

    @property
    def kind(self) -> str:
        """'scalar', 'char' (fixed, NUL-padded) or 'str' (variable tail)."""
        m = SIZED.match(self.type)
        return m.group(1) if m else "scalar"

    @property
    def size(self) -> int:
        """Bytes on the wire (the maximum, for a str tail)."""
        m = SIZED.match(self.type)
        return int(m.group(2)) if m else SCALARS[self.type][0]


@dataclass(frozen=True)
class Message:
    id: int
    name: str
    direction: str
    doc: str
    fields: tuple[Field, ...]

    @property
    def class_name(self) -> str:
        return "".join(part.capitalize() for part in self.name.split("_"))

    @property
    def fixed_fields(self) -> tuple[Field, ...]:
        return tuple(f for f in self.fields if f.kind != "str")

    @property
    def tail(self) -> Field | None:
        last = self.fields[-1] if self.fields else None
        return last if last is not None and last.kind == "str" else None

    @property
    def fixed_size(self) -> int:
        return sum(f.size for f in self.fixed_fields)

    @property
    def max_size(self) -> int:
        return self.fixed_size + (self.tail.size if self.tail else 0)

    @property
    def struct_format(self) -> str:
        parts = []
        for f in self.fixed_fields:
            parts.append(f"{f.size}s" if f.kind == "char" else SCALARS[f.type][1])
        return "<" + "".join(parts)


@dataclass(frozen=True)
class Table:
    version: int
    max_frame_bytes: int
    header_bytes: int
    crc_bytes: int
    enums: dict[str, dict[str, int]]
    enum_docs: dict[str, str]
    bits: dict[str, dict[str, int]]
    bit_docs: dict[str, str]
    messages: tuple[Message, ...]

    @property
    def max_body_bytes(self) -> int:
        return self.max_frame_bytes - self.header_bytes - self.crc_bytes

    def canonical(self) -> bytes:
        """The wire-relevant part of the table (no docs, no units) as canonical JSON."""
        data = {
            "version": self.version,
            "max_frame_bytes": self.max_frame_bytes,
            "header_bytes": self.header_bytes,
            "crc_bytes": self.crc_bytes,
            "enums": self.enums,
            "bits": self.bits,
            "messages": [
                {
                    "id": m.id,
                    "name": m.name,
                    "direction": m.direction,
                    "fields": [[f.name, f.type, f.enum or "", f.bits or ""] for f in m.fields],
                }
                for m in self.messages
            ],
        }
        return json.dumps(data, sort_keys=True, separators=(",", ":")).encode()

    @property
    def table_hash(self) -> int:
        return zlib.crc32(self.canonical())


def load(path: Path = TABLE) -> Table:
    raw = tomllib.loads(path.read_text(encoding="utf-8"))
    proto = raw["protocol"]
    enums = {name: dict(e["values"]) for name, e in raw.get("enums", {}).items()}
    bits = {name: dict(b["bits"]) for name, b in raw.get("bits", {}).items()}
    messages = []
    for m in raw["messages"]:
        fields = tuple(
            Field(
                name=f["name"],
                type=f["type"],
                unit=f["unit"],
                doc=f["doc"],
                enum=f.get("enum"),
                bits=f.get("bits"),
            )
            for f in m["fields"]
        )
        messages.append(Message(m["id"], m["name"], m["direction"], m["doc"], fields))
    table = Table(
        version=proto["version"],
        max_frame_bytes=proto["max_frame_bytes"],
        header_bytes=proto["header_bytes"],
        crc_bytes=proto["crc_bytes"],
        enums=enums,
        enum_docs={name: e["doc"] for name, e in raw.get("enums", {}).items()},
        bits=bits,
        bit_docs={name: b["doc"] for name, b in raw.get("bits", {}).items()},
        messages=tuple(messages),
    )
    validate(table)
    return table


def validate(table: Table) -> None:
    ids: set[int] = set()
    names: set[str] = set()
    for m in table.messages:
        lo, hi = DIRECTIONS.get(m.direction, (1, 0))
        if not lo <= m.id <= hi:
            raise TableError(f"{m.name}: id {m.id:#x} outside the {m.direction} range")
        if m.id in ids or m.name in names:
            raise TableError(f"{m.name}: duplicate id or name")
        ids.add(m.id)
        names.add(m.name)
        seen: set[str] = set()
        for i, f in enumerate(m.fields):
            if f.name in seen:
                raise TableError(f"{m.name}.{f.name}: duplicate field")
            seen.add(f.name)
            if f.type not in SCALARS and not SIZED.match(f.type):
                raise TableError(f"{m.name}.{f.name}: unknown type {f.type}")
            if f.kind == "str" and i != len(m.fields) - 1:
                raise TableError(f"{m.name}.{f.name}: str[] must be the last field")
            if f.enum and f.enum not in table.enums:
                raise TableError(f"{m.name}.{f.name}: unknown enum {f.enum}")
            if f.bits and f.bits not in table.bits:
                raise TableError(f"{m.name}.{f.name}: unknown bit set {f.bits}")
            if not f.unit:
                raise TableError(f"{m.name}.{f.name}: every field names its unit")
        if m.max_size > table.max_body_bytes:
            raise TableError(f"{m.name}: {m.max_size} B body exceeds {table.max_body_bytes} B")
    for name, b in table.bits.items():
        if any(not 0 <= v <= 31 for v in b.values()):
            raise TableError(f"bits {name}: bit numbers are 0..31")


# ---------------------------------------------------------------------------------
# C++


def _cpp_const(name: str) -> str:
    return "k" + "".join(p.capitalize() for p in name.split("_"))


def render_cpp(t: Table) -> str:
    out: list[str] = []
    w = out.append
    w("// GENERATED by protocol/generate.py from protocol/messages.toml. Do not edit.")
    w("// Message definitions of the ICGT wire protocol; framing lives in frame.hpp.")
    w("#pragma once")
    w("")
    w("#include <cstddef>")
    w("#include <cstdint>")
    w("#include <cstring>")
    w("")
    w('#include "wire.hpp"')
    w("")
    w("namespace icgt::proto {")
    w("")
    w(f"inline constexpr uint8_t kProtocolVersion = {t.version};")
    w(f"inline constexpr uint32_t kTableHash = 0x{t.table_hash:08X}u;")
    w(f"inline constexpr std::size_t kMaxFrameBytes = {t.max_frame_bytes};")
    w(f"inline constexpr std::size_t kHeaderBytes = {t.header_bytes};")
    w(f"inline constexpr std::size_t kCrcBytes = {t.crc_bytes};")
    w(f"inline constexpr std::size_t kMaxBodyBytes = {t.max_body_bytes};")
    w("")
    w("enum class MsgId : uint8_t {")
    for m in t.messages:
        w(f"  {m.name} = 0x{m.id:02X},")
    w("};")
    w("")
    w("// Name of a message id, or nullptr if the id is not in the table.")
    w("[[nodiscard]] constexpr const char* msg_name(uint8_t id) {")
    w("  switch (id) {")
    for m in t.messages:
        w(f'    case 0x{m.id:02X}: return "{m.name}";')
    w("    default: return nullptr;")
    w("  }")
    w("}")
    w("")
    w("// Body length limits of a message id; false if the id is unknown.")
    w("[[nodiscard]] constexpr bool body_size_range(uint8_t id, std::size_t& min_bytes, std::size_t& max_bytes) {")
    w("  switch (id) {")
    for m in t.messages:
        w(f"    case 0x{m.id:02X}: min_bytes = {m.fixed_size}; max_bytes = {m.max_size}; return true;")
    w("    default: return false;")
    w("  }")
    w("}")
    w("")
    for name, values in t.enums.items():
        w(f"// {t.enum_docs[name]}")
        w(f"enum class {name} : uint8_t {{")
        for k, v in values.items():
            w(f"  {k} = {v},")
        w("};")
        w("")
    for name, bits in t.bits.items():
        w(f"// {t.bit_docs[name]}")
        w(f"namespace {name} {{")
        for k, v in bits.items():
            w(f"inline constexpr uint32_t {k} = 1u << {v};")
        w(f"}}  // namespace {name}")
        w("")
    for m in t.messages:
        w(f"// {m.name} ({m.direction.replace('_', ' ')}): {m.doc}")
        w(f"struct {m.class_name} {{")
        w(f"  static constexpr MsgId kId = MsgId::{m.name};")
        w(f'  static constexpr const char* kName = "{m.name}";')
        w(f"  static constexpr std::size_t kMinBodyBytes = {m.fixed_size};")
        w(f"  static constexpr std::size_t kMaxBodyBytes = {m.max_size};")
        for f in m.fields:
            if f.kind == "scalar":
                w(f"  {SCALARS[f.type][2]} {f.name}{{}};  // [{f.unit}] {f.doc}")
            elif f.kind == "char":
                w(f"  char {f.name}[{f.size}]{{}};  // NUL-padded. {f.doc}")
            else:
                w(f"  char {f.name}[{f.size}]{{}};  // {f.doc}")
                w(f"  uint8_t {f.name}_len{{}};  // bytes used in {f.name}")
        w("")
        w("  // Writes the body into out; returns the bytes written, 0 if cap is too small.")
        w("  [[nodiscard]] std::size_t encode(uint8_t* out, std::size_t cap) const {")
        size_expr = f"{m.fixed_size}u" + (f" + {m.tail.name}_len" if m.tail else "")
        w(f"    const std::size_t n = {size_expr};")
        if m.tail:
            w(f"    if ({m.tail.name}_len > sizeof({m.tail.name}) || n > cap) return 0;")
        else:
            w("    if (n > cap) return 0;")
        off = 0
        for f in m.fixed_fields:
            if f.kind == "char":
                w(f"    std::memcpy(out + {off}, {f.name}, {f.size});")
            else:
                w(f"    wire::put(out + {off}, {f.name});")
            off += f.size
        if m.tail:
            w(f"    if ({m.tail.name}_len > 0) std::memcpy(out + {off}, {m.tail.name}, {m.tail.name}_len);")
        if not m.fields:
            w("    (void)out;")
        w("    return n;")
        w("  }")
        w("")
        w("  // Reads a body of exactly the right length; false (and *this untouched) otherwise.")
        w("  [[nodiscard]] bool decode(const uint8_t* in, std::size_t len) {")
        if m.tail:
            w("    if (len < kMinBodyBytes || len > kMaxBodyBytes) return false;")
        else:
            w("    if (len != kMinBodyBytes) return false;")
        off = 0
        for f in m.fixed_fields:
            if f.kind == "char":
                w(f"    std::memcpy({f.name}, in + {off}, {f.size});")
            else:
                w(f"    {f.name} = wire::get<{SCALARS[f.type][2]}>(in + {off});")
            off += f.size
        if m.tail:
            w(f"    {m.tail.name}_len = static_cast<uint8_t>(len - {off});")
            w(f"    if ({m.tail.name}_len > 0) std::memcpy({m.tail.name}, in + {off}, {m.tail.name}_len);")
        if not m.fields:
            w("    (void)in;")
        w("    return true;")
        w("  }")
        w("")
        w("  // Calls v(name, value) for every field in wire order (strings as wire::StrView).")
        w("  template <class Visitor>")
        w("  void visit(Visitor&& v) const {")
        for f in m.fields:
            if f.kind == "scalar":
                w(f'    v("{f.name}", {f.name});')
            elif f.kind == "char":
                w(f'    v("{f.name}", wire::StrView{{{f.name}, wire::strnlen_bounded({f.name}, {f.size})}});')
            else:
                w(f'    v("{f.name}", wire::StrView{{{f.name}, {f.name}_len}});')
        if not m.fields:
            w("    (void)v;")
        w("  }")
        w("};")
        w("")
    w("// Calls fn(MessageStruct{}) with a default instance of the message type for id;")
    w("// returns false if the id is unknown.")
    w("template <class Fn>")
    w("[[nodiscard]] bool with_message_type(uint8_t id, Fn&& fn) {")
    w("  switch (id) {")
    for m in t.messages:
        w(f"    case 0x{m.id:02X}: fn({m.class_name}{{}}); return true;")
    w("    default: return false;")
    w("  }")
    w("}")
    w("")
    w("}  // namespace icgt::proto")
    return "\n".join(out) + "\n"


# ---------------------------------------------------------------------------------
# Python


def _py_default(f: Field) -> str:
    if f.kind != "scalar":
        return '""'
    return "0.0" if SCALARS[f.type][3] == "float" else "0"


def render_py(t: Table) -> str:
    out: list[str] = []
    w = out.append
    w('"""Message definitions of the ICGT wire protocol.')
    w("")
    w("GENERATED by protocol/generate.py from protocol/messages.toml. Do not edit.")
    w('Framing and the stream decoder live in icgt.protocol.codec."""')
    w("")
    w("from __future__ import annotations")
    w("")
    w("import struct")
    w("from dataclasses import dataclass")
    w("from enum import IntEnum, IntFlag")
    w("from typing import ClassVar")
    w("")
    w("from icgt.errors import EncodeError")
    w("")
    w(f"PROTOCOL_VERSION = {t.version}")
    w(f"TABLE_HASH = 0x{t.table_hash:08X}")
    w(f"MAX_FRAME_BYTES = {t.max_frame_bytes}")
    w(f"HEADER_BYTES = {t.header_bytes}")
    w(f"CRC_BYTES = {t.crc_bytes}")
    w(f"MAX_BODY_BYTES = {t.max_body_bytes}")
    w("")
    w("")
    w("class MsgId(IntEnum):")
    w('    """Message type ids."""')
    w("")
    for m in t.messages:
        w(f"    {m.name} = 0x{m.id:02X}")
    w("")
    for name, values in t.enums.items():
        w("")
        w(f"class {name}(IntEnum):")
        w(f'    """{t.enum_docs[name]}"""')
        w("")
        for k, v in values.items():
            w(f"    {k.upper()} = {v}")
        w("")
    for name, bits in t.bits.items():
        w("")
        w(f"class {name}(IntFlag):")
        w(f'    """{t.bit_docs[name]}"""')
        w("")
        for k, v in bits.items():
            w(f"    {k.upper()} = 1 << {v}")
        w("")
    w("")
    w("class Message:")
    w('    """Base of every message dataclass."""')
    w("")
    w("    __slots__ = ()")
    w("    ID: ClassVar[int]")
    w("    NAME: ClassVar[str]")
    w("    DIRECTION: ClassVar[str]")
    w("    MIN_BODY: ClassVar[int]")
    w("    MAX_BODY: ClassVar[int]")
    w("    UNITS: ClassVar[dict[str, str]]")
    w("")
    w("    def body(self) -> bytes:")
    w('        """The message body as sent on the wire (no header, no CRC)."""')
    w("        raise NotImplementedError")
    w("")
    w("    @classmethod")
    w("    def from_buffer(cls, buf: bytes, offset: int, end: int) -> Message:")
    w('        """Build from the body at buf[offset:end], whose length the caller has checked."""')
    w("        raise NotImplementedError")
    w("")
    w("    @classmethod")
    w("    def from_body(cls, body: bytes) -> Message:")
    w('        """Build from a body whose length the caller has checked."""')
    w("        return cls.from_buffer(body, 0, len(body))")
    w("")
    for m in t.messages:
        sname = f"_S_{m.name}"
        w("")
        w(f"{sname} = struct.Struct({m.struct_format!r})")
        w("")
        w("")
        w("@dataclass(slots=True)")
        w(f"class {m.class_name}(Message):")
        w(f'    """{m.name}: {m.doc}"""')
        w("")
        w(f"    ID: ClassVar[int] = 0x{m.id:02X}")
        w(f'    NAME: ClassVar[str] = "{m.name}"')
        w(f'    DIRECTION: ClassVar[str] = "{m.direction}"')
        w(f"    MIN_BODY: ClassVar[int] = {m.fixed_size}")
        w(f"    MAX_BODY: ClassVar[int] = {m.max_size}")
        units = ", ".join(f'"{f.name}": "{f.unit}"' for f in m.fields)
        w(f"    UNITS: ClassVar[dict[str, str]] = {{{units}}}")
        w("")
        for f in m.fields:
            ann = SCALARS[f.type][3] if f.kind == "scalar" else "str"
            w(f"    {f.name}: {ann} = {_py_default(f)}")
            w(f'    """[{f.unit}] {f.doc}"""')
        w("")
        # body()
        w("    def body(self) -> bytes:")
        for f in m.fields:
            if f.kind != "scalar":
                w(f"        {f.name} = self.{f.name}.encode()")
                w(f"        if len({f.name}) > {f.size}:")
                w(f'            raise EncodeError(f"{m.name}.{f.name}: {{len({f.name})}} bytes, at most {f.size}")')
        args = [f.name if f.kind == "char" else f"self.{f.name}" for f in m.fixed_fields]
        packed = f"{sname}.pack({', '.join(args)})"
        if m.tail:
            w(f"        return {packed} + {m.tail.name}")
        else:
            w(f"        return {packed}")
        w("")
        # from_buffer()
        w("    @classmethod")
        w(f"    def from_buffer(cls, buf: bytes, offset: int, end: int) -> {m.class_name}:")
        has_char = any(f.kind == "char" for f in m.fields)
        if not has_char and not m.tail:
            w(f"        return cls(*{sname}.unpack_from(buf, offset))")
        else:
            w(f"        v = list({sname}.unpack_from(buf, offset))")
            for i, f in enumerate(m.fixed_fields):
                if f.kind == "char":
                    w(f'        v[{i}] = v[{i}].split(b"\\0", 1)[0].decode("utf-8", "replace")')
            if m.tail:
                w(f'        v.append(buf[offset + {m.fixed_size} : end].decode("utf-8", "replace"))')
            w("        return cls(*v)")
        w("")
    w("")
    w("MESSAGE_TYPES: dict[int, type[Message]] = {")
    for m in t.messages:
        w(f"    0x{m.id:02X}: {m.class_name},")
    w("}")
    w('"""Every message class by id."""')
    w("")
    w("FIELD_TYPES: dict[str, tuple[tuple[str, str], ...]] = {")
    for m in t.messages:
        ft = ", ".join(f'("{f.name}", "{f.type}")' for f in m.fields)
        w(f'    "{m.name}": ({ft}{"," if len(m.fields) == 1 else ""}),')
    w("}")
    w('"""Wire type of every field, by message name, in wire order."""')
    return "\n".join(out) + "\n"


def outputs(table: Table) -> dict[Path, str]:
    return {CPP_OUT: render_cpp(table), PY_OUT: render_py(table)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="fail if generated files are stale")
    args = parser.parse_args(argv)
    try:
        table = load()
    except (TableError, KeyError, tomllib.TOMLDecodeError) as exc:
        print(f"generate.py: bad message table: {exc}", file=sys.stderr)
        return 2
    stale = []
    for path, text in outputs(table).items():
        current = path.read_text(encoding="utf-8") if path.exists() else None
        if current == text:
            continue
        if args.check:
            stale.append(path.relative_to(ROOT))
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path.relative_to(ROOT)}")
    if stale:
        names = ", ".join(str(p) for p in stale)
        print(f"stale generated files: {names}; run python protocol/generate.py", file=sys.stderr)
        return 1
    print(f"table hash 0x{table.table_hash:08X}, {len(table.messages)} messages")
    return 0


if __name__ == "__main__":
    sys.exit(main())
