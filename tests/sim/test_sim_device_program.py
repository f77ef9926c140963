"""The simulated device program seen from the host, exactly as the recorder sees a real board:
the expected stream for a capture, link impairments the decoder survives, an unplug, and
`icgt sim` stopping cleanly on Ctrl-C."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest
import serial

from icgt.protocol import StreamDecoder, encode_frame
from icgt.protocol.codec import Received
from icgt.protocol.messages import Exposure, Hello, Imu, Range, StartCapture, Status
from icgt.sim.session import find_device_binary

OFFSET_US = 5_000_000
DRIFT_PPM = 50.0


class Device:
    def __init__(self, tmp: Path) -> None:
        self.t0 = time.monotonic_ns()
        self.control = tmp / "ctl.sock"
        self.proc = subprocess.Popen(
            [str(find_device_binary()), "--link", f"pty:{tmp / 'dev'}", "--t0-monotonic-ns", str(self.t0),
             "--device-offset-us", str(OFFSET_US), "--device-drift-ppm", str(DRIFT_PPM),
             "--control", str(self.control), "--seed", "3"],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        assert self.proc.stdout is not None
        self.url = self.proc.stdout.readline().decode().strip().removeprefix("link: ")
        self.port = serial.serial_for_url(self.url, timeout=0.05)
        self.decoder = StreamDecoder()
        self.seq = 0

    def device_us_at(self, host_ns: int) -> float:
        return OFFSET_US + (host_ns - self.t0) / 1000.0 * (1 + DRIFT_PPM * 1e-6)

    def send(self, msg: StartCapture) -> None:
        self.port.write(encode_frame(msg, self.seq))
        self.seq += 1

    def read_for(self, seconds: float) -> Iterator[tuple[Received, int]]:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            data = self.port.read(1)  # returns as soon as a byte is there
            waiting = self.port.in_waiting
            # Stamped after counting what is there: every byte read below arrived before `now`
            # (stamping before the count would date bytes that arrived meanwhile too early, by
            # as long as this process was descheduled in between).
            now = time.monotonic_ns()
            data += self.port.read(waiting)
            for r in self.decoder.feed(data):
                yield r, now

    def command(self, line: str) -> str:
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.connect(str(self.control))
            s.sendall(line.encode() + b"\n")
            return s.makefile().readline().strip()

    def close(self) -> None:
        self.port.close()
        self.proc.terminate()
        self.proc.wait(timeout=5)


@pytest.fixture
def device(tmp_path: Path) -> Iterator[Device]:
    d = Device(tmp_path)
    yield d
    d.close()


def test_capture_stream_has_the_rates_gapless_indices_and_the_simulated_clock(device: Device) -> None:
    list(device.read_for(1.6))  # boot: the BNO055 takes ~1.4 s
    device.send(StartCapture(mode=1, interval_us=200_000, shutter_pulse_us=20_000))
    got: list[tuple[Received, int]] = list(device.read_for(5.0))
    # Rates counted on the device's own clock over the 4 s after the first trigger (read on until the stream
    # has passed it): what a loaded host read in 5 s of its own time includes the boot's backlog or not.
    first = next(r.message.trigger_t_us for r, _ in got if isinstance(r.message, Exposure))
    end = first + 4_000_000

    def stamp(m: object) -> int | None:
        if isinstance(m, Exposure):
            return m.trigger_t_us
        if isinstance(m, Imu):
            return m.read_start_t_us
        if isinstance(m, Range):
            return m.acq_start_t_us
        return m.t_us if isinstance(m, Status) else None

    deadline = time.monotonic() + 30.0
    while max((stamp(r.message) or 0) for r, _ in got) < end + 100_000 and time.monotonic() < deadline:
        got += list(device.read_for(0.5))
    kinds = Counter(r.message.NAME for r, _ in got if first <= (stamp(r.message) or -1) < end)
    assert kinds["EXPOSURE"] == 20  # 5 fps
    assert 396 <= kinds["IMU"] <= 404  # 100 Hz
    assert 792 <= kinds["RANGE"] <= 808  # the firmware default 200 Hz: what a LIDAR-Lite v3 delivers
    assert 3 <= kinds["STATUS"] <= 5  # 1 Hz
    indices = [r.message.image_index for r, _ in got if isinstance(r.message, Exposure)]
    assert indices == list(range(indices[0], indices[0] + len(indices)))
    assert device.decoder.stats.seq_missed == 0 and device.decoder.stats.rejected == 0
    # The device clock the simulator runs (offset and drift given above) as the host sees it: no
    # message arrives before its device stamp, and in every half second the earliest arrival is
    # within the link's latency. Only the lower envelope is bounded from above: a reader that the
    # shared machine descheduled for a while receives late, which says nothing about the clock.
    lowest_lag_us: dict[int, float] = {}
    for r, host_ns in got:
        m = r.message
        t = m.t_us if isinstance(m, Status) else m.read_end_t_us if isinstance(m, Imu) else None
        if isinstance(m, Range):
            t = m.read_t_us
        if t is not None:
            lag_us = device.device_us_at(host_ns) - t
            assert lag_us >= -100, (m.NAME, lag_us)  # never received before it was stamped
            window = int(t // 500_000)
            lowest_lag_us[window] = min(lag_us, lowest_lag_us.get(window, float("inf")))
    assert len(lowest_lag_us) >= 9
    assert all(lag <= 20_000 for lag in lowest_lag_us.values()), lowest_lag_us


def test_impaired_link_is_seen_by_the_decoder_which_recovers(device: Device) -> None:
    list(device.read_for(1.6))
    assert device.command("impair drop=0.002 flip=0.002") == "ok"
    list(device.read_for(3.0))
    stats = device.decoder.stats
    assert stats.rejected > 10 and stats.seq_missed > 10
    assert device.command("impair drop=0 flip=0") == "ok"
    list(device.read_for(0.5))
    before = (stats.rejected, stats.seq_missed)
    clean = list(device.read_for(2.0))
    assert len(clean) > 500  # IMU 100 Hz + RANGE 200 Hz (the firmware defaults) for 2 s
    assert (stats.rejected, stats.seq_missed) == before


def test_unplug_makes_the_port_fail_and_replug_brings_it_back(device: Device) -> None:
    list(device.read_for(0.5))
    assert device.command("disconnect 1.0") == "ok"
    with pytest.raises(serial.SerialException):
        for _ in range(50):
            device.port.read(4096)
            time.sleep(0.02)
    device.port.close()
    deadline = time.monotonic() + 5
    while True:
        try:
            device.port = serial.serial_for_url(device.url, timeout=0.05)
            break
        except serial.SerialException:
            assert time.monotonic() < deadline
            time.sleep(0.1)
    got = [r.message for r, _ in device.read_for(1.0)]
    assert any(isinstance(m, Hello) for m in got), "a replugged device says HELLO again"


def test_icgt_sim_stops_cleanly_on_ctrl_c_leaving_no_process(tmp_path: Path) -> None:
    out = tmp_path / "simout"
    proc = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "sim", "hover", "--out", str(out), "--mavlink-port", "0",
         "--gcs-port", "0"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    lines = [proc.stdout.readline() for _ in range(3)]
    assert any("icgt record --device" in line for line in lines), lines
    time.sleep(2.0)
    proc.send_signal(signal.SIGINT)
    rest, _ = proc.communicate(timeout=30)
    assert proc.returncode == 0, rest
    assert "truth written" in rest
    leftovers = subprocess.run(["pgrep", "-f", str(out)], capture_output=True, text=True).stdout.split()
    assert [p for p in leftovers if int(p) != os.getpid()] == []
    assert (out / "truth_exposures.jsonl").exists() and (out / "card").is_dir()
