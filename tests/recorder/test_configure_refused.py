"""A CONFIGURE the device refuses is never recorded through with the device's old settings.

Against the simulated device program (the real firmware core): a board whose BNO055 does not answer
refuses CONFIGURE naming imu_missing, and the recorder records without the IMU and says so; a board
with no feedback line refuses the configured feedback, and the recorder does not start (no file left).
"""

from __future__ import annotations

import logging
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from icgt.recorder import Recorder
from icgt.recorder.capture import ConfigureRefusedError
from icgt.recorder.config import RecorderConfig, parse_config
from icgt.sim.recorder_setup import free_udp_port
from icgt.sim.scenario import load_scenario
from icgt.sim.session import find_device_binary
from icgt.sim.truth import write_sensor_truth

SCENARIO = Path(__file__).parents[1] / "e2e" / "short_flight.toml"


@contextmanager
def sim_device(tmp_path: Path, *flags: str) -> Iterator[str]:
    truth = tmp_path / "sensor_truth.csv"
    write_sensor_truth(load_scenario(SCENARIO), truth)
    cmd = [str(find_device_binary()), "--truth", str(truth), "--t0-monotonic-ns", str(time.monotonic_ns()),
           "--link", f"pty:{tmp_path / 'device'}", *flags]  # fmt: skip
    with (tmp_path / "device.log").open("wb") as err:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=err)
        try:
            assert proc.stdout is not None
            first = proc.stdout.readline().decode().strip()
            assert first.startswith("link: "), first
            yield first.removeprefix("link: ")
        finally:
            proc.terminate()
            proc.wait(timeout=10)


def _config(tmp_path: Path, device: str) -> RecorderConfig:
    return parse_config(
        {
            "device": {"url": device, "wait_s": 5.0},
            "mavlink": {"url": f"udpin:127.0.0.1:{free_udp_port()}"},
            "output": {"dir": str(tmp_path / "rec")},
        },
        "test.toml",
    )


def test_a_sensor_that_does_not_answer_is_switched_off_loudly(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with sim_device(tmp_path, "--no-imu") as url:
        time.sleep(1.5)  # the driver gives the part up as absent after its boot timeout
        rec = Recorder(_config(tmp_path, url))
        with caplog.at_level(logging.WARNING, logger="icgt.recorder"):
            rec.start()
            rec.stop()
    assert rec.capture.sensors.imu_rate_hz == 0
    assert any(
        "limit imu_missing" in r.getMessage() and "recording without it" in r.getMessage() for r in caplog.records
    )


def test_feedback_asked_for_on_a_board_without_the_line_stops_the_start(tmp_path: Path) -> None:
    with sim_device(tmp_path, "--no-feedback") as url:
        rec = Recorder(_config(tmp_path, url))
        with pytest.raises(ConfigureRefusedError, match=r"feedback_line_missing.*not recording with the device's"):
            rec.start()
    assert not list((tmp_path / "rec").glob("*.mcap")), "a start that fails leaves no file"
