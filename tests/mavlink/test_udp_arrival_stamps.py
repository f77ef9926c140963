"""UDP arrival stamps must be the datagram's arrival, not the moment a busy reader got to it (host bug, issue 9).

Found with the simulator's autopilot profiles (benchmarks/autopilot_profiles.py, profile ideal, 50 Hz,
TIMESYNC never answered): on the shared machine the recorder read its UDP socket up to 1.7 s behind,
stamped every datagram with the read time, and the one-way (arrival) autopilot clock, fed those stamps,
mapped mid-exposure 1.5 s wrong (15 m at 10 m/s) while each frame claimed +-3 ms. Any reader falls
behind sometimes (start-up, CPU load, a parameter download); the kernel knows when each datagram came
(SO_TIMESTAMPNS on Linux). Here a subscriber that takes 300 ms stands in for a descheduled reader.
Right behaviour: the datagram sent meanwhile is stamped within a few ms of when it was sent.
"""

from __future__ import annotations

import contextlib
import itertools
import socket
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.link import LinkConfig, MavlinkLink, MavlinkMessage


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_a_datagram_is_stamped_with_its_arrival_while_the_reader_is_busy() -> None:
    port = _free_udp_port()
    link = MavlinkLink(LinkConfig(url=f"udpin:127.0.0.1:{port}"))
    got: dict[str, int] = {}
    busy = threading.Event()

    def on_message(rec: MavlinkMessage) -> None:
        if rec.type == "HEARTBEAT" and not busy.is_set():
            busy.set()
            time.sleep(0.3)  # the reader is descheduled for 300 ms
        elif rec.type == "SYSTEM_TIME":
            got["rx_ns"] = rec.rx_ns

    link.subscribe(on_message)
    link.start()
    try:
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            hb = mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
            tx.sendto(hb.pack(mav), ("127.0.0.1", port))
            assert busy.wait(2.0)
            sent_ns = time.monotonic_ns()
            tx.sendto(mav.system_time_encode(0, 1000).pack(mav), ("127.0.0.1", port))
            deadline = time.monotonic() + 2.0
            while "rx_ns" not in got and time.monotonic() < deadline:
                time.sleep(0.01)
    finally:
        link.stop()
    assert "rx_ns" in got
    assert got["rx_ns"] - sent_ns < 50_000_000, f"stamped {(got['rx_ns'] - sent_ns) / 1e6:.0f} ms after it was sent"


def test_an_owner_pumped_link_has_no_threads_and_pump_hands_on_each_datagram_with_its_arrival() -> None:
    """owner_pumps (the recorder's worker reads the UDP link): no reader or service thread; pump() reads
    every datagram waiting, in order, each stamped with its arrival (here 300 ms before the pump), and runs
    the service step (a TIMESYNC request sent)."""
    port = _free_udp_port()
    sent_ts: list[int] = []
    link = MavlinkLink(LinkConfig(url=f"udpin:127.0.0.1:{port}", owner_pumps=True), on_timesync_sent=sent_ts.append)
    got: list[MavlinkMessage] = []
    link.subscribe(got.append)
    before = {t.name for t in threading.enumerate()}
    link.start()
    try:
        assert link.pumped and link.running
        assert not {t.name for t in threading.enumerate()} - before, "an owner-pumped link started a thread"
        assert link.pump() == 0
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            hb = mav.heartbeat_encode(mavlink2.MAV_TYPE_QUADROTOR, mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 4)
            sent_ns = time.monotonic_ns()
            tx.sendto(hb.pack(mav), ("127.0.0.1", port))
            for i in range(20):
                tx.sendto(mav.system_time_encode(0, 1000 + i).pack(mav), ("127.0.0.1", port))
            time.sleep(0.3)
            pumped_ns = time.monotonic_ns()
            assert link.pump() == 21
            tx.sendto(mav.system_time_encode(0, 2000).pack(mav), ("127.0.0.1", port))
            time.sleep(0.05)
    finally:
        link.stop()  # what came after the last pump is handed on by stop(), not closed away
    assert not link.pumped and link.pump() == 0
    assert [m.type for m in got] == ["HEARTBEAT"] + ["SYSTEM_TIME"] * 21
    assert [m.msg.time_boot_ms for m in got[1:]] == [*range(1000, 1020), 2000]
    assert all(sent_ns <= m.rx_ns < sent_ns + 100_000_000 < pumped_ns for m in got[:-1]), "stamped at the pump"
    assert sent_ts, "the service step did not run"


def test_an_autopilot_already_sending_is_stamped_on_arrival_from_its_first_datagram() -> None:
    """A real autopilot streams before the recorder is up (issue 34): the first datagrams reach the socket
    while it is being opened, when the kernel may not stamp arrivals yet and would stamp them when read.
    Every message must carry its arrival, no later than the moment its send returned, and per sender the
    receive times must follow the send order (here the first pump comes 300 ms after the link opened)."""
    port = _free_udp_port()
    link = MavlinkLink(LinkConfig(url=f"udpin:127.0.0.1:{port}", owner_pumps=True))
    got: list[MavlinkMessage] = []
    link.subscribe(got.append)
    sent_after: dict[int, int] = {}  # time_boot_ms -> host clock when its sendto returned [ns]
    stop = threading.Event()

    def autopilot() -> None:
        mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
            k = 0
            while not stop.is_set():
                k += 1
                with contextlib.suppress(OSError):  # nobody bound yet (ECONNREFUSED): an autopilot does not care
                    tx.sendto(mav.system_time_encode(0, k).pack(mav), ("127.0.0.1", port))
                sent_after[k] = time.monotonic_ns()
                time.sleep(0.0005)

    sender = threading.Thread(target=autopilot, daemon=True)
    sender.start()
    try:
        time.sleep(0.05)
        link.start()
        time.sleep(0.3)  # the recorder's first step comes late
        for _ in range(10):
            link.pump()
            time.sleep(0.02)
    finally:
        stop.set()
        sender.join(2.0)
        link.stop()
    msgs = [m for m in got if m.type == "SYSTEM_TIME"]
    assert len(msgs) > 100
    ks = [m.msg.time_boot_ms for m in msgs]
    assert ks == sorted(ks), "datagrams handed on out of order"
    late = [
        (k, (m.rx_ns - sent_after[k]) / 1e6)
        for k, m in zip(ks, msgs, strict=True)
        if m.rx_ns > sent_after[k] + 2_000_000
    ]
    assert not late, f"stamped over 2 ms after their send returned (message, ms late): {late[:5]}"
    rx = [m.rx_ns for m in msgs]
    assert all(a <= b for a, b in itertools.pairwise(rx)), "receive times run backwards"
