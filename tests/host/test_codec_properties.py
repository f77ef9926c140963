"""Property tests of the Python codec (SPEC.md §7 invariants), with Hypothesis."""

from __future__ import annotations

import math
import struct
from dataclasses import fields

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from icgt.errors import EncodeError
from icgt.protocol import MESSAGE_TYPES, PROTOCOL_VERSION, Message, StreamDecoder, encode_frame
from icgt.protocol.codec import MAX_ENCODED_BYTES
from icgt.protocol.messages import FIELD_TYPES, Log, Ping

INT_BITS = {
    "u8": (8, False),
    "u16": (16, False),
    "u32": (32, False),
    "u64": (64, False),
    "i8": (8, True),
    "i16": (16, True),
    "i32": (32, True),
    "i64": (64, True),
}


def value_strategy(wire: str) -> st.SearchStrategy[object]:
    if wire in INT_BITS:
        bits, signed = INT_BITS[wire]
        lo, hi = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if signed else (0, 2**bits - 1)
        return st.integers(lo, hi)
    if wire == "f32":
        return st.floats(width=32, allow_nan=True, allow_infinity=True)
    if wire == "f64":
        return st.floats(allow_nan=True, allow_infinity=True)
    size = int(wire.split("[")[1].rstrip("]"))
    text = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=size)
    return text.filter(lambda s: len(s.encode()) <= size)


@st.composite
def messages(draw: st.DrawFn) -> Message:
    cls = draw(st.sampled_from(list(MESSAGE_TYPES.values())))
    values = {name: draw(value_strategy(wire)) for name, wire in FIELD_TYPES[cls.NAME]}
    return cls(**values)  # type: ignore[arg-type]


def same(a: Message, b: Message) -> bool:
    if type(a) is not type(b):
        return False
    for f in fields(a):  # type: ignore[arg-type]
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, float):
            if not (x == y or (math.isnan(x) and math.isnan(y))) or math.copysign(1, x) != math.copysign(1, y):
                return False
        elif x != y:
            return False
    return True


@given(messages(), st.integers(0, 2**32 - 1), st.integers(0, 255))
def test_every_message_round_trips(msg: Message, seq: int, flags: int) -> None:
    wire = encode_frame(msg, seq, flags)
    assert wire.count(0) == 1 and wire.endswith(b"\x00")
    assert len(wire) <= MAX_ENCODED_BYTES + 1
    (got,) = StreamDecoder().feed(wire)
    assert got.seq == seq and got.flags == flags
    assert same(got.message, msg)


@settings(suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=4096))
def test_arbitrary_bytes_never_raise_and_every_candidate_is_counted(data: bytes) -> None:
    dec = StreamDecoder()
    got = dec.feed(data)
    candidates = sum(1 for part in data.split(b"\x00")[:-1] if part)
    assert dec.stats.frames_ok + dec.stats.rejected == candidates
    assert len(got) == dec.stats.frames_ok
    assert dec.pending_bytes <= MAX_ENCODED_BYTES + 1


@given(st.binary(max_size=2048), messages())
def test_after_any_junk_the_next_frame_decodes(junk: bytes, msg: Message) -> None:
    dec = StreamDecoder()
    dec.feed(junk + b"\x00")
    (got,) = dec.feed(encode_frame(msg, 5))
    assert same(got.message, msg)


@given(st.lists(messages(), min_size=1, max_size=8), st.data())
def test_splitting_the_stream_anywhere_changes_nothing(msgs: list[Message], data: st.DataObject) -> None:
    stream = b"".join(encode_frame(m, i) for i, m in enumerate(msgs))
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=12)))
    whole = StreamDecoder()
    expected = whole.feed(stream)
    pieces = StreamDecoder()
    got = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True):
        got += pieces.feed(stream[a:b])
    assert [r.seq for r in got] == [r.seq for r in expected]
    assert all(same(x.message, y.message) for x, y in zip(got, expected, strict=True))
    assert pieces.stats == whole.stats


def test_every_byte_split_of_a_frame_decodes_the_same() -> None:
    wire = encode_frame(Log(t_us=1, level=2, text="split me"), 9)
    for cut in range(len(wire) + 1):
        dec = StreamDecoder()
        got = dec.feed(wire[:cut]) + dec.feed(wire[cut:])
        assert len(got) == 1 and got[0].message == Log(t_us=1, level=2, text="split me")


def test_oversized_frame_is_bounded_and_counted_once() -> None:
    dec = StreamDecoder()
    for _ in range(100):
        assert dec.feed(b"\x42" * 1000) == []
        assert dec.pending_bytes == MAX_ENCODED_BYTES + 1
    got = dec.feed(b"\x00" + encode_frame(Ping(nonce=3), 0))
    assert dec.stats.oversized == 1 and got[0].message == Ping(nonce=3)


def test_values_that_do_not_fit_are_refused_not_truncated() -> None:
    for bad in (Ping(nonce=2**32), Log(text="x" * 201), Log(level=-1)):
        try:
            encode_frame(bad, 0)
        except EncodeError:
            continue
        raise AssertionError(f"{bad} was encoded")


def test_invalid_utf8_text_decodes_with_replacement_characters() -> None:
    body = struct.pack("<QB", 1, 2) + b"ok \xff\xfe"
    import zlib

    from cobs import cobs

    raw = struct.pack("<BBBBI", PROTOCOL_VERSION, Log.ID, 0, 0, 0) + body
    wire = cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"
    (got,) = StreamDecoder().feed(wire)
    assert got.message.text == "ok \ufffd\ufffd"  # type: ignore[attr-defined]
