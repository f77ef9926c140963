"""One MAVLink connection to the autopilot (and, through it or a router, to the ground station).

`MavlinkLink` opens a pymavlink transport from a URL as users write them (``udpin:0.0.0.0:14550``,
``udpout:192.168.1.10:14550``, ``tcp:127.0.0.1:5760``, ``/dev/ttyAMA0,921600``) and runs two threads:

* the **reader** stamps every received chunk with ``time.monotonic_ns()`` the moment it arrives, parses it
  with a MAVLink 2 parser (which also accepts MAVLink 1 frames, so mixed v1/v2 input is fine; garbage
  becomes a counted bad frame, never an exception) and dispatches each message as a `MavlinkMessage` to the
  subscribers. Subscribers are **callbacks run on the reader thread**: they must return quickly and never
  block (take a lock briefly at most, or hand the message to your own queue). `subscribe_queue()` gives a
  bounded `queue.Queue` instead for consumers that want to block on their own thread.
* the **service** thread runs the `LinkScheduler` (icgt.mavlink.link_scheduler): TIMESYNC requests (each send
  time goes to ``on_timesync_sent``: pairing the replies is the synchroniser's job, `icgt.sync`, so that the
  live recorder and the offline recompute pair them by one rule) and the telemetry stream rates asked with
  MAV_CMD_SET_MESSAGE_INTERVAL.

The link keeps no account of the autopilot's presence: the core does (`icgt.mavlink.autopilot_rules.
AutopilotPresence`, in the synchroniser), and its owner passes each change on as a hint (`autopilot_hint`):
rates are asked again and TIMESYNC goes fast when the autopilot appears, comes back or reboots. The link's
own events are about itself: its transport, its rate requests, its socket's drops.

If a stream transport (serial, TCP) fails, the reader closes it and reopens it every ``reopen_delay_s``
until it works again or the link is stopped. `send()` may be called from any thread.

**Owner-pumped** (``LinkConfig.owner_pumps``, UDP with kernel receive timestamps only): neither thread runs;
the owner calls `pump()` from its own periodic thread, which reads every waiting datagram, calls the
subscribers on that thread and runs the service step when due. Each datagram carries the kernel's arrival
stamp, so reading it a few tens of milliseconds later changes nothing it says, and the two threads' wake-ups
(each costs about as much CPU as handling a dozen messages) and the hand-offs between threads are saved.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import queue
import select
import socket
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.autopilot_rules import PresenceChange
from icgt.mavlink.frames import ForeignFrame, UndecodedBatch, UndecodedFrame, split_foreign
from icgt.mavlink.link_scheduler import LinkScheduler
from icgt.mavlink.link_types import (
    DEFAULT_STREAM_RATES,
    MAV_COMP_ID_CAMERA,
    LinkConfig,
    LinkError,
    LinkEventKind,
    LinkStats,
    MavlinkEvent,
    MavlinkMessage,
    RateRequestResult,
    StreamRate,
    Subscription,
)
from icgt.mavlink.signing import SigningState
from icgt.mavlink.transport import is_datagram, open_transport
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

__all__ = [
    "DEFAULT_STREAM_RATES",
    "MAV_COMP_ID_CAMERA",
    "LinkConfig",
    "LinkError",
    "LinkEventKind",
    "LinkStats",
    "MavlinkEvent",
    "MavlinkLink",
    "MavlinkMessage",
    "RateRequestResult",
    "StreamRate",
    "Subscription",
    "mavlink2",
]

log = logging.getLogger(__name__)

# Linux's SO_TIMESTAMPNS / SCM_TIMESTAMPNS (Python's socket module does not name them): a struct timespec
# of the datagram's arrival on CLOCK_REALTIME in the ancillary data of recvmsg.
_SCM_TIMESTAMPNS = SO_TIMESTAMPNS  # the control message's type is the option's number
# SO_RXQ_OVFL: a datagram read after the kernel dropped some (receive buffer full) carries the socket's count of
# drops so far (a u32) in its ancillary data.
_CMSG_SPACE = socket.CMSG_SPACE(16) + socket.CMSG_SPACE(4)
_U32 = struct.Struct("I")
_DRAIN_MAX = 1024  # datagrams read per wake-up, at most
_PUMP_DRAINS = 8  # drains per pump() call, at most (owner-pumped links)


class MavlinkLink:
    """A MAVLink connection with a stamping reader thread, TIMESYNC and stream rates (on the core's hints).

    ``on_event`` and ``on_timesync_sent`` (the ts1 [ns, host clock] of each TIMESYNC request just sent) are
    called on the link's threads: keep them short and non-blocking.
    ``clock`` is the host clock (time.monotonic_ns); tests may pass another.
    """

    def __init__(
        self,
        config: LinkConfig,
        *,
        on_event: Callable[[MavlinkEvent], None] | None = None,
        on_timesync_sent: Callable[[int], None] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.config = config
        self._on_event = on_event
        self._on_timesync_sent = on_timesync_sent
        self._clock = clock
        self._ap_system = config.effective_autopilot_system
        # One MAVLink 2 parser for input (it accepts v1 frames too) and one packer for output, both owned
        # here rather than by mavutil, whose dialect is a process-wide global switched by environment.
        self.signing = (
            SigningState(config.signing_key, config.signing_link_id) if config.signing_key is not None else None
        )
        self._parser: Any = self._new_parser()
        self._packer: Any = mavlink2.MAVLink(None, srcSystem=config.system_id, srcComponent=config.component_id)
        if self.signing is not None:
            self.signing.attach_output(self._packer)
        self._conn: Any = None
        self._datagram = is_datagram(config.url)
        self._send_lock = threading.Lock()
        self._lock = threading.Lock()  # state shared between the reader, service and caller threads
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._subs: tuple[Subscription, ...] = ()
        # TIMESYNC and stream-rate requests, on the core's hints (under self._lock)
        self._scheduler = LinkScheduler(config)
        self._watched: tuple[int, int] | None = None  # the autopilot's ids as the core named them
        # counters
        self._by_type: dict[str, int] = {}
        self._bad_frames = 0
        self._v1 = 0
        self._v2 = 0
        self._bytes = 0
        self._sent = 0
        self._send_failures = 0
        self._callback_errors = 0
        self._queue_drops = 0
        self._self_echoes = 0
        self._same_id_frames = 0  # frames with our ids that we did not send
        self._same_id_warned_ns = 0
        self._recent_sent: deque[bytes] = deque(maxlen=256)  # to tell our echoes from a device with our ids
        self._ts_sent = 0
        self._undecoded = 0
        self.receive_buffer_bytes = 0  # the UDP socket's receive buffer once open: what the kernel granted [bytes]
        self.receive_buffer_asked_bytes = 0  # ... and what was asked (config.udp_receive_buffer_bytes) [bytes]
        self._drop_sock: socket.socket | None = None  # the UDP socket whose kernel drop count is followed
        self._drops_reported = 0  # kernel drops told in a KERNEL_DROPS event so far
        self._kernel_stamps = False  # SO_TIMESTAMPNS on (Linux): datagrams carry their arrival time
        self._kernel_drops = 0  # datagrams the kernel dropped (receive buffer full), all sockets so far
        self._socket_drops = 0  # ... of which the current socket's
        self._drops_warned_ns = -(1 << 62)
        self._transport_errors = 0
        # owner-pumped (see the module docstring): no threads; pump() reads and services
        self._pumped = False
        self._reopen_at_ns = 0  # pumped, transport closed: when pump() tries to reopen it next [ns, host clock]

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Open the transport (raises LinkError if it cannot) and start the reader and service threads
        (none when `pumped`: the owner calls `pump()`)."""
        if self._threads or self._pumped:
            raise LinkError("link already started")
        self._conn = open_transport(self.config, stamped=self._clock is time.monotonic_ns)
        self._tune_socket(self._conn)
        self._stop.clear()
        if self.config.owner_pumps and self._datagram and self._kernel_stamps:
            self._pumped = True
            log.info(
                "MAVLink link %s open as %d:%d (read by its owner's thread)",
                self.config.url,
                self.config.system_id,
                self.config.component_id,
            )
            return
        self._threads = [
            threading.Thread(target=self._reader_loop, name="icgt-mavlink-reader", daemon=True),
            threading.Thread(target=self._service_loop, name="icgt-mavlink-service", daemon=True),
        ]
        for thread in self._threads:
            thread.start()
        log.info("MAVLink link %s open as %d:%d", self.config.url, self.config.system_id, self.config.component_id)

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

    def stop(self, timeout_s: float = 2.0) -> None:
        """Stop both threads (joined) and close the transport. Safe to call twice."""
        self._stop.set()
        for thread in self._threads:
            if thread is not threading.current_thread():
                thread.join(timeout_s)
        self._threads = []
        if self._pumped and self._conn is not None:
            # What arrived since the owner's last pump is handed on (to this thread's caller), not closed away.
            with contextlib.suppress(Exception):
                self._drain_stamped(self._conn, self._conn.port)
        self._pumped = False
        self._poll_kernel_drops(final=True)  # the socket's last count, before it closes
        with self._send_lock:
            self._close_transport()

    def __enter__(self) -> MavlinkLink:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def running(self) -> bool:
        return (bool(self._threads) or self._pumped) and not self._stop.is_set()

    @property
    def pumped(self) -> bool:
        """True when the owner must call `pump()` (``owner_pumps`` on a UDP link with kernel stamps)."""
        return self._pumped

    def pump(self) -> int:
        """An owner-pumped link's reader and service step, on the caller's thread: every datagram waiting is
        read (with the kernel's arrival stamp) and handled, subscribers called here; then TIMESYNC and
        stream-rate requests when due. A socket error closes the transport (a TRANSPORT_ERROR event) and
        later calls reopen it every ``reopen_delay_s``. Returns the datagrams read; 0 and nothing done on a
        link that is not `pumped` (its own threads read) or is stopped."""
        if not self._pumped or self._stop.is_set():
            return 0
        read = 0
        conn = self._conn
        if conn is None:
            now = self._clock()
            if now >= self._reopen_at_ns:
                self._reopen_at_ns = now + int(self.config.reopen_delay_s * 1e9)
                self._try_reopen()
        else:
            try:
                # A backlog (the owner was held up, a flood) is read on up to _PUMP_DRAINS drains per call,
                # so that one call stays bounded and the rest waits in the socket's buffer for the next.
                for _ in range(_PUMP_DRAINS):
                    n = self._drain_stamped(conn, conn.port)
                    read += n
                    if n < _DRAIN_MAX:
                        break
            except Exception as exc:
                self._transport_failed(exc)
                self._reopen_at_ns = self._clock() + int(self.config.reopen_delay_s * 1e9)
        try:
            self._service_once(self._clock())
        except Exception:
            log.exception("MAVLink service step failed")
        return read

    # ------------------------------------------------------------------ subscriptions
    def subscribe(
        self,
        callback: Callable[[MavlinkMessage], object],
        types: Iterable[str] | None = None,
        *,
        undecoded: Callable[[UndecodedBatch], object] | None = None,
    ) -> Subscription:
        """Call ``callback(received)`` on the reader thread for every message (or those of ``types``).

        With ``undecoded``, the frames of other systems than ``LinkConfig.decode_systems`` (left undecoded)
        go to ``undecoded(batch)`` instead, several at a time and in order (each `UndecodedBatch` ends where
        a decoded message came in between, which goes to ``callback`` after it), whatever ``types`` says.
        The callbacks must not block; exceptions they raise are counted and logged, never propagated."""
        sub = Subscription(callback, None if types is None else frozenset(types), undecoded)
        with self._lock:
            self._subs = (*self._subs, sub)
        return sub

    def unsubscribe(self, sub: Subscription) -> None:
        with self._lock:
            self._subs = tuple(s for s in self._subs if s is not sub)

    def subscribe_queue(self, types: Iterable[str] | None = None, maxsize: int = 1000) -> queue.Queue[MavlinkMessage]:
        """A bounded queue fed by the reader; when full the oldest entry is dropped (counted in stats)."""
        q: queue.Queue[MavlinkMessage] = queue.Queue(maxsize=maxsize)

        def put(item: MavlinkMessage) -> None:
            while True:
                try:
                    q.put_nowait(item)
                    return
                except queue.Full:
                    with contextlib.suppress(queue.Empty):
                        q.get_nowait()
                    with self._lock:
                        self._queue_drops += 1

        self.subscribe(put, types)
        return q

    # ------------------------------------------------------------------ sending
    @property
    def mav(self) -> Any:
        """The pymavlink MAVLink 2 object: use its ``*_encode`` methods to build messages for `send`."""
        return self._packer

    def send(self, msg: Any, *, force_mavlink1: bool = False) -> bool:
        """Pack ``msg`` with our system/component id and write it. Thread-safe. False if not sent."""
        with self._send_lock:
            conn = self._conn
            if conn is None:
                self._send_failures += 1
                return False
            try:
                buf = msg.pack(self._packer, force_mavlink1=force_mavlink1)
                self._packer.seq = (self._packer.seq + 1) % 256
                self._recent_sent.append(bytes(buf))
                conn.write(buf)
            except Exception as exc:
                self._send_failures += 1
                log.warning("MAVLink send of %s failed: %s", msg.get_type(), exc)
                return False
            self._sent += 1
            return True

    def send_command_long(
        self,
        target_system: int,
        target_component: int,
        command: int,
        params: Iterable[float] = (),
        confirmation: int = 0,
    ) -> bool:
        p = [*(float(x) for x in params), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        msg = self._packer.command_long_encode(target_system, target_component, command, confirmation, *p)
        return self.send(msg)

    # ------------------------------------------------------------------ state
    @property
    def transport_up(self) -> bool:
        """The transport is open (a failed serial or TCP one is down until it reopens)."""
        return self._conn is not None

    @property
    def autopilot(self) -> tuple[int, int] | None:
        """(system, component) of the autopilot as the core last named it (`autopilot_hint`)."""
        with self._lock:
            return self._scheduler.autopilot

    def autopilot_hint(self, change: PresenceChange, system: int, component: int | None, host_ns: int) -> None:
        """The core's word on the autopilot (its one state machine, `AutopilotPresence`): seen, back or rebooted
        asks every stream rate again and starts TIMESYNC's fast phase; lost drops the pending rate requests.
        Any thread; the requests go out at the service thread's (or the owner's `pump`) next step."""
        with self._lock:
            if not change.appeared:
                self._scheduler.autopilot_lost()
                return
            comp = 1 if component is None else component
            self._watched = (system, comp)
            self._scheduler.autopilot_appeared(system, comp, host_ns)

    def rate_results(self) -> list[RateRequestResult]:
        """The latest result per requested message id."""
        with self._lock:
            return self._scheduler.rate_results()

    def request_rates(self) -> None:
        """(Re)send the configured SET_MESSAGE_INTERVAL commands now, if the autopilot is there (normally on
        the core's hints)."""
        with self._lock:
            self._scheduler.request_rates()

    def stats(self) -> LinkStats:
        signing = self.signing.counts if self.signing is not None else {}
        self._poll_kernel_drops()
        with self._lock:
            return LinkStats(
                **signing,
                messages_by_type=dict(self._by_type),
                bad_frames=self._bad_frames,
                v1_frames=self._v1,
                v2_frames=self._v2,
                bytes_received=self._bytes,
                messages_sent=self._sent,
                send_failures=self._send_failures,
                callback_errors=self._callback_errors,
                queue_drops=self._queue_drops,
                self_echoes=self._self_echoes,
                same_id_frames=self._same_id_frames,
                timesync_sent=self._ts_sent,
                undecoded_frames=self._undecoded,
                transport_errors=self._transport_errors,
                kernel_drops=self._kernel_drops,
                udp_receive_buffer_bytes=self.receive_buffer_bytes,
                udp_receive_buffer_asked_bytes=self.receive_buffer_asked_bytes,
            )

    # ------------------------------------------------------------------ reader thread
    def _reader_loop(self) -> None:
        while not self._stop.is_set():
            conn = self._conn
            if conn is None:
                self._reopen()
                continue
            try:
                self._read_once(conn)
            except Exception as exc:
                self._transport_failed(exc)

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
                if self._drain_stamped(conn, sock) >= _DRAIN_MAX:
                    return  # a backlog (the reader was held up): read on without the pause
            else:
                for _ in range(_DRAIN_MAX):  # drain the socket, stamping each datagram as it is read
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
        """Read every waiting datagram (up to _DRAIN_MAX) with its arrival time from the kernel; how many.

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
            for _ in range(_DRAIN_MAX):
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

    def _new_parser(self) -> Any:
        parser = mavlink2.MAVLink(None, srcSystem=self.config.system_id, srcComponent=self.config.component_id)
        parser.robust_parsing = True
        if self.signing is not None:
            self.signing.attach_input(parser)  # one replay-protection state for every parser of this link
        return parser

    def _feed(self, data: bytes, rx_ns: int) -> None:
        """One chunk read at ``rx_ns``: a datagram (other systems' frames split off, see `decode_systems`)
        or a piece of a stream."""
        decode = self.config.decode_systems
        if decode is not None and self._datagram:
            foreign: list[ForeignFrame] = []
            data = bytes(data)
            keep = split_foreign(data, rx_ns, decode, foreign)
            if keep is not None:
                if foreign:
                    self._pass_on_foreign(foreign)
                if keep:
                    self._parse(keep, rx_ns, whole_frame=keep is data)
                return
        self._parse(data, rx_ns)

    def _parse(self, data: bytes, rx_ns: int, *, whole_frame: bool = False) -> None:
        """Decode with pymavlink and handle each message (a datagram's cut-off frame counts as bad).

        ``whole_frame``: ``data`` is exactly one frame by its header (`split_foreign` said so), as most
        datagrams are: pymavlink's decode straight away (CRC, signature, fields), without its byte-stream
        state machine, which is a third of its time per message. A frame it refuses counts as bad, as the
        BAD_DATA that parse_buffer would make of it."""
        if whole_frame:
            try:
                msg = self._parser.decode(bytearray(data))
            except Exception:  # MAVError: bad CRC, unknown id, bad signature; struct.error: bad length
                msg = None
            with self._lock:
                self._bytes += len(data)
                self._bad_frames += msg is None
            if msg is not None:
                self._handle(MavlinkMessage(msg, rx_ns))
            return
        truncated = False
        try:
            msgs = self._parser.parse_buffer(data) or []
            if self._datagram and self._parser.buf_len() > 0:
                # A frame cut off at the end of a datagram is never completed by the next datagram:
                # drop it rather than let it swallow the start of the next one.
                truncated = True
                self._parser = self._new_parser()
        except Exception as exc:  # robust parsing should not raise; count it if it ever does
            log.debug("MAVLink parser raised %s", exc)
            self._parser = self._new_parser()
            msgs, truncated = [], True
        with self._lock:
            self._bytes += len(data)
            self._bad_frames += int(truncated)
        for msg in msgs:
            self._handle(MavlinkMessage(msg, rx_ns))

    def _pass_on_foreign(self, frames: list[ForeignFrame]) -> None:
        """Other systems' frames, in order: counted under one lock, then to the subscribers, as one
        `UndecodedBatch` to those that take batches and one `UndecodedFrame` each to the others.

        What `_handle` does for each, less what cannot apply to them: they are never BAD_DATA, and a frame
        with our system id or the autopilot's (not the case when decode_systems holds them, as the recorder's
        does) still goes through `_handle` (echo and same-id checks, liveness)."""
        batch = UndecodedBatch(frames)
        mine = (self.config.system_id, self._ap_system)
        if any(f[1] in mine for f in frames):
            with self._lock:
                self._bytes += batch.size_bytes()
                self._undecoded += len(frames)
            for frame, rx_ns in batch.undecoded_frames():
                self._handle(MavlinkMessage(frame, rx_ns))
            return
        types = batch.type_counts()
        v1 = batch.v1_frames()
        size = batch.size_bytes()
        with self._lock:
            self._bytes += size
            self._undecoded += len(frames)
            by_type = self._by_type
            for name, n in types.items():
                by_type[name] = by_type.get(name, 0) + n
            self._v1 += v1
            self._v2 += len(frames) - v1
            subs = self._subs
        singles: list[tuple[UndecodedFrame, int]] | None = None
        for sub in subs:
            if sub.undecoded is not None:
                try:
                    sub.undecoded(batch)
                except Exception:
                    self._count_callback_error(f"subscriber {sub.undecoded!r} on {batch!r}")
                continue
            if singles is None:
                singles = batch.undecoded_frames()
            for frame, rx_ns in singles:
                mtype = frame.get_type()
                if sub.types is None or mtype in sub.types:
                    try:
                        sub.callback(MavlinkMessage(frame, rx_ns))
                    except Exception:
                        self._count_callback_error(f"subscriber {sub.callback!r} on {mtype}")

    def _handle(self, rec: MavlinkMessage) -> None:
        msg = rec.msg
        mtype = rec.type
        if mtype == "BAD_DATA":
            with self._lock:
                self._bad_frames += 1
            return
        src = (rec.src_system, rec.src_component)
        if src == (self.config.system_id, self.config.component_id):
            if bytes(msg.get_msgbuf()) in self._recent_sent:
                with self._lock:
                    self._self_echoes += 1
                return  # our own frame, looped back by a router or a broadcast
            self._foreign_same_id(rec)
        with self._lock:
            self._by_type[mtype] = self._by_type.get(mtype, 0) + 1
            if rec.mavlink_version == 1:
                self._v1 += 1
            else:
                self._v2 += 1
            if src == self._watched:
                self._scheduler.on_autopilot_message(rec.msg_id, msg, rec.rx_ns)
            subs = self._subs
        for sub in subs:
            if sub.types is None or mtype in sub.types:
                try:
                    sub.callback(rec)
                except Exception:
                    self._count_callback_error(f"subscriber {sub.callback!r} on {mtype}")

    def _foreign_same_id(self, rec: MavlinkMessage) -> None:
        """A frame with our system and component id that we did not send: another device (a real camera at
        component 100?) uses our ids. Said loudly (once every 10 s), counted, and passed on like any message."""
        now = rec.rx_ns
        with self._lock:
            self._same_id_frames += 1
            n = self._same_id_frames
            due = now - self._same_id_warned_ns >= 10_000_000_000 or n == 1
            if due:
                self._same_id_warned_ns = now
        if due:
            log.error(
                "another device on the vehicle uses our MAVLink id %d:%d (%s, %d frames so far): ground "
                "stations cannot tell the two apart; give this camera another id ([mavlink] component_id)",
                self.config.system_id,
                self.config.component_id,
                rec.type,
                n,
            )

    def _count_callback_error(self, what: str) -> None:
        with self._lock:
            self._callback_errors += 1
            n = self._callback_errors
        if n <= 10 or n % 1000 == 0:
            log.exception("%s raised (error #%d)", what, n)

    def _emit(self, event: MavlinkEvent, level: int = logging.INFO) -> None:
        log.log(level, "MAVLink %s %d:%d %s", event.kind.value, event.system, event.component, event.detail)
        if self._on_event is not None:
            try:
                self._on_event(event)
            except Exception:
                self._count_callback_error("event callback")

    # ------------------------------------------------------------------ transport failures
    def _close_transport(self) -> None:
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()

    def _transport_failed(self, exc: BaseException) -> None:
        self._poll_kernel_drops(final=True)  # the closing socket's last count
        with self._send_lock:
            self._close_transport()
        with self._lock:
            self._transport_errors += 1
        self._parser = self._new_parser()
        event = MavlinkEvent(
            LinkEventKind.TRANSPORT_ERROR,
            self._clock(),
            self.config.system_id,
            self.config.component_id,
            detail=str(exc),
        )
        self._emit(event, logging.WARNING)

    def _reopen(self) -> None:
        if self._stop.wait(self.config.reopen_delay_s):
            return
        self._try_reopen()

    def _try_reopen(self) -> None:
        try:
            conn = open_transport(self.config, stamped=self._clock is time.monotonic_ns)
        except LinkError as exc:
            log.debug("reopen of %s failed: %s", self.config.url, exc)
            return
        self._tune_socket(conn)
        with self._send_lock:
            if self._stop.is_set():
                with contextlib.suppress(Exception):
                    conn.close()
                return
            self._conn = conn
        cfg = self.config
        self._emit(
            MavlinkEvent(
                LinkEventKind.TRANSPORT_REOPENED, self._clock(), cfg.system_id, cfg.component_id, detail=cfg.url
            )
        )

    # ------------------------------------------------------------------ service thread
    def _service_loop(self) -> None:
        while not self._stop.wait(self.config.service_period_s):
            try:
                self._service_once(self._clock())
            except Exception:
                log.exception("MAVLink service step failed")

    def _service_once(self, now: int) -> None:
        self._poll_kernel_drops()
        with self._lock:
            due = self._scheduler.due(now)
        for event, level in due.events:
            self._emit(event, level)
        if due.timesync:
            self._send_timesync()
        if due.rate is not None:
            rate = due.rate.rate
            self.send_command_long(
                *due.rate.target,
                mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL,
                (rate.message_id, rate.interval_us, 0, 0, 0, 0, 0),
                confirmation=due.rate.confirmation,
            )

    def _send_timesync(self) -> None:
        tx_ns = self._clock()
        msg = self._packer.timesync_encode(0, tx_ns)
        # Told before the send, so that the request is known before its reply can arrive.
        if self._on_timesync_sent is not None:
            try:
                self._on_timesync_sent(tx_ns)
            except Exception:
                self._count_callback_error("timesync_sent callback")
        if self.send(msg):
            with self._lock:
                self._ts_sent += 1
