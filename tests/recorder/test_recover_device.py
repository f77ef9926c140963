"""`icgt recover-device` refuses clearly (exit 1, what was asked and what was found): no device, a device from
another flight or another boot, nothing left in the device's history. The fetch itself, against a flight
that ended mid-outage: tests/e2e/test_host_silence.py."""

from __future__ import annotations

import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from icgt.cli import main
from icgt.protocol.messages import DeviceState, Hello
from icgt.recorder.flight_log import FlightLog
from icgt.recorder.recover_device import RecoverDeviceError, _check_flight, _first_wanted
from icgt.sim.session import find_device_binary


def _flight(**kw: object) -> FlightLog:
    base: dict[str, object] = dict(
        path=Path("icgt_20261203T100000Z.mcap"), recording_id=0x1234ABCD, serial_number=85590017,
        rtc_utc_us_at_boot=None, last_seq=5000, last_t_us=60_000_000,
    )  # fmt: skip
    base.update(kw)
    return FlightLog(**base)  # type: ignore[arg-type]


HELLO = Hello(serial_number=85590017)
STATE = DeviceState(t_us=90_000_000, next_seq=9000, history_first_seq=0, recording_id=0x1234ABCD)


def test_the_flights_own_device_passes() -> None:
    _check_flight(_flight(), HELLO, STATE)
    _check_flight(_flight(recording_id=None), HELLO, DeviceState(t_us=90_000_000, next_seq=9000))  # protocol 1 log


@pytest.mark.parametrize(
    ("flight", "hello", "state", "said"),
    [
        (_flight(), Hello(serial_number=7), STATE, "device from another flight: asked for the flight of "
         "icgt_20261203T100000Z.mcap (device serial 85590017), found device serial 7"),
        (_flight(), HELLO, DeviceState(t_us=90_000_000, next_seq=9000, recording_id=0x99),
         "(recording 0x1234ABCD), the device's last host logged recording 0x00000099"),
        (_flight(), HELLO, DeviceState(t_us=2_000_000, next_seq=40, recording_id=0),
         "the device restarted since the flight of icgt_20261203T100000Z.mcap: its sequence is at 40"),
        (_flight(last_seq=10), HELLO, DeviceState(t_us=2_000_000, next_seq=40),
         "its clock reads 2.0 s, the log reached 60.0 s"),
    ],
)  # fmt: skip
def test_a_device_of_another_flight_or_boot_is_refused_naming_both(
    flight: FlightLog, hello: Hello, state: DeviceState, said: str
) -> None:
    with pytest.raises(RecoverDeviceError) as exc:
        _check_flight(flight, hello, state)
    assert said in str(exc.value)


def test_the_fetch_starts_where_the_flight_log_stops() -> None:
    marked = DeviceState(next_seq=9000, host_received_valid=1, host_received_seq=4000, history_first_seq=100)
    assert _first_wanted(_flight(), marked) == 4000  # the mark is earlier: the overlap is merge-checked
    assert _first_wanted(_flight(last_seq=3000), marked) == 3001
    assert _first_wanted(None, DeviceState(next_seq=9000, history_first_seq=100)) == 100  # all the ring knows
    old = DeviceState(next_seq=9000, host_received_valid=1, host_received_seq=50, history_first_seq=100)
    assert _first_wanted(None, old) == 100  # not older than the ring knows


def test_no_device_is_said(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["recover-device", "--device", str(tmp_path / "ttyACM9")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("icgt: no device: device ") and "does not exist" in err


def test_a_flight_log_that_is_not_there_is_said(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "x.mcap"
    assert main(["recover-device", "--device", str(tmp_path / "ttyACM9"), "--flight", str(missing)]) == 1
    assert capsys.readouterr().err.strip() == f"icgt: --flight {missing}: no such file"


@pytest.fixture
def bare_device(tmp_path: Path) -> Iterator[str]:
    """The simulated device without IMU and LiDAR, never captured: its history holds no frame worth resending."""
    proc = subprocess.Popen(
        [str(find_device_binary()), "--link", f"pty:{tmp_path / 'dev'}", "--no-imu", "--no-lidar"],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    assert proc.stdout is not None
    url = proc.stdout.readline().decode().strip().removeprefix("link: ")
    try:
        yield url
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_nothing_left_in_the_ring_is_said_with_what_was_asked(
    bare_device: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "recovered.mcap"
    assert main(["recover-device", "--device", bare_device, "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("icgt: nothing left in the device's history for the flight of its last host: asked for "
                          "device frames 0..")  # fmt: skip
    assert "status/replies/logs" in err
    assert not out.exists()  # nothing claimed, nothing written
