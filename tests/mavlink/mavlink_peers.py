"""Minimal pymavlink peers for the MAVLink tests: an "autopilot" and a "ground station" on 127.0.0.1 UDP.

Each peer owns a UDP socket on an ephemeral port, packs with its own (system, component) ids and collects
everything it receives on a reader thread. The autopilot peer answers SET_MESSAGE_INTERVAL and TIMESYNC
the way ArduPilot and PX4 do, and can stream telemetry and go silent to simulate a link outage.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

# MAVLink 1 payload lengths of the messages with MAVLink 2 extensions used in the tests: a MAVLink 1
# sender (C library, ArduPilot on a v1 port) sends only these bytes; pymavlink's force_mavlink1 would
# also pack the extension fields.
V1_PAYLOAD_LEN = {"GPS_RAW_INT": 30, "ATTITUDE_QUATERNION": 32, "COMMAND_ACK": 3, "HEARTBEAT": 9}


def pack_v1(msg: Any, mav: Any) -> bytes:
    """A MAVLink 1 frame as a MAVLink 1 sender would write it (no extension fields)."""
    buf = bytearray(msg.pack(mav, force_mavlink1=True))
    assert buf[0] == 0xFE
    length = V1_PAYLOAD_LEN.get(msg.get_type(), buf[1])
    header = bytes([0xFE, length]) + bytes(buf[2:6])
    payload = bytes(buf[6 : 6 + length])
    crc = mavlink2.x25crc(header[1:] + payload)
    crc.accumulate(bytes([msg.crc_extra]))
    return header + payload + crc.crc.to_bytes(2, "little")


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def wait_until(predicate: Callable[[], object], timeout: float = 2.0, step: float = 0.005) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return bool(predicate())


class Peer:
    """A MAVLink endpoint at (system, component) that talks to the link under test at ``target``."""

    def __init__(self, system: int, component: int, target_port: int) -> None:
        self.system = system
        self.component = component
        self.target = ("127.0.0.1", target_port)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.02)
        self.mav: Any = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
        self._parser: Any = mavlink2.MAVLink(None, srcSystem=system, srcComponent=component)
        self._parser.robust_parsing = True
        self._lock = threading.Lock()
        self.received: list[Any] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"peer-{system}-{component}", daemon=True)
        self._thread.start()

    # sending
    def send(self, msg: Any, *, v1: bool = False) -> None:
        buf = pack_v1(msg, self.mav) if v1 else msg.pack(self.mav)
        self.mav.seq = (self.mav.seq + 1) % 256
        self.sock.sendto(buf, self.target)

    def send_raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.target)

    def command_long(
        self, target_system: int, target_component: int, command: int, *params: float, confirmation: int = 0
    ) -> None:
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.send(self.mav.command_long_encode(target_system, target_component, command, confirmation, *p))

    # receiving
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(65536)
            except (TimeoutError, OSError):
                continue
            for msg in self._parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    continue
                with self._lock:
                    self.received.append(msg)
                self.on_message(msg)

    def on_message(self, msg: Any) -> None:
        """Hook for auto-responders."""

    def mark(self) -> int:
        with self._lock:
            return len(self.received)

    def messages(self, mtype: str | None = None, since: int = 0) -> list[Any]:
        with self._lock:
            msgs = self.received[since:]
        return [m for m in msgs if mtype is None or m.get_type() == mtype]

    def wait_for(
        self, mtype: str, predicate: Callable[[Any], bool] = lambda m: True, timeout: float = 2.0, since: int = 0
    ) -> Any:
        found: list[Any] = []

        def check() -> bool:
            found[:] = [m for m in self.messages(mtype, since) if predicate(m)]
            return bool(found)

        if not wait_until(check, timeout):
            raise AssertionError(f"no {mtype} matching within {timeout} s")
        return found[0]

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)
        self.sock.close()


class AutopilotPeer(Peer):
    """System 1 component 1 by default. Answers SET_MESSAGE_INTERVAL (optionally ignoring the first
    ``ignore_first`` requests per message id, or never for ids in ``never_ack``) and TIMESYNC requests with
    tc1 = its boot clock in ns. ``stream()`` sends HEARTBEAT + telemetry until ``silence()``."""

    def __init__(self, target_port: int, system: int = 1, component: int = 1) -> None:
        self.boot_ns = time.monotonic_ns() - 5_000_000_000  # "booted" 5 s ago
        self.interval_requests: list[tuple[int, int, int]] = []  # (message id, interval us, confirmation)
        self.ignore_first: dict[int, int] = {}
        self.never_ack: set[int] = set()
        self.answer_timesync = True
        self.timesync_requests: list[int] = []
        self._silent = threading.Event()
        self._streaming = threading.Event()
        self._stream_thread: threading.Thread | None = None
        super().__init__(system, component, target_port)

    def boot_ms(self) -> int:
        return (time.monotonic_ns() - self.boot_ns) // 1_000_000

    def on_message(self, msg: Any) -> None:
        if self._silent.is_set():
            return
        mtype = msg.get_type()
        if mtype == "COMMAND_LONG" and msg.command == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            msg_id = int(msg.param1)
            self.interval_requests.append((msg_id, int(msg.param2), int(msg.confirmation)))
            if msg_id in self.never_ack:
                return
            if self.ignore_first.get(msg_id, 0) > 0:
                self.ignore_first[msg_id] -= 1
                return
            self.send(
                self.mav.command_ack_encode(
                    msg.command, mavlink2.MAV_RESULT_ACCEPTED, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
                )
            )
        elif mtype == "TIMESYNC" and msg.tc1 == 0:
            self.timesync_requests.append(int(msg.ts1))
            if self.answer_timesync:
                self.send(self.mav.timesync_encode(time.monotonic_ns() - self.boot_ns, msg.ts1))

    def heartbeat(self) -> None:
        self.send(
            self.mav.heartbeat_encode(
                mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, mavlink2.MAV_STATE_ACTIVE
            )
        )

    def stream(self, hz: float = 50.0) -> None:
        self._silent.clear()
        if self._stream_thread is None:
            self._streaming.set()
            self._stream_thread = threading.Thread(target=self._stream_loop, args=(hz,), daemon=True)
            self._stream_thread.start()

    def silence(self) -> None:
        self._silent.set()

    def resume(self) -> None:
        """Answer again after `silence` (without starting a stream)."""
        self._silent.clear()

    def _stream_loop(self, hz: float) -> None:
        next_hb = 0.0
        while self._streaming.is_set():
            if not self._silent.is_set():
                now = time.monotonic()
                if now >= next_hb:
                    self.heartbeat()
                    next_hb = now + 0.2
                self.send(self.mav.attitude_encode(self.boot_ms(), 0.1, -0.05, 1.0, 0.0, 0.0, 0.0))
            time.sleep(1.0 / hz)

    def close(self) -> None:
        self._streaming.clear()
        if self._stream_thread is not None:
            self._stream_thread.join(1.0)
        super().close()
