"""Framing of the ICGT wire protocol (protocol/SPEC.md): frame encoder and stream decoder.

The decoder is I/O-free: give it whatever bytes arrived, in any pieces, and it returns the
messages whose frames completed. It never raises on input and never holds more than one
frame's worth of bytes. COBS runs in the `cobs` package's C code and the CRC in zlib, so the
per-byte work never happens in Python.
"""

from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass, fields
from typing import NamedTuple

from cobs import cobs

from icgt.errors import EncodeError
from icgt.protocol.messages import (
    CRC_BYTES,
    HEADER_BYTES,
    MAX_BODY_BYTES,
    MAX_FRAME_BYTES,
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    FrameFlags,
    Message,
)

MAX_ENCODED_BYTES = MAX_FRAME_BYTES + MAX_FRAME_BYTES // 254 + 1
"""Longest COBS-encoded frame between delimiters (SPEC.md §5)."""

_HEADER = struct.Struct("<BBBBI")
_CRC = struct.Struct("<I")
_MIN_DECODED = HEADER_BYTES + CRC_BYTES
_RETRANSMIT = int(FrameFlags.RETRANSMIT)
# CRC-32 run over data followed by its own CRC (little-endian) always gives this residue,
# so one C call checks a frame without slicing off its last four bytes.
_CRC32_RESIDUE = 0x2144DF1C
_new_received = tuple.__new__  # NamedTuple's own __new__ costs 4x more per message
_cobs_decode = cobs.decode
_CobsError = cobs.DecodeError
_crc32 = zlib.crc32
_unpack_header = _HEADER.unpack_from


class Received(NamedTuple):
    """One decoded frame: its header fields and the message it carried."""

    seq: int
    flags: int
    message: Message


def encode_frame(message: Message, seq: int, flags: int = 0) -> bytes:
    """The wire form of one message: COBS(header + body + CRC-32) and the 0x00 delimiter.

    Raises EncodeError for values that do not fit their fields (invariant 8: refuse, never
    truncate).
    """
    try:
        raw = _HEADER.pack(PROTOCOL_VERSION, message.ID, flags, 0, seq) + message.body()
    except struct.error as exc:
        raise EncodeError(f"{message.NAME}: {exc}") from exc
    if len(raw) - HEADER_BYTES > MAX_BODY_BYTES:
        raise EncodeError(f"{message.NAME}: body of {len(raw) - HEADER_BYTES} bytes exceeds {MAX_BODY_BYTES}")
    encoded: bytes = cobs.encode(raw + _CRC.pack(zlib.crc32(raw)))
    return encoded + b"\x00"


@dataclass(slots=True)
class DecoderStats:
    """Counters of SPEC.md §6: one of the first eight grows for every non-empty candidate."""

    frames_ok: int = 0
    oversized: int = 0
    cobs_error: int = 0
    truncated: int = 0
    crc_error: int = 0
    wrong_version: int = 0
    unknown_type: int = 0
    bad_length: int = 0
    seq_gaps: int = 0
    seq_missed: int = 0
    seq_resets: int = 0
    last_foreign_version: int | None = None

    @property
    def rejected(self) -> int:
        """Candidate frames rejected for any reason."""
        return (
            self.oversized
            + self.cobs_error
            + self.truncated
            + self.crc_error
            + self.wrong_version
            + self.unknown_type
            + self.bad_length
        )

    def as_dict(self) -> dict[str, int | None]:
        return {f.name: getattr(self, f.name) for f in fields(self)}


class StreamDecoder:
    """Turns a byte stream into messages (SPEC.md §6, with the invariants of §7)."""

    def __init__(self) -> None:
        self.stats = DecoderStats()
        self._pending = b""
        self._overflow = False  # the frame in progress already passed MAX_ENCODED_BYTES
        self._expected_seq: int | None = None

    @property
    def pending_bytes(self) -> int:
        """Bytes held for a frame in progress (at most MAX_ENCODED_BYTES + 1)."""
        return MAX_ENCODED_BYTES + 1 if self._overflow else len(self._pending)

    def feed(self, data: bytes | bytearray | memoryview) -> list[Received]:
        """Consume bytes; return the messages of every frame they completed, in order."""
        parts = (self._pending + bytes(data)).split(b"\x00") if self._pending else bytes(data).split(b"\x00")
        tail = parts.pop()
        stats = self.stats
        if parts and self._overflow:
            # The first part finishes a frame that was already too long: SPEC.md §6 rule b.
            stats.oversized += 1
            self._overflow = False
            parts[0] = b""
        if self._overflow or len(tail) > MAX_ENCODED_BYTES:
            self._overflow = True
            self._pending = b""
        else:
            self._pending = tail
        # The loop body is SPEC.md §6 rules c-i, inlined: at ~1 µs per message a method call
        # per frame would be a tenth of the decoder's time.
        out: list[Received] = []
        append = out.append
        expected = self._expected_seq
        types = MESSAGE_TYPES
        for part in parts:
            if not part:
                continue
            if len(part) > MAX_ENCODED_BYTES:
                stats.oversized += 1
                continue
            try:
                raw = _cobs_decode(part)
            except _CobsError:
                stats.cobs_error += 1
                continue
            n = len(raw)
            if n < _MIN_DECODED:
                stats.truncated += 1
                continue
            if _crc32(raw) != _CRC32_RESIDUE:
                stats.crc_error += 1
                continue
            version, msg_type, flags, _reserved, seq = _unpack_header(raw)
            if version != PROTOCOL_VERSION:
                stats.wrong_version += 1
                stats.last_foreign_version = version
                continue
            cls = types.get(msg_type)
            if cls is None:
                stats.unknown_type += 1
                continue
            end = n - CRC_BYTES
            if not cls.MIN_BODY <= end - HEADER_BYTES <= cls.MAX_BODY:
                stats.bad_length += 1
                continue
            append(_new_received(Received, (seq, flags, cls.from_buffer(raw, HEADER_BYTES, end))))
            if flags & _RETRANSMIT:
                continue  # resends carry their original seq and move no expectation (SPEC.md §3)
            if seq != expected and expected is not None:
                d = (seq - expected) & 0xFFFFFFFF
                if d < 0x80000000:
                    stats.seq_gaps += 1
                    stats.seq_missed += d
                else:
                    stats.seq_resets += 1
            expected = (seq + 1) & 0xFFFFFFFF
        self._expected_seq = expected
        stats.frames_ok += len(out)
        return out
