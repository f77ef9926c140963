"""MAVLink 2 message signing: the key file, and turning signing on for a pymavlink parser or packer.

The key file holds a passphrase (UTF-8 text; one trailing newline is ignored). The 32-byte secret key is
its SHA-256, which is what QGroundControl (Application Settings > MAVLink > signing key) and MAVProxy
(``signing setup PASSPHRASE``) derive from the passphrase typed there, so the same passphrase in all three
gives the same key. The key itself never leaves this module's callers: it is not logged, not in the
recording's configuration record (which holds the file's path only) and not in any repr.

Signing state (`SigningState`) keeps one MAVLinkSigning object for the link's input, shared by every
parser the link makes (a parser is replaced after a truncated datagram; the replay protection, the last
timestamp seen per stream, must survive that), and one for its output.
"""

from __future__ import annotations

import hashlib
import hmac
import logging
import os
import stat
import time
from pathlib import Path
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.errors import IcgtError

__all__ = ["SigningError", "SigningState", "frame_has_signature", "key_from_passphrase", "load_signing_key"]

log = logging.getLogger(__name__)

_EPOCH_2015_S = 1_420_070_400  # MAVLink signing timestamps count 10 us units since 2015-01-01 00:00 UTC
_KEY_BYTES = 32
_NEW_STREAM_SLACK = 60 * 100_000  # a new stream may start up to one minute behind (10 us units), as MAVLink says


class SigningError(IcgtError):
    """The signing key file cannot be used (missing, unreadable, empty, not UTF-8)."""


def key_from_passphrase(passphrase: str) -> bytes:
    """The 32-byte secret key of a passphrase: SHA-256 of its UTF-8 bytes (as QGroundControl and MAVProxy)."""
    if not passphrase:
        raise SigningError("the signing passphrase is empty")
    return hashlib.sha256(passphrase.encode("utf-8")).digest()


def load_signing_key(path: Path) -> bytes:
    """The secret key of the passphrase in ``path``. SigningError names the file and what is wrong."""
    try:
        raw = path.read_bytes()
        mode = path.stat().st_mode
    except OSError as exc:
        raise SigningError(f"[mavlink] signing_key_file {str(path)!r}: cannot read it ({exc.strerror})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise SigningError(f"[mavlink] signing_key_file {str(path)!r}: not UTF-8 text") from None
    if text.endswith("\n"):
        text = text[:-1].removesuffix("\r")
    if not text:
        raise SigningError(f"[mavlink] signing_key_file {str(path)!r}: empty (write the passphrase into it)")
    if os.name == "posix" and mode & (stat.S_IRWXG | stat.S_IRWXO):
        # not fatal (a read-only SD card image may not keep modes), but worth saying
        log.warning("signing key file %s is readable by other users (mode %o): chmod 600 it", path, stat.S_IMODE(mode))
    return key_from_passphrase(text)


def _now_timestamp() -> int:
    """The signing timestamp of now: 10 us units since 2015-01-01 UTC."""
    return max(0, (time.time_ns() // 10_000) - _EPOCH_2015_S * 100_000)


def frame_has_signature(msg: Any) -> bool:
    """Whether a received frame carried a signature block (valid or not): MAVLink 2 incompat flag 0x01."""
    buf = msg.get_msgbuf()
    return bool(buf) and buf[0] == mavlink2.PROTOCOL_MARKER_V2 and bool(buf[2] & mavlink2.MAVLINK_IFLAG_SIGNED)


class SigningState:
    """Signing for one link: ``attach_input`` on each parser, ``attach_output`` on the packer.

    Input accepts unsigned and badly signed frames (other systems' messages are still logged); each message
    says whether its signature was valid (``msg.get_signed()``) and the consumers decide: the camera for
    commands, the synchroniser (``SyncConfig.require_signed_autopilot``) for the autopilot's telemetry.
    Counters: `counts`."""

    def __init__(self, key: bytes, link_id: int = 0) -> None:
        if len(key) != _KEY_BYTES:
            raise SigningError(f"a MAVLink signing key has {_KEY_BYTES} bytes, got {len(key)}")
        self._rx = mavlink2.MAVLinkSigning()
        self._rx.secret_key = key
        self._rx.timestamp = _now_timestamp()
        self._rx.allow_unsigned_callback = lambda _mav, _msg_id: True
        self._tx = mavlink2.MAVLinkSigning()
        self._tx.secret_key = key
        self._tx.link_id = link_id & 0xFF
        self._tx.sign_outgoing = True
        self._tx.timestamp = _now_timestamp()

    def __repr__(self) -> str:
        return f"SigningState(link_id={self._tx.link_id})"  # never the key

    def attach_input(self, parser: Any) -> None:
        parser.signing = self._rx
        # pymavlink's own check records a stream's timestamp before it compares the signature, so one forged
        # frame with a timestamp far ahead would make every genuine frame of that stream look replayed.
        parser.check_signature = self._check

    def _check(self, msgbuf: bytearray, src_system: int, src_component: int) -> bool:
        """A frame's signature is valid (our key) and its timestamp newer than its stream's last one."""
        rx = self._rx
        expected = hashlib.sha256(bytes(rx.secret_key) + bytes(msgbuf[:-6])).digest()[:6]
        if not hmac.compare_digest(expected, bytes(msgbuf[-6:])):
            return False
        link_id = msgbuf[-13]
        stamp = int.from_bytes(bytes(msgbuf[-12:-6]), "little")
        stream = (link_id, src_system, src_component)
        last = rx.stream_timestamps.get(stream)
        if last is not None and stamp <= last:
            return False  # replayed (or reordered): refused
        if last is None and stamp + _NEW_STREAM_SLACK < rx.timestamp:
            return False  # a new stream whose clock is far behind ours: an old recording played back
        rx.stream_timestamps[stream] = stamp
        rx.timestamp = max(rx.timestamp, stamp)
        return True

    def attach_output(self, packer: Any) -> None:
        # a timestamp behind the wall clock (a long idle link) would be refused as stale by receivers
        self._tx.timestamp = max(self._tx.timestamp, _now_timestamp())
        packer.signing = self._tx

    @property
    def counts(self) -> dict[str, int]:
        """Frames received with a valid signature, with an invalid one (bad key, replayed) and without."""
        rx = self._rx
        return {
            "signed_ok": int(rx.goodsig_count),
            "signed_bad": int(rx.badsig_count),
            "unsigned": int(rx.unsigned_count) - int(rx.badsig_count),
        }
