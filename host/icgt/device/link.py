"""The serial link to the ICGT device: open, handshake, read, command, reconnect.

One reader thread owns the port. It stamps every read with the host's monotonic clock the
moment bytes arrive, decodes frames, answers waiting commands and TIME_SYNC exchanges, and
hands every message to the recorder's callback. When the port fails (unplugged cable) it
reports the outage, reopens the same URL until the device is back, and asks the device again
for every frame the sequence numbers say it missed (`icgt.device.resend`): retransmitted
frames are delivered like live ones (late), duplicates are dropped, and what the device could
no longer send is counted by kind and reported as a 'history_lost' event. Every second it tells
the device how far its log is complete (HOST_RECEIVED, a few seconds behind, so a host killed
meanwhile loses nothing that a successor cannot ask for again).
"""

from __future__ import annotations

import contextlib
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import serial
from serial.urlhandler import protocol_socket

from icgt.device.limits import describe_refusal
from icgt.device.resend import LossReport, ResendTracker
from icgt.errors import ProtocolError, VersionMismatchError
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH, Received, StreamDecoder, encode_frame
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

HANDSHAKE_TIMEOUT_S = 3.0
COMMAND_TIMEOUT_S = 0.3
REOPEN_INTERVAL_S = 0.2
HOST_RECEIVED_PERIOD_NS = 1_000_000_000
# HOST_RECEIVED reports what was complete this long ago: the worker writes a frame to the log within
# milliseconds, but the MCAP chunk holding it is closed only every second, and a chunk not closed when
# the recorder is killed is not in the file. A successor asks RESEND from there (duplicates across the
# two files, never a loss).
HOST_RECEIVED_LAG_NS = 3_000_000_000
PROMPT_WINDOW_NS = 100_000_000
"""After each send that awaits an answer, the reader reads as soon as bytes arrive for this long [ns] (its stamp),
or until every answer awaited has come (see _dispatch: a TIME_SYNC_REPLY comes within a millisecond or two)."""
PUMPED_PAUSE_S = 0.1
"""While the owner pumps (`pump()`), the reader's pause between reads when nothing is awaited or due [s]: it
only reads what no pump took (the owner stopped pumping), sends the TIME_SYNCs and waits for answers."""
CATCH_UP_TIMEOUT_S = 0.02
"""How long a TIME_SYNC request waits for a batching reader to take what it held back [s]."""


class DeviceLinkError(ProtocolError):
    """The device cannot be reached, or did not answer."""


class DeviceAbsentError(DeviceLinkError):
    """The device's port does not exist (yet): not plugged in, or not enumerated."""


class DeviceBusyError(DeviceLinkError):
    """Another program holds the device's port."""


class CommandRefusedError(DeviceLinkError):
    """The device refused a command (NACK) and changed nothing."""

    def __init__(self, command: str, code: int, detail: int) -> None:
        # ACK.detail names the limit broken (protocol Limit); describe_refusal says it in words.
        super().__init__(f"device refused {command}: {describe_refusal(code, detail)}")
        self.command = command
        self.code = code
        self.detail = detail


@dataclass(frozen=True, slots=True)
class TimeSyncSample:
    """One NTP-style exchange: host send/receive [ns, host monotonic], device receive/transmit [us]."""

    host_tx_ns: int
    device_rx_us: int
    device_tx_us: int
    host_rx_ns: int

    @property
    def round_trip_ns(self) -> int:
        return (self.host_rx_ns - self.host_tx_ns) - (self.device_tx_us - self.device_rx_us) * 1000


@dataclass(frozen=True, slots=True)
class DeviceLinkEvent:
    """Something about the link itself, for the log: kind is one of 'connected', 'disconnected',
    'sequence_gap', 'frames_rejected', 'table_hash_mismatch', 'history_lost' (frames the device could no
    longer send: count = exposures + PPS + samples, detail by kind)."""

    kind: str
    host_ns: int
    detail: str
    count: int = 0
    outage_ns: int = 0


MessageCallback = Callable[[Received, int], None]
EventCallback = Callable[[DeviceLinkEvent], None]
TimeSyncCallback = Callable[[TimeSyncSample], None]


@dataclass
class _Pending:
    done: threading.Event = field(default_factory=threading.Event)
    ack: Ack | None = None


class DeviceLink:
    """A connection to one device by URL (`/dev/ttyACM0`, the simulator's pty, `socket://host:port`)."""

    def __init__(
        self,
        url: str,
        *,
        on_message: MessageCallback,
        on_event: EventCallback,
        on_time_sync: TimeSyncCallback,
        baudrate: int = 115200,
        reconnect: bool = True,
        batch_s: float = 0.0,
    ) -> None:
        """`batch_s` > 0: between reads, while no reply is awaited, the reader sleeps this long [s] and then
        takes everything that arrived in one read (see `_read_loop`); 0 reads each USB transfer at once."""
        self.url = url
        self._on_message = on_message
        self._on_event = on_event
        self._on_time_sync = on_time_sync
        self._baudrate = baudrate
        self._reconnect = reconnect
        self._port: serial.SerialBase | None = None
        self._decoder = StreamDecoder()
        self._tx_lock = threading.Lock()
        self._seq = 0
        self._pending: dict[int, _Pending] = {}
        self._sync_sent: dict[int, int] = {}  # request seq -> host_tx_ns
        self._hello: Hello | None = None
        self._hello_event = threading.Event()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = threading.Event()
        self._down_since_ns = 0
        self._rejected_reported = 0
        self._batch_s = batch_s
        self._prompt = threading.Event()  # set by send(): the reader stops batching at once
        self._prompt_until_ns = 0  # reads are prompt until then (a reply is awaited) [ns, host monotonic]
        self._caught_up = threading.Event()  # set by the reader when it is prompt and has read everything
        self.bytes_received = 0
        self.resend = ResendTracker(self._send_quietly, on_loss=self._history_lost)
        self._device_state: DeviceState | None = None
        self._device_state_event = threading.Event()
        self._received_marks: list[tuple[int, int]] = []  # (host ns, HOST_RECEIVED value) not sent yet
        self._next_mark_ns = 0
        self.reads = 0  # read calls that returned bytes (what batching saves)
        # The owner's log, named in every HOST_RECEIVED (nonzero; 0: none): the device gives it back in
        # DEVICE_STATE, so a later host knows which recording the frames it still holds follow.
        self.recording_id = 0
        # TIME_SYNC sent by the reader itself, every this many seconds (see _time_sync_if_due); None: only
        # when the owner calls request_time_sync(). The owner may change it at any time (a float, set whole).
        self.time_sync_interval_s: float | None = None
        self._next_sync_ns = 0  # the reader's next TIME_SYNC [ns, host monotonic]; 0: at once (after a connect)
        # One reader of the port at a time, the reader thread or the owner's pump(): the decoder, the RESEND
        # tracker and the order of the messages handed on are theirs while they hold it.
        self._rx_lock = threading.Lock()
        self._pumped = False  # the owner calls pump() (set_pumped): the reader only waits for answers

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> Hello:
        """Open the port, start the reader and complete the handshake. Returns the device's HELLO.

        Raises VersionMismatchError if the device speaks another protocol version and
        DeviceLinkError if it cannot be opened or does not answer.
        """
        self._port = self._open()
        self._connected.set()
        self._thread = threading.Thread(target=self._read_loop, name="icgt-device-reader", daemon=True)
        self._thread.start()
        try:
            return self._handshake()
        except Exception:
            self.stop()
            raise

    def stop(self) -> None:
        self._stop.set()
        self._prompt.set()  # out of a batching pause
        port = self._port
        if port is not None:
            with contextlib.suppress(Exception):
                port.cancel_read()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        self._port = None

    @property
    def hello(self) -> Hello | None:
        return self._hello

    @property
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def down_since_ns(self) -> int | None:
        """When the link went down (host CLOCK_MONOTONIC [ns]); None while it is up."""
        return None if self._connected.is_set() else self._down_since_ns

    @property
    def decoder_stats(self) -> dict[str, int | None]:
        return self._decoder.stats.as_dict()

    @property
    def device_state(self) -> DeviceState | None:
        """The last DEVICE_STATE (sent after every HELLO)."""
        return self._device_state

    def wait_device_state(self, timeout_s: float) -> DeviceState | None:
        self._device_state_event.wait(timeout_s)
        return self._device_state

    @property
    def frames_rejected(self) -> int:
        """Device frames rejected for any reason (SPEC.md §6)."""
        return self._decoder.stats.rejected

    # ---------------------------------------------------------------- commands
    def send(self, message: Message, *, pending: _Pending | None = None) -> int:
        """Frame and send one message; returns its sequence number. Raises DeviceLinkError if the port is down.

        A `pending` is registered under the frame's sequence number before the bytes leave,
        so its ACK cannot arrive unclaimed.
        """
        with self._tx_lock:
            port = self._port
            if port is None or not self._connected.is_set():
                raise DeviceLinkError(f"device link {self.url} is down")
            seq = self._seq
            self._seq = (self._seq + 1) & 0xFFFFFFFF
            if pending is not None:
                self._pending[seq] = pending
            frame = encode_frame(message, seq)
            if self._batch_s > 0.0 and (pending is not None or isinstance(message, TimeSync | Ping)):
                # Its answer (an ACK, a TIME_SYNC_REPLY, a HELLO) must be stamped when it arrives. A
                # HOST_RECEIVED has none, and RESEND's retransmitted frames carry device time: those
                # leave the reader batching (each kept it prompt for 100 ms, one read per USB frame).
                self._prompt_until_ns = time.monotonic_ns() + PROMPT_WINDOW_NS
                if threading.current_thread() is not self._thread:  # the reader itself is awake already
                    self._prompt.set()
            if isinstance(message, TimeSync):
                # The send time is taken after framing, right before the bytes go to the kernel: the
                # field in the message only identifies the request (every microsecond of host-side
                # delay counted in the request's path biases the offset by half of it).
                self._sync_sent[seq] = time.monotonic_ns()
            try:
                port.write(frame)
            except (serial.SerialException, OSError) as exc:
                self._pending.pop(seq, None)
                raise DeviceLinkError(f"writing to {self.url}: {exc}") from exc
        return seq

    def command(self, message: Message, *, timeout_s: float = COMMAND_TIMEOUT_S, retries: int = 3) -> Ack:
        """Send a command and wait for its ACK, retrying with a new sequence number if none comes.

        Raises CommandRefusedError when the device refuses it. A retried START_CAPTURE that
        is refused with busy_capturing after an unanswered first attempt counts as accepted:
        the first attempt reached the device and only its ACK was lost.
        """
        last_error: DeviceLinkError | None = None
        for attempt in range(retries + 1):
            pending = _Pending()
            try:
                seq = self.send(message, pending=pending)
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

    def request_time_sync(self) -> None:
        """Send one TIME_SYNC; the reply arrives through on_time_sync.

        With `batch_s` the reader is first woken and given up to CATCH_UP_TIMEOUT_S to take what arrived
        during its pause, so that it waits in select() when the reply comes back: a reply arriving while it
        decodes a backlog would be stamped late by that much."""
        if self._batch_s > 0.0:
            self._caught_up.clear()
            self._prompt_until_ns = time.monotonic_ns() + PROMPT_WINDOW_NS
            self._prompt.set()
            self._caught_up.wait(CATCH_UP_TIMEOUT_S)
        self.send(TimeSync(host_t_ns=time.monotonic_ns()))

    # ---------------------------------------------------------------- internals
    def _open(self) -> serial.SerialBase:
        local = "://" not in self.url
        if local and not os.path.exists(self.url):
            raise DeviceAbsentError(f"device {self.url} does not exist (not plugged in?)")
        try:
            # exclusive: an flock on the port, so a second recorder cannot read half of the stream.
            port = serial.serial_for_url(
                self.url, baudrate=self._baudrate, timeout=0.05, write_timeout=0.5, exclusive=local or None
            )
        except (serial.SerialException, OSError, ValueError) as exc:
            if local and "exclusively lock" in str(exc):
                holders = ", ".join(f"pid {pid} ({cmd})" for pid, cmd in port_holders(self.url)) or "another program"
                raise DeviceBusyError(f"device {self.url} is in use by {holders}") from None
            if local and not os.path.exists(self.url):
                raise DeviceAbsentError(f"device {self.url} disappeared while opening it") from None
            raise DeviceLinkError(f"cannot open device {self.url}: {exc}") from exc
        return port

    def _handshake(self) -> Hello:
        deadline = time.monotonic() + HANDSHAKE_TIMEOUT_S
        asked = False
        while time.monotonic() < deadline:
            if self._hello_event.wait(0.3):
                hello = self._hello
                assert hello is not None
                if hello.protocol_version != PROTOCOL_VERSION:
                    raise VersionMismatchError(hello.protocol_version, PROTOCOL_VERSION)
                return hello
            foreign = self._decoder.stats.last_foreign_version
            if foreign is not None:
                raise VersionMismatchError(foreign, PROTOCOL_VERSION)
            if not asked:
                # The device said HELLO at boot, perhaps long before we opened the port.
                with contextlib.suppress(DeviceLinkError):
                    self.send(Ping(nonce=0))
                asked = True
        stats = self._decoder.stats
        raise DeviceLinkError(
            f"no HELLO from {self.url} within {HANDSHAKE_TIMEOUT_S:.0f} s "
            f"({self.bytes_received} bytes received, {stats.rejected} frames rejected): is it an ICGT device?"
        )

    # ---------------------------------------------------------------- pumped by the owner
    def set_pumped(self, on: bool) -> bool:
        """From now on the owner reads the port with `pump()` every few tens of ms (on: True) or no longer
        (False: the reader reads everything again). Honoured on a port with a file descriptor (a serial
        device, socket://; not loop://). Returns whether the link is pumped now.

        While pumped, the reader thread sleeps between the TIME_SYNCs it sends (time_sync_interval_s) and
        reads only while an answer is awaited: the device's stream is read by the owner's periodic thread
        that handles it anyway, which saves the reader's wake-up every batch_s. Stamps: a message read by a
        pump is stamped when read (late by up to the pump period, as a batching reader's are by batch_s);
        what the clocks use is not, the replies are read by the reader as they arrive."""
        port = self._port
        self._pumped = bool(on) and self._batch_s > 0.0 and port is not None and _port_fd(port) is not None
        self._prompt.set()  # out of the current pause: the next one is the new mode's
        return self._pumped

    @property
    def pumped(self) -> bool:
        return self._pumped

    @property
    def readable_fd(self) -> int | None:
        """The descriptor a pumping owner may wait on for the device's input (select()), None when the link
        is not pumped or is down. Readable means `pump()` has something to read (or the port hung up)."""
        port = self._port
        if not self._pumped or port is None or not self._connected.is_set():
            return None
        return _port_fd(port)

    def pump(self) -> int:
        """Read and hand on (on_message, on_time_sync, on_event, on this thread) whatever the device sent
        since the last read; returns the bytes read. Does nothing when not pumped, when the link is down or
        while the reader thread is reading (an answer is awaited: what it reads is handed on as usual)."""
        if not self._pumped or not self._connected.is_set() or not self._rx_lock.acquire(blocking=False):
            return 0
        try:
            port = self._port
            if port is None or _port_fd(port) is None:
                return 0
            try:
                # A serial port read with nothing waiting gives b"" (pyserial's VMIN 0), as a hung-up one
                # does: select() first tells them apart, as the reader's reads do.
                data = self._read_chunk(port, 0.0)
            except (serial.SerialException, OSError) as exc:
                self._link_down(str(exc))
                return 0
            self._took(data, time.monotonic_ns())
            return len(data)
        finally:
            self._rx_lock.release()

    # ---------------------------------------------------------------- the reader thread
    def _read_loop(self) -> None:
        while not self._stop.is_set():
            port = self._port
            if port is None or not self._connected.is_set():
                self._try_reopen()
                continue
            with self._rx_lock:
                try:
                    if self._batch_s > 0.0 and time.monotonic_ns() < self._prompt_until_ns:
                        self._caught_up.set()  # nothing held back: about to wait in select() for the reply
                    data = self._read_chunk(port)
                    # Stamped after the last byte of the chunk is in hand: a frame that completes in it
                    # arrived no later than this (a stamp taken after the first byte could precede it).
                    host_rx_ns = time.monotonic_ns()
                except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                    if self._stop.is_set():
                        break  # stop() cancelled or closed the port under the read: not an outage
                    self._link_down(str(exc))
                    continue
                self._took(data, host_rx_ns)
                self._time_sync_if_due(host_rx_ns)
            if (data or self._pumped) and self._batch_s > 0.0:
                self._pause(host_rx_ns)

    def _took(self, data: bytes, host_rx_ns: int) -> None:
        """What one read gave, handed on; then the RESEND tracker's and HOST_RECEIVED's turn (rx lock held)."""
        if data:
            self.bytes_received += len(data)
            self.reads += 1
            self._feed(data, host_rx_ns)
        self.resend.tick()
        self._report_received(host_rx_ns)

    def _time_sync_if_due(self, now_ns: int) -> None:
        """With `time_sync_interval_s` set, send a TIME_SYNC when one is due, from this (the reader) thread.

        It has just read and decoded everything that had arrived, so it goes back to select() with nothing
        held back, and the reply is stamped as soon as it comes; the reads stay prompt until then (send()).
        Sent here rather than by another thread, an exchange costs one wake-up (the reply's), not the four of
        a request_time_sync() from elsewhere (that thread's timer, waking the reader from its pause, the
        catch-up it waits for, the reply), each of which costs as much CPU as handling dozens of messages."""
        interval = self.time_sync_interval_s
        if interval is None or now_ns < self._next_sync_ns:
            return
        self._next_sync_ns = now_ns + int(max(interval, 0.001) * 1e9)
        with contextlib.suppress(DeviceLinkError):  # down: the reconnect restarts the schedule
            self.send(TimeSync(host_t_ns=time.monotonic_ns()))

    def _send_quietly(self, message: Message) -> None:
        self.send(message)  # DeviceLinkError when down: the tracker asks again later

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
            self.send(HostReceived(next_seq=due[-1][1], recording_id=self.recording_id))

    def _pause(self, now_ns: int) -> None:
        """Between two reads, unless a reply is awaited: sleep `batch_s`, so that one read takes what the
        device sent meanwhile (it delivers every USB frame, 1 ms or less apart: one wake-up, one read and
        one decoder call each cost more than their messages). The stamp of a message that arrived during
        the pause is late by up to `batch_s`; what the clocks use is not: a TIME_SYNC reply comes while
        reads are prompt (a send awaiting an answer ends any pause and keeps reads prompt for PROMPT_WINDOW_NS), and the
        device's own messages carry device time. A late stamp only makes their host_rx_ns later."""
        if now_ns < self._prompt_until_ns:
            return
        wait_s = self._batch_s
        if self._pumped:
            wait_s = PUMPED_PAUSE_S
            if self.time_sync_interval_s is not None:  # awake again for the next TIME_SYNC
                wait_s = min(wait_s, max(0.0, (self._next_sync_ns - now_ns) / 1e9))
        self._prompt.wait(wait_s)
        self._prompt.clear()

    @staticmethod
    def _read_chunk(port: serial.SerialBase, timeout_s: float = 0.05) -> bytes:
        """Whatever has arrived, as soon as anything has (or b"" after `timeout_s`, 50 ms).

        On a POSIX serial port one select() and one read() of the file descriptor: pyserial's
        read(1) + in_waiting + read(n) costs three more system calls and their Python overhead
        between the bytes' arrival and the stamp, a delay on the reply path alone that biases
        the device clock mapping by half of it. A socket:// port the same way, through the
        descriptor pyserial's `fileno()` gives for select(): its `in_waiting` only says whether
        the socket is readable (1), so read(1) + read(in_waiting) returned 2 bytes per call.
        Other URLs (loop://, rfc2217:// with its telnet layer) go through pyserial.
        """
        fd = _port_fd(port)
        is_socket = isinstance(port, protocol_socket.Serial)
        if fd is not None:
            ready, _, _ = select.select([fd], [], [], timeout_s)
            if not ready:
                return b""
            try:
                chunk = os.read(fd, 65536)
            except BlockingIOError:  # both are non-blocking: readiness without data is not an outage
                return b""
            if not chunk:  # readable but empty: the device went away (as pyserial reports it)
                if is_socket:
                    raise serial.SerialException("the device closed the connection")
                # pyserial's words for it ("device reports readiness to read but returned no data") name
                # no cause; this is end of file on the port
                raise serial.SerialException(
                    "the serial port gave end of file (the device was unplugged, powered off or its program ended)"
                )
            return chunk
        data: bytes = port.read(1)
        waiting = port.in_waiting
        if waiting:
            data += port.read(waiting)
        return data

    def _feed(self, data: bytes, host_rx_ns: int) -> None:
        stats = self._decoder.stats
        missed_before = stats.seq_missed
        for received in self._decoder.feed(data):
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
                with self._tx_lock:  # against a send() between the test and the reset
                    if not self._sync_sent and not self._pending:
                        self._prompt_until_ns = 0  # nothing else awaited: batch again at once
            if len(self._sync_sent) > 64:  # replies lost on the wire: forget the oldest requests
                for seq in sorted(self._sync_sent)[:32]:
                    del self._sync_sent[seq]
        elif isinstance(msg, DeviceState):
            self._device_state = msg
            self._device_state_event.set()
        elif isinstance(msg, Hello):
            self._hello = msg
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

    def _link_down(self, why: str) -> None:
        now = time.monotonic_ns()
        self._connected.clear()
        self._down_since_ns = now
        port = self._port
        with self._tx_lock:
            self._port = None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        # A half-received frame must not be glued to the first bytes after the outage.
        self._decoder.feed(b"\x00")
        self._on_event(DeviceLinkEvent("disconnected", now, f"device link lost: {why}"))
        if not self._reconnect:
            self._stop.set()

    def _try_reopen(self) -> None:
        if self._stop.wait(REOPEN_INTERVAL_S):
            return
        try:
            port = self._open()
        except DeviceLinkError:
            return
        now = time.monotonic_ns()
        with self._tx_lock:
            self._port = port
        self._connected.set()
        self._next_sync_ns = 0  # resynchronise at once
        self.resend.link_restored()
        outage = now - self._down_since_ns
        self._on_event(
            DeviceLinkEvent("connected", now, f"device link back after {outage / 1e9:.2f} s", outage_ns=outage)
        )


def _port_fd(port: serial.SerialBase) -> int | None:
    """The file descriptor to select() and read() on: a POSIX serial port's or a socket:// port's; None for
    the others (loop://, rfc2217://), which are read through pyserial."""
    fd = port.fileno() if isinstance(port, protocol_socket.Serial) else getattr(port, "fd", None)
    return fd if isinstance(fd, int) and fd >= 0 else None


def port_holders(path: str) -> list[tuple[int, str]]:
    """Processes that have `path` open (pid, command line), from /proc: to name who holds a busy port."""
    try:
        target = os.path.realpath(path)
    except OSError:
        return []
    found: list[tuple[int, str]] = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            fds = os.scandir(f"/proc/{entry.name}/fd")
            if any(os.path.realpath(fd.path) == target for fd in fds):
                with open(f"/proc/{entry.name}/cmdline", "rb") as f:
                    cmd = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
                found.append((int(entry.name), cmd[:120]))
        except OSError:
            continue
    return found
