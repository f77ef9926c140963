"""Bad input on the command line (issue 30, part 5): one line naming what is wrong, exit 1, never a traceback."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from icgt.cli import main
from icgt.control import ControlError, ControlServer, request


def _one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("icgt: "), err
    assert "Traceback" not in err
    return lines[0]


def test_a_binary_scenario_file_is_named_not_a_unicode_traceback(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    binary = tmp_path / "flight.toml"
    binary.write_bytes(b"\x00\xff")
    assert main(["-q", "sim", str(binary), "--out", str(tmp_path / "out")]) == 1
    line = _one_line_error(capsys)
    assert str(binary) in line and "not UTF-8 text" in line and "0xff at offset 1" in line, line


@pytest.mark.parametrize(
    ("option", "value", "words"),
    [
        ("--duration", "-1", "--duration -1.0: a duration is a finite number of seconds greater than 0"),
        ("--duration", "0", "--duration 0.0: a duration is"),
        ("--duration", "nan", "--duration nan: a duration is"),
        ("--duration", "inf", "--duration inf: a duration is"),
        ("--mavlink-port", "99999", "--mavlink-port 99999: a port is a number from 1 to 65535"),
        ("--mavlink-port", "65536", "--mavlink-port 65536: a port is"),
        ("--gcs-port", "-5", "--gcs-port -5: a port is"),
    ],
)
def test_sim_refuses_a_bad_duration_or_port_before_it_starts(
    option: str, value: str, words: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    assert main(["-q", "sim", "hover", "--out", str(out), option, value]) == 1
    assert words in _one_line_error(capsys)
    assert not out.exists()  # refused before anything ran


def test_record_refuses_a_live_port_out_of_range(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["-q", "record", "--live", "70000", "--out", str(tmp_path), "--socket", str(tmp_path / "s")]) == 1
    assert "--live 70000: a port is a number from 1 to 65535" in _one_line_error(capsys)


def test_a_socket_path_too_long_for_a_unix_socket_is_refused_naming_its_length(tmp_path: Path) -> None:
    long_path = tmp_path / ("d" * 60) / ("s" * 60 + ".sock")
    size = len(str(long_path))
    assert size > 108
    out = subprocess.run(
        [sys.executable, "-m", "icgt.cli", "-q", "record", "--device", "/dev/null/none", "--mavlink",
         "udpin:127.0.0.1:1", "--out", str(tmp_path / "out"), "--socket", str(long_path)],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert out.returncode == 1, out.stderr
    lines = [line for line in out.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, out.stderr
    assert f"control socket path '{long_path}' is {size} bytes long" in lines[0], lines[0]
    assert "at most 107: choose a shorter --socket" in lines[0]
    # the clients (icgt start/stop/status) say the same, rather than "not answering: AF_UNIX path too long"
    with pytest.raises(ControlError, match=f"is {size} bytes long"):
        request(long_path, {"command": "status"})
    with pytest.raises(ControlError, match=f"is {size} bytes long"):
        ControlServer(long_path, lambda r: r).start()
