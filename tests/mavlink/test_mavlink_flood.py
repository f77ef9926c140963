"""A MAVLink flood on the recorder's UDP link (read by its owner's steps, as `icgt record` reads it), with every
core kept busy: each datagram sent is either read or counted as a kernel drop (on loopback nothing else loses
them), the count is complete when the flood ends in drops (no later datagram has to bring it), and the drops
are told with their cause, the receive buffer the kernel granted."""

from __future__ import annotations

import socket
import time

import pytest
from mavlink_peers import free_udp_port
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.link import LinkConfig, LinkEventKind, MavlinkEvent, MavlinkLink
from icgt.mavlink.udp_stamps import socket_drops
from icgt.report.summary import kernel_drops_row
from icgt.sim.cpu_load import CpuBurners


def _frames(n: int) -> list[bytes]:
    """n real ATTITUDE frames of another system (42): the recorder keeps them raw, one count each."""
    mav = mavlink2.MAVLink(None, srcSystem=42, srcComponent=1)
    return [bytes(mav.attitude_encode(k, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(mav)) for k in range(n)]


def _link(buffer_bytes: int) -> tuple[MavlinkLink, int, list[MavlinkEvent]]:
    port = free_udp_port()
    events: list[MavlinkEvent] = []
    config = LinkConfig(
        url=f"udpin:127.0.0.1:{port}",
        request_rates=False,
        timesync=False,
        decode_systems=frozenset({1, 100}),
        owner_pumps=True,
        udp_receive_buffer_bytes=buffer_bytes,
    )
    return MavlinkLink(config, on_event=events.append), port, events


def _pump_until_quiet(link: MavlinkLink) -> None:
    quiet = 0
    while quiet < 5:
        quiet = quiet + 1 if link.pump() == 0 else 0
        time.sleep(0.01)


@pytest.mark.parametrize("pump_every_s", [None, 0.1])
def test_every_datagram_of_a_flood_is_read_or_counted_as_a_kernel_drop(pump_every_s: float | None) -> None:
    """None: the owner is held up for the whole flood, which ends in drops; 0.1: it steps every 100 ms, as the
    recorder's worker does, during 10 000 msg/s for 1 s. Either way sent == read + counted drops."""
    n = 10_000
    frames = _frames(n)
    link, port, events = _link(65_536)
    link.start()
    sender = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        assert link.pumped
        with CpuBurners():
            t0 = time.monotonic()
            next_pump = t0
            for k, frame in enumerate(frames):
                sender.sendto(frame, ("127.0.0.1", port))
                now = time.monotonic()
                if pump_every_s is not None and now >= next_pump:
                    link.pump()
                    next_pump = now + pump_every_s
                if k % 100 == 99:  # 10 000 msg/s
                    time.sleep(max(0.0, t0 + (k + 1) / n - time.monotonic()))
            _pump_until_quiet(link)
        stats = link.stats()
        assert stats.udp_receive_buffer_asked_bytes == 65_536
        granted = stats.udp_receive_buffer_bytes
        assert granted == link.receive_buffer_bytes > 0
        assert stats.undecoded_frames + stats.kernel_drops == n, stats
        assert socket_drops(link._conn.port) == stats.kernel_drops  # the kernel's own count, read back
        if pump_every_s is None:
            assert stats.kernel_drops > n // 2, stats  # a 64 KiB buffer holds a few hundred of them
        link.stop()  # told at most once a second while it lasts, and what is left when the link stops
        told = [e for e in events if e.kind is LinkEventKind.KERNEL_DROPS]
        assert bool(told) == bool(stats.kernel_drops), events
        assert sum(e.count for e in told) == stats.kernel_drops, told
        if told:
            assert f"{granted} bytes granted" in told[-1].detail, told[-1]
            assert f"({stats.kernel_drops} so far)" in told[-1].detail, told[-1]
    finally:
        sender.close()
        link.stop()


def test_icgt_info_row_names_the_drops_and_the_buffer_granted() -> None:
    assert kernel_drops_row({"kernel_drops": 0}) is None  # no buffer: not a UDP link (or an older log)
    row = kernel_drops_row({"kernel_drops": 0, "udp_receive_buffer_bytes": 4_194_304})
    assert row == ("MAVLink datagrams dropped by the kernel", "0 (UDP receive buffer 4194304 bytes granted)")
    counters = {"kernel_drops": 9005, "udp_receive_buffer_bytes": 212_992, "udp_receive_buffer_asked_bytes": 4_194_304}
    row = kernel_drops_row(counters)
    assert row is not None and row[1].startswith("9005: the buffer was full")
    assert "212992 bytes granted of 4194304 asked (capped by net.core.rmem_max)" in row[1]
