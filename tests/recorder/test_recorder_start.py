"""Starting the recorder on a bad day: a device not there yet, a device held by another program, a bad --out;
no start that fails leaves a file behind."""

from __future__ import annotations

import os
import time
from pathlib import Path

import msgspec
import pytest

from icgt.device import DeviceAbsentError, DeviceBusyError
from icgt.device.port import open_port
from icgt.recorder import Recorder, RecorderConfig
from icgt.recording import RecordingError


def _config(tmp_path: Path, device: str, wait_s: float) -> RecorderConfig:
    cfg = RecorderConfig().with_overrides(device_url=device, mavlink_url="udpin:127.0.0.1:0", out_dir=tmp_path / "out")
    return msgspec.structs.replace(cfg, device=msgspec.structs.replace(cfg.device, wait_s=wait_s))


def test_a_device_that_never_appears_is_waited_for_then_a_clear_error_and_no_file(tmp_path: Path) -> None:
    rec = Recorder(_config(tmp_path, str(tmp_path / "ttyACM9"), wait_s=1.0), control_socket=tmp_path / "c.sock")
    started = time.monotonic()
    with pytest.raises(DeviceAbsentError, match=r"ttyACM9 does not exist .*waited 1 s"):
        rec.start()
    assert time.monotonic() - started >= 0.9
    assert list((tmp_path / "out").iterdir()) == []
    assert not (tmp_path / "c.sock").exists()


def test_status_says_waiting_while_the_device_is_not_there(tmp_path: Path) -> None:
    import threading

    from icgt.control import request

    sock = tmp_path / "c.sock"
    rec = Recorder(_config(tmp_path, str(tmp_path / "ttyACM9"), wait_s=3.0), control_socket=sock)
    errors: list[BaseException] = []

    def start() -> None:
        try:
            rec.start()
        except DeviceAbsentError as exc:
            errors.append(exc)

    t = threading.Thread(target=start, daemon=True)
    t.start()
    deadline = time.monotonic() + 2.0
    status = None
    while time.monotonic() < deadline:
        if sock.exists():
            status = request(sock, {"command": "status"})["status"]
            if status["waiting_for_device"]:
                break
        time.sleep(0.05)
    assert status is not None and status["waiting_for_device"] and not status["device_connected"]
    t.join(5.0)
    assert len(errors) == 1


def test_a_port_held_by_another_program_is_a_clear_error(tmp_path: Path) -> None:
    master, slave = os.openpty()
    try:
        path = os.ttyname(slave)
        port = open_port(path, 115200)  # holds the port's exclusive lock, as a running recorder does
        try:
            with pytest.raises(DeviceBusyError, match=f"device {path} is in use"):
                open_port(path, 115200)
        finally:
            port.close()
    finally:
        os.close(master)
        os.close(slave)


@pytest.mark.parametrize("problem", ["a file", "read-only parent"])
def test_out_problems_are_clear_errors(tmp_path: Path, problem: str) -> None:
    if problem == "a file":
        out = tmp_path / "flights"
        out.write_text("not a folder")
        match = "exists and is not a folder"
    else:
        if os.geteuid() == 0:
            out = Path("/proc/icgt-flights")  # even root cannot create folders in /proc
        else:
            ro = tmp_path / "ro"
            ro.mkdir(mode=0o500)
            out = ro / "flights"
        match = "cannot create the folder"
    cfg = RecorderConfig().with_overrides(device_url=str(tmp_path / "none"), out_dir=out)
    with pytest.raises(RecordingError, match=match):
        Recorder(cfg).start()
