"""The MAVLink link's receiving side: parse what the transport read, and hand each message on with its arrival time.

`LinkReceiver` decodes chunks (a datagram, or a piece of a serial / TCP stream) stamped by the reader
(`icgt.mavlink.link_reader`) with a MAVLink 2 parser (which accepts MAVLink 1 frames too; garbage becomes a counted
bad frame, never an exception), tells our own echoes from another device using our ids, passes other systems'
frames on undecoded (`decode_systems`), counts everything, and calls the subscribers (on the reading thread).
Messages of the autopilot's ids as the core named them (`_watched`) go to `_autopilot_message` first (the link's
scheduler: command ACKs, rate checks). It keeps no account of the autopilot's presence: that is the core's.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.frames import ForeignFrame, UndecodedBatch, UndecodedFrame, split_foreign
from icgt.mavlink.link_types import LinkConfig, MavlinkEvent, MavlinkMessage, Subscription
from icgt.mavlink.signing import SigningState
from icgt.mavlink.transport import is_datagram

__all__ = ["LinkReceiver"]

log = logging.getLogger("icgt.mavlink.link")


class LinkReceiver:
    """Parsing, counting and dispatch of what a MAVLink link receives (the base of `MavlinkLink`)."""

    def __init__(
        self,
        config: LinkConfig,
        on_event: Callable[[MavlinkEvent], None] | None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.config = config
        self._on_event = on_event
        self._clock = clock
        self._ap_system = config.effective_autopilot_system
        self._datagram = is_datagram(config.url)
        # One MAVLink 2 parser for input (it accepts v1 frames too), owned here rather than by mavutil, whose
        # dialect is a process-wide global switched by environment.
        self.signing = (
            SigningState(config.signing_key, config.signing_link_id) if config.signing_key is not None else None
        )
        self._parser: Any = self._new_parser()
        self._lock = threading.Lock()  # state shared between the reader, service and caller threads
        self._subs: tuple[Subscription, ...] = ()
        self._watched: tuple[int, int] | None = None  # the autopilot's ids as the core named them
        self._recent_sent: deque[bytes] = deque(maxlen=256)  # to tell our echoes from a device with our ids
        # counters
        self._by_type: dict[str, int] = {}
        self._bad_frames = 0
        self._v1 = 0
        self._v2 = 0
        self._bytes = 0
        self._callback_errors = 0
        self._queue_drops = 0
        self._self_echoes = 0
        self._same_id_frames = 0  # frames with our ids that we did not send
        self._same_id_warned_ns = 0
        self._undecoded = 0

    def _autopilot_message(self, rec: MavlinkMessage) -> None:
        """A message of the `_watched` ids, before the subscribers get it; called with self._lock held."""

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
                self._autopilot_message(rec)
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
