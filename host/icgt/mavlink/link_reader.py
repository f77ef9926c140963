"""The MAVLink link's reading side: read the transport, stamp each chunk with its arrival time, follow the socket.

`LinkReader` reads whatever the transport has (a UDP socket drained with the kernel's arrival stamps,
SO_TIMESTAMPNS; a serial port or a TCP stream stamped as read), answers pymavlink's bookkeeping of UDP clients,
sizes the UDP receive buffer and counts what the kernel dropped (KERNEL_DROPS events); what it reads goes to
`LinkReceiver._feed` / `_parse`. Opening, closing and reopening the transport are the link's (`icgt.mavlink.link`).
"""

from __future__ import annotations

import contextlib
import errno
import logging
import select
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Any

from pymavlink import mavutil

from icgt.mavlink.frames import ForeignFrame, split_foreign
from icgt.mavlink.link_receive import LinkReceiver
from icgt.mavlink.link_types import LinkConfig, LinkEventKind, MavlinkEvent
from icgt.mavlink.udp_stamps import (
    SO_RXQ_OVFL,
    SO_TIMESTAMPNS,
    TIMESPEC,
    enable_stamps,
    rmem_max,
    socket_drops,
    stamps_enabled,
    wait_until_arrivals_stamped,
)

__all__ = ["DRAIN_MAX", "LinkReader"]

log = logging.getLogger("icgt.mavlink.link")

# Linux's SO_TIMESTAMPNS / SCM_TIMESTAMPNS (Python's socket module does not name them): a struct timespec
# of the datagram's arrival on CLOCK_REALTIME in the ancillary data of recvmsg.
_SCM_TIMESTAMPNS = SO_TIMESTAMPNS  # the control message's type is the option's number
# SO_RXQ_OVFL: a datagram read after the kernel dropped some (receive buffer full) carries the socket's count of
# drops so far (a u32) in its ancillary data.
_CMSG_SPACE = socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4)
_U32 = struct.Struct("I")
DRAIN_MAX = 1024  # datagrams read per wake-up, at most


class LinkReader(LinkReceiver):
    """Reading and stamping the transport, and the UDP socket's buffer and drops (a base of `MavlinkLink`)."""

    def __init__(
        self,
        config: LinkConfig,
        on_event: Callable[[MavlinkEvent], None] | None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        super().__init__(config, on_event, clock)
        self._send_lock = threading.Lock()  # writes, and closing a TCP client socket
        self._stop = threading.Event()
        self.receive_buffer_bytes = 0  # the UDP socket's receive buffer once open: what the kernel granted [bytes]
        self.receive_buffer_asked_bytes = 0  # ... and what was asked (config.udp_receive_buffer_bytes) [bytes]
        self._drop_sock: socket.socket | None = None  # the UDP socket whose kernel drop count is followed
        self._drops_reported = 0  # kernel drops told in a KERNEL_DROPS event so far
        self._kernel_stamps = False  # SO_TIMESTAMPNS on (Linux): datagrams carry their arrival time
        self._kernel_drops = 0  # datagrams the kernel dropped (receive buffer full), all sockets so far
        self._socket_drops = 0  # ... of which the current socket's
        self._drops_warned_ns = -(1 << 62)

    def _tune_socket(self, conn: Any) -> None:
        """A larger UDP receive buffer: a parameter download or a burst of another system's traffic
        overflows Linux's default (about 208 KB) between two reads, and the kernel drops silently."""
        sock = getattr(conn, "port", None)
        if not self._datagram or not isinstance(sock, socket.socket):
            return
        want = self.config.udp_receive_buffer_bytes
        self._socket_drops = 0  # a new socket counts from 0
        self._drop_sock = sock
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, want)
        got = sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) // 2  # Linux reports twice what it books
        # The kernel's stamps are on the host clock only. A listening socket has them already, from before
        # its bind; an udpout one gets them before its first send, so before any answer can arrive.
        if self._clock is time.monotonic_ns:
            if not stamps_enabled(sock) and enable_stamps(sock):
                wait_until_arrivals_stamped()
            if stamps_enabled(sock):
                self._kernel_stamps = True
        if got < want:
            log.warning(
                "UDP receive buffer is %d bytes, %d asked: the kernel caps it at net.core.rmem_max (%s bytes); "
                "raise that to allow it",
                got,
                want,
                rmem_max(),
            )
        self.receive_buffer_bytes = got
        self.receive_buffer_asked_bytes = want

    def _read_once(self, conn: Any) -> None:
        fd = conn.fd
        if fd is None:
            ready = bool(conn.select(0.05))
        else:
            try:
                ready = bool(select.select([fd], [], [], 0.05)[0])
            except (OSError, ValueError) as exc:
                raise OSError(f"select failed: {exc}") from exc
        if not ready:
            return
        if self._datagram:
            sock = getattr(conn, "port", None)
            if self._kernel_stamps and isinstance(sock, socket.socket):
                if self._drain_stamped(conn, sock) >= DRAIN_MAX:
                    return  # a backlog (the reader was held up): read on without the pause
            else:
                for _ in range(DRAIN_MAX):  # drain the socket, stamping each datagram as it is read
                    got = self._recv_datagram(conn)
                    if got is None:
                        break
                    self._feed(*got)
            if self._kernel_stamps and self.config.read_batch_s > 0.0:
                # Each datagram carries its arrival time from the kernel: reading it later changes no stamp,
                # and one wake-up per pause instead of one per datagram saves most of the reader's CPU.
                self._stop.wait(self.config.read_batch_s)
        elif isinstance(conn, mavutil.mavtcpin):
            had_client = conn.port is not None
            data = conn.recv(4096)  # accepts a client when there is none
            rx_ns = self._clock()
            if data:
                self._feed(data if isinstance(data, bytes) else bytes(data), rx_ns)
            elif had_client:  # the client went away: listen for the next one
                with self._send_lock:
                    with contextlib.suppress(Exception):
                        conn.port.close()
                    conn.port = None
                    conn.fd = conn.listen.fileno()
        else:
            port = getattr(conn, "port", None)
            if isinstance(port, socket.socket):  # TCP: read the socket itself (mavtcp prints and reconnects)
                try:
                    data = port.recv(4096)
                except (BlockingIOError, InterruptedError):
                    return
            else:
                data = conn.recv(4096)
            rx_ns = self._clock()
            if not data:
                raise OSError("end of stream (peer closed the connection)")
            self._feed(data if isinstance(data, bytes) else bytes(data), rx_ns)

    def _recv_datagram(self, conn: Any) -> tuple[bytes, int] | None:
        """One datagram and its read time [ns, host clock], or None when none is waiting (no kernel stamps:
        another clock than the host's, or a platform without SO_TIMESTAMPNS)."""
        data = conn.recv()
        rx_ns = self._clock()
        return (bytes(data), rx_ns) if data else None

    def _drain_stamped(self, conn: Any, sock: socket.socket) -> int:
        """Read every waiting datagram (up to DRAIN_MAX) with its arrival time from the kernel; how many.

        With the kernel's receive timestamp (SO_TIMESTAMPNS) the arrival time is when the datagram reached
        the socket, not when this thread got round to reading it: a reader that is late (a loaded computer,
        a burst in the receive buffer) must not make every message look late, which a one-way clock from
        arrival times cannot tell from the autopilot's clock. pymavlink's mavudp reads with recvfrom and
        keeps no timestamp, so the socket is read here, with mavudp's own client bookkeeping (once per
        sender per drain, at its first datagram). The kernel stamps on CLOCK_REALTIME: its offset to the
        host's monotonic clock is read once per drain (a few ms at most), and a stamp is never later than
        its read time (a realtime step would say so). Other systems' frames are collected over the drain and
        passed on as batches, each ending where a decoded message comes in between (order kept)."""
        recvmsg = sock.recvmsg
        clock = self._clock
        unpack = TIMESPEC.unpack_from
        decode = self.config.decode_systems
        # Frames of our system or the autopilot's left undecoded take `_handle`'s per-message checks.
        bulk = decode is not None and not ({self.config.system_id, self._ap_system} - decode)
        offset_ns = time.time_ns() - time.monotonic_ns()
        foreign: list[ForeignFrame] = []
        senders: set[Any] = set()
        drops = self._socket_drops
        read = 0
        try:
            for _ in range(DRAIN_MAX):
                try:
                    data, ancdata, _flags, addr = recvmsg(65535, _CMSG_SPACE)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError as exc:
                    if exc.errno == errno.ECONNREFUSED:
                        break
                    raise
                rx_ns = clock()
                for level, kind, payload in ancdata:
                    if level != socket.SOL_SOCKET:
                        continue
                    if kind == _SCM_TIMESTAMPNS and len(payload) >= 16:
                        sec, nsec = unpack(payload)
                        stamped = sec * 1_000_000_000 + nsec - offset_ns
                        if stamped < rx_ns:
                            rx_ns = stamped
                    elif kind == SO_RXQ_OVFL and len(payload) >= 4:
                        drops = _U32.unpack_from(payload)[0]
                read += 1
                if addr not in senders:  # before its frames are handled: an answer to them goes back to it
                    senders.add(addr)
                    self._note_sender(conn, addr)
                if not data:
                    continue
                if not bulk or decode is None:
                    self._feed(data, rx_ns)
                    continue
                keep = split_foreign(data, rx_ns, decode, foreign)
                if keep:
                    if foreign:
                        self._pass_on_foreign(foreign)
                        foreign = []
                    self._parse(keep, rx_ns, whole_frame=keep is data)  # the datagram is that one frame
                elif keep is None:  # not whole frames: all of it to pymavlink
                    if foreign:
                        self._pass_on_foreign(foreign)
                        foreign = []
                    self._parse(data, rx_ns)
        finally:
            if foreign:
                self._pass_on_foreign(foreign)
            if drops != self._socket_drops:
                self._count_kernel_drops(drops)
        return read

    def _poll_kernel_drops(self, *, final: bool = False) -> None:
        """The socket's drop count read now (SO_MEMINFO): drops are counted when they happen, not only when a
        later datagram brings the count (SO_RXQ_OVFL), so a flood that ends in drops is counted in full.
        `final`: the socket is about to close, any drops not yet in an event are told now."""
        sock = self._drop_sock
        if sock is None:
            return
        count = socket_drops(sock)
        if count is not None and count != self._socket_drops:
            self._count_kernel_drops(count, final=final)
        elif final:
            self._count_kernel_drops(self._socket_drops, final=True)

    def _count_kernel_drops(self, socket_drops: int, *, final: bool = False) -> None:
        """The socket's count of datagrams dropped by the kernel (sk_drops, a u32 that may wrap): what it went up
        by is counted (stats) and told in a KERNEL_DROPS event with its cause, at most once a second."""
        now = self._clock()
        with self._lock:
            new = (socket_drops - self._socket_drops) % (1 << 32)
            if new >= 1 << 31:
                new = 0  # an older reading than the one counted (another thread's): nothing new
            else:
                self._socket_drops = socket_drops
                self._kernel_drops += new
            total = self._kernel_drops
            if total == self._drops_reported or (not final and now - self._drops_warned_ns < 1_000_000_000):
                return
            since = total - self._drops_reported
            self._drops_reported = total
            self._drops_warned_ns = now
        granted, asked = self.receive_buffer_bytes, self.receive_buffer_asked_bytes
        cap = rmem_max()
        why = (
            f"asked {asked}, the kernel capped it at net.core.rmem_max ({cap} bytes)"
            if granted < asked
            else f"as asked ([mavlink] udp_receive_buffer_bytes; net.core.rmem_max {cap} bytes)"
        )
        detail = (
            f"{since} datagrams dropped by the kernel ({total} so far): the UDP receive buffer was full, "
            f"{granted} bytes granted, {why}; this process did not read them in time"
        )
        self._emit(MavlinkEvent(LinkEventKind.KERNEL_DROPS, now, 0, 0, detail=detail, count=since), logging.WARNING)

    @staticmethod
    def _note_sender(conn: Any, addr: Any) -> None:
        """mavudp's bookkeeping of who sent to us: a udpin link answers its clients, a broadcast one the last."""
        if getattr(conn, "udp_server", False):
            conn.clients.add(addr)
            conn.clients_last_alive[addr] = time.time()
        elif getattr(conn, "broadcast", False):
            conn.last_address = addr
