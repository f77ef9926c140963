"""The simulated autopilot's MAVLink on a TCP stream instead of UDP datagrams, for the recorder's threaded path.

A recorder on a companion computer often reaches the autopilot over a byte stream, not UDP: a serial port
(the flight controller's TELEM port) or TCP (ArduPilot SITL's primary port 5760, mavlink-router's TCP
server). On such a link the recorder's MAVLink reader thread reads the stream (`icgt.mavlink.link`), not its
worker, and what the worker does while it waits for a frame's telemetry differs. The simulator speaks UDP
only, so this bridge stands in for the router: it takes the autopilot's datagrams on the UDP port the
simulator sends to and writes their bytes to the one TCP client connected (the recorder, with
``--mavlink tcp:127.0.0.1:PORT``); what the client writes goes back to the address the datagrams came from.
Datagrams that arrive while no client is connected are dropped, as a serial line drops bytes sent with
nothing listening, and counted (`dropped_datagrams`).

Written here rather than taken from mavlink-router: that is a C++ daemon to build and configure, and the
tests need only this forwarding, in-process and on any port.
"""

from __future__ import annotations

import contextlib
import selectors
import socket
import threading

__all__ = ["TcpBridge"]


class TcpBridge:
    """UDP datagrams from the simulator <-> one TCP client (a background thread; `close()` ends it)."""

    def __init__(self, udp_port: int) -> None:
        self._udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self._udp.bind(("127.0.0.1", udp_port))
        self._server = socket.create_server(("127.0.0.1", 0))
        self.tcp_port: int = self._server.getsockname()[1]
        self.dropped_datagrams = 0
        self.forwarded_datagrams = 0
        self._peer: tuple[str, int] | None = None
        self._client: socket.socket | None = None
        self._stop = threading.Event()
        self._sel = selectors.DefaultSelector()
        self._thread = threading.Thread(target=self._run, name="sim-tcp-bridge", daemon=True)
        self._thread.start()

    @property
    def url(self) -> str:
        """The pymavlink URL the recorder connects with."""
        return f"tcp:127.0.0.1:{self.tcp_port}"

    def _run(self) -> None:
        self._sel.register(self._udp, selectors.EVENT_READ, "udp")
        self._sel.register(self._server, selectors.EVENT_READ, "accept")
        while not self._stop.is_set():
            for key, _ in self._sel.select(timeout=0.2):
                if key.data == "udp":
                    self._from_udp()
                elif key.data == "accept":
                    self._accept()
                else:
                    self._from_client(key.fileobj)  # type: ignore[arg-type]

    def _from_udp(self) -> None:
        try:
            data, self._peer = self._udp.recvfrom(65536)
        except OSError:
            return
        client = self._client
        if client is None:
            self.dropped_datagrams += 1
            return
        try:
            client.sendall(data)
            self.forwarded_datagrams += 1
        except OSError:
            self.dropped_datagrams += 1
            self._drop_client()

    def _accept(self) -> None:
        conn, _ = self._server.accept()
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # a router forwards each message at once
        self._drop_client()  # one client at a time: the newest (a recorder that reconnected)
        self._client = conn
        self._sel.register(conn, selectors.EVENT_READ, "client")

    def _from_client(self, sock: socket.socket) -> None:
        client = self._client
        if client is None or sock is not client:  # an event of a client dropped earlier in this batch
            return
        try:
            data = client.recv(65536)
        except OSError:
            data = b""
        if not data:
            self._drop_client()
            return
        if self._peer is not None:
            with contextlib.suppress(OSError):
                self._udp.sendto(data, self._peer)

    def _drop_client(self) -> None:
        client, self._client = self._client, None
        if client is not None:
            with contextlib.suppress(KeyError, ValueError):
                self._sel.unregister(client)
            client.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._drop_client()
        for s in (self._udp, self._server):
            s.close()
        self._sel.close()
