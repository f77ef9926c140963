"""Kernel receive timestamps on a UDP socket, on before the first datagram can arrive.

Linux stamps a datagram on arrival (SO_TIMESTAMPNS) only once receive stamping is on system-wide, and it
switches that on *later* than the `setsockopt` that asks for it (a deferred work item enables it). A datagram
that arrives before (one already queued when the option is set, or one in the short window after) carries no
arrival stamp: the kernel fills in the time it is *read*. For a recorder whose autopilot was already sending
when it started, that made the first message of a recording look up to a few hundred milliseconds late,
later than messages the autopilot sent after it.

So the option is set before the socket is bound, and the bind waits until a loopback probe shows that
arrivals are stamped (a datagram sent to itself carries a stamp no later than the moment `sendto` returned;
a read-time stamp is later than that). pymavlink's `mavudp` binds in its constructor, before any option can
be set, hence `replace_socket`: the bound, stamped socket is put in place of the one pymavlink made.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import struct
import time
from typing import Any

log = logging.getLogger(__name__)

# Linux's values (Python's socket module does not name them).
SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
SO_MEMINFO = getattr(socket, "SO_MEMINFO", 55)
TIMESPEC = struct.Struct("qq")  # struct timespec: tv_sec, tv_nsec
_SK_MEMINFO_DROPS = 8  # index of sk_drops in SO_MEMINFO's u32 array (Linux 4.15+)
RMEM_MAX_PATH = "/proc/sys/net/core/rmem_max"

PROBE_WAIT_S = 2.0
"""How long the bind waits for the kernel to stamp arrivals before it goes ahead without [s]."""


def stamps_enabled(sock: socket.socket) -> bool:
    """Has `sock` asked for arrival stamps already (a listening socket made by `stamped_udp_socket`)?"""
    try:
        return bool(sock.getsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS))
    except OSError:
        return False


def enable_stamps(sock: socket.socket) -> bool:
    """Ask for arrival stamps (and the kernel's drop count) on `sock`; False if the platform refuses."""
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError as exc:
        log.warning("no kernel receive timestamps on the MAVLink socket (%s): arrival = read time", exc)
        return False
    with contextlib.suppress(OSError):
        sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
    return True


def socket_drops(sock: socket.socket) -> int | None:
    """The kernel's count of datagrams it dropped for `sock` (sk_drops: receive buffer full, bad checksum), read
    now with SO_MEMINFO; the same counter SO_RXQ_OVFL reports and /proc/net/udp's 'drops' column shows. None where
    the platform does not tell (not Linux, an old kernel, a closed socket)."""
    try:
        raw = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 64)
    except OSError:
        return None
    if len(raw) < 4 * (_SK_MEMINFO_DROPS + 1):
        return None
    value: int = struct.unpack_from("I", raw, 4 * _SK_MEMINFO_DROPS)[0]
    return value


def rmem_max() -> int | None:
    """net.core.rmem_max [bytes]: the most SO_RCVBUF may grant an unprivileged process; None if unreadable."""
    try:
        with open(RMEM_MAX_PATH) as f:
            return int(f.read().strip())
    except (OSError, ValueError):
        return None


def arrivals_stamped(probe: socket.socket) -> bool:
    """One loopback datagram through `probe` (stamps on, bound to 127.0.0.1): stamped when it arrived?"""
    probe.sendto(b"icgt-stamp-probe", probe.getsockname())
    sent_ns = time.time_ns()
    for _ in range(100):
        try:
            _data, ancdata, _flags, _addr = probe.recvmsg(64, socket.CMSG_SPACE(16))
        except BlockingIOError:
            time.sleep(0.0005)
            continue
        for level, kind, payload in ancdata:
            if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(payload) >= 16:
                sec, nsec = TIMESPEC.unpack_from(payload)
                return bool(sec * 1_000_000_000 + nsec <= sent_ns)
        return False
    return False


def wait_until_arrivals_stamped(timeout_s: float = PROBE_WAIT_S) -> bool:
    """Block until the kernel stamps datagrams on arrival (at most `timeout_s`); whether it does.

    The caller's socket must already have asked for stamps: that request is what turns stamping on."""
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        probe.bind(("127.0.0.1", 0))
        probe.setblocking(False)
        if not enable_stamps(probe):
            return False
        deadline = time.monotonic() + timeout_s
        while True:
            if arrivals_stamped(probe):
                return True
            if time.monotonic() >= deadline:
                log.warning("the kernel did not stamp UDP arrivals within %.1f s: early ones get read times", timeout_s)
                return False
            time.sleep(0.001)
    except OSError as exc:
        log.warning("UDP arrival stamp probe failed (%s)", exc)
        return False
    finally:
        probe.close()


def stamped_udp_socket(host: str, port: int) -> socket.socket:
    """A non-blocking UDP socket bound to (host, port) whose every datagram carries its arrival stamp."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as pymavlink's mavudp does
        if enable_stamps(sock):
            wait_until_arrivals_stamped()
        sock.bind((host, port))
        sock.setblocking(False)
    except BaseException:
        sock.close()
        raise
    return sock


def replace_socket(conn: Any, sock: socket.socket) -> None:
    """Put `sock` in place of a pymavlink mavudp's own socket (closed), fd included."""
    old = conn.port
    conn.port = sock
    conn.fd = sock.fileno()
    old.close()
