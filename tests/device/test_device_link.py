"""Unit tests of `icgt.device.link.DeviceLink` against a fake device that speaks the real protocol.

Transport. pyserial's ``loop://`` hands back whatever the host writes, so the "device" would answer
a PING with the PING itself: no HELLO, no ACK, no TIME_SYNC_REPLY, only a test of the decoder
talking to itself. Instead the fake device below runs on a thread at the other end of

* a pseudo-terminal pair (the link opens the slave by a symlink, as it opens /dev/ttyACM0): this is
  the production read path (select() + os.read() on the file descriptor, the stamp after the read).
  Pulling the cable is closing the master (the link's read fails with EIO, as an unplugged USB CDC
  port fails); plugging it back is a new pty behind the same symlink;
* a TCP socket behind a ``socket://`` URL (the simulator's TCP mode): pyserial's own read path.
  Pulling the cable is closing the connection and the listening socket.

The device decodes the host's frames with `icgt.protocol.StreamDecoder` and answers with
`encode_frame`, following protocol/SPEC.md section 8: PING nonce 0 -> HELLO, every command -> one
ACK with the command's seq, TIME_SYNC -> TIME_SYNC_REPLY with its own receive/transmit stamps.
Its clock is the host's CLOCK_MONOTONIC minus a known boot time, so the stamps of an exchange can
be checked for order against the host's.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import select
import socket
import struct
import threading
import time
import tty
import zlib
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
from cobs import cobs

from icgt.device import CommandRefusedError, DeviceLink, DeviceLinkError, DeviceLinkEvent, TimeSyncSample
from icgt.errors import VersionMismatchError
from icgt.protocol import PROTOCOL_VERSION, TABLE_HASH, Received, StreamDecoder, encode_frame
from icgt.protocol.messages import (
    Ack,
    Board,
    ErrorCode,
    Hello,
    HostReceived,
    Message,
    Ping,
    Resend,
    ResendLost,
    StartCapture,
    Status,
    StopCapture,
    TimeSync,
    TimeSyncReply,
)

pytestmark = pytest.mark.timeout(60)


# --------------------------------------------------------------------------- transports
class PtyPort:
    """The device end of a pseudo-terminal; the host reaches it through a symlink that survives a replug."""

    def __init__(self, directory: Path) -> None:
        self.path = directory / "ttyICGT0"
        self._lock = threading.Lock()  # the device thread must not select() on a closed descriptor
        self.master = self.slave = -1
        self.plug()

    @property
    def url(self) -> str:
        return str(self.path)

    def plug(self) -> None:
        with self._lock:
            master, slave = os.openpty()
            # Raw from the start (pyserial makes it raw when the host opens it; bytes the device writes
            # before then must not go through a line discipline). The slave stays open here so the
            # master never reads EIO while the host has it closed.
            tty.setraw(slave)
            staged = self.path.with_name(self.path.name + ".new")
            staged.unlink(missing_ok=True)
            os.symlink(os.ttyname(slave), staged)
            os.replace(staged, self.path)
            self.master, self.slave = master, slave

    def unplug(self) -> None:
        with self._lock:
            if self.master < 0:
                return
            self.path.unlink()
            os.close(self.master)
            os.close(self.slave)
            self.master = self.slave = -1

    def read(self, timeout_s: float) -> bytes:
        with self._lock:
            fd = self.master
            if fd >= 0:
                ready, _, _ = select.select([fd], [], [], timeout_s)
                if not ready:
                    return b""
                try:
                    return os.read(fd, 65536)
                except OSError:
                    return b""
        time.sleep(timeout_s)
        return b""

    def write(self, data: bytes) -> None:
        fd = self.master
        if fd >= 0:
            with contextlib.suppress(OSError):  # closed by unplug() meanwhile: the bytes go nowhere
                os.write(fd, data)

    def close(self) -> None:
        self.unplug()


class SocketPort:
    """The device end of a TCP connection (`socket://127.0.0.1:port`), accepting one host at a time."""

    def __init__(self, _directory: Path) -> None:
        self._lock = threading.Lock()
        self.server: socket.socket | None = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.conn: socket.socket | None = None

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.port}"

    def plug(self) -> None:
        with self._lock:
            self.server = socket.create_server(("127.0.0.1", self.port))  # SO_REUSEADDR on POSIX

    def unplug(self) -> None:
        with self._lock:
            for s in (self.conn, self.server):
                if s is not None:
                    with contextlib.suppress(OSError):
                        s.shutdown(socket.SHUT_RDWR)
                    s.close()
            self.conn = self.server = None

    def read(self, timeout_s: float) -> bytes:
        with self._lock:
            if self.conn is not None:
                ready, _, _ = select.select([self.conn], [], [], timeout_s)
                if not ready:
                    return b""
                data = self.conn.recv(65536)
                if not data:
                    self.conn.close()
                    self.conn = None
                return data
            if self.server is not None:
                ready, _, _ = select.select([self.server], [], [], timeout_s)
                if ready:
                    self.conn, _ = self.server.accept()
                    self.conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                return b""
        time.sleep(timeout_s)
        return b""

    def write(self, data: bytes) -> None:
        # The host's connect() completes in the listen backlog before this side accepts it: wait
        # for the accept, or bytes sent right after the host says "connected" would be lost here.
        deadline = time.monotonic() + 2.0
        while self.conn is None and self.server is not None and time.monotonic() < deadline:
            time.sleep(0.005)
        conn = self.conn
        if conn is not None:
            with contextlib.suppress(OSError):  # closed by unplug() meanwhile: the bytes go nowhere
                conn.sendall(data)

    def close(self) -> None:
        self.unplug()


# --------------------------------------------------------------------------- the fake device
def with_bad_crc(frame: bytes) -> bytes:
    """The same frame with one body bit flipped and its CRC left as it was."""
    raw = bytearray(cobs.decode(frame[:-1]))
    raw[9] ^= 0x40
    return cobs.encode(bytes(raw)) + b"\x00"


def with_header_version(frame: bytes, version: int) -> bytes:
    """The same frame with another protocol version in its header (and a CRC that matches)."""
    raw = cobs.decode(frame[:-1])[:-4]
    raw = bytes([version]) + raw[1:]
    return cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"


class FakeDevice:
    """A device that answers as SPEC.md section 8 says, with knobs to misbehave."""

    def __init__(self, port: PtyPort | SocketPort, hello: Hello | None = None) -> None:
        self.port = port
        self.hello = hello or Hello(
            protocol_version=PROTOCOL_VERSION,
            table_hash=TABLE_HASH,
            firmware_version="0.1.0+test",
            board=int(Board.SIMULATOR),
            serial_number=4242,
        )
        self.boot_us = time.monotonic_ns() // 1000 - 1_000_000  # up for a second
        self.seq = 0
        self.answer_hello = True
        self.hello_version: int | None = None  # header version of HELLO frames, if not ours
        self.drop: dict[str, int] = {}  # message name -> how many to leave unanswered
        self.refuse: dict[str, tuple[int, int]] = {}  # command name -> (error code, detail)
        self.received: list[Received] = []
        self._decoder = StreamDecoder()
        self._tx = threading.RLock()  # also held by a test across several writes (exclusive())
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="fake-device", daemon=True)
        self._thread.start()

    def now_us(self) -> int:
        return time.monotonic_ns() // 1000 - self.boot_us

    def send(self, message: Message, *, seq: int | None = None, flags: int = 0) -> bytes:
        with self._tx:
            if seq is None:
                seq, self.seq = self.seq, self.seq + 1
            frame = encode_frame(message, seq, flags)
            if isinstance(message, Hello) and self.hello_version is not None:
                frame = with_header_version(frame, self.hello_version)
            self.port.write(frame)
            return frame

    def write_raw(self, data: bytes) -> None:
        with self._tx:
            self.port.write(data)

    def exclusive(self) -> threading.RLock:
        """`with device.exclusive():` no reply of the serving thread (TIME_SYNC, ACK) takes a sequence number
        or goes out in between: a test that sets `seq` itself and writes frames sees its own numbers."""
        return self._tx

    def received_of(self, cls: type[Message]) -> list[Received]:
        return [r for r in list(self.received) if isinstance(r.message, cls)]

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self.port.close()

    def _serve(self) -> None:
        while not self._stop.is_set():
            data = self.port.read(0.02)
            rx_us = self.now_us()
            for r in self._decoder.feed(data):
                self.received.append(r)
                self._answer(r, rx_us)

    def _answer(self, r: Received, rx_us: int) -> None:
        m = r.message
        if self.drop.get(m.NAME, 0) > 0:
            self.drop[m.NAME] -= 1
            return
        if isinstance(m, TimeSync):
            reply = TimeSyncReply(host_t_ns=m.host_t_ns, request_seq=r.seq, device_rx_t_us=rx_us)
            reply.device_tx_t_us = self.now_us()  # framed right after: SPEC.md section 8
            self.send(reply)
            return
        if isinstance(m, Ping) and m.nonce == 0 and self.answer_hello:
            self.send(dataclasses.replace(self.hello, t_us=self.now_us()))
        code, detail = self.refuse.get(m.NAME, (int(ErrorCode.OK), 0))
        self.send(Ack(request_seq=r.seq, request_type=m.ID, error_code=code, detail=detail))


# --------------------------------------------------------------------------- the host side
class Host:
    """Callbacks of one DeviceLink, collected for the test to wait on."""

    def __init__(self) -> None:
        self.messages: list[tuple[Received, int]] = []
        self.events: list[DeviceLinkEvent] = []
        self.syncs: list[TimeSyncSample] = []
        self._cv = threading.Condition()

    def on_message(self, r: Received, host_rx_ns: int) -> None:
        with self._cv:
            self.messages.append((r, host_rx_ns))
            self._cv.notify_all()

    def on_event(self, e: DeviceLinkEvent) -> None:
        with self._cv:
            self.events.append(e)
            self._cv.notify_all()

    def on_time_sync(self, s: TimeSyncSample) -> None:
        with self._cv:
            self.syncs.append(s)
            self._cv.notify_all()

    def wait(self, what: Callable[[], Any], timeout_s: float = 5.0, why: str = "") -> Any:
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while True:
                value = what()
                if value:
                    return value
                left = deadline - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"timed out waiting for {why or what}")
                self._cv.wait(left)

    def events_of(self, kind: str) -> list[DeviceLinkEvent]:
        with self._cv:
            return [e for e in self.events if e.kind == kind]

    def messages_of(self, cls: type[Message]) -> list[Any]:
        with self._cv:
            return [r.message for r, _ in self.messages if isinstance(r.message, cls)]

    def link(self, url: str, **kw: Any) -> DeviceLink:
        return DeviceLink(url, on_message=self.on_message, on_event=self.on_event, on_time_sync=self.on_time_sync, **kw)


@pytest.fixture(params=["pty", "socket"])
def device(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[FakeDevice]:
    port = PtyPort(tmp_path) if request.param == "pty" else SocketPort(tmp_path)
    dev = FakeDevice(port)
    yield dev
    dev.stop()


@pytest.fixture
def host() -> Host:
    return Host()


@contextlib.contextmanager
def started(host: Host, device: FakeDevice, **kw: Any) -> Iterator[DeviceLink]:
    link = host.link(device.port.url, **kw)
    link.start()
    try:
        yield link
    finally:
        link.stop()


def wait_until(cond: Callable[[], Any], timeout_s: float = 5.0) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = cond()
        if value:
            return value
        time.sleep(0.01)
    raise AssertionError("timed out")


# --------------------------------------------------------------------------- handshake
def test_handshake_asks_with_ping_zero_and_returns_the_hello(host, device):
    link = host.link(device.port.url)
    try:
        hello = link.start()
        assert isinstance(hello, Hello)
        assert (hello.protocol_version, hello.table_hash) == (PROTOCOL_VERSION, TABLE_HASH)
        assert (hello.firmware_version, hello.board, hello.serial_number) == ("0.1.0+test", Board.SIMULATOR, 4242)
        assert 1_000_000 <= hello.t_us <= device.now_us()
        assert link.hello == hello and link.connected
        pings = device.received_of(Ping)
        assert [p.message.nonce for p in pings] == [0]
        assert host.messages_of(Hello) == [hello]
        assert host.wait(lambda: host.messages_of(Ack))[0].request_seq == pings[0].seq
        assert host.events == []  # same version, same table: nothing to report
    finally:
        link.stop()


def test_a_different_table_hash_is_reported_and_not_fatal(host, device):
    device.hello = dataclasses.replace(device.hello, table_hash=TABLE_HASH ^ 0x5A5A)
    with started(host, device) as link:
        (event,) = host.events_of("table_hash_mismatch")
        assert f"0x{TABLE_HASH ^ 0x5A5A:08X}" in event.detail and f"0x{TABLE_HASH:08X}" in event.detail
        assert link.command(StopCapture(camera_id=0)).error_code == ErrorCode.OK


@pytest.mark.parametrize("version", [0, PROTOCOL_VERSION + 1, 255])
def test_a_device_of_another_version_in_the_frame_header_is_refused_naming_both(host, device, version):
    device.hello_version = version
    device.hello = dataclasses.replace(device.hello, protocol_version=version)
    link = host.link(device.port.url)
    with pytest.raises(VersionMismatchError) as err:
        link.start()
    assert (err.value.device_version, err.value.host_version) == (version, PROTOCOL_VERSION)
    assert f"device speaks protocol version {version}, this host speaks version {PROTOCOL_VERSION}" in str(err.value)
    assert link.decoder_stats["wrong_version"] >= 1


def test_a_hello_announcing_another_version_is_refused(host, device):
    device.hello = dataclasses.replace(device.hello, protocol_version=PROTOCOL_VERSION + 1)
    with pytest.raises(VersionMismatchError, match=f"protocol version {PROTOCOL_VERSION + 1}, this host speaks"):
        host.link(device.port.url).start()


def test_a_silent_device_is_a_clear_error(host, device):
    device.answer_hello = False
    device.drop["PING"] = 100
    t0 = time.monotonic()
    with pytest.raises(DeviceLinkError, match=r"no HELLO from .* within 3 s .*is it an ICGT device\?"):
        host.link(device.port.url).start()
    assert time.monotonic() - t0 < 10


def test_a_port_that_does_not_exist_is_a_clear_error(host, tmp_path):
    with pytest.raises(DeviceLinkError, match=r"device .*ttyNONE does not exist"):
        host.link(str(tmp_path / "ttyNONE")).start()


# --------------------------------------------------------------------------- commands
def test_command_is_acknowledged_with_its_own_seq(host, device):
    with started(host, device) as link:
        ack = link.command(StartCapture(mode=1, camera_id=0, interval_us=200_000, count=3))
        (cmd,) = device.received_of(StartCapture)
        assert (ack.request_seq, ack.request_type, ack.error_code) == (cmd.seq, StartCapture.ID, ErrorCode.OK)
        assert cmd.message == StartCapture(mode=1, camera_id=0, interval_us=200_000, count=3)


@pytest.mark.parametrize(
    ("code", "detail", "text"),
    [
        (ErrorCode.SENSOR_MISSING, 18, "sensor_missing: the BNO055 does not answer (limit imu_missing)"),
        (ErrorCode.OUT_OF_RANGE, 3, "out_of_range: limit interval (0.05 .. 3600 s)"),
        (ErrorCode.OUT_OF_RANGE, 999, "out_of_range (detail 999)"),
        (200, 0, "error 200"),
    ],
)
def test_a_refused_command_raises_with_the_code_name(host, device, code, detail, text):
    device.refuse["START_CAPTURE"] = (int(code), detail)
    with started(host, device) as link:
        with pytest.raises(CommandRefusedError) as err:
            link.command(StartCapture(mode=1))
        assert str(err.value) == f"device refused START_CAPTURE: {text}"
        assert (err.value.command, err.value.code, err.value.detail) == ("START_CAPTURE", int(code), detail)
        assert len(device.received_of(StartCapture)) == 1  # refused: not retried


def test_an_unanswered_command_is_retried_with_a_new_seq(host, device):
    device.drop["STOP_CAPTURE"] = 2
    with started(host, device) as link:
        ack = link.command(StopCapture(camera_id=0), timeout_s=0.3, retries=3)
        sent = device.received_of(StopCapture)
        assert len(sent) == 3
        assert len({r.seq for r in sent}) == 3
        assert ack.request_seq == sent[-1].seq and ack.error_code == ErrorCode.OK


def test_busy_capturing_after_a_lost_ack_counts_as_accepted(host, device):
    device.drop["START_CAPTURE"] = 1  # the first attempt reached the device, its ACK did not come back
    device.refuse["START_CAPTURE"] = (int(ErrorCode.BUSY_CAPTURING), 0)
    with started(host, device) as link:
        ack = link.command(StartCapture(mode=1), timeout_s=0.3)
        assert ack.error_code == ErrorCode.BUSY_CAPTURING
        assert len(device.received_of(StartCapture)) == 2


def test_busy_capturing_on_the_first_attempt_is_a_refusal(host, device):
    device.refuse["START_CAPTURE"] = (int(ErrorCode.BUSY_CAPTURING), 0)
    with started(host, device) as link, pytest.raises(CommandRefusedError, match="busy_capturing"):
        link.command(StartCapture(mode=1), timeout_s=0.1)


def test_a_command_never_answered_is_an_error_after_every_retry(host, device):
    device.drop["STOP_CAPTURE"] = 100
    with started(host, device) as link:
        t0 = time.monotonic()
        with pytest.raises(DeviceLinkError, match="no ACK for STOP_CAPTURE within 50 ms"):
            link.command(StopCapture(camera_id=0), timeout_s=0.05, retries=2)
        assert time.monotonic() - t0 >= 3 * 0.05
        wait_until(lambda: len(device.received_of(StopCapture)) == 3)
        assert len({r.seq for r in device.received_of(StopCapture)}) == 3


def test_an_ack_for_someone_else_does_not_answer_a_command(host, device):
    device.drop["STOP_CAPTURE"] = 1
    with started(host, device) as link:
        device.send(Ack(request_seq=10_000, request_type=StopCapture.ID))  # nobody waits for this one
        ack = link.command(StopCapture(camera_id=0), timeout_s=0.3)
        assert ack.request_seq == device.received_of(StopCapture)[-1].seq != 10_000
        assert len(device.received_of(StopCapture)) == 2


# --------------------------------------------------------------------------- time sync
def test_time_sync_exchange_has_consistent_stamps(host, device):
    with started(host, device) as link:
        for _ in range(5):
            n = len(host.syncs)
            link.request_time_sync()
            host.wait(lambda n=n: len(host.syncs) > n, why="TIME_SYNC_REPLY")
        requests = device.received_of(TimeSync)
        assert len(requests) == 5
    for s in host.syncs:
        # host send <= device receive <= device transmit <= host receive, on one clock (device
        # microseconds floor-rounded: 1 us slack each way)
        dev_rx_ns = (s.device_rx_us + device.boot_us) * 1000
        dev_tx_ns = (s.device_tx_us + device.boot_us) * 1000
        assert s.host_tx_ns <= dev_rx_ns + 1000
        assert s.device_rx_us <= s.device_tx_us
        assert dev_tx_ns <= s.host_rx_ns
        assert 0 <= s.round_trip_ns < 1_000_000_000
    assert len({s.host_tx_ns for s in host.syncs}) == 5
    # the request's host_t_ns field only identifies it; the stamp is taken after framing, later
    for req, s in zip(requests, host.syncs, strict=True):
        assert req.message.host_t_ns <= s.host_tx_ns


def test_a_time_sync_reply_to_no_request_is_ignored(host, device):
    with started(host, device) as link:
        device.send(TimeSyncReply(host_t_ns=1, request_seq=9_999, device_rx_t_us=5, device_tx_t_us=6))
        device.send(Status(t_us=device.now_us()))
        host.wait(lambda: host.messages_of(Status))
        assert host.syncs == []
        assert host.messages_of(TimeSyncReply)  # still handed on: the log keeps everything
        link.request_time_sync()
        host.wait(lambda: host.syncs)
        assert len(host.syncs) == 1


# --------------------------------------------------------------------------- stream faults
def test_corrupt_bytes_give_frames_rejected_and_decoding_goes_on(host, device):
    with started(host, device) as link:
        with device.exclusive():
            seq = device.seq
            corrupt = with_bad_crc(encode_frame(Status(t_us=device.now_us(), triggers_fired=3), seq))
            device.write_raw(b"\x13\x37 line noise \x01\x00" + corrupt)
            device.send(Status(t_us=device.now_us(), triggers_fired=3), seq=seq)  # the same frame, intact
            device.seq = seq + 1
        host.wait(lambda: host.messages_of(Status), why="STATUS after the noise")
        rejected = host.wait(
            lambda: sum(e.count for e in host.events_of("frames_rejected")) >= 2 and host.events_of("frames_rejected")
        )
        assert sum(e.count for e in rejected) == 2 == link.frames_rejected
        assert all("corrupt frames skipped" in e.detail for e in rejected)
        assert [m.triggers_fired for m in host.messages_of(Status)] == [3]
        assert link.decoder_stats["crc_error"] == 1
        assert host.events_of("sequence_gap") == []
        assert link.command(StopCapture()).error_code == ErrorCode.OK


def test_a_sequence_gap_is_reported_with_the_count(host, device):
    with started(host, device) as link:
        with device.exclusive():  # a TIME_SYNC answer in between would move the numbers
            device.send(Status(t_us=1))
            first_missing = device.seq
            device.seq += 4  # four frames the host never sees
            device.send(Status(t_us=2))
        (gap,) = host.wait(lambda: host.events_of("sequence_gap"))
        assert gap.count == 4 and gap.detail == "4 device messages missing: asked again"
        # the host asks for exactly the missing four (RESEND)
        (ask,) = host.wait(lambda: device.received_of(Resend))
        assert (ask.message.first_seq, ask.message.count) == (first_missing, 4)
        # a retransmitted frame carries its old seq and moves no expectation
        device.send(Status(t_us=3), seq=first_missing + 1, flags=1)
        device.send(Status(t_us=3), seq=first_missing + 1, flags=1)  # twice: the duplicate is dropped
        device.send(Status(t_us=4))
        host.wait(lambda: len(host.messages_of(Status)) == 4)
        assert len(host.events_of("sequence_gap")) == 1
        # the answer's end: three of the four are gone, by kind
        device.send(ResendLost(first_seq=ask.message.first_seq, count=4, resent=1, exposures=1, samples=1, other=1))
        (lost,) = host.wait(lambda: host.events_of("history_lost"))
        assert lost.count == 2 and "1 exposures, 0 PPS, 1 samples" in lost.detail
        c = link.resend.counters
        assert (c.recovered, c.duplicates, c.lost_exposures, c.lost_samples, c.lost_other) == (1, 1, 1, 1, 1)
        assert link.resend.missing_now == 0


def test_a_burst_is_taken_in_few_reads_each_stamped_once(host, device):
    """Whatever has arrived is read at once and its frames share the stamp taken after the read.

    Over socket:// pyserial's in_waiting is 1 for any readable socket, so read(1) + read(in_waiting)
    took 2 bytes per call: 200 frames written at once came out of ~8400 reads, 200 stamps."""
    with started(host, device):
        with device.exclusive():
            first = device.seq
            device.write_raw(b"".join(encode_frame(Status(t_us=i), first + i) for i in range(200)))
            device.seq = first + 200
        host.wait(lambda: len(host.messages_of(Status)) == 200, why="200 STATUS")
        with host._cv:
            stamps = {ns for r, ns in host.messages if isinstance(r.message, Status)}
        assert len(stamps) <= 50, f"{len(stamps)} reads for 16.8 kB that arrived together"
        assert [m.t_us for m in host.messages_of(Status)] == list(range(200))
        assert host.events_of("sequence_gap") == []


def test_batched_reads_take_a_stream_in_few_reads_and_stamp_replies_promptly(host, device):
    """With batch_s the reader sleeps between reads (one read per pause, not per message), except while a
    reply is awaited: a TIME_SYNC_REPLY sent in the middle of the stream is stamped as it arrives, not at
    the end of a pause (its round trip stays far below the pause)."""
    batch_s = 0.4
    stop = threading.Event()

    def stream() -> None:  # a STATUS every 2 ms, as the device's sensors stream
        while not stop.wait(0.002):
            device.send(Status(t_us=device.now_us()))

    with started(host, device, batch_s=batch_s) as link:
        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        try:
            time.sleep(1.0)  # past the handshake's prompt window: batching
            reads0, n0 = link.reads, len(host.messages_of(Status))
            time.sleep(2.0)
            reads, n = link.reads - reads0, len(host.messages_of(Status)) - n0
            assert n >= 100, f"only {n} STATUS in 2 s"
            assert reads <= 2.0 / batch_s + 3, f"{reads} reads for {n} messages in 2 s with {batch_s} s pauses"
            for _ in range(3):
                time.sleep(0.5)  # back to batching, then in the middle of a pause:
                k = len(host.syncs)
                link.request_time_sync()
                host.wait(lambda k=k: len(host.syncs) > k, why="TIME_SYNC_REPLY")
        finally:
            stop.set()
            streamer.join()
    for s in host.syncs:
        assert s.round_trip_ns < batch_s * 1e9 / 2, f"round trip {s.round_trip_ns / 1e6:.1f} ms: stamped late"


def test_messages_without_an_answer_leave_the_reader_batching(host, device):
    """HOST_RECEIVED (once a second, from 3 s on) expects no answer: sending it must not make the reader
    prompt (it did, for 100 ms each time: one read per frame of the stream)."""
    batch_s = 0.2
    stop = threading.Event()

    def stream() -> None:
        while not stop.wait(0.002):
            device.send(Status(t_us=device.now_us()))

    with started(host, device, batch_s=batch_s) as link:
        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        try:
            time.sleep(4.2)  # HOST_RECEIVED is sent from ~3 s on, once a second
            reads0 = link.reads
            time.sleep(2.0)
            reads = link.reads - reads0
        finally:
            stop.set()
            streamer.join()
        assert device.received_of(HostReceived), "no HOST_RECEIVED sent"
    assert reads <= 2.0 / batch_s + 3, f"{reads} reads in 2 s with {batch_s} s pauses and HOST_RECEIVED sent"


# --------------------------------------------------------------------------- unplug / replug
def test_unplug_is_reported_and_replug_reconnects(host, device):
    with started(host, device) as link:
        assert link.command(StopCapture()).error_code == ErrorCode.OK
        device.write_raw(encode_frame(Status(t_us=1), device.seq)[:12])  # half a frame, then the cable goes
        time.sleep(0.1)
        t_unplug = time.monotonic_ns()
        device.port.unplug()
        (down,) = host.wait(lambda: host.events_of("disconnected"), why="disconnected")
        assert down.detail.startswith("device link lost: ")
        assert not link.connected
        with pytest.raises(DeviceLinkError, match="is down"):
            link.send(StopCapture())
        time.sleep(0.5)  # a few reopen attempts fail meanwhile
        assert host.events_of("connected") == []
        device.port.plug()
        (up,) = host.wait(lambda: host.events_of("connected"), why="connected")
        assert up.outage_ns >= 400_000_000 and up.host_ns > t_unplug
        assert up.detail.startswith("device link back after ")
        assert link.connected
        device.send(Status(t_us=2, triggers_fired=9))  # the half frame before the outage is not glued to it
        host.wait(lambda: host.messages_of(Status), why="STATUS after replug")
        assert host.messages_of(Status)[0].triggers_fired == 9
        assert link.command(StopCapture()).error_code == ErrorCode.OK
        assert [e.kind for e in host.events if e.kind in ("disconnected", "connected")] == ["disconnected", "connected"]


def test_without_reconnect_the_link_stays_down(host, device):
    with started(host, device, reconnect=False) as link:
        device.port.unplug()
        host.wait(lambda: host.events_of("disconnected"))
        device.port.plug()
        time.sleep(0.6)
        assert host.events_of("connected") == []
        assert not link.connected


# --------------------------------------------------------------------------- pumped by the owner
def test_pumped_link_hands_the_stream_on_from_pump_and_the_reader_sends_and_stamps_the_time_syncs(host, device):
    """The recorder's way: the owner's thread reads the stream with pump() every 50 ms; the reader thread
    sends a TIME_SYNC every time_sync_interval_s and stamps each reply as it comes (not at a pump), and
    otherwise reads nothing: every STATUS arrives, in order, each exactly once, and the reader's reads are
    the exchanges' (a few per exchange), not one per batch_s."""
    stop = threading.Event()
    sent = 0

    def stream() -> None:  # a STATUS every 2 ms, as the device's sensors stream
        nonlocal sent
        while not stop.wait(0.002):
            device.send(Status(t_us=device.now_us()))
            sent += 1

    with started(host, device, batch_s=0.02) as link:
        assert link.set_pumped(True) and link.pumped
        link.time_sync_interval_s = 0.1
        streamer = threading.Thread(target=stream, daemon=True)
        streamer.start()
        pumped_bytes = 0
        try:
            time.sleep(0.3)
            reads0, syncs0 = link.reads, len(host.syncs)
            t_end = time.monotonic() + 2.0
            while time.monotonic() < t_end:
                pumped_bytes += link.pump()
                time.sleep(0.05)
            stop.set()
            streamer.join()
            time.sleep(0.1)
            while link.pump():
                pass
            reads, syncs = link.reads - reads0, len(host.syncs) - syncs0
        finally:
            stop.set()
        assert pumped_bytes > 0
        assert 12 <= syncs <= 25, f"{syncs} TIME_SYNC exchanges in 2 s at 0.1 s"
        # 40 pumps; the reader reads for its exchanges only: far fewer than the 100 of a 20 ms batching reader
        assert reads <= 40 + 4 * syncs, f"{reads} reads in 2 s"
    statuses = [r for r, _ in host.messages if isinstance(r.message, Status)]
    seqs = [r.seq for r in statuses]
    assert len(statuses) == sent and seqs == sorted(seqs) and len(set(seqs)) == len(seqs)
    for s in host.syncs[syncs0:]:
        assert s.round_trip_ns < 20_000_000, f"round trip {s.round_trip_ns / 1e6:.1f} ms: stamped at a pump"


def test_a_link_not_pumped_ignores_pump_and_unpumped_reads_on_its_own(host, device):
    with started(host, device, batch_s=0.02) as link:
        assert link.pump() == 0  # not pumped: the reader reads
        device.send(Status(t_us=device.now_us()))
        host.wait(lambda: host.messages_of(Status), why="STATUS read by the reader")
        assert link.set_pumped(True)
        assert not link.set_pumped(False) and not link.pumped
        device.send(Status(t_us=device.now_us()))
        host.wait(lambda: len(host.messages_of(Status)) == 2, why="STATUS read by the reader again")


def test_a_pumped_link_reports_an_unplug_from_the_pump(host, device):
    with started(host, device, batch_s=0.02) as link:
        link.set_pumped(True)
        device.port.close()
        deadline = time.monotonic() + 5.0
        while not host.events_of("disconnected") and time.monotonic() < deadline:
            link.pump()
            time.sleep(0.02)
        assert host.events_of("disconnected")


def test_a_pumped_link_to_a_silent_device_stays_up(host, device):
    """A serial port read with nothing waiting gives b"" (pyserial sets VMIN 0), as a hung-up one does: a
    pump that took it for an unplug dropped the link every few pumps of a quiet stream."""
    with started(host, device, batch_s=0.02) as link:
        assert link.set_pumped(True)
        for _ in range(20):
            link.pump()
            time.sleep(0.02)
        assert link.connected and not host.events_of("disconnected")
