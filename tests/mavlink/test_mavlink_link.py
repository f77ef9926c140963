"""MavlinkLink against pymavlink peers over 127.0.0.1, with a synchroniser fed and its presence changes hinted
to the link as the recorder does: stream-rate requests (again after an outage or a reboot the synchroniser saw),
TIMESYNC requests (paired by the synchroniser), robustness to garbage and to a TCP peer going away,
subscriptions, and a clean stop."""

from __future__ import annotations

import socket
import threading
import time

import pytest
from mavlink_peers import AutopilotPeer, Peer, free_udp_port, wait_until
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.autopilot_rules import REBOOT_SILENCE_NS, AutopilotState
from icgt.mavlink.frames import UndecodedBatch
from icgt.mavlink.link import (
    DEFAULT_STREAM_RATES,
    LinkConfig,
    LinkError,
    LinkEventKind,
    MavlinkEvent,
    MavlinkLink,
    MavlinkMessage,
)
from icgt.sync import SyncConfig, SyncEvent, Synchroniser, TimesyncReply

RATE_IDS = [r.message_id for r in DEFAULT_STREAM_RATES]


class Recorder:
    """Collects the link's events and feeds a synchroniser as the recorder does (requests, then messages), handing
    the synchroniser's presence changes to the link as hints."""

    def __init__(self, timesync_timeout_s: float = 1.0, autopilot_timeout_s: float = 0.3):
        self.events: list[MavlinkEvent] = []
        self.timesync: list[TimesyncReply] = []
        self.presence: list[SyncEvent] = []
        self.link: MavlinkLink | None = None
        self.lock = threading.Lock()
        self.sync = Synchroniser(
            SyncConfig(timesync_timeout_s=timesync_timeout_s, autopilot_timeout_s=autopilot_timeout_s)
        )

    def _hint(self) -> None:
        for event in self.sync.take_events():
            if event.presence is not None:
                self.presence.append(event)
                if self.link is not None:
                    ap = self.sync.autopilot
                    self.link.autopilot_hint(event.presence, ap.system, ap.component, event.host_ns)

    def presence_of(self, kind: str) -> list[SyncEvent]:
        """The synchroniser's presence changes of `kind` so far (polled now, as the recorder's worker does)."""
        with self.lock:
            self.sync.poll(time.monotonic_ns())
            self._hint()
            return [e for e in self.presence if e.kind == kind]

    def on_event(self, e: MavlinkEvent) -> None:
        with self.lock:
            self.events.append(e)

    def on_timesync_sent(self, tx_ns: int) -> None:
        with self.lock:
            self.sync.on_timesync_request(tx_ns)

    def on_message(self, rec: MavlinkMessage) -> None:
        with self.lock:
            verdict = self.sync.on_mavlink(rec.msg, rec.rx_ns)
            if verdict.timesync is not None:
                self.timesync.append(verdict.timesync)
            if rec.type == "COMMAND_ACK" and verdict.believed and self.link is not None:
                self.link.autopilot_answered(rec.msg, rec.rx_ns)
            self._hint()

    def unanswered(self) -> int:
        with self.lock:
            self.sync.poll(time.monotonic_ns())
            return self.sync.timesync.unanswered

    def kinds(self) -> list[LinkEventKind]:
        with self.lock:
            return [e.kind for e in self.events]

    def of(self, kind: LinkEventKind) -> list[MavlinkEvent]:
        with self.lock:
            return [e for e in self.events if e.kind is kind]


def make_link(rec: Recorder | None = None, **overrides) -> tuple[MavlinkLink, int]:
    port = free_udp_port()
    cfg = dict(url=f"udpin:127.0.0.1:{port}", rate_ack_timeout_s=0.1, timesync_fast_hz=20.0)
    cfg.update(overrides)
    rec = rec or Recorder()
    link = MavlinkLink(LinkConfig(**cfg), on_event=rec.on_event, on_timesync_sent=rec.on_timesync_sent)
    rec.link = link
    link.subscribe(rec.on_message)
    return link, port


@pytest.fixture
def recorder():
    return Recorder()


def our_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("icgt-")]


def test_link_loss_and_return_with_outage_and_rates_resent():
    recorder = Recorder(autopilot_timeout_s=0.4)
    link, port = make_link(recorder)
    link.start()
    ap = AutopilotPeer(port)
    try:
        ap.stream(hz=50)
        assert wait_until(lambda: recorder.presence_of("autopilot_seen"))
        assert link.autopilot == (1, 1) and recorder.sync.autopilot.state is AutopilotState.UP
        assert wait_until(lambda: len(link.rate_results()) == len(RATE_IDS), timeout=5.0)
        assert all(r.accepted for r in link.rate_results())
        requested = [m for m, _, _ in ap.interval_requests]
        assert requested[: len(RATE_IDS)] == RATE_IDS  # one at a time, in the configured order
        intervals = {m: us for m, us, _ in ap.interval_requests}
        assert intervals[mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT] == 20_000  # 50 Hz default

        ap.silence()
        silent_at = time.monotonic_ns()
        assert wait_until(lambda: any(e.host_ns > silent_at for e in recorder.presence_of("autopilot_lost")))
        lost = next(e for e in recorder.presence_of("autopilot_lost") if e.host_ns > silent_at)
        assert 0.4e9 <= lost.outage_ns < 1.0e9
        assert recorder.sync.autopilot.state is AutopilotState.LOST
        time.sleep(0.4)
        n_before = len(ap.interval_requests)
        ap.stream()
        assert wait_until(lambda: any(e.host_ns > silent_at for e in recorder.presence_of("autopilot_back")))
        back = next(e for e in recorder.presence_of("autopilot_back") if e.host_ns > silent_at)
        gap = back.host_ns - silent_at
        assert abs(back.outage_ns - gap) < 0.1e9 and back.outage_ns >= 0.75e9
        assert wait_until(lambda: len(ap.interval_requests) >= n_before + len(RATE_IDS), timeout=5.0)
        assert [m for m, _, _ in ap.interval_requests[n_before:]][: len(RATE_IDS)] == RATE_IDS
        assert recorder.sync.counters()["autopilot_outages"] == 1
        assert [len(recorder.presence_of(k)) for k in ("autopilot_seen", "autopilot_lost", "autopilot_back")] == [1] * 3
    finally:
        ap.close()
        link.stop()


def test_rate_requests_are_retried_until_acked_and_bounded(recorder):
    link, port = make_link(recorder, rate_max_attempts=3, rate_ack_timeout_s=0.15)
    ap = AutopilotPeer(port)
    gps = mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT
    att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
    ap.ignore_first[gps] = 2
    ap.never_ack.add(att)
    link.start()
    try:
        ap.stream(hz=50)
        assert wait_until(lambda: len(link.rate_results()) == len(RATE_IDS), timeout=3.0)
        results = {r.message_id: r for r in link.rate_results()}
        assert results[gps].accepted and results[gps].attempts == 3
        assert results[att].result is None and results[att].attempts == 3
        assert [c for m, _, c in ap.interval_requests if m == gps] == [0, 1, 2]  # confirmation counts re-sends
        assert len([m for m, _, _ in ap.interval_requests if m == att]) == 3
        others = [r for m, r in results.items() if m not in (gps, att)]
        assert all(r.accepted for r in others)  # the one never answered did not block the rest
        details = [e.detail for e in recorder.of(LinkEventKind.RATE_REQUEST)]
        assert any("ATTITUDE at 50 Hz: no COMMAND_ACK after 3 attempts" in d for d in details)
    finally:
        ap.close()
        link.stop()


def test_a_second_sender_with_the_autopilots_ids_cannot_answer_a_rate_request(recorder):
    # Issue 26: the link took any COMMAND_ACK with the autopilot's ids from its reading thread, so a second
    # sender (a router's echo, another flight stack, an attacker) could "accept" a rate the autopilot never
    # took. Only the ACKs the synchroniser believes (the autopilot's stream) answer now.
    link, port = make_link(recorder, rate_max_attempts=3, rate_ack_timeout_s=0.15)
    ap = AutopilotPeer(port)
    spoofer = Peer(1, 1, port)  # the autopilot's ids, its own sequence numbers
    att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
    ap.never_ack.add(att)
    stop = threading.Event()

    def spoof() -> None:
        while not stop.wait(0.01):
            spoofer.mav.seq = (ap.mav.seq + 128) % 256  # never the stream's next numbers
            spoofer.send(
                spoofer.mav.command_ack_encode(
                    mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink2.MAV_RESULT_ACCEPTED, 0, 0, 0, 0
                )
            )

    thread = threading.Thread(target=spoof, daemon=True)
    link.start()
    try:
        ap.stream(hz=50)
        assert wait_until(lambda: recorder.sync.autopilot.state is AutopilotState.UP, timeout=3.0)
        thread.start()
        assert wait_until(lambda: len(link.rate_results()) == len(RATE_IDS), timeout=5.0)
        results = {r.message_id: r for r in link.rate_results()}
        assert results[att].result is None and results[att].attempts == 3, results[att]
        assert all(r.accepted for m, r in results.items() if m != att)  # the autopilot's own ACKs still count
        assert recorder.sync.counters()["autopilot_second_sender_messages"] > 0
    finally:
        stop.set()
        thread.join(timeout=1.0)
        spoofer.close()
        ap.close()
        link.stop()


def test_reboot_detected_and_rates_requested_again():
    recorder = Recorder(autopilot_timeout_s=5.0)
    link, port = make_link(recorder)
    link.start()
    ap = AutopilotPeer(port)
    try:
        ap.heartbeat()
        ap.send(ap.mav.attitude_encode(600_000, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: len(link.rate_results()) == len(RATE_IDS))
        n = len(ap.interval_requests)
        ap.silence()  # a rebooting autopilot is silent while it boots, then starts its sequence numbers again
        time.sleep(REBOOT_SILENCE_NS / 1e9 + 0.1)
        ap.resume()
        ap.mav.seq = 0
        ap.send(ap.mav.attitude_encode(1_200, 0, 0, 0, 0, 0, 0))  # boot clock restarted
        assert wait_until(lambda: recorder.presence_of("autopilot_rebooted"))
        assert wait_until(lambda: len(ap.interval_requests) >= n + len(RATE_IDS))
    finally:
        ap.close()
        link.stop()


def test_a_stray_sender_with_the_autopilots_ids_over_udp_is_counted_not_believed():
    """Issue 30: ~70 GLOBAL_POSITION_INT with ids 1:1 and time_boot_ms near 1e9 from another socket while the
    autopilot streams: no reboot (link or synchroniser), no rate-request storm, none of them in the poses."""
    recorder = Recorder(autopilot_timeout_s=5.0)
    link, port = make_link(recorder)
    link.start()
    ap = AutopilotPeer(port)
    stray = AutopilotPeer(port)
    stray.boot_ns = ap.boot_ns - 1_000_000_000 * 1_000_000  # its boot clock reads about 1e9 ms
    try:
        ap.stream(hz=50)
        assert wait_until(lambda: len(link.rate_results()) == len(RATE_IDS), timeout=10.0)
        n = len(ap.interval_requests)
        for k in range(70):
            stray.send(stray.mav.global_position_int_encode(stray.boot_ms(), 473_977_000 + k, 85_455_000, 500_000,
                                                            20_000, 0, 0, 0, 0))  # fmt: skip
            time.sleep(0.01)
        ap.send(ap.mav.global_position_int_encode(ap.boot_ms(), 473_977_000, 85_455_000, 500_000, 20_000, 0, 0, 0, 0))
        assert wait_until(lambda: link.stats().messages_by_type.get("GLOBAL_POSITION_INT", 0) >= 71, timeout=10.0)
    finally:
        stray.close()
        ap.close()
        link.stop()
    assert not recorder.presence_of("autopilot_rebooted")
    assert len(ap.interval_requests) == n  # no rates requested again
    with recorder.lock:
        counters = recorder.sync.counters()
        fused = recorder.sync.telemetry.fused.samples()
    assert counters["autopilot_reboots"] == 0 and counters["autopilot_clock_resets"] == 0
    assert counters["autopilot_second_sender_messages"] >= 70
    assert fused and all(s.boot_us < 1e11 for s in fused)  # the autopilot's, up minutes; the stray's near 1e12


def test_timesync_client_pairs_replies(recorder):
    link, port = make_link(recorder, request_rates=False, timesync_fast_hz=10.0, timesync_fast_count=5)
    link.start()
    ap = AutopilotPeer(port)
    other = AutopilotPeer(port, system=1, component=191)  # another component answering: not our autopilot
    try:
        ap.stream(hz=20)
        assert wait_until(lambda: len(recorder.timesync) >= 4, timeout=2.0)
        # replies that are not answers to our requests are ignored
        ap.send(ap.mav.timesync_encode(123, 987_654_321))
        other.send(other.mav.timesync_encode(456, ap.timesync_requests[-1]))
        time.sleep(0.05)
        samples = list(recorder.timesync)
        assert all(s.autopilot_tc1_ns not in (123, 456) for s in samples)
        sent = set(ap.timesync_requests)
        for s in samples:
            assert s.host_tx_ns in sent  # ts1 matched
            assert s.host_tx_ns <= s.host_rx_ns and s.rtt_ns < 200e6
            # the peer answers with its boot clock: host time minus its boot instant
            assert s.host_tx_ns - 1e6 <= s.autopilot_tc1_ns + ap.boot_ns <= s.host_rx_ns + 1e6
        # several per second at first (5 at 10 Hz here), then 1 Hz
        assert samples[3].host_tx_ns - samples[0].host_tx_ns < 0.5e9
        assert wait_until(lambda: len(ap.timesync_requests) >= 6)
        n = len(ap.timesync_requests)
        time.sleep(0.6)
        assert len(ap.timesync_requests) - n <= 1
        assert recorder.sync.timesync.answered == len(recorder.timesync)
        assert link.stats().timesync_sent >= len(recorder.timesync)
    finally:
        other.close()
        ap.close()
        link.stop()


def test_unanswered_timesync_is_forgotten():
    recorder = Recorder(timesync_timeout_s=0.1)
    link, port = make_link(recorder, request_rates=False)
    ap = AutopilotPeer(port)
    ap.answer_timesync = False
    link.start()
    try:
        ap.heartbeat()
        assert wait_until(lambda: recorder.unanswered() >= 2)
        assert recorder.timesync == []
    finally:
        ap.close()
        link.stop()


def test_garbage_and_callback_errors_never_stop_the_reader(recorder):
    link, port = make_link(recorder, request_rates=False, timesync=False)
    got: list[MavlinkMessage] = []

    def bad_callback(r):
        raise RuntimeError("subscriber bug")

    link.subscribe(bad_callback)
    link.subscribe(got.append, ["ATTITUDE"])
    link.start()
    ap = AutopilotPeer(port)
    try:
        import random

        rng = random.Random(3)
        for _ in range(50):
            ap.send_raw(bytes(rng.randrange(256) for _ in range(rng.randint(1, 300))))
        ap.send_raw(b"\xfd\xff" + b"\x00" * 20)  # a v2 start with a huge length, cut short
        ap.send(ap.mav.attitude_encode(77, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: any(r.msg.time_boot_ms == 77 for r in got))
        stats = link.stats()
        assert stats.bad_frames >= 50 and stats.callback_errors >= 1
        assert got[-1].mavlink_version == 2 and got[-1].src_system == 1
    finally:
        ap.close()
        link.stop()


def test_a_device_with_our_ids_is_not_taken_for_our_echo(recorder, caplog):
    """A real camera at component 100 of the vehicle: its frames are passed on and said loudly; our own
    frames looped back are echoes."""
    link, port = make_link(recorder, request_rates=False, timesync=False)
    got: list[MavlinkMessage] = []
    link.subscribe(got.append, ["HEARTBEAT", "CAMERA_INFORMATION"])
    link.start()
    other_camera = AutopilotPeer(port, system=1, component=100)
    try:
        other_camera.send(other_camera.mav.heartbeat_encode(mavlink2.MAV_TYPE_CAMERA, 8, 0, 0, 4))
        assert wait_until(lambda: any(r.src_component == 100 for r in got))
        assert link.stats().same_id_frames == 1 and link.stats().self_echoes == 0
        assert any("uses our MAVLink id 1:100" in r.getMessage() for r in caplog.records)
    finally:
        other_camera.close()
        link.stop()


def test_other_systems_on_udp_are_passed_on_undecoded(recorder):
    link, port = make_link(recorder, request_rates=False, timesync=False, decode_systems=frozenset({1}))
    got: list[MavlinkMessage] = []
    link.subscribe(got.append)
    link.start()
    ap = AutopilotPeer(port)
    stranger = AutopilotPeer(port, system=42, component=1)
    try:
        stranger.send(stranger.mav.attitude_encode(5, 0.1, 0, 0, 0, 0, 0))
        ap.send(ap.mav.attitude_encode(6, 0.2, 0, 0, 0, 0, 0))
        assert wait_until(lambda: {r.src_system for r in got} >= {1, 42})
        mine = next(r for r in got if r.src_system == 1)
        theirs = next(r for r in got if r.src_system == 42)
        assert mine.msg.time_boot_ms == 6  # decoded
        assert theirs.type == "ATTITUDE" and not hasattr(theirs.msg, "time_boot_ms")  # header only
        assert link.stats().undecoded_frames == 1
        assert link.receive_buffer_bytes >= 1_000_000
    finally:
        stranger.close()
        ap.close()
        link.stop()


def test_datagrams_carry_their_arrival_time_even_when_the_reader_is_late(recorder):
    """The kernel's receive timestamp, not the moment a busy reader got to the datagram: a one-way clock from
    arrival times would otherwise see the autopilot's clock move by the reader's backlog."""
    link, port = make_link(recorder, request_rates=False, timesync=False)
    got: list[MavlinkMessage] = []

    def slow(rec: MavlinkMessage) -> None:
        got.append(rec)
        if len(got) == 1:
            time.sleep(0.3)  # the reader is stuck here while the next datagram arrives

    link.subscribe(slow, ["ATTITUDE"])
    link.start()
    ap = AutopilotPeer(port)
    try:
        ap.send(ap.mav.attitude_encode(1, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: len(got) == 1)
        sent_ns = time.monotonic_ns()
        ap.send(ap.mav.attitude_encode(2, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: len(got) == 2)
        assert got[1].rx_ns - sent_ns < 100_000_000  # arrived at once, read ~0.3 s later
        assert got[1].rx_ns >= sent_ns - 1_000_000
    finally:
        ap.close()
        link.stop()


def test_batched_udp_reads_keep_each_datagrams_arrival_time(recorder):
    """read_batch_s: the reader sleeps between drains of the socket, and each datagram still carries its own
    arrival time (the kernel's), not the time of the read that took it; other systems' frames taken in bulk
    are counted like the rest."""
    batch_s = 0.3
    link, port = make_link(
        recorder, request_rates=False, timesync=False, decode_systems=frozenset({1}), read_batch_s=batch_s
    )
    got: list[MavlinkMessage] = []
    link.subscribe(got.append, ["ATTITUDE"])
    link.start()
    ap = AutopilotPeer(port)
    stranger = AutopilotPeer(port, system=42, component=1)
    sent: list[int] = []
    try:
        time.sleep(0.5)
        for k in range(40):  # one every 10 ms: several per pause
            sent.append(time.monotonic_ns())
            peer = ap if k % 2 else stranger
            peer.send(peer.mav.attitude_encode(k, 0, 0, 0, 0, 0, 0))
            time.sleep(0.01)
        assert wait_until(lambda: len(got) == 40)
        by_boot = {int(r.msg.time_boot_ms): r.rx_ns for r in got if r.src_system == 1}
        lags = [by_boot[k] - sent[k] for k in range(1, 40, 2)]
        assert max(lags) < batch_s * 1e9 / 3, f"stamps up to {max(lags) / 1e6:.0f} ms after the send: read time"
        assert min(lags) > -1_000_000
        stats = link.stats()
        assert stats.undecoded_frames == 20
        assert stats.messages_by_type["ATTITUDE"] == 40
    finally:
        stranger.close()
        ap.close()
        link.stop()


def test_subscribe_queue_is_bounded_and_drops_oldest(recorder):
    link, port = make_link(recorder, request_rates=False, timesync=False)
    q = link.subscribe_queue(["ATTITUDE"], maxsize=3)
    link.start()
    ap = AutopilotPeer(port)
    try:
        for i in range(10):
            ap.send(ap.mav.attitude_encode(i, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: link.stats().queue_drops == 7)
        assert [q.get_nowait().msg.time_boot_ms for _ in range(3)] == [7, 8, 9]
    finally:
        ap.close()
        link.stop()


def test_tcp_peer_going_away_and_coming_back(recorder):
    server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    server.settimeout(2.0)
    port = server.getsockname()[1]
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, 0, 0, 4)
    link = MavlinkLink(
        LinkConfig(f"tcp:127.0.0.1:{port}", request_rates=False, timesync=False, reopen_delay_s=0.05),
        on_event=recorder.on_event,
    )
    got: list[MavlinkMessage] = []
    link.subscribe(got.append, ["HEARTBEAT"])
    link.start()
    try:
        conn, _ = server.accept()
        conn.sendall(hb.pack(mav))
        assert wait_until(lambda: len(got) == 1)
        conn.close()  # the autopilot side drops the connection
        assert wait_until(lambda: LinkEventKind.TRANSPORT_ERROR in recorder.kinds())
        conn2, _ = server.accept()  # the link reconnects by itself
        assert wait_until(lambda: LinkEventKind.TRANSPORT_REOPENED in recorder.kinds())
        conn2.sendall(hb.pack(mav))
        assert wait_until(lambda: len(got) == 2)
        assert link.send(mav.heartbeat_encode(30, 8, 0, 0, 4))
        conn2.settimeout(1.0)
        assert conn2.recv(64)[0] == 0xFD
        conn2.close()
    finally:
        link.stop()
        server.close()


def test_tcpin_accepts_a_new_client_after_one_leaves(recorder):
    port = free_udp_port()  # a free TCP port just as well on 127.0.0.1
    link = MavlinkLink(LinkConfig(f"tcpin:127.0.0.1:{port}", request_rates=False, timesync=False))
    got: list[MavlinkMessage] = []
    link.subscribe(got.append, ["HEARTBEAT"])
    link.start()
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    hb = mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_PX4, 0, 0, 4)
    try:
        for n in (1, 2):
            client = socket.create_connection(("127.0.0.1", port), timeout=2.0)
            client.sendall(hb.pack(mav))
            assert wait_until(lambda n=n: len(got) == n)
            client.close()
        assert link.stats().transport_errors == 0
    finally:
        link.stop()


def test_bad_urls_raise_link_error():
    for url in ("", "bogus:1.2.3.4", "/dev/does-not-exist-icgt,921600", "udpin:not-an-address"):
        with pytest.raises(LinkError):
            MavlinkLink(LinkConfig(url)).start()


def test_stop_joins_threads_and_closes_the_socket(recorder):
    before = our_threads()
    link, port = make_link(recorder)
    link.start()
    assert len(our_threads()) == len(before) + 2
    conn = link._conn
    link.stop()
    assert our_threads() == before
    assert conn.port.fileno() == -1  # socket closed
    assert not link.send(link.mav.heartbeat_encode(30, 8, 0, 0, 4))
    link.stop()  # twice is fine
    # the port is free again
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.close()


def test_other_systems_frames_come_in_order_in_batches_to_a_batch_subscriber(recorder):
    """A burst of other systems' frames with the autopilot's in between, read in drains (read_batch_s): the
    batch subscriber gets every foreign frame once, in order with the decoded messages, each with its own
    arrival time, several per batch; a plain subscriber still gets one message per foreign frame."""
    batch_s = 0.2
    link, port = make_link(
        recorder, request_rates=False, timesync=False, decode_systems=frozenset({1}), read_batch_s=batch_s
    )
    seen: list[tuple[str, int, int]] = []  # (who, time_boot_ms of the frame, rx_ns) as delivered
    batches: list[UndecodedBatch] = []
    lock = threading.Lock()

    def on_batch(batch: UndecodedBatch) -> None:
        with lock:
            batches.append(batch)
            for buf, sysid, _comp, _mid, rx in batch.frames:
                seen.append(("foreign", int(mavlink2.MAVLink(None).decode(bytearray(buf)).time_boot_ms), rx))
                assert sysid == 42

    def on_message(rec: MavlinkMessage) -> None:
        if rec.type == "ATTITUDE":
            with lock:
                seen.append(("autopilot", int(rec.msg.time_boot_ms), rec.rx_ns))

    link.subscribe(on_message, undecoded=on_batch)
    plain: list[MavlinkMessage] = []
    link.subscribe(plain.append, ["ATTITUDE"])
    link.start()
    ap = AutopilotPeer(port)
    stranger = AutopilotPeer(port, system=42, component=1)
    try:
        time.sleep(0.3)
        sent: dict[int, int] = {}
        for k in range(60):  # 5 foreign frames, then one of the autopilot's, ...
            peer = ap if k % 6 == 5 else stranger
            sent[k] = time.monotonic_ns()
            peer.send(peer.mav.attitude_encode(k, 0, 0, 0, 0, 0, 0))
            if k % 12 == 11:
                time.sleep(0.05)
        assert wait_until(lambda: len(seen) == 60 and len(plain) == 60)
        with lock:
            assert [k for _, k, _ in seen] == list(range(60))  # every frame once, in the order sent
            assert [who for who, k, _ in seen] == ["autopilot" if k % 6 == 5 else "foreign" for k in range(60)]
            lags = [rx - sent[k] for _, k, rx in seen]
            assert max(lags) < batch_s * 1e9 / 2, "a stamp is the read time, not the arrival"
            assert min(lags) > -1_000_000
            assert sum(len(b) for b in batches) == 50 and len(batches) < 50
        assert [r.src_system == 42 for r in plain] == [k % 6 != 5 for k in range(60)]
        stats = link.stats()
        assert stats.undecoded_frames == 50 and stats.messages_by_type["ATTITUDE"] == 60
        assert stats.v2_frames >= 60 and stats.bytes_received >= 60 * len(
            bytes(ap.mav.attitude_encode(0, 0, 0, 0, 0, 0, 0).pack(ap.mav))
        )
    finally:
        stranger.close()
        ap.close()
        link.stop()


def test_datagrams_the_kernel_drops_are_counted(recorder):
    """A reader held up with a small receive buffer: the kernel drops what does not fit, and the link counts
    it (SO_RXQ_OVFL, told with the next datagram), so that what was received plus what was dropped is what
    was sent."""
    link, port = make_link(
        recorder,
        request_rates=False,
        timesync=False,
        decode_systems=frozenset({1}),
        read_batch_s=0.02,
        udp_receive_buffer_bytes=16_384,
    )
    held = threading.Event()
    release = threading.Event()

    def hold(rec: MavlinkMessage) -> None:
        if rec.src_system == 1 and not held.is_set():
            held.set()
            release.wait(5.0)  # the reader is stuck here while the flood comes

    link.subscribe(hold, ["ATTITUDE"])
    link.start()
    ap = AutopilotPeer(port)
    stranger = AutopilotPeer(port, system=42, component=1)
    n = 2000
    try:
        ap.send(ap.mav.attitude_encode(0, 0, 0, 0, 0, 0, 0))
        assert wait_until(held.is_set)
        for k in range(n):
            stranger.send(stranger.mav.attitude_encode(k, 0, 0, 0, 0, 0, 0))
        release.set()
        assert wait_until(lambda: link.stats().undecoded_frames > 0)
        # the count comes with the next datagram queued after the drops
        stranger.send(stranger.mav.attitude_encode(n, 0, 0, 0, 0, 0, 0))
        ok = wait_until(lambda: link.stats().undecoded_frames + link.stats().kernel_drops == n + 1, timeout=5.0)
        assert ok, link.stats()
        stats = link.stats()
        assert 0 < stats.kernel_drops < n, stats
    finally:
        release.set()
        stranger.close()
        ap.close()
        link.stop()


def test_one_frame_datagrams_decode_as_the_byte_stream_parser_decodes_them():
    """The whole-frame path (pymavlink's decode straight away) gives the messages and bad-frame counts that
    parse_buffer gives: MAVLink 1 and 2, signed (no key here), zero-trimmed payloads, a bad CRC, an unknown id."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    signer = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    signer.signing.secret_key = bytes(range(32))
    signer.signing.sign_outgoing = True
    good = [
        bytes(mav.attitude_encode(7, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0).pack(mav)),
        bytes(mav.attitude_encode(8, 0.1, -0.2, 0.3, 0.0, 0.0, 0.0).pack(mav, force_mavlink1=True)),
        bytes(mav.global_position_int_encode(9, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav)),  # trailing zeros trimmed
        bytes(mav.param_value_encode(b"GAIN", 1.5, 9, 10, 2).pack(mav)),
        bytes(signer.system_time_encode(1_700_000_000_000_000, 10).pack(signer)),
    ]
    bad_crc = bytearray(good[0])
    bad_crc[-1] ^= 0xFF
    unknown = bytearray(good[0])
    unknown[7:10] = (60_000).to_bytes(3, "little")
    datagrams = [*good, bytes(bad_crc), bytes(unknown)]

    def run(decode_systems):
        link = MavlinkLink(
            LinkConfig(url="udpin:127.0.0.1:0", decode_systems=decode_systems, request_rates=False, timesync=False)
        )
        got: list[MavlinkMessage] = []
        link.subscribe(got.append)
        for k, d in enumerate(datagrams):
            link._feed(d, 1000 + k)
        msgs = [(r.type, r.rx_ns, r.msg.to_dict(), bytes(r.msg.get_msgbuf())) for r in got if r.type != "BAD_DATA"]
        return msgs, link.stats().bad_frames

    whole, whole_bad = run(frozenset({1}))  # split by headers: each datagram is one whole frame
    stream, stream_bad = run(None)  # everything through parse_buffer
    assert whole == stream
    assert [m[0] for m in whole[len(good) :]] == ["UNKNOWN_60000"]  # pymavlink's message of an unknown id
    assert whole_bad == stream_bad == 1  # the bad CRC


def test_accepted_rate_that_does_not_come_is_asked_for_again_bounded(recorder):
    """ArduPilot ACKs a SET_MESSAGE_INTERVAL taken during its boot and then resets the stream (issue 29)."""
    from icgt.mavlink.link_types import StreamRate

    gps = mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT
    att = mavlink2.MAVLINK_MSG_ID_ATTITUDE
    rates = (StreamRate(att, "ATTITUDE", 20.0), StreamRate(gps, "GPS_RAW_INT", 10.0))
    link, port = make_link(recorder, stream_rates=rates, rate_verify_s=0.4, rate_max_rerequests=2)
    ap = AutopilotPeer(port)  # streams ATTITUDE (50 Hz), never GPS_RAW_INT
    link.start()
    try:
        ap.stream(hz=50)
        assert wait_until(lambda: len([m for m, _, _ in ap.interval_requests if m == gps]) == 3, timeout=6.0)
        time.sleep(1.5)  # bounded: no fourth request
        assert len([m for m, _, _ in ap.interval_requests if m == gps]) == 3
        assert len([m for m, _, _ in ap.interval_requests if m == att]) == 1, "a stream that comes is left alone"
        details = [e.detail for e in recorder.of(LinkEventKind.RATE_REQUEST)]
        assert any("GPS_RAW_INT at 10 Hz: ACCEPTED but 0 came" in d and "(2 of 2)" in d for d in details), details
    finally:
        ap.close()
        link.stop()
