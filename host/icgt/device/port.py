"""The device's port as bytes: open a URL (a serial device, the simulator's pty, `socket://host:port`), read.

`open_port` opens it exclusively (an flock, so a second recorder cannot read half of the stream) and says why
it cannot (`DeviceAbsentError`, `DeviceBusyError` naming who holds it, `DeviceLinkError`). `read_chunk` takes
whatever has arrived, as soon as anything has, with as few system calls as possible between the bytes' arrival
and the caller's stamp. Nothing here knows the protocol: that is `icgt.device.session`'s.
"""

from __future__ import annotations

import os
import select

import serial
from serial.urlhandler import protocol_socket

from icgt.device.link_types import DeviceAbsentError, DeviceBusyError, DeviceLinkError

__all__ = ["open_port", "port_fd", "port_holders", "read_chunk"]


def open_port(url: str, baudrate: int) -> serial.SerialBase:
    local = "://" not in url
    if local and not os.path.exists(url):
        raise DeviceAbsentError(f"device {url} does not exist (not plugged in?)")
    try:
        # exclusive: an flock on the port, so a second recorder cannot read half of the stream.
        port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.05, write_timeout=0.5, exclusive=local or None)
    except (serial.SerialException, OSError, ValueError) as exc:
        if local and "exclusively lock" in str(exc):
            holders = ", ".join(f"pid {pid} ({cmd})" for pid, cmd in port_holders(url)) or "another program"
            raise DeviceBusyError(f"device {url} is in use by {holders}") from None
        if local and not os.path.exists(url):
            raise DeviceAbsentError(f"device {url} disappeared while opening it") from None
        raise DeviceLinkError(f"cannot open device {url}: {exc}") from exc
    return port


def read_chunk(port: serial.SerialBase, timeout_s: float = 0.05) -> bytes:
    """Whatever has arrived, as soon as anything has (or b"" after `timeout_s`, 50 ms).

    On a POSIX serial port one select() and one read() of the file descriptor: pyserial's
    read(1) + in_waiting + read(n) costs three more system calls and their Python overhead
    between the bytes' arrival and the stamp, a delay on the reply path alone that biases
    the device clock mapping by half of it. A socket:// port the same way, through the
    descriptor pyserial's `fileno()` gives for select(): its `in_waiting` only says whether
    the socket is readable (1), so read(1) + read(in_waiting) returned 2 bytes per call.
    Other URLs (loop://, rfc2217:// with its telnet layer) go through pyserial.
    """
    fd = port_fd(port)
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


def port_fd(port: serial.SerialBase) -> int | None:
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
