"""The companion-computer files in deploy/: configuration, systemd unit and udev rule agree and are valid.

- recorder.toml loads through the recorder's own schema (every range checked) and writes where the
  unit's StateDirectory is;
- icgt-recorder@.service passes `systemd-analyze verify` (Debian's systemd) with no complaint, once
  for an instance, its ExecStart pointing at this venv's `icgt`; the command line is one that
  `icgt record` accepts;
- 99-icgt.rules is well-formed udev syntax, matches the Teensy's USB ids and names the port the
  way the unit opens it.
"""

from __future__ import annotations

import configparser
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from icgt.cli import build_parser
from icgt.recorder import load_config

ROOT = Path(__file__).resolve().parents[2]
DEPLOY = ROOT / "deploy"
UNIT = DEPLOY / "icgt-recorder@.service"
RULES = DEPLOY / "99-icgt.rules"
INSTALLED_ICGT = "/opt/icgt/venv/bin/icgt"
SERIAL = "12345670"  # a Teensy-style USB serial number


def _unit() -> configparser.ConfigParser:
    unit = configparser.ConfigParser(interpolation=None, strict=True)
    unit.optionxform = str  # type: ignore[assignment,method-assign]  # systemd keys are case-sensitive
    unit.read_string(UNIT.read_text())
    return unit


def _exec_start(serial: str) -> list[str]:
    return shlex.split(_unit()["Service"]["ExecStart"].replace("%i", serial))


def test_example_config_loads_and_writes_to_the_state_directory() -> None:
    config = load_config(DEPLOY / "recorder.toml")
    state = _unit()["Service"]["StateDirectory"]
    assert config.output.dir == Path("/var/lib") / state
    assert config.device.wait_s >= 30.0  # the board may enumerate after the service starts
    assert config.camera.lever_arm_body_m == (0.10, 0.0, 0.05)


def test_unit_command_is_accepted_by_icgt_record() -> None:
    argv = _exec_start(SERIAL)
    assert argv[0] == INSTALLED_ICGT
    args = build_parser().parse_args(argv[1:])
    assert args.command == "record"
    assert args.device == f"/dev/icgt-{SERIAL}"
    assert args.config == Path("/etc/icgt/recorder.toml")
    assert args.socket == Path(f"/run/icgt/{SERIAL}.sock")
    assert args.socket.parent == Path("/run") / _unit()["Service"]["RuntimeDirectory"]


def test_unit_passes_systemd_analyze_verify(tmp_path: Path) -> None:
    analyze = shutil.which("systemd-analyze")
    assert analyze, "systemd-analyze is missing: install Debian's systemd package (.ci/run does)"
    icgt = Path(sys.executable).parent / "icgt"
    assert icgt.is_file(), icgt
    text = UNIT.read_text().replace(INSTALLED_ICGT, str(icgt))
    instance = tmp_path / f"icgt-recorder@{SERIAL}.service"
    instance.write_text(text)
    (tmp_path / UNIT.name).write_text(text)
    out = subprocess.run([analyze, "verify", str(instance)], capture_output=True, text=True, check=False, timeout=60)
    # verify exits 0 on unknown keys or bad values and only says so: any message is a defect of the unit
    complaints = [line for line in out.stderr.splitlines() if str(tmp_path) in line or "icgt" in line]
    assert out.returncode == 0 and not complaints, out.stderr


def test_unit_verify_catches_a_broken_unit(tmp_path: Path) -> None:
    """The check above can fail: a misspelt key in the same unit is reported."""
    analyze = shutil.which("systemd-analyze")
    assert analyze
    text = UNIT.read_text().replace(INSTALLED_ICGT, str(Path(sys.executable).parent / "icgt"))
    instance = tmp_path / f"icgt-recorder@{SERIAL}.service"
    instance.write_text(text.replace("RestartSec=", "RestartSecs="))
    out = subprocess.run([analyze, "verify", str(instance)], capture_output=True, text=True, check=False, timeout=60)
    assert "RestartSecs" in out.stderr


# udev rule syntax (udev(7)): comma-separated KEY[{attribute}]OP"value" pairs on one line
_PAIR = re.compile(r'\s*(?P<key>[A-Z_]+)(?:\{(?P<attr>[^}]+)\})?(?P<op>==|!=|\+=|-=|:=|=)"(?P<value>[^"]*)"\s*(?:,|$)')
_MATCH_KEYS = {"SUBSYSTEM", "SUBSYSTEMS", "KERNEL", "KERNELS", "ATTR", "ATTRS", "ENV", "DRIVERS", "ACTION", "TAG"}
_ASSIGN_KEYS = {"SYMLINK", "GROUP", "MODE", "OWNER", "ENV", "TAG", "RUN"}


def _rules() -> list[list[tuple[str, str | None, str, str]]]:
    rules = []
    for line in RULES.read_text().splitlines():
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        pairs, pos = [], 0
        while pos < len(line):
            m = _PAIR.match(line, pos)
            assert m, f"{RULES.name}: not udev syntax at column {pos}: {line[pos:]!r}"
            pairs.append((m["key"], m["attr"], m["op"], m["value"]))
            pos = m.end()
        rules.append(pairs)
    return rules


def test_udev_rule_names_the_teensy_by_its_serial() -> None:
    (rule,) = _rules()
    for key, _, op, _ in rule:
        assert key in (_MATCH_KEYS if op in ("==", "!=") else _ASSIGN_KEYS), (key, op)
    matches = {(k, a): v for k, a, op, v in rule if op == "=="}
    assert matches[("SUBSYSTEM", None)] == "tty"
    assert matches[("ENV", "ID_VENDOR_ID")] == "16c0"  # PJRC's Teensy USB serial
    assert matches[("ENV", "ID_MODEL_ID")] == "0483"
    (symlink,) = [v for k, _, op, v in rule if k == "SYMLINK" and op in ("+=", "=")]
    # the unit opens /dev/icgt-%i: the same name with the instance in place of the serial number
    device = _exec_start(SERIAL)[_exec_start(SERIAL).index("--device") + 1]
    assert "/dev/" + symlink.replace("$env{ID_SERIAL_SHORT}", SERIAL) == device
    assert ("GROUP", None, "=", "dialout") in rule
    assert ("ENV", "ID_MM_DEVICE_IGNORE", "=", "1") in rule


@pytest.mark.parametrize("bad", ['SUBSYSTEM=="tty" SYMLINK+="x"', 'SUBSYSTEM=="tty", SYMLINK+=x'])
def test_udev_parser_refuses_bad_syntax(bad: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = tmp_path / "bad.rules"
    path.write_text(bad + "\n")
    monkeypatch.setattr(sys.modules[__name__], "RULES", path)
    with pytest.raises(AssertionError, match="not udev syntax"):
        _rules()
