"""Local control of a running recorder: `icgt start`, `icgt stop`, `icgt status`.

A Unix-domain socket (never a network port: nothing off the companion computer can reach
it) carrying one JSON object per line each way. The recorder serves it; the CLI commands
are its clients.

Local trust: the socket lives in a private directory ($XDG_RUNTIME_DIR, or `icgt-<uid>` in the
system temp directory, created 0700) that must be a real directory owned by this user that group
and others cannot write in; anything else (another user's pre-created directory, mode 0777, a symlink) is refused
with what is wrong, by the server and by the client. The socket file is 0600. Each side checks the
other's uid with SO_PEERCRED: a client talks only to a server running as the same user, the server
answers only its own user (or root).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
import stat
import struct
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError

log = logging.getLogger(__name__)

Request = dict[str, Any]
Reply = dict[str, Any]
Handler = Callable[[Request], Reply]


class ControlError(IcgtError):
    """The recorder's control socket cannot be reached or answered with an error."""


def default_socket_path() -> Path:
    """Where a recorder listens unless told otherwise: the user's runtime directory."""
    runtime = os.environ.get("XDG_RUNTIME_DIR") or str(Path(tempfile.gettempdir()) / f"icgt-{os.getuid()}")
    return Path(runtime) / "icgt-recorder.sock"


# sun_path in struct sockaddr_un holds 108 bytes on Linux, with the terminating NUL.
UNIX_PATH_MAX = 108


def check_socket_path(path: Path) -> None:
    """Refuse (ControlError) a control socket path too long for a Unix socket's address, naming its length."""
    size = len(os.fsencode(path))
    if size >= UNIX_PATH_MAX:
        raise ControlError(
            f"control socket path {str(path)!r} is {size} bytes long; a Unix socket path holds at most "
            f"{UNIX_PATH_MAX - 1}: choose a shorter --socket"
        )


def peer_uid(sock: socket.socket) -> int:
    """The uid of the process at the other end of a connected Unix socket (SO_PEERCRED: pid, uid, gid)."""
    creds = sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, struct.calcsize("3i"))
    _pid, uid, _gid = struct.unpack("3i", creds)
    return int(uid)


def ensure_private_dir(path: Path, *, create: bool) -> None:
    """The socket's directory: created 0700 if missing (and `create`), then refused unless it is a real
    directory owned by this user that no group or other may write in (ControlError naming what is wrong):
    whoever can write there can put their own socket in place of the recorder's."""
    if create and not os.path.lexists(path):
        path.parent.mkdir(parents=True, exist_ok=True)
        with contextlib.suppress(FileExistsError):  # someone else may win the race: checked below
            os.mkdir(path, 0o700)
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        raise ControlError(f"no recorder running (no control directory {path})") from None
    me = os.getuid()
    if stat.S_ISLNK(st.st_mode) or not stat.S_ISDIR(st.st_mode):
        raise ControlError(f"control directory {path} is not a directory (a symlink or a file): refusing it")
    if st.st_uid != me:
        raise ControlError(
            f"control directory {path} is owned by uid {st.st_uid}, not by you (uid {me}): refusing it "
            "(remove it, or set XDG_RUNTIME_DIR)"
        )
    mode = stat.S_IMODE(st.st_mode)
    if mode & 0o022:
        raise ControlError(
            f"control directory {path} has mode {mode:04o}: group or others may write in it; refusing it "
            "(chmod 700 it, or remove it)"
        )


class ControlServer:
    """Serves control requests on a Unix socket from a background thread."""

    def __init__(self, path: Path, handler: Handler) -> None:
        self.path = path
        self._handler = handler
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self) -> None:
        check_socket_path(self.path)
        ensure_private_dir(self.path.parent, create=True)
        if self.path.exists():
            if _answers(self.path):
                raise ControlError(f"another recorder is already running (control socket {self.path})")
            self.path.unlink()  # left behind by a recorder that was killed
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.bind(str(self.path))
        os.chmod(self.path, 0o600)  # only this user may start or stop capture
        sock.listen(4)
        sock.settimeout(0.2)
        self._sock = sock
        self._thread = threading.Thread(target=self._serve, name="icgt-control", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._sock is not None:
            self._sock.close()
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()

    def _serve(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                return
            with conn:
                conn.settimeout(2.0)
                try:
                    uid = peer_uid(conn)
                except OSError:
                    uid = -1
                if uid not in (os.getuid(), 0):
                    log.warning("control request from uid %d refused (this recorder runs as uid %d)", uid, os.getuid())
                    with contextlib.suppress(OSError):
                        conn.sendall(
                            (json.dumps({"error": f"uid {uid} may not control this recorder"}) + "\n").encode()
                        )
                    continue
                try:
                    line = conn.makefile("r", encoding="utf-8").readline()
                    request = json.loads(line) if line else {}
                    reply = self._handler(request) if isinstance(request, dict) else {"error": "not a JSON object"}
                except (OSError, ValueError) as exc:
                    reply = {"error": f"bad request: {exc}"}
                except IcgtError as exc:
                    reply = {"error": str(exc)}
                except Exception as exc:  # the server outlives any request, and says what went wrong
                    log.exception("control request failed")
                    reply = {"error": f"internal error: {type(exc).__name__}: {exc}"}
                with contextlib.suppress(OSError):
                    conn.sendall((json.dumps(reply) + "\n").encode())


def _answers(path: Path) -> bool:
    try:
        request(path, {"command": "status"}, timeout_s=1.0)
    except ControlError:
        return False
    return True


def request(path: Path, message: Request, *, timeout_s: float = 5.0) -> Reply:
    """Send one request to the recorder at `path` and return its reply.

    Refused (ControlError) when the socket's directory is not private to this user or the process
    serving it runs as another user."""
    check_socket_path(path)
    ensure_private_dir(path.parent, create=False)
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout_s)
            sock.connect(str(path))
            server = peer_uid(sock)
            if server != os.getuid():
                raise ControlError(
                    f"the control socket {path} is served by uid {server}, not by you (uid {os.getuid()}): "
                    "not sending it anything"
                )
            # A server that answers and closes before it takes the request (a refusal) breaks the pipe: its
            # answer is still there to be read.
            with contextlib.suppress(BrokenPipeError, ConnectionResetError):
                sock.sendall((json.dumps(message) + "\n").encode())
            line = sock.makefile("r", encoding="utf-8").readline()
            if not line:
                raise ControlError(f"recorder at {path} closed the connection without answering")
    except FileNotFoundError as exc:
        raise ControlError(f"no recorder running (no control socket at {path})") from exc
    except OSError as exc:
        raise ControlError(f"recorder at {path} not answering: {exc}") from exc
    try:
        reply = json.loads(line)
    except ValueError as exc:
        raise ControlError(f"recorder at {path} sent a bad reply: {line!r}") from exc
    if not isinstance(reply, dict):
        raise ControlError(f"recorder at {path} sent a bad reply: {line!r}")
    if "error" in reply:
        raise ControlError(str(reply["error"]))
    return reply
