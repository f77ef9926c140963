"""The serial link to the ICGT device as a transport: the port, its reader thread, its up/down state.

`DeviceLink` moves bytes. One reader thread owns the port: it stamps every read with the host's monotonic
clock the moment bytes arrive and hands them, with that stamp, to the link's `DeviceSession`
(`icgt.device.session`: the protocol, its answers and its schedules), which decodes them and hands every
message to the owner's callback. Or the owner reads the port itself at its own steps (`set_pumped`, `pump`)
while the reader only waits for answers. Between reads the reader may pause (`batch_s`), so that one read
takes many USB transfers; a send that awaits an answer keeps the reads prompt, so the answer is stamped as it
arrives. When the port fails (unplugged cable) the link reports the outage, reopens the same URL until the
device is back, and says so ('disconnected', 'connected' events). Opening and reading the port itself:
`icgt.device.port`.
"""

from __future__ import annotations

import contextlib
import threading
import time

import serial

from icgt.device.link_types import DeviceLinkError, DeviceLinkEvent, EventCallback, MessageCallback, TimeSyncCallback
from icgt.device.port import open_port, port_fd, read_chunk
from icgt.device.resend import ResendTracker
from icgt.device.session import COMMAND_TIMEOUT_S, DeviceSession, Pending
from icgt.protocol import encode_frame
from icgt.protocol.messages import Ack, DeviceState, Hello, Message, Ping, TimeSync

__all__ = ["DeviceLink"]

REOPEN_INTERVAL_S = 0.2
PROMPT_WINDOW_NS = 100_000_000
"""After each send that awaits an answer, the reader reads as soon as bytes arrive for this long [ns] (its stamp),
or until every answer awaited has come (see _answered: a TIME_SYNC_REPLY comes within a millisecond or two)."""
PUMPED_PAUSE_S = 0.1
"""While the owner pumps (`pump()`), the reader's pause between reads when nothing is awaited or due [s]: it
only reads what no pump took (the owner stopped pumping), sends the TIME_SYNCs and waits for answers."""
CATCH_UP_TIMEOUT_S = 0.02
"""How long a TIME_SYNC request waits for a batching reader to take what it held back [s]."""


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
        self._on_event = on_event
        self._baudrate = baudrate
        self._reconnect = reconnect
        self._port: serial.SerialBase | None = None
        self._tx_lock = threading.Lock()
        self._seq = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._connected = threading.Event()
        self._down_since_ns = 0
        self._batch_s = batch_s
        self._prompt = threading.Event()  # set by send(): the reader stops batching at once
        self._prompt_until_ns = 0  # reads are prompt until then (a reply is awaited) [ns, host monotonic]
        self._caught_up = threading.Event()  # set by the reader when it is prompt and has read everything
        self.bytes_received = 0
        self.reads = 0  # read calls that returned bytes (what batching saves)
        self.session = DeviceSession(
            url,
            lambda message, pending: self.send(message, pending=pending),
            on_message=on_message,
            on_event=on_event,
            on_time_sync=on_time_sync,
            on_answered=self._answered,
        )
        # One reader of the port at a time, the reader thread or the owner's pump(): the session's decoder, its
        # RESEND tracker and the order of the messages handed on are theirs while they hold it.
        self._rx_lock = threading.Lock()
        self._pumped = False  # the owner calls pump() (set_pumped): the reader only waits for answers

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> Hello:
        """Open the port, start the reader and complete the handshake. Returns the device's HELLO.

        Raises VersionMismatchError if the device speaks another protocol version and
        DeviceLinkError if it cannot be opened or does not answer.
        """
        self._port = open_port(self.url, self._baudrate)
        self._connected.set()
        self._thread = threading.Thread(target=self._read_loop, name="icgt-device-reader", daemon=True)
        self._thread.start()
        try:
            return self.session.handshake(lambda: self.bytes_received)
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
    def connected(self) -> bool:
        return self._connected.is_set()

    @property
    def down_since_ns(self) -> int | None:
        """When the link went down (host CLOCK_MONOTONIC [ns]); None while it is up."""
        return None if self._connected.is_set() else self._down_since_ns

    # ---------------------------------------------------------------- the session's, as the owner sees them
    @property
    def hello(self) -> Hello | None:
        return self.session.hello

    @property
    def device_state(self) -> DeviceState | None:
        """The last DEVICE_STATE (sent after every HELLO)."""
        return self.session.device_state

    def wait_device_state(self, timeout_s: float) -> DeviceState | None:
        return self.session.wait_device_state(timeout_s)

    @property
    def decoder_stats(self) -> dict[str, int | None]:
        return self.session.decoder.stats.as_dict()

    @property
    def frames_rejected(self) -> int:
        """Device frames rejected for any reason (SPEC.md §6)."""
        return self.session.decoder.stats.rejected

    @property
    def resend(self) -> ResendTracker:
        return self.session.resend

    @property
    def recording_id(self) -> int:
        """The owner's log, named in every HOST_RECEIVED (nonzero; 0: none)."""
        return self.session.recording_id

    @recording_id.setter
    def recording_id(self, value: int) -> None:
        self.session.recording_id = value

    @property
    def time_sync_interval_s(self) -> float | None:
        """TIME_SYNC sent by the reader itself every this many seconds; None: only on request_time_sync()."""
        return self.session.time_sync_interval_s

    @time_sync_interval_s.setter
    def time_sync_interval_s(self, value: float | None) -> None:
        self.session.time_sync_interval_s = value

    def command(self, message: Message, *, timeout_s: float = COMMAND_TIMEOUT_S, retries: int = 3) -> Ack:
        """Send a command and wait for its ACK (`DeviceSession.command`); CommandRefusedError when refused."""
        return self.session.command(message, timeout_s=timeout_s, retries=retries)

    # ---------------------------------------------------------------- sending
    def send(self, message: Message, *, pending: Pending | None = None) -> int:
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
            frame = encode_frame(message, seq)
            if self._batch_s > 0.0 and (pending is not None or isinstance(message, TimeSync | Ping)):
                # Its answer (an ACK, a TIME_SYNC_REPLY, a HELLO) must be stamped when it arrives. A
                # HOST_RECEIVED has none, and RESEND's retransmitted frames carry device time: those
                # leave the reader batching (each kept it prompt for 100 ms, one read per USB frame).
                self._prompt_until_ns = time.monotonic_ns() + PROMPT_WINDOW_NS
                if threading.current_thread() is not self._thread:  # the reader itself is awake already
                    self._prompt.set()
            self.session.sending(seq, message, pending)
            try:
                port.write(frame)
            except (serial.SerialException, OSError) as exc:
                self.session.not_sent(seq)
                raise DeviceLinkError(f"writing to {self.url}: {exc}") from exc
        return seq

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

    def _answered(self) -> None:
        """A TIME_SYNC reply was handed on: with nothing else awaited, batch again at once."""
        with self._tx_lock:  # against a send() between the test and the reset
            if not self.session.awaiting:
                self._prompt_until_ns = 0

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
        self._pumped = bool(on) and self._batch_s > 0.0 and port is not None and port_fd(port) is not None
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
        return port_fd(port)

    def pump(self) -> int:
        """Read and hand on (on_message, on_time_sync, on_event, on this thread) whatever the device sent
        since the last read; returns the bytes read. Does nothing when not pumped, when the link is down or
        while the reader thread is reading (an answer is awaited: what it reads is handed on as usual)."""
        if not self._pumped or not self._connected.is_set() or not self._rx_lock.acquire(blocking=False):
            return 0
        try:
            port = self._port
            if port is None or port_fd(port) is None:
                return 0
            try:
                # A serial port read with nothing waiting gives b"" (pyserial's VMIN 0), as a hung-up one
                # does: select() first tells them apart, as the reader's reads do.
                data = read_chunk(port, 0.0)
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
                    data = read_chunk(port)
                    # Stamped after the last byte of the chunk is in hand: a frame that completes in it
                    # arrived no later than this (a stamp taken after the first byte could precede it).
                    host_rx_ns = time.monotonic_ns()
                except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                    if self._stop.is_set():
                        break  # stop() cancelled or closed the port under the read: not an outage
                    self._link_down(str(exc))
                    continue
                self._took(data, host_rx_ns)
                # A TIME_SYNC due goes from here: the reader has just read and decoded everything that had
                # arrived, so it goes back to select() with nothing held back, and the reply is stamped as
                # soon as it comes (the reads stay prompt until then, send()). Sent here rather than by another
                # thread, an exchange costs one wake-up (the reply's), not the four of a request_time_sync()
                # from elsewhere (that thread's timer, waking the reader from its pause, the catch-up it waits
                # for, the reply), each of which costs as much CPU as handling dozens of messages.
                self.session.time_sync_if_due(host_rx_ns)
            if (data or self._pumped) and self._batch_s > 0.0:
                self._pause(host_rx_ns)

    def _took(self, data: bytes, host_rx_ns: int) -> None:
        """What one read gave, to the session (rx lock held)."""
        if data:
            self.bytes_received += len(data)
            self.reads += 1
        self.session.took(data, host_rx_ns)

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
            if self.session.time_sync_interval_s is not None:  # awake again for the next TIME_SYNC
                wait_s = min(wait_s, max(0.0, (self.session.next_sync_ns - now_ns) / 1e9))
        self._prompt.wait(wait_s)
        self._prompt.clear()

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
        self.session.link_down()
        self._on_event(DeviceLinkEvent("disconnected", now, f"device link lost: {why}"))
        if not self._reconnect:
            self._stop.set()

    def _try_reopen(self) -> None:
        if self._stop.wait(REOPEN_INTERVAL_S):
            return
        try:
            port = open_port(self.url, self._baudrate)
        except DeviceLinkError:
            return
        now = time.monotonic_ns()
        with self._tx_lock:
            self._port = port
        self._connected.set()
        self.session.link_restored()
        outage = now - self._down_since_ns
        self._on_event(
            DeviceLinkEvent("connected", now, f"device link back after {outage / 1e9:.2f} s", outage_ns=outage)
        )
