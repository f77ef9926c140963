"""The simulated autopilot's links: each MAVLink connection, the pair of them, and MAVLink 1 framing.

`AutopilotLink` is one connection (mavutil for the transport, a MAVLink 2 codec of our own);
`mavlink1_frame` writes a message as a real MAVLink 1 sender does. `AutopilotLinks` holds the
companion link and the optional GCS link, and knows when the scenario's "autopilot link drops" silence
the companion link. Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import contextlib
import struct
import threading
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v10 import common as mavlink1_dialect
from pymavlink.dialects.v20 import common as mavlink2

from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.scenario import Scenario, SimError

__all__ = ["COMPONENT_ID", "SYSTEM_ID", "AutopilotLink", "AutopilotLinks", "mavlink1_frame"]

SYSTEM_ID = 1
COMPONENT_ID = 1


def _v1_payload_length(msg_id: int) -> int | None:
    cls = mavlink1_dialect.mavlink_map.get(msg_id)
    return None if cls is None else struct.calcsize(bytes(cls.native_format).decode())


def mavlink1_frame(msg: Any, mav: Any) -> bytes:
    """A MAVLink 1 frame as a MAVLink 1 sender writes it: without the MAVLink 2 extension fields.

    (pymavlink's force_mavlink1 keeps the extensions in the payload; real v1 senders cannot.)
    """
    buf = bytes(msg.pack(mav, force_mavlink1=True))
    length = _v1_payload_length(msg.get_msgId())
    if length is None or length >= buf[1]:
        return buf
    header = bytes([buf[0], length]) + buf[2:6]
    payload = buf[6 : 6 + length]
    crc = mavlink2.x25crc(header[1:] + payload)
    crc.accumulate(bytes([msg.crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


class AutopilotLink:
    """One MAVLink connection: mavutil for the transport, a MAVLink 2 codec of our own."""

    def __init__(self, url: str, name: str, baud: int, system_id: int = SYSTEM_ID) -> None:
        self.url = url
        self.name = name
        try:
            self.conn: Any = mavutil.mavlink_connection(
                url, baud=baud, source_system=system_id, source_component=COMPONENT_ID, autoreconnect=False
            )
        except (OSError, ValueError) as exc:
            raise SimError(f"autopilot {name} link {url}: cannot open: {exc}") from exc
        self.tx = mavlink2.MAVLink(self.conn, srcSystem=system_id, srcComponent=COMPONENT_ID)
        self.rx = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=COMPONENT_ID)
        self.rx.robust_parsing = True
        self.lock = threading.Lock()

    def fileno(self) -> int | None:
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def local_address(self) -> tuple[str, int] | None:
        port = getattr(self.conn, "port", None)
        try:
            addr = port.getsockname() if port is not None else None
        except OSError:
            return None
        return (str(addr[0]), int(addr[1])) if isinstance(addr, tuple) else None

    def send(self, msg: Any, mavlink1: bool = False) -> None:
        with self.lock:
            if not mavlink1:
                self.tx.send(msg)
                return
            self.conn.write(mavlink1_frame(msg, self.tx))
            self.tx.seq = (self.tx.seq + 1) % 256

    def send_as(self, msg: Any, codec: Any) -> None:
        """Send a message packed by another sender's codec (its own system/component and sequence)."""
        with self.lock:
            self.conn.write(bytes(msg.pack(codec)))
            codec.seq = (codec.seq + 1) % 256

    def forward(self, raw: bytes) -> None:
        with self.lock:
            self.conn.write(raw)

    def read(self) -> list[Any]:
        """Every complete message that has arrived (non-blocking)."""
        out: list[Any] = []
        for _ in range(64):
            try:
                data = self.conn.recv(4096)
            except OSError:
                break
            if not data:
                break
            if isinstance(data, str):
                data = data.encode("latin-1")
            msgs = self.rx.parse_buffer(data)
            if msgs:
                out.extend(m for m in msgs if m.get_type() != "BAD_DATA")
        return out

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.close()


class AutopilotLinks:
    """The companion link and the optional GCS link (open between `open` and `close`)."""

    def __init__(self, scenario: Scenario, clock: AutopilotClock) -> None:
        self.scenario = scenario
        self.clock = clock
        self.companion: AutopilotLink | None = None
        self.gcs: AutopilotLink | None = None

    def open(self, companion_url: str, gcs_url: str | None, baud: int, system_id: int) -> None:
        try:
            self.companion = AutopilotLink(companion_url, "companion", baud, system_id)
            if gcs_url is not None:
                self.gcs = AutopilotLink(gcs_url, "gcs", baud, system_id)
        except SimError:
            self.close()
            raise

    def close(self) -> None:
        for link in (self.companion, self.gcs):
            if link is not None:
                link.close()
        self.companion = None
        self.gcs = None

    def companion_dropped(self, tau_s: float) -> bool:
        return any(a <= tau_s < b for a, b in self.scenario.faults.autopilot_link_drops_s)

    def send_companion(self, msg: Any) -> None:
        """A command of the autopilot's camera backend: on the companion link, where the camera is."""
        if self.companion is not None and not self.companion_dropped(self.clock.tau_now()):
            self.companion.send(msg)

    def links_now(self, *, companion_only: bool = False) -> list[AutopilotLink]:
        out: list[AutopilotLink] = []
        if self.companion is not None and not self.companion_dropped(self.clock.tau_now()):
            out.append(self.companion)
        if self.gcs is not None and not companion_only:
            out.append(self.gcs)
        return out
