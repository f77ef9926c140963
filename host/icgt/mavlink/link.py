"""One MAVLink connection to the autopilot (and, through it or a router, to the ground station).

`MavlinkLink` opens a pymavlink transport from a URL as users write them (``udpin:0.0.0.0:14550``,
``udpout:192.168.1.10:14550``, ``tcp:127.0.0.1:5760``, ``/dev/ttyAMA0,921600``) and runs two threads:

* the **reader** stamps every received chunk with ``time.monotonic_ns()`` the moment it arrives, parses it
  with a MAVLink 2 parser (which also accepts MAVLink 1 frames, so mixed v1/v2 input is fine; garbage
  becomes a counted bad frame, never an exception) and dispatches each message as a `MavlinkMessage` to the
  subscribers. Subscribers are **callbacks run on the reader thread**: they must return quickly and never
  block (take a lock briefly at most, or hand the message to your own queue). `subscribe_queue()` gives a
  bounded `queue.Queue` instead for consumers that want to block on their own thread. (Reading and
  stamping: `icgt.mavlink.link_reader`; parsing and dispatch: `icgt.mavlink.link_receive`.)
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
import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.autopilot_rules import PresenceChange
from icgt.mavlink.link_reader import DRAIN_MAX, LinkReader
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
from icgt.mavlink.transport import open_transport

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

_PUMP_DRAINS = 8  # drains per pump() call, at most (owner-pumped links)


class MavlinkLink(LinkReader):
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
        super().__init__(config, on_event, clock)
        self._on_timesync_sent = on_timesync_sent
        # One packer for output (the parser is LinkReceiver's), owned here rather than by mavutil.
        self._packer: Any = mavlink2.MAVLink(None, srcSystem=config.system_id, srcComponent=config.component_id)
        if self.signing is not None:
            self.signing.attach_output(self._packer)
        self._conn: Any = None
        self._threads: list[threading.Thread] = []
        # TIMESYNC and stream-rate requests, on the core's hints (under self._lock)
        self._scheduler = LinkScheduler(config)
        self._sent = 0
        self._send_failures = 0
        self._ts_sent = 0
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

    @property
    def readable_fd(self) -> int | None:
        """The socket an owner that pumps may wait on for datagrams (select()), None when the link is not
        pumped, is stopped or its transport is closed."""
        conn = self._conn
        if not self._pumped or self._stop.is_set() or conn is None:
            return None
        try:
            fd = conn.port.fileno()
        except (AttributeError, OSError, ValueError):
            return None
        return fd if isinstance(fd, int) and fd >= 0 else None

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
                    if n < DRAIN_MAX:
                        break
            except Exception as exc:
                self._transport_failed(exc)
                self._reopen_at_ns = self._clock() + int(self.config.reopen_delay_s * 1e9)
        try:
            self._service_once(self._clock())
        except Exception:
            log.exception("MAVLink service step failed")
        return read

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

    def _autopilot_message(self, rec: MavlinkMessage) -> None:
        self._scheduler.counted(rec.msg_id)

    def autopilot_answered(self, msg: Any, rx_ns: int) -> None:
        """A COMMAND_ACK that the core believed to be the autopilot's (`Synchroniser.on_mavlink` returned
        ``believed``): the answer to a rate command in flight. The link does not take ACKs from its reading
        thread: whoever uses the autopilot's ids could answer for it (issue 26)."""
        with self._lock:
            self._scheduler.on_command_ack(msg, rx_ns)

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
