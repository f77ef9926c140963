"""The control socket's local trust: its directory must be this user's and not writable by others, and each
side checks the other's uid (SO_PEERCRED).

A foreign owner is made for real with os.chown (these tests run as root in CI, as `make test` does); a server
or client of another uid is simulated by monkeypatching `icgt.control.peer_uid`, the peer-credential reader."""

from __future__ import annotations

import os
import stat
import threading
from pathlib import Path

import pytest

from icgt import control
from icgt.control import ControlError, ControlServer, ensure_private_dir, request

FOREIGN_UID = 65534  # nobody


def _serve(path: Path) -> ControlServer:
    server = ControlServer(path, lambda req: {"ok": True, "echo": req.get("command")})
    server.start()
    return server


def test_the_default_directory_is_created_private(tmp_path: Path) -> None:
    d = tmp_path / "icgt-test"
    ensure_private_dir(d, create=True)
    st = os.lstat(d)
    assert stat.S_IMODE(st.st_mode) == 0o700 and st.st_uid == os.getuid()
    server = _serve(d / "icgt-recorder.sock")
    try:
        assert stat.S_IMODE(os.stat(d / "icgt-recorder.sock").st_mode) == 0o600
        assert request(d / "icgt-recorder.sock", {"command": "status"})["echo"] == "status"
    finally:
        server.stop()


def test_a_foreign_owned_world_writable_directory_is_refused_by_server_and_client(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    d = tmp_path / f"icgt-{os.getuid()}"  # pre-created by someone else, as in the issue
    d.mkdir()
    os.chmod(d, 0o777)
    if os.getuid() == 0:
        os.chown(d, FOREIGN_UID, FOREIGN_UID)  # for real
        owner = FOREIGN_UID
    else:  # without root: this process pretends to be another user
        owner = os.getuid()
        monkeypatch.setattr(control.os, "getuid", lambda: FOREIGN_UID)
    with pytest.raises(ControlError, match=rf"owned by uid {owner}, not by you"):
        _serve(d / "icgt-recorder.sock")
    with pytest.raises(ControlError, match="owned by uid"):
        request(d / "icgt-recorder.sock", {"command": "stop"})


def test_a_directory_others_may_write_in_is_refused(tmp_path: Path) -> None:
    d = tmp_path / "shared"
    d.mkdir()
    os.chmod(d, 0o777)
    with pytest.raises(ControlError, match="mode 0777: group or others may write in it"):
        _serve(d / "icgt-recorder.sock")
    os.chmod(d, 0o755)  # readable is fine: the socket itself is 0600
    server = _serve(d / "icgt-recorder.sock")
    server.stop()


def test_a_symlinked_directory_is_refused(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir(mode=0o700)
    link = tmp_path / "link"
    link.symlink_to(real)
    with pytest.raises(ControlError, match="not a directory"):
        ensure_private_dir(link, create=True)


def test_the_client_refuses_a_server_of_another_uid(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    d = tmp_path / "ctl"
    ensure_private_dir(d, create=True)
    server = _serve(d / "s.sock")
    try:
        real = control.peer_uid

        def fake_peer_uid(sock: object) -> int:  # the client's view of the server only
            if threading.current_thread().name == "icgt-control":
                return real(sock)  # type: ignore[arg-type]
            return FOREIGN_UID

        monkeypatch.setattr(control, "peer_uid", fake_peer_uid)
        with pytest.raises(ControlError, match=rf"served by uid {FOREIGN_UID}, not by you"):
            request(d / "s.sock", {"command": "stop"})
    finally:
        monkeypatch.undo()
        server.stop()


def test_the_server_refuses_a_client_of_another_uid(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    d = tmp_path / "ctl"
    ensure_private_dir(d, create=True)
    seen: list[object] = []
    server = ControlServer(d / "s.sock", lambda req: seen.append(req) or {"ok": True})
    server.start()
    try:
        me = os.getuid()

        def fake_peer_uid(sock: object) -> int:  # the server thread sees a stranger; the client sees us
            return FOREIGN_UID if threading.current_thread().name == "icgt-control" else me

        monkeypatch.setattr(control, "peer_uid", fake_peer_uid)
        with pytest.raises(ControlError, match=rf"uid {FOREIGN_UID} may not control this recorder"):
            request(d / "s.sock", {"command": "stop"})
        assert seen == [], "the handler never ran"
    finally:
        monkeypatch.undo()
        server.stop()
