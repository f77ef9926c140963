"""Local control of a running recorder: `icgt start`, `icgt stop`, `icgt status`.

A Unix-domain socket (never a network port: nothing off the companion computer can reach
it) carrying one JSON object per line each way. The recorder serves it; the CLI commands
are its clients.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import socket
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
    runtime = os.environ.get("XDG_RUNTIME_DIR") or f"/tmp/icgt-{os.getuid()}"
    return Path(runtime) / "icgt-recorder.sock"


class ControlServer:
    """Serves control requests on a Unix socket from a background thread."""

    def __init__(self, path: Path, handler: Handler) -> None:
        self.path = path
        self._handler = handler
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()

    def start(self) -> None:
        self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
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
    """Send one request to the recorder at `path` and return its reply."""
    try:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
            sock.settimeout(timeout_s)
            sock.connect(str(path))
            sock.sendall((json.dumps(message) + "\n").encode())
            line = sock.makefile("r", encoding="utf-8").readline()
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
