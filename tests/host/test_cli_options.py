"""The command line's global options and the package's metadata (issue 15's packaging list)."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from icgt import __version__
from icgt.cli import build_parser

ROOT = Path(__file__).resolve().parents[2]


def test_version_flag_prints_and_exits_0() -> None:
    out = subprocess.run([sys.executable, "-m", "icgt.cli", "--version"], capture_output=True, text=True, check=False)
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith(f"icgt {__version__}, protocol version ")


@pytest.mark.parametrize(
    ("argv", "level"),
    [
        (["version"], "INFO"),
        (["-v", "version"], "DEBUG"),
        (["version", "-v"], "DEBUG"),
        (["version", "--verbose"], "DEBUG"),
        (["-q", "version"], "WARNING"),
        (["version", "-q"], "WARNING"),
        (["version", "--log-level", "error"], "ERROR"),
        (["--log-level", "debug", "export", "x.mcap", "--out", "o"], "DEBUG"),
        (["export", "x.mcap", "--out", "o", "-q"], "WARNING"),
        (["-q", "version", "-v"], "DEBUG"),  # the later one wins
    ],
)
def test_logging_options_anywhere(argv: list[str], level: str) -> None:
    assert build_parser().parse_args(argv).log_level == level


def test_bad_log_level_is_refused(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        build_parser().parse_args(["version", "--log-level", "loud"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_license_file_and_spdx_string() -> None:
    project = tomllib.loads((ROOT / "host" / "pyproject.toml").read_text())["project"]
    assert project["license"] == "Apache-2.0"
    for path in (ROOT / "LICENSE", ROOT / "host" / "LICENSE"):
        text = path.read_text()
        assert "Apache License" in text and "Version 2.0, January 2004" in text
        assert "END OF TERMS AND CONDITIONS" in text


def test_readme_is_self_contained() -> None:
    readme = (ROOT / "README.md").read_text()
    assert "../" not in readme
    assert "bash .ci/run" in readme
    assert "`make`" in readme
