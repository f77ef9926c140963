"""Splitting a UDP datagram into MAVLink frames by their headers, to leave other systems' frames undecoded.

pymavlink parses every frame fully (CRC, unpacking, a message object), about 20 us each in Python; on a
shared network or a swarm's radio most traffic may come from other systems that the recorder only keeps
raw. The header alone (MAVLink 1: ``FE len seq sys comp msgid``, MAVLink 2: ``FD len incompat compat
seq sys comp msgid[3]``, then payload, CRC and, if signed, 13 signature bytes) tells a frame's length
and its sender, which pymavlink has no call to read without decoding. `split_datagram` walks the
headers and returns None as soon as anything does not look like whole frames, so that the caller hands
the datagram to pymavlink as before. The frames left undecoded are not CRC-checked: they are kept raw
and used for nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = ["ALWAYS_DECODED", "UndecodedFrame", "split_datagram"]

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


@dataclass(frozen=True, slots=True)
class UndecodedFrame:
    """A frame left undecoded: what a pymavlink message tells about itself without its fields."""

    buf: bytes
    src_system: int
    src_component: int
    msg_id: int

    def get_type(self) -> str:
        return _NAMES.get(self.msg_id, f"UNKNOWN_{self.msg_id}")

    def get_srcSystem(self) -> int:  # noqa: N802 - pymavlink's spelling
        return self.src_system

    def get_srcComponent(self) -> int:  # noqa: N802
        return self.src_component

    def get_msgId(self) -> int:  # noqa: N802
        return self.msg_id

    def get_msgbuf(self) -> bytes:
        return self.buf


def split_datagram(data: bytes, decode_systems: frozenset[int]) -> tuple[bytes, list[UndecodedFrame]] | None:
    """(bytes of the frames to decode, frames of other systems) or None if the datagram is not whole frames."""
    keep = bytearray()
    other: list[UndecodedFrame] = []
    i, n = 0, len(data)
    while i < n:
        stx = data[i]
        if stx == _STX_V2:
            if i + 10 > n:
                return None
            end = i + 12 + data[i + 1] + (13 if data[i + 2] & _SIGNED else 0)
            sysid, compid = data[i + 5], data[i + 6]
            msgid = data[i + 7] | data[i + 8] << 8 | data[i + 9] << 16
        elif stx == _STX_V1:
            if i + 6 > n:
                return None
            end = i + 8 + data[i + 1]
            sysid, compid, msgid = data[i + 3], data[i + 4], data[i + 5]
        else:
            return None
        if end > n:
            return None
        if sysid in decode_systems or msgid in ALWAYS_DECODED:
            keep += data[i:end]
        else:
            other.append(UndecodedFrame(bytes(data[i:end]), sysid, compid, msgid))
        i = end
    return bytes(keep), other
