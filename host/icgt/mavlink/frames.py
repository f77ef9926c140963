"""Splitting a UDP datagram into MAVLink frames by their headers, to leave other systems' frames undecoded.

pymavlink parses every frame fully (CRC, unpacking, a message object), about 20 us each in Python; on a
shared network or a swarm's radio most traffic may come from other systems that the recorder only keeps
raw. The header alone (MAVLink 1: ``FE len seq sys comp msgid``, MAVLink 2: ``FD len incompat compat
seq sys comp msgid[3]``, then payload, CRC and, if signed, 13 signature bytes) tells a frame's length
and its sender, which pymavlink has no call to read without decoding. `split_datagram` walks the
headers and returns None as soon as anything does not look like whole frames, so that the caller hands
the datagram to pymavlink as before. The frames left undecoded are not CRC-checked: they are kept raw
and used for nothing.

Under a flood (10 k foreign frames/s) every object per frame counts: `split_foreign` appends each foreign
frame as a plain tuple (`ForeignFrame`: bytes, system, component, message id, receive time [ns]) to the
caller's list, and the link hands a whole `UndecodedBatch` of them to the subscribers that take batches
(the recorder: one inbox item, one bulk count and one list of raw records per batch, not per frame).
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import itemgetter

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = [
    "ALWAYS_DECODED",
    "ForeignFrame",
    "UndecodedBatch",
    "UndecodedFrame",
    "message_name",
    "split_datagram",
    "split_foreign",
]

_STX_V1 = 0xFE
_STX_V2 = 0xFD
_SIGNED = 0x01
_NAMES: dict[int, str] = {mid: cls.msgname for mid, cls in mavlink2.mavlink_map.items()}
ALWAYS_DECODED = frozenset(
    {
        mavlink2.MAVLINK_MSG_ID_HEARTBEAT,  # who is on the network (1 Hz per component)
        mavlink2.MAVLINK_MSG_ID_COMMAND_LONG,  # commands to the camera, answered or refused, from anyone
        mavlink2.MAVLINK_MSG_ID_COMMAND_INT,
    }
)
"""Message ids decoded whatever their sender."""

ForeignFrame = tuple[bytes, int, int, int, int]
"""One frame left undecoded: (frame bytes, src_system, src_component, msg_id, receive time [ns, host monotonic])."""
_BUF = itemgetter(0)
_MSG_ID = itemgetter(3)


def message_name(msg_id: int) -> str:
    """pymavlink's name of a message id (``UNKNOWN_<id>`` for ids the dialect does not know)."""
    return _NAMES.get(msg_id) or f"UNKNOWN_{msg_id}"


@dataclass(frozen=True, slots=True)
class UndecodedFrame:
    """A frame left undecoded: what a pymavlink message tells about itself without its fields."""

    buf: bytes
    src_system: int
    src_component: int
    msg_id: int

    def get_type(self) -> str:
        return message_name(self.msg_id)

    def get_srcSystem(self) -> int:  # noqa: N802 - pymavlink's spelling
        return self.src_system

    def get_srcComponent(self) -> int:  # noqa: N802
        return self.src_component

    def get_msgId(self) -> int:  # noqa: N802
        return self.msg_id

    def get_msgbuf(self) -> bytes:
        return self.buf


class UndecodedBatch:
    """Other systems' frames left undecoded, in arrival order (of one datagram or of one drain of the socket,
    up to where a decoded message came in between): what a batch subscriber of `MavlinkLink` receives."""

    __slots__ = ("_types", "frames")

    def __init__(self, frames: list[ForeignFrame]) -> None:
        if not frames:
            raise ValueError("an UndecodedBatch holds at least one frame, got none")
        self.frames = frames
        self._types: dict[str, int] | None = None

    def __len__(self) -> int:
        return len(self.frames)

    def __repr__(self) -> str:
        return f"UndecodedBatch({len(self.frames)} frames from {self.rx_ns} ns)"

    @property
    def rx_ns(self) -> int:
        """Receive time of the first frame [ns, host monotonic]."""
        return self.frames[0][4]

    def type_counts(self) -> dict[str, int]:
        """Frames per message type name (pymavlink's names; ``UNKNOWN_<id>`` for ids it does not know)."""
        if self._types is None:
            frames = self.frames
            if len(frames) == 1:
                self._types = {message_name(frames[0][3]): 1}
            else:
                ids: dict[int, int] = {}
                for mid in map(_MSG_ID, frames):
                    ids[mid] = ids.get(mid, 0) + 1
                self._types = {message_name(mid): n for mid, n in ids.items()}
        return self._types

    def size_bytes(self) -> int:
        """Their bytes, all frames together."""
        return sum(map(len, map(_BUF, self.frames)))

    def v1_frames(self) -> int:
        """How many are MAVLink 1 frames (the rest are MAVLink 2)."""
        return sum(1 for f in self.frames if f[0][0] == _STX_V1)

    def undecoded_frames(self) -> list[tuple[UndecodedFrame, int]]:
        """Each frame as an `UndecodedFrame` with its receive time [ns], for per-message consumers."""
        return [(UndecodedFrame(buf, sysid, compid, mid), rx) for buf, sysid, compid, mid, rx in self.frames]


def split_foreign(data: bytes, rx_ns: int, decode_systems: frozenset[int], out: list[ForeignFrame]) -> bytes | None:
    """Append the frames of other systems than ``decode_systems`` to ``out`` (stamped ``rx_ns``) and return the
    bytes of the frames to decode (b"" if none); None, with ``out`` unchanged, if the datagram is not whole
    frames (then all of it is pymavlink's)."""
    n = len(data)
    if n < 8:
        return None if n else b""
    stx = data[0]
    # One frame per datagram (what autopilots, routers and most floods send): no copies, no loop.
    if stx == _STX_V2 and n >= 10:
        end = 12 + data[1] + (13 if data[2] & _SIGNED else 0)
        if end == n:
            sysid = data[5]
            msgid = data[7] | data[8] << 8 | data[9] << 16
            if sysid in decode_systems or msgid in ALWAYS_DECODED:
                return data
            out.append((data, sysid, data[6], msgid, rx_ns))
            return b""
    elif stx == _STX_V1 and 8 + data[1] == n:
        sysid, msgid = data[3], data[5]
        if sysid in decode_systems or msgid in ALWAYS_DECODED:
            return data
        out.append((data, sysid, data[4], msgid, rx_ns))
        return b""
    keep = bytearray()
    mark = len(out)
    i = 0
    while i < n:
        stx = data[i]
        if stx == _STX_V2:
            if i + 10 > n:
                del out[mark:]
                return None
            end = i + 12 + data[i + 1] + (13 if data[i + 2] & _SIGNED else 0)
            sysid, compid = data[i + 5], data[i + 6]
            msgid = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
        elif stx == _STX_V1:
            if i + 6 > n:
                del out[mark:]
                return None
            end = i + 8 + data[i + 1]
            sysid, compid, msgid = data[i + 3], data[i + 4], data[i + 5]
        else:
            del out[mark:]
            return None
        if end > n:
            del out[mark:]
            return None
        if sysid in decode_systems or msgid in ALWAYS_DECODED:
            keep += data[i:end]
        else:
            out.append((bytes(data[i:end]), sysid, compid, msgid, rx_ns))
        i = end
    return bytes(keep)


def split_datagram(data: bytes, decode_systems: frozenset[int]) -> tuple[bytes, list[UndecodedFrame]] | None:
    """(bytes of the frames to decode, frames of other systems) or None if the datagram is not whole frames."""
    others: list[ForeignFrame] = []
    keep = split_foreign(bytes(data), 0, decode_systems, others)
    if keep is None:
        return None
    return keep, [UndecodedFrame(buf, sysid, compid, mid) for buf, sysid, compid, mid, _ in others]
