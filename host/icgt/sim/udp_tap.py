"""A UDP relay between a ground station and the simulated autopilot's ground-station port that can cut the link.

`UdpTap` listens on a local port for the client (MAVSDK ``udpout://127.0.0.1:<port>``, pymavlink
``udpout:127.0.0.1:<port>``) and relays every datagram to the upstream port from a socket of its own, and
every answer back to the client that spoke last. While `dropping` (a radio drop) it discards both
directions and counts what it discarded: the client and the camera each see the other go silent, as with
a telemetry radio out of range. A client that restarts (a new socket, a new port) is followed: answers go
to whoever spoke last.
"""

from __future__ import annotations

import select
import socket
import threading

__all__ = ["UdpTap"]


class UdpTap:
    """Relay ``127.0.0.1:port`` <-> ``upstream``; `drop` cuts both directions. Context manager."""

    def __init__(self, upstream: tuple[str, int]) -> None:
        self.upstream = upstream
        self._client_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._client_side.bind(("127.0.0.1", 0))
        self._upstream_side = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._upstream_side.bind(("127.0.0.1", 0))
        for s in (self._client_side, self._upstream_side):
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.port: int = self._client_side.getsockname()[1]
        self._client: tuple[str, int] | None = None
        self._dropping = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self.relayed = {"to_upstream": 0, "to_client": 0}
        self.dropped = {"to_upstream": 0, "to_client": 0}
        self._thread = threading.Thread(target=self._run, name="icgt-udp-tap", daemon=True)

    @property
    def mavsdk_url(self) -> str:
        return f"udpout://127.0.0.1:{self.port}"

    @property
    def dropping(self) -> bool:
        return self._dropping.is_set()

    def drop(self, on: bool = True) -> None:
        """Cut (True) or restore (False) the link, both directions."""
        if on:
            self._dropping.set()
        else:
            self._dropping.clear()

    def start(self) -> UdpTap:
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self._client_side.close()
        self._upstream_side.close()

    def __enter__(self) -> UdpTap:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _count(self, which: dict[str, int], key: str) -> None:
        with self._lock:
            which[key] += 1

    def _run(self) -> None:
        socks = [self._client_side, self._upstream_side]
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select(socks, [], [], 0.1)
            except (OSError, ValueError):
                return
            for s in ready:
                try:
                    data, addr = s.recvfrom(65536)
                except OSError:
                    continue
                if s is self._client_side:
                    self._client = addr
                    if self.dropping:
                        self._count(self.dropped, "to_upstream")
                        continue
                    try:
                        self._upstream_side.sendto(data, self.upstream)
                    except OSError:
                        continue  # the simulator is gone (shutting down)
                    self._count(self.relayed, "to_upstream")
                else:
                    if self.dropping or self._client is None:
                        self._count(self.dropped, "to_client")
                        continue
                    try:
                        self._client_side.sendto(data, self._client)
                    except OSError:
                        continue  # the client is gone (restarting)
                    self._count(self.relayed, "to_client")
