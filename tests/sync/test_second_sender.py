"""A second sender with the autopilot's MAVLink ids cannot take its place (issue 30, part 1).

The autopilot (1:1) streams HEARTBEAT at 1 Hz and GLOBAL_POSITION_INT, ATTITUDE at 10 Hz from one pymavlink
encoder (so its packet sequence numbers run on, as a real one's do). Another sender uses the same ids: spoofed
positions with a boot clock of 1e9 ms, spoofed heartbeats, a replay of the flight's first seconds, an echo of
the real stream 1 s late. The synchroniser believes no reboot, keeps the autopilot's clock and poses, counts the
second sender's messages and says so once; a real reboot (the stream stops, the boot clock starts again) is
still believed.
"""

from __future__ import annotations

from collections.abc import Iterator

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.ingest.recompute import _Feeder
from icgt.mavlink.signing import SigningState, key_from_passphrase
from icgt.recorder import topics
from icgt.sync import SyncConfig, Synchroniser

S = 1_000_000_000
MS = 1_000_000
BOOT_HOST_NS = 50 * S  # host time at the autopilot's boot
DELAY_NS = 2 * MS  # link delay


class Sender:
    """One MAVLink sender (its own sequence counter) with ids 1:1 and a boot clock starting at ``boot_host_ns``."""

    def __init__(self, boot_host_ns: int = BOOT_HOST_NS) -> None:
        self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.boot_host_ns = boot_host_ns

    def _frame(self, msg: mavlink2.MAVLink_message) -> bytes:
        frame = bytes(msg.pack(self.mav))
        self.mav.seq = (self.mav.seq + 1) % 256  # what MAVLink.send does after packing
        return frame

    def heartbeat(self) -> bytes:
        return self._frame(self.mav.heartbeat_encode(2, 3, 0, 0, 4))

    def position(self, boot_ms: int) -> bytes:
        lat = 473_977_000 + boot_ms // 100  # ~1 m/s north
        return self._frame(self.mav.global_position_int_encode(boot_ms, lat, 85_455_000, 500_000, 20_000, 100, 0, 0, 0))

    def attitude(self, boot_ms: int) -> bytes:
        return self._frame(self.mav.attitude_encode(boot_ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0))

    def stream(self, start_ms: int, end_ms: int) -> Iterator[tuple[int, bytes]]:
        """(host receive time, frame) of its flight between two boot times: 10 Hz telemetry, 1 Hz heartbeat."""
        for boot_ms in range(start_ms, end_ms, 100):
            rx = self.boot_host_ns + boot_ms * MS + DELAY_NS
            if boot_ms % 1000 == 0:
                yield rx, self.heartbeat()
            yield rx, self.position(boot_ms)
            yield rx + MS, self.attitude(boot_ms)


def feed(sync: Synchroniser, frames: list[tuple[int, bytes]]) -> None:
    parser = mavlink2.MAVLink(None)
    for rx, frame in sorted(frames, key=lambda f: f[0]):
        for msg in parser.parse_buffer(frame) or []:
            sync.on_mavlink(msg, rx)


def assert_only_the_autopilot_was_believed(sync: Synchroniser, real_positions: int, strays: int) -> None:
    counters = sync.counters()
    assert counters["autopilot_reboots"] == 0
    assert counters["autopilot_clock_resets"] == 0
    assert counters["autopilot_second_sender_messages"] == strays
    positions = sync.telemetry.fused.samples()
    assert len(positions) == real_positions  # none of the second sender's samples
    boot_us = [p.boot_us for p in positions]
    assert boot_us == sorted(boot_us) and max(boot_us) < 1e9
    events = sync.take_events()
    said = [e for e in events if e.kind == "autopilot_second_sender"]
    assert len(said) == 1, events  # loudly once; the count is in every counters record
    assert "second sender uses the autopilot's MAVLink id 1:1" in said[0].detail
    assert [e.kind for e in events if e.kind != "autopilot_second_sender"] == ["autopilot_seen"]


def test_spoofed_positions_with_a_far_boot_clock_are_a_second_sender() -> None:
    real = list(Sender().stream(0, 60_000))
    stray = Sender()
    spoofed = []  # 70 positions over 5 s from 20 s on, boot clock near 1e9 ms
    for k in range(70):
        rx = BOOT_HOST_NS + 20 * S + k * 71 * MS + 37 * MS
        spoofed.append((rx, stray.position(1_000_000_000 + 71 * k)))
    sync = Synchroniser()
    feed(sync, real + spoofed)
    assert_only_the_autopilot_was_believed(sync, real_positions=600, strays=70)
    # the autopilot's clock held: boot time 30 s is 30 s after its boot
    boot_us = sync.autopilot_time.host_to_autopilot_us(BOOT_HOST_NS + 30 * S + DELAY_NS)
    assert abs(boot_us - 30_000_000) <= 3_000


def test_spoofed_heartbeats_are_a_second_sender() -> None:
    real = list(Sender().stream(0, 20_000))
    stray = Sender()
    spoofed = [(BOOT_HOST_NS + 5 * S + k * 250 * MS + 50 * MS, stray.heartbeat()) for k in range(20)]
    sync = Synchroniser()
    feed(sync, real + spoofed)
    assert_only_the_autopilot_was_believed(sync, real_positions=200, strays=20)


def test_a_replay_of_the_flights_first_seconds_is_not_a_reboot() -> None:
    autopilot = Sender()
    first = list(autopilot.stream(0, 10_000))  # recorded by someone
    later = list(autopilot.stream(10_000, 60_000))
    replay = [(rx + 30 * S, frame) for rx, frame in first]  # played back 30 s later, while the autopilot flies on
    sync = Synchroniser()
    feed(sync, first + later + replay)
    assert_only_the_autopilot_was_believed(sync, real_positions=600, strays=len(replay))


def test_an_echo_of_the_real_stream_1_s_late_is_a_second_sender() -> None:
    real = list(Sender().stream(0, 30_000))
    echo = [(rx + S, frame) for rx, frame in real if rx > BOOT_HOST_NS + 10 * S]  # a router loop from 10 s on
    sync = Synchroniser()
    feed(sync, real + echo)
    assert_only_the_autopilot_was_believed(sync, real_positions=300, strays=len(echo))


def test_a_link_that_holds_the_stream_back_is_still_the_autopilot() -> None:
    """A radio's buffer (or a congested router) delays every message by 1.5 s for 10 s, in order, then sends the
    backlog in a burst: the stream's origin moves late by the delay, its boot clock and sequence numbers run on,
    and all of it is believed (before, anything more than 0.5 s late was refused as a second sender, and one
    late message moved the origin so that the next timely ones were)."""
    real = list(Sender().stream(0, 30_000))
    held, last_rx = [], 0
    for rx, frame in real:
        late = 1500 * MS if BOOT_HOST_NS + 10 * S <= rx < BOOT_HOST_NS + 20 * S else 0
        last_rx = max(rx + late, last_rx + 10_000)  # in order: nothing overtakes what the buffer holds
        held.append((last_rx, frame))
    sync = Synchroniser()
    feed(sync, held)
    assert sync.counters()["autopilot_second_sender_messages"] == 0
    assert len(sync.telemetry.fused.samples()) == 300


def test_an_answer_on_time_while_the_first_seconds_of_telemetry_wait_is_still_the_autopilot() -> None:
    """At start-up the autopilot's telemetry reaches the host 0.8 s late for 3 s (its sender busy, a host starting
    up; seen in the simulator under full CPU load) while its TIMESYNC answer comes on time: that answer's boot
    clock puts the origin 0.8 s earlier than the telemetry so far did. Believed, with the telemetry after it (it
    used to be refused as a second sender, and with it the TIMESYNC answers)."""
    sender = Sender()
    frames: list[tuple[int, bytes]] = []
    last_rx = 0
    for rx, frame in sender.stream(0, 30_000):
        late = 800 * MS if rx < BOOT_HOST_NS + 3 * S else 0
        last_rx = max(rx + late, last_rx + 10_000)  # in order on the telemetry's way
        frames.append((last_rx, frame))
        if rx == BOOT_HOST_NS + 1_500 * MS + DELAY_NS:  # generated after the 1.5 s position: its sequence number
            answer = sender._frame(sender.mav.timesync_encode(1_500 * MS, 123))
            frames.append((rx + MS, answer))
    sync = Synchroniser()
    feed(sync, frames)
    assert sync.counters()["autopilot_second_sender_messages"] == 0
    assert len(sync.telemetry.fused.samples()) == 300


def test_flight_stacks_booted_2_s_before_or_after_the_autopilot_are_second_senders() -> None:
    """Another flight stack on the network with the autopilot's id, booted 2 s earlier (its boot clock ahead: its
    origin earlier than any message of the autopilot can be) or 2 s later (its clock behind the autopilot's)."""
    for boot_shift in (-2 * S, 2 * S):
        real = list(Sender().stream(0, 30_000))
        other = Sender(boot_host_ns=BOOT_HOST_NS + boot_shift)
        # its positions from 10 s to 15 s of the autopilot's flight (host time), at 10 Hz
        stray = [
            (BOOT_HOST_NS + t_ms * MS + 37 * MS, other.position(t_ms - boot_shift // MS))
            for t_ms in range(10_000, 15_000, 100)
        ]
        sync = Synchroniser()
        feed(sync, real + stray)
        assert_only_the_autopilot_was_believed(sync, real_positions=300, strays=len(stray))


def test_a_real_reboot_is_still_believed() -> None:
    before = Sender()
    after = Sender(boot_host_ns=BOOT_HOST_NS + 40 * S)  # it stopped at 30 s and booted again at 40 s
    sync = Synchroniser()
    feed(sync, list(before.stream(0, 30_000)) + list(after.stream(0, 10_000)))
    kinds = [e.kind for e in sync.take_events()]
    assert kinds.count("autopilot_rebooted") == 1 and "autopilot_second_sender" not in kinds
    assert sync.counters()["autopilot_second_sender_messages"] == 0


def test_with_signing_configured_unsigned_messages_with_the_autopilots_id_are_not_believed() -> None:
    """The autopilot signs with the key; a stray sender without it sends positions and heartbeats as 1:1."""
    key = key_from_passphrase("bridge inspection")
    autopilot = Sender()
    SigningState(key, link_id=1).attach_output(autopilot.mav)
    real = list(autopilot.stream(0, 20_000))
    stray = Sender()
    spoofed = []
    for k in range(30):
        rx = BOOT_HOST_NS + 5 * S + k * 100 * MS + 37 * MS
        spoofed += [(rx, stray.position(5_000 + 100 * k + 37)), (rx + MS, stray.heartbeat())]
    sync = Synchroniser(SyncConfig(require_signed_autopilot=True))
    parser = mavlink2.MAVLink(None)
    SigningState(key).attach_input(parser)
    for rx, frame in sorted(real + spoofed, key=lambda f: f[0]):
        for msg in parser.parse_buffer(frame) or []:
            sync.on_mavlink(msg, rx)
    counters = sync.counters()
    assert counters["autopilot_unsigned_messages"] == 60
    assert counters["autopilot_second_sender_messages"] == 0  # refused before: on its signature alone
    assert len(sync.telemetry.fused.samples()) == 200
    said = [e for e in sync.take_events() if e.kind == "autopilot_unsigned"]
    assert len(said) == 1 and "no valid signature and signing is configured" in said[0].detail


def test_the_recompute_believes_what_the_recorder_believed_with_signing() -> None:
    """The log keeps the recorder's signature verdict ("signed", the key is not in the log); the recompute's
    synchroniser, fed the logged payloads, takes and refuses the same messages as the live one."""
    key = key_from_passphrase("bridge inspection")
    autopilot, stray = Sender(), Sender()
    SigningState(key, link_id=1).attach_output(autopilot.mav)
    frames = [*autopilot.stream(0, 5_000), (BOOT_HOST_NS + 2 * S + 37 * MS, stray.position(2_037))]
    parser = mavlink2.MAVLink(None)
    SigningState(key).attach_input(parser)
    live = Synchroniser(SyncConfig(require_signed_autopilot=True))
    replay = Synchroniser(SyncConfig(require_signed_autopilot=True))
    feeder = _Feeder(replay, None, 0.0, requests_logged=True)
    for rx, frame in sorted(frames, key=lambda f: f[0]):
        for msg in parser.parse_buffer(frame) or []:
            live.on_mavlink(msg, rx)
            assert feeder._mavlink(topics.mavlink_topic(msg.get_type()), topics.mavlink_payload(msg, rx))
    assert live.counters()["autopilot_unsigned_messages"] == 1
    assert replay.counters() == live.counters()
    assert replay.telemetry.fused.samples() == live.telemetry.fused.samples()


def test_the_autopilot_is_believed_over_hours_of_clock_drift() -> None:
    """The boot origin follows the clocks' drift: an autopilot clock 100 ppm slow puts its origin 0.36 s further
    every hour, past the 0.5 s tolerance after 1.4 h; all of a 3 h stream (one position a second) is believed."""
    from icgt.mavlink.autopilot_rules import AutopilotPresence, Freshness

    presence = AutopilotPresence(1, component=1)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    parser = mavlink2.MAVLink(None)
    refused = 0
    for k in range(3 * 3600):
        boot_ms = 1000 * k
        msg = parser.parse_char(mav.global_position_int_encode(boot_ms, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav))
        rx_ns = BOOT_HOST_NS + int(boot_ms * 1_000_000 * (1 + 100e-6))
        if presence.observe(msg, "GLOBAL_POSITION_INT", rx_ns) == Freshness.SECOND_SENDER:
            refused += 1
    assert presence.origin_ns is not None
    assert refused == 0


def test_each_message_says_whether_it_was_the_autopilots_own() -> None:
    """`on_mavlink` returns its verdict with the message (the recorder lets only a believed COMMAND_ACK answer
    its rate commands): the autopilot's own stream believed, the spoofer's positions and another system not."""
    real = [(rx, frame, True) for rx, frame in Sender().stream(0, 20_000)]
    stray = Sender()
    spoofed = [
        (BOOT_HOST_NS + 5 * S + k * 71 * MS + 37 * MS, stray.position(1_000_000_000 + 71 * k), False) for k in range(30)
    ]
    ground = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
    others = [
        (BOOT_HOST_NS + 7 * S + k * S, bytes(ground.heartbeat_encode(6, 8, 0, 0, 4).pack(ground)), False)
        for k in range(5)
    ]
    sync = Synchroniser()
    parser = mavlink2.MAVLink(None)
    verdicts: dict[bool, list[bool]] = {True: [], False: []}
    for rx, frame, own in sorted(real + spoofed + others, key=lambda f: f[0]):
        for msg in parser.parse_buffer(frame) or []:
            verdict = sync.on_mavlink(msg, rx)
            assert verdict.timesync is None  # no TIMESYNC was asked for
            verdicts[own].append(verdict.believed)
    assert len(verdicts[True]) == 420 and all(verdicts[True])
    assert len(verdicts[False]) == 35 and not any(verdicts[False])
