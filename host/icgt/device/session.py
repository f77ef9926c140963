"""The device protocol over the link's bytes: handshake, commands and their ACKs, TIME_SYNC, completeness notes.

`DeviceSession` holds everything the link's bytes mean, and none of the I/O (that is `DeviceLink`'s, which
feeds it what it reads with its arrival stamp and sends what it asks for):
- the stream decoder and the RESEND tracker (`icgt.device.resend`): messages the sequence numbers say are
  missing are asked again, duplicates dropped, and what the device could no longer send reported as a
  'history_lost' event; a sequence gap and corrupt frames are events too;
- the answers: an ACK to the command waiting for it (`command`: retried with a new sequence number when none
  comes; a retried START/STOP refused as already done counts as accepted), a TIME_SYNC_REPLY with its request's
  send time as a `TimeSyncSample`, the HELLO (`handshake`) and the last DEVICE_STATE;
- the schedules: a TIME_SYNC every `time_sync_interval_s` (sent by the link's reader right after it read, see
  `DeviceLink`), and every second a HOST_RECEIVED telling the device how far the log is complete, a few
  seconds behind, so a host killed meanwhile loses nothing that a successor cannot ask for again.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from icgt.device.link_types import (
    CommandRefusedError,
    DeviceLinkError,
    DeviceLinkEvent,
    EventCallback,
    MessageCallback,
    TimeSyncCallback,
    TimeSyncSample,
)
from icgt.device.resend import LossReport, ResendTracker
from icgt.errors import VersionMismatchError
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH, Received, StreamDecoder
from icgt.protocol.messages import (
    Ack,
    DeviceState,
    ErrorCode,
    Hello,
    HostReceived,
    Message,
    Ping,
    TimeSync,
    TimeSyncReply,
)

__all__ = ["COMMAND_TIMEOUT_S", "HANDSHAKE_TIMEOUT_S", "DeviceSession", "Pending", "SendFunction"]

HANDSHAKE_TIMEOUT_S = 3.0
COMMAND_TIMEOUT_S = 0.3
HOST_RECEIVED_PERIOD_NS = 1_000_000_000
# HOST_RECEIVED reports what was complete this long ago: the worker writes a frame to the log within
# milliseconds, but the MCAP chunk holding it is closed only every second, and a chunk not closed when
# the recorder is killed is not in the file. A successor asks RESEND from there (duplicates across the
# two files, never a loss).
HOST_RECEIVED_LAG_NS = 3_000_000_000


@dataclass
class Pending:
    """A command waiting for its ACK."""

    done: threading.Event = field(default_factory=threading.Event)
    ack: Ack | None = None


SendFunction = Callable[[Message, Pending | None], int]
"""The link's send: frames and writes one message (registering `pending` first), returns its sequence number;
DeviceLinkError when the link is down."""


class DeviceSession:
    """The protocol state of one device link. `send`: the link's; `on_answered`: called after a TIME_SYNC reply
    was handed on (the link may stop waiting for answers)."""

    def __init__(
        self,
        url: str,
        send: SendFunction,
        *,
        on_message: MessageCallback,
        on_event: EventCallback,
        on_time_sync: TimeSyncCallback,
        on_answered: Callable[[], None],
    ) -> None:
        self._url = url
        self._send = send
        self._on_message = on_message
        self._on_event = on_event
        self._on_time_sync = on_time_sync
        self._on_answered = on_answered
        self.decoder = StreamDecoder()
        self._pending: dict[int, Pending] = {}
        self._sync_sent: dict[int, int] = {}  # request seq -> host_tx_ns
        self.hello: Hello | None = None
        self._hello_event = threading.Event()
        self.device_state: DeviceState | None = None  # the last DEVICE_STATE (sent after every HELLO)
        self._device_state_event = threading.Event()
        self._rejected_reported = 0
        self.resend = ResendTracker(self._send_quietly, on_loss=self._history_lost)
        self._received_marks: list[tuple[int, int]] = []  # (host ns, HOST_RECEIVED value) not sent yet
        self._next_mark_ns = 0
        # The owner's log, named in every HOST_RECEIVED (nonzero; 0: none): the device gives it back in
        # DEVICE_STATE, so a later host knows which recording the frames it still holds follow.
        self.recording_id = 0
        # TIME_SYNC sent by the reader itself, every this many seconds (see time_sync_if_due); None: only
        # when the owner calls request_time_sync(). The owner may change it at any time (a float, set whole).
        self.time_sync_interval_s: float | None = None
        self.next_sync_ns = 0  # the reader's next TIME_SYNC [ns, host monotonic]; 0: at once (after a connect)

    # ------------------------------------------------------------ sending (the link's tx lock held)
    def sending(self, seq: int, message: Message, pending: Pending | None) -> None:
        """Right before the bytes of frame `seq` leave: its ACK, or its TIME_SYNC reply, cannot come unclaimed.

        A TIME_SYNC's send time is taken here, after framing, right before the bytes go to the kernel: the
        field in the message only identifies the request (every microsecond of host-side delay counted in the
        request's path biases the offset by half of it)."""
        if pending is not None:
            self._pending[seq] = pending
        if isinstance(message, TimeSync):
            self._sync_sent[seq] = time.monotonic_ns()

    def not_sent(self, seq: int) -> None:
        self._pending.pop(seq, None)

    @property
    def awaiting(self) -> bool:
        """A command's ACK or a TIME_SYNC reply is still awaited."""
        return bool(self._sync_sent or self._pending)

    # ------------------------------------------------------------ commands
    def handshake(self, bytes_received: Callable[[], int]) -> Hello:
        deadline = time.monotonic() + HANDSHAKE_TIMEOUT_S
        asked = False
        while time.monotonic() < deadline:
            if self._hello_event.wait(0.3):
                hello = self.hello
                assert hello is not None
                if hello.protocol_version != PROTOCOL_VERSION:
                    raise VersionMismatchError(hello.protocol_version, PROTOCOL_VERSION)
                return hello
            foreign = self.decoder.stats.last_foreign_version
            if foreign is not None:
                raise VersionMismatchError(foreign, PROTOCOL_VERSION)
            if not asked:
                # The device said HELLO at boot, perhaps long before we opened the port.
                with contextlib.suppress(DeviceLinkError):
                    self._send(Ping(nonce=0), None)
                asked = True
        stats = self.decoder.stats
        raise DeviceLinkError(
            f"no HELLO from {self._url} within {HANDSHAKE_TIMEOUT_S:.0f} s "
            f"({bytes_received()} bytes received, {stats.rejected} frames rejected): is it an ICGT device?"
        )

    def command(self, message: Message, *, timeout_s: float = COMMAND_TIMEOUT_S, retries: int = 3) -> Ack:
        """Send a command and wait for its ACK, retrying with a new sequence number if none comes.

        Raises CommandRefusedError when the device refuses it. A retried START_CAPTURE that
        is refused with busy_capturing after an unanswered first attempt counts as accepted:
        the first attempt reached the device and only its ACK was lost.
        """
        last_error: DeviceLinkError | None = None
        for attempt in range(retries + 1):
            pending = Pending()
            try:
                seq = self._send(message, pending)
            except DeviceLinkError as exc:
                last_error = exc
                time.sleep(timeout_s)
                continue
            answered = pending.done.wait(timeout_s)
            self._pending.pop(seq, None)
            if answered:
                ack = pending.ack
                assert ack is not None
                if ack.error_code == ErrorCode.OK:
                    return ack
                if attempt > 0 and ack.error_code in (ErrorCode.BUSY_CAPTURING, ErrorCode.NOT_CAPTURING):
                    return ack
                raise CommandRefusedError(message.NAME, ack.error_code, ack.detail)
            last_error = DeviceLinkError(f"no ACK for {message.NAME} within {timeout_s * 1000:.0f} ms")
        raise last_error or DeviceLinkError(f"{message.NAME} not answered")

    def wait_device_state(self, timeout_s: float) -> DeviceState | None:
        self._device_state_event.wait(timeout_s)
        return self.device_state

    # ------------------------------------------------------------ what the link read (its rx lock held)
    def took(self, data: bytes, host_rx_ns: int) -> None:
        """What one read gave, handed on; then the RESEND tracker's and HOST_RECEIVED's turn."""
        if data:
            self._feed(data, host_rx_ns)
        self.resend.tick()
        self._report_received(host_rx_ns)

    def time_sync_if_due(self, now_ns: int) -> None:
        """With `time_sync_interval_s` set, send a TIME_SYNC when one is due (from the link's reader thread)."""
        interval = self.time_sync_interval_s
        if interval is None or now_ns < self.next_sync_ns:
            return
        self.next_sync_ns = now_ns + int(max(interval, 0.001) * 1e9)
        with contextlib.suppress(DeviceLinkError):  # down: the reconnect restarts the schedule
            self._send(TimeSync(host_t_ns=time.monotonic_ns()), None)

    def link_down(self) -> None:
        # A half-received frame must not be glued to the first bytes after the outage.
        self.decoder.feed(b"\x00")

    def link_restored(self) -> None:
        self.next_sync_ns = 0  # resynchronise at once
        self.resend.link_restored()

    def _feed(self, data: bytes, host_rx_ns: int) -> None:
        stats = self.decoder.stats
        missed_before = stats.seq_missed
        for received in self.decoder.feed(data):
            if self.resend.observe(received):
                self._dispatch(received, host_rx_ns)
        if stats.seq_missed != missed_before:
            n = stats.seq_missed - missed_before
            self._on_event(
                DeviceLinkEvent("sequence_gap", host_rx_ns, f"{n} device messages missing: asked again", count=n)
            )
        if stats.rejected != self._rejected_reported:
            n = stats.rejected - self._rejected_reported
            self._rejected_reported = stats.rejected
            self._on_event(DeviceLinkEvent("frames_rejected", host_rx_ns, f"{n} corrupt frames skipped", count=n))

    def _dispatch(self, received: Received, host_rx_ns: int) -> None:
        msg = received.message
        if isinstance(msg, Ack):
            pending = self._pending.get(msg.request_seq)
            if pending is not None:
                pending.ack = msg
                pending.done.set()
        elif isinstance(msg, TimeSyncReply):
            host_tx_ns = self._sync_sent.pop(msg.request_seq, None)
            if host_tx_ns is not None:
                self._on_time_sync(TimeSyncSample(host_tx_ns, msg.device_rx_t_us, msg.device_tx_t_us, host_rx_ns))
                self._on_answered()
            if len(self._sync_sent) > 64:  # replies lost on the wire: forget the oldest requests
                for seq in sorted(self._sync_sent)[:32]:
                    del self._sync_sent[seq]
        elif isinstance(msg, DeviceState):
            self.device_state = msg
            self._device_state_event.set()
        elif isinstance(msg, Hello):
            self.hello = msg
            self._hello_event.set()
            if msg.table_hash != TABLE_HASH and msg.protocol_version == PROTOCOL_VERSION:
                self._on_event(
                    DeviceLinkEvent(
                        "table_hash_mismatch",
                        host_rx_ns,
                        f"device message table 0x{msg.table_hash:08X}, host 0x{TABLE_HASH:08X}: different builds",
                    )
                )
        self._on_message(received, host_rx_ns)

    def _send_quietly(self, message: Message) -> None:
        self._send(message, None)  # DeviceLinkError when down: the tracker asks again later

    def _history_lost(self, r: LossReport) -> None:
        if r.exposures + r.pps + r.samples + r.unknown == 0:
            return  # only STATUS/ACK/LOG frames, which the device never keeps: counted, not worth an event
        detail = (
            f"device frames {r.first_seq}..{(r.first_seq + r.count - 1) & 0xFFFFFFFF} not recoverable "
            f"({r.resent} came back): {r.exposures} exposures, {r.pps} PPS, {r.samples} samples, "
            f"{r.other} status/replies/logs, {r.unknown} unknown"
        )
        self._on_event(
            DeviceLinkEvent("history_lost", time.monotonic_ns(), detail, count=r.exposures + r.pps + r.samples)
        )

    def _report_received(self, now_ns: int) -> None:
        """Every second note how far the log is complete; send the note from HOST_RECEIVED_LAG_NS ago."""
        if now_ns < self._next_mark_ns:
            return
        self._next_mark_ns = now_ns + HOST_RECEIVED_PERIOD_NS
        through = self.resend.received_through()
        if through is not None:
            self._received_marks.append((now_ns, through))
        due = [m for m in self._received_marks if now_ns - m[0] >= HOST_RECEIVED_LAG_NS]
        if not due:
            return
        self._received_marks = [m for m in self._received_marks if now_ns - m[0] < HOST_RECEIVED_LAG_NS]
        with contextlib.suppress(DeviceLinkError):
            self._send(HostReceived(next_seq=due[-1][1], recording_id=self.recording_id), None)
