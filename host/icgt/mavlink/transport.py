"""Opening a pymavlink transport from a URL as users write them, with the checks pymavlink does not make."""

from __future__ import annotations

import os
from typing import Any

from pymavlink import mavutil

from icgt.mavlink.link_types import LinkConfig, LinkError
from icgt.mavlink.udp_stamps import replace_socket, stamped_udp_socket

__all__ = ["is_datagram", "open_transport"]


def is_datagram(url: str) -> bool:
    return url.startswith(("udp:", "udpin:", "udpout:", "udpbcast:", "mcast:"))


def _listening_address(url: str) -> tuple[str, int] | None:
    """(host, port) of a URL on which pymavlink binds and listens (udpin:, udp:), else None."""
    for prefix in ("udpin:", "udp:"):
        if url.startswith(prefix):
            host, sep, port = url[len(prefix) :].rpartition(":")
            if sep and port.isdigit():
                return host, int(port)
    return None


def open_transport(config: LinkConfig, *, stamped: bool = False) -> Any:
    """Open the pymavlink transport. Serial device paths go straight to mavserial (pymavlink would take a
    /dev/serial/by-id/...:... path for a UDP address because of its colon).

    `stamped`: a listening UDP socket has kernel arrival stamps on before it is bound (`icgt.mavlink.udp_stamps`:
    otherwise the datagrams of an autopilot that is already sending get the time they are read)."""
    url = config.url.strip()
    if not url:
        raise LinkError("empty MAVLink URL: use e.g. udpin:0.0.0.0:14550, tcp:host:5760 or /dev/ttyAMA0,921600")
    try:
        if url.startswith("/") or url.upper().startswith("COM"):
            device, _, baud_text = url.partition(",")
            baud = int(baud_text) if baud_text else config.baud
            if not os.path.exists(device) and not url.upper().startswith("COM"):
                raise LinkError(f"serial device {device} does not exist")
            return mavutil.mavserial(
                device, baud=baud, source_system=config.system_id, source_component=config.component_id
            )
        if not url.startswith(("udp:", "udpin:", "udpout:", "udpbcast:", "tcp:", "tcpin:", "mcast:")):
            raise LinkError(
                f"unsupported MAVLink URL {url!r}: use udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
                "tcpin:HOST:PORT or a serial device such as /dev/ttyAMA0,921600"
            )
        listen = _listening_address(url) if stamped else None
        if listen is not None:
            sock = stamped_udp_socket(*listen)
            try:  # pymavlink's mavudp on a placeholder port, then given the stamped socket
                conn = mavutil.mavlink_connection(
                    f"udpin:{listen[0]}:0", source_system=config.system_id, source_component=config.component_id
                )
            except BaseException:
                sock.close()
                raise
            replace_socket(conn, sock)
            return conn
        return mavutil.mavlink_connection(
            url,
            baud=config.baud,
            source_system=config.system_id,
            source_component=config.component_id,
            robust_parsing=True,
            autoreconnect=False,
            retries=0,
        )
    except LinkError:
        raise
    except Exception as exc:  # pymavlink raises OSError, ValueError, SerialException, ...
        raise LinkError(f"cannot open MAVLink link {url!r}: {exc}") from exc
