"""The device wire protocol: generated message classes and the framing codec."""

from icgt.protocol.codec import DecoderStats, Received, StreamDecoder, encode_frame
from icgt.protocol.messages import MESSAGE_TYPES, PROTOCOL_VERSION, TABLE_HASH, Message, MsgId

__all__ = [
    "MESSAGE_TYPES",
    "PROTOCOL_VERSION",
    "TABLE_HASH",
    "DecoderStats",
    "Message",
    "MsgId",
    "Received",
    "StreamDecoder",
    "encode_frame",
]
