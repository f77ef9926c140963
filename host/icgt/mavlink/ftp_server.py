"""A read-only MAVLink FTP server (https://mavlink.io/en/services/ftp.html) for a few files held in memory.

The camera serves its definition file this way (``cam_definition_uri = "mftp://<name>"``): the ground
station reaches the recorder only over MAVLink (a telemetry radio through the autopilot), so an http URI
would need a network route it does not have. Written here because pymavlink has only an FTP client
(`pymavlink.mavftp`) and no server; what it implements, from the protocol's page:

* OpenFileRO (the size back as a uint32), ReadFile (up to 239 bytes at an offset; past the end: NAK EOF),
  BurstReadFile (the rest of the file in consecutive ACKs, the last marked burst_complete), TerminateSession,
  ResetSessions, ListDirectory of the root (``F<name>\\t<size>`` entries) and CalcFileCRC32 (zlib's CRC-32, the
  protocol's). Every other opcode: NAK FileProtected for the writing ones (this file system is read-only),
  UnknownCommand otherwise.
* Each client (system, component) has its own sessions, numbered from 0 (MAVSDK never reads the session a
  reply gives and always sends 0); at most `MAX_SESSIONS` per client, the oldest one closed for a new one.
* A reply's seq_number is the request's + 1. A request that repeats the client's previous seq_number is
  a retransmission (its reply was lost): the previous replies are sent again, not recomputed.
* A path is a file's name with or without a leading ``/``; MAVSDK saves a download under the path it asked
  for, so names have no folder.

`FtpServer.handle` takes one request payload (the 251 bytes of FILE_TRANSFER_PROTOCOL.payload) and returns
the reply payloads; the camera component sends them to the requester.
"""

from __future__ import annotations

import dataclasses
import struct
import threading
import zlib
from collections.abc import Mapping

__all__ = ["HEADER", "MAX_DATA", "MAX_SESSIONS", "FtpError", "FtpOpcode", "FtpReply", "FtpServer", "pack", "unpack"]

HEADER = struct.Struct("<HBBBBBBI")  # seq_number, session, opcode, size, req_opcode, burst_complete, padding, offset
PAYLOAD_LEN = 251
MAX_DATA = PAYLOAD_LEN - HEADER.size  # 239
MAX_SESSIONS = 4


class FtpOpcode:
    NONE = 0
    TERMINATE_SESSION = 1
    RESET_SESSIONS = 2
    LIST_DIRECTORY = 3
    OPEN_FILE_RO = 4
    READ_FILE = 5
    CREATE_FILE = 6
    WRITE_FILE = 7
    REMOVE_FILE = 8
    CREATE_DIRECTORY = 9
    REMOVE_DIRECTORY = 10
    OPEN_FILE_WO = 11
    TRUNCATE_FILE = 12
    RENAME = 13
    CALC_FILE_CRC32 = 14
    BURST_READ_FILE = 15
    ACK = 128
    NAK = 129


class FtpError:
    """NAK error codes (data[0] of a NAK)."""

    FAIL = 1
    INVALID_DATA_SIZE = 3
    INVALID_SESSION = 4
    NO_SESSIONS_AVAILABLE = 5
    EOF = 6
    UNKNOWN_COMMAND = 7
    FILE_PROTECTED = 9
    FILE_NOT_FOUND = 10


_WRITING = {
    FtpOpcode.CREATE_FILE,
    FtpOpcode.WRITE_FILE,
    FtpOpcode.REMOVE_FILE,
    FtpOpcode.CREATE_DIRECTORY,
    FtpOpcode.REMOVE_DIRECTORY,
    FtpOpcode.OPEN_FILE_WO,
    FtpOpcode.TRUNCATE_FILE,
    FtpOpcode.RENAME,
}


@dataclasses.dataclass(frozen=True, slots=True)
class FtpReply:
    """One FTP payload's fields (a request or a reply)."""

    seq: int
    session: int
    opcode: int
    req_opcode: int = 0
    offset: int = 0
    data: bytes = b""
    burst_complete: bool = False


def pack(p: FtpReply) -> list[int]:
    """The 251 payload bytes (as FILE_TRANSFER_PROTOCOL's uint8_t[251] wants them) of one FTP message."""
    head = HEADER.pack(
        p.seq & 0xFFFF, p.session, p.opcode, len(p.data), p.req_opcode, int(p.burst_complete), 0, p.offset
    )
    return list((head + p.data).ljust(PAYLOAD_LEN, b"\0"))


def unpack(payload: bytes | list[int]) -> FtpReply:
    """One FTP message from its payload bytes (the data cut to its size field, at most 239 bytes)."""
    raw = bytes(payload).ljust(PAYLOAD_LEN, b"\0")
    seq, session, opcode, size, req_opcode, burst, _, offset = HEADER.unpack_from(raw)
    data = raw[HEADER.size : HEADER.size + min(size, MAX_DATA)]
    return FtpReply(seq, session, opcode, req_opcode, offset, data, bool(burst))


@dataclasses.dataclass
class _Client:
    sessions: dict[int, str] = dataclasses.field(default_factory=dict)  # session -> file name, oldest first
    last_seq: int | None = None
    last_replies: list[FtpReply] = dataclasses.field(default_factory=list)


class FtpServer:
    """Read-only files by name. Thread-safe; `counts` says what was served."""

    def __init__(self, files: Mapping[str, bytes]) -> None:
        for name in files:
            if not name or "/" in name or "\0" in name:
                raise ValueError(f"FTP file name {name!r}: no folders, not empty")
        self._files = dict(files)
        self._clients: dict[tuple[int, int], _Client] = {}
        self._lock = threading.Lock()
        self.counts = {"ftp_requests": 0, "ftp_retransmissions": 0, "ftp_files_opened": 0, "ftp_bytes_read": 0}

    def handle(self, client: tuple[int, int], payload: bytes | list[int]) -> list[FtpReply]:
        """The replies to one request from ``client`` (system, component)."""
        req = unpack(payload)
        with self._lock:
            state = self._clients.setdefault(client, _Client())
            self.counts["ftp_requests"] += 1
            if state.last_seq == req.seq and state.last_replies:
                self.counts["ftp_retransmissions"] += 1
                return list(state.last_replies)
            replies = self._answer(state, req)
            state.last_seq, state.last_replies = req.seq, replies
            return replies

    # ------------------------------------------------------------------ opcodes (lock held)
    def _answer(self, state: _Client, req: FtpReply) -> list[FtpReply]:
        op = req.opcode
        if op == FtpOpcode.OPEN_FILE_RO:
            return [self._open(state, req)]
        if op == FtpOpcode.READ_FILE:
            return [self._read(state, req)]
        if op == FtpOpcode.BURST_READ_FILE:
            return self._burst(state, req)
        if op == FtpOpcode.TERMINATE_SESSION:
            if state.sessions.pop(req.session, None) is None:
                return [self._nak(req, FtpError.INVALID_SESSION)]
            return [self._ack(req)]
        if op == FtpOpcode.RESET_SESSIONS:
            state.sessions.clear()
            return [self._ack(req)]
        if op == FtpOpcode.LIST_DIRECTORY:
            return [self._list(req)]
        if op == FtpOpcode.CALC_FILE_CRC32:
            name = self._name(req.data)
            if name is None:
                return [self._nak(req, FtpError.FILE_NOT_FOUND)]
            return [self._ack(req, struct.pack("<I", zlib.crc32(self._files[name])))]
        if op in _WRITING:
            return [self._nak(req, FtpError.FILE_PROTECTED)]
        return [self._nak(req, FtpError.UNKNOWN_COMMAND)]

    def _name(self, data: bytes) -> str | None:
        name = data.split(b"\0", 1)[0].decode("utf-8", "replace").lstrip("/")
        return name if name in self._files else None

    def _open(self, state: _Client, req: FtpReply) -> FtpReply:
        name = self._name(req.data)
        if name is None:
            return self._nak(req, FtpError.FILE_NOT_FOUND)
        if len(state.sessions) >= MAX_SESSIONS:
            del state.sessions[next(iter(state.sessions))]  # a client that never closed its oldest one
        session = min(set(range(MAX_SESSIONS + 1)) - set(state.sessions))
        state.sessions[session] = name
        self.counts["ftp_files_opened"] += 1
        return dataclasses.replace(self._ack(req, struct.pack("<I", len(self._files[name]))), session=session)

    def _read(self, state: _Client, req: FtpReply) -> FtpReply:
        name = state.sessions.get(req.session)
        if name is None:
            return self._nak(req, FtpError.INVALID_SESSION)
        data = self._files[name]
        if req.offset >= len(data):
            return self._nak(req, FtpError.EOF)
        size = len(req.data) or MAX_DATA  # a request's data is its size field's worth of bytes (zeros)
        chunk = data[req.offset : req.offset + size]
        self.counts["ftp_bytes_read"] += len(chunk)
        return self._ack(req, chunk)

    def _burst(self, state: _Client, req: FtpReply) -> list[FtpReply]:
        name = state.sessions.get(req.session)
        if name is None:
            return [self._nak(req, FtpError.INVALID_SESSION)]
        data = self._files[name]
        if req.offset >= len(data):
            return [self._nak(req, FtpError.EOF)]
        out = []
        offsets = list(range(req.offset, len(data), MAX_DATA))
        for k, offset in enumerate(offsets):
            chunk = data[offset : offset + MAX_DATA]
            self.counts["ftp_bytes_read"] += len(chunk)
            last = k == len(offsets) - 1
            out.append(FtpReply(req.seq + 1 + k, req.session, FtpOpcode.ACK, req.opcode, offset, chunk, last))
        return out

    def _list(self, req: FtpReply) -> FtpReply:
        path = req.data.split(b"\0", 1)[0].decode("utf-8", "replace").strip("/")
        if path not in ("", "."):
            return self._nak(req, FtpError.FILE_NOT_FOUND)
        entries = [f"F{name}\t{len(data)}".encode() + b"\0" for name, data in sorted(self._files.items())]
        if req.offset >= len(entries):
            return self._nak(req, FtpError.EOF)
        body = b""
        for entry in entries[req.offset :]:
            if len(body) + len(entry) > MAX_DATA:
                break
            body += entry
        return self._ack(req, body)

    @staticmethod
    def _ack(req: FtpReply, data: bytes = b"") -> FtpReply:
        return FtpReply(req.seq + 1, req.session, FtpOpcode.ACK, req.opcode, req.offset, data)

    @staticmethod
    def _nak(req: FtpReply, error: int) -> FtpReply:
        return FtpReply(req.seq + 1, req.session, FtpOpcode.NAK, req.opcode, req.offset, bytes([error]))
