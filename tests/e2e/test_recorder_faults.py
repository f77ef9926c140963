"""The recorder against the faults that end a recording: kill -9, and a device of another protocol version."""

from __future__ import annotations

import os
import signal
import struct
import subprocess
import sys
import threading
import time
import zlib
from pathlib import Path

import pytest
from cobs import cobs
from mcap.exceptions import EndOfFile
from mcap.reader import make_reader
from mcap.stream_reader import StreamReader

from icgt.control import request
from icgt.recording import recover
from icgt.sim.recorder_setup import free_udp_port, recorder_config_text
from icgt.sim.scenario import load_scenario
from icgt.sim.session import SimSession

SCENARIO = Path(__file__).with_name("short_flight.toml")


def test_kill_9_mid_recording_loses_at_most_one_second(tmp_path: Path) -> None:
    sc = load_scenario(SCENARIO)
    # Held until the recorder is up, so that the kill comes before the scenario's unplug at 8 s however long
    # a loaded machine takes to start it.
    session = SimSession(sc, tmp_path / "sim", mavlink_port=free_udp_port(), gcs_port=free_udp_port(), hold=True)
    urls = session.start()
    rec_dir = tmp_path / "recording"
    config = tmp_path / "recorder.toml"
    config.write_text(recorder_config_text(sc, rec_dir))
    sock = tmp_path / "rec.sock"
    log = (tmp_path / "recorder.log").open("w")
    recorder = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
         "--mavlink", urls.mavlink, "--socket", str(sock)],
        stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 15
        while not sock.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        session.release()
        session.wait_until(1.0)
        request(sock, {"command": "start"})
        time.sleep(5.3)  # mid-chunk, at a time unrelated to the 1 s chunk grid
        killed_at_ns = time.time_ns()
        recorder.send_signal(signal.SIGKILL)
        recorder.wait(timeout=5)
    finally:
        if recorder.poll() is None:
            recorder.kill()
        log.close()
        session.stop()
    (path,) = rec_dir.glob("*.mcap")

    # The official reader streams the unfinished file up to its last complete record, where it
    # meets the end of the file exactly at a record boundary (EndOfFile, not a corrupt record).
    newest = 0
    with path.open("rb") as f, pytest.raises(EndOfFile):
        for record in StreamReader(f, skip_magic=False, emit_chunks=False).records:
            newest = max(newest, getattr(record, "log_time", 0))
    assert newest > 0

    fixed = tmp_path / "recovered.mcap"
    report = recover(path, fixed)
    with fixed.open("rb") as f:
        reader = make_reader(f)
        assert reader.get_summary() is not None
        times = [m.log_time for _, _, m in reader.iter_messages()]
    assert len(times) == report.messages > 1000
    lost_s = (killed_at_ns - max(times)) / 1e9
    assert lost_s <= 1.2, f"{lost_s:.2f} s of data lost (chunks close every 1 s)"
    # The log's clock is host monotonic plus an offset to UTC fixed at start: allow its drift since then.
    assert lost_s > -0.1


def _fake_device(fd: int, version: int, stop: threading.Event) -> None:
    """A device that speaks another protocol version: HELLO frames with version byte `version`."""
    seq = 0
    while not stop.is_set():
        body = struct.pack("<BIQ16sBIBqB", version, 0x1234, seq, b"9.9.9", 2, 42, 1, 0, 0)
        raw = struct.pack("<BBBBI", version, 0x01, 0, 0, seq) + body
        frame = cobs.encode(raw + struct.pack("<I", zlib.crc32(raw))) + b"\x00"
        try:
            os.write(fd, frame)
        except OSError:
            return
        seq += 1
        stop.wait(0.2)


@pytest.mark.parametrize("version", [1, 3, 0])  # 1: a device flashed before the sensor snapshot
def test_a_device_of_another_protocol_version_is_a_clear_error(tmp_path: Path, version: int) -> None:
    master, slave = os.openpty()
    stop = threading.Event()
    t = threading.Thread(target=_fake_device, args=(master, version, stop), daemon=True)
    t.start()
    try:
        out = subprocess.run(
            [sys.executable, "-m", "icgt.cli", "record", "--device", os.ttyname(slave), "--mavlink",
             f"udpin:127.0.0.1:{free_udp_port()}", "--out", str(tmp_path), "--socket", str(tmp_path / "s.sock")],
            capture_output=True, text=True, timeout=30,
        )  # fmt: skip
    finally:
        stop.set()
        t.join()
        os.close(master)
        os.close(slave)
    assert out.returncode == 1
    assert f"device speaks protocol version {version}, this host speaks version 2" in out.stderr
    assert "Traceback" not in out.stderr
