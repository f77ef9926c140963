"""Canonical JSON of decoded vectors (protocol/SPEC.md §9).

Written by hand rather than with json.dumps because both codecs must print byte-identical
text: floats as %.17g of the double value, NaN/infinities as strings, and one fixed rule
for escaping strings, which json.dumps does not offer.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import fields

from icgt.protocol.codec import DecoderStats, Received

STAT_KEYS = (
    "frames_ok",
    "oversized",
    "cobs_error",
    "truncated",
    "crc_error",
    "wrong_version",
    "unknown_type",
    "bad_length",
    "seq_gaps",
    "seq_missed",
    "seq_resets",
)

JsonValue = int | float | str | Mapping[str, "JsonValue"] | list["JsonValue"]


def _string(s: str) -> str:
    out = ['"']
    for ch in s:
        if ch in '"\\':
            out.append("\\" + ch)
        elif ord(ch) < 0x20 or ord(ch) == 0x7F:
            out.append(f"\\u{ord(ch):04x}")
        else:
            out.append(ch)
    out.append('"')
    return "".join(out)


def dumps(value: JsonValue) -> str:
    """Serialise with sorted keys, no spaces and the number/string rules above."""
    if isinstance(value, bool):
        raise TypeError("canonical JSON has no booleans")
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return '"NaN"'
        if math.isinf(value):
            return '"Infinity"' if value > 0 else '"-Infinity"'
        return f"{value:.17g}"
    if isinstance(value, str):
        return _string(value)
    if isinstance(value, Mapping):
        return "{" + ",".join(f"{_string(k)}:{dumps(value[k])}" for k in sorted(value)) + "}"
    return "[" + ",".join(dumps(v) for v in value) + "]"


def message_dict(received: Received) -> dict[str, JsonValue]:
    msg = received.message
    return {
        "type": msg.NAME,
        "seq": received.seq,
        "flags": received.flags,
        "fields": {f.name: getattr(msg, f.name) for f in fields(msg)},  # type: ignore[arg-type]
    }


def decoding(messages: Iterable[Received], stats: DecoderStats, pending_bytes: int) -> str:
    """The canonical JSON of a whole vector's decoding."""
    counters: dict[str, JsonValue] = {k: getattr(stats, k) for k in STAT_KEYS}
    counters["pending_bytes"] = pending_bytes
    return dumps({"messages": [message_dict(r) for r in messages], "stats": counters})
