"""The wheel, built as a user would build it, installed into a fresh venv: `icgt sim` and `icgt demo` work.

One module-scoped fixture builds the wheel from host/ with scikit-build-core (CMake compiles the
simulated device program into it; the CMake build folder build/wheel is kept, so a second run
recompiles nothing) and installs it into a new venv with nothing else of the checkout: the
dependencies come from the package index through pip's cache. The commands then run from a
folder outside the repository, without $ICGT_SIM_DEVICE or PYTHONPATH, so everything they find
comes from the installed package:

- the wheel's contents: the device program, the scenarios, the ROS message file, LICENSE and the
  SPDX licence expression in its metadata;
- `icgt --version`, and -v/-q after the subcommand;
- `icgt sim hover --duration 4` (a packaged scenario by name) runs the packaged device and writes
  the truth files;
- `icgt demo --scenario wheel_flight.toml` flies a 12 s flight end to end (recorder, ground
  station, camera card) and says OK;
- the sdist carries the C++ sources CMake needs (a wheel built from it compiles them under cpp/).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent


def _run(argv: list[str | Path], *, timeout: float, **kw: Any) -> subprocess.CompletedProcess[str]:
    out = subprocess.run([str(a) for a in argv], capture_output=True, text=True, timeout=timeout, check=False, **kw)
    assert out.returncode == 0, f"{argv}: exit {out.returncode}\n{out.stdout[-3000:]}\n{out.stderr[-3000:]}"
    return out


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Installed:
    def __init__(self, wheel: Path, venv: Path, workdir: Path) -> None:
        self.wheel, self.venv, self.workdir = wheel, venv, workdir
        self.env = {k: v for k, v in os.environ.items() if k not in ("ICGT_SIM_DEVICE", "PYTHONPATH", "VIRTUAL_ENV")}
        self.env["PATH"] = f"{venv / 'bin'}{os.pathsep}{self.env.get('PATH', '')}"

    def run(self, *argv: str | Path, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        return _run([self.venv / "bin" / str(argv[0]), *argv[1:]], timeout=timeout, cwd=self.workdir, env=self.env)


@pytest.fixture(scope="module")
def installed(tmp_path_factory: pytest.TempPathFactory) -> Installed:
    tmp = tmp_path_factory.mktemp("wheel")
    dist = tmp / "dist"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check"]
    # scikit-build-core is in the dev venv (host[dev]): no isolated build environment to download each run
    _run([*pip, "wheel", "--no-build-isolation", "--no-deps", "--quiet", "-w", dist, ROOT / "host"], timeout=1200)
    (wheel,) = dist.glob("icgt-*.whl")
    venv = tmp / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", venv], timeout=120)
    # this venv's pip installs into the fresh one (`--python`): the same pip cache serves the dependencies;
    # no byte-compiling of every dependency (2/3 of the install's CPU time; Python compiles what it imports)
    _run([*pip, "--python", venv / "bin" / "python", "install", "--quiet", "--no-compile", wheel], timeout=1200)
    workdir = tmp / "work"  # outside the repository: nothing resolves relative to the checkout
    workdir.mkdir()
    return Installed(wheel, venv, workdir)


def test_wheel_contents_and_metadata(installed: Installed) -> None:
    assert installed.wheel.name.endswith("-py3-none-linux_x86_64.whl")  # a program inside, for any Python 3
    with zipfile.ZipFile(installed.wheel) as whl:
        names = set(whl.namelist())
        info = next(n for n in names if n.endswith(".dist-info/METADATA"))
        metadata = whl.read(info).decode()
        device = whl.getinfo("icgt/sim/bin/icgt-sim-device")
    assert device.external_attr >> 16 & 0o111, "the device program must be executable"
    assert {"icgt/sim/scenarios/pier_scan.toml", "icgt/sim/scenarios/hover.toml"} <= names
    assert "icgt/export/msg/FrameRecord.msg" in names
    assert any(n.endswith(".dist-info/licenses/LICENSE") for n in names)
    assert "License-Expression: Apache-2.0" in metadata.splitlines()
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]


def test_installed_package_uses_its_own_files(installed: Installed) -> None:
    code = (
        "import json, icgt, icgt.sim.scenario as s, icgt.sim.session as d;"
        "print(json.dumps([icgt.__file__, str(s.SCENARIO_DIR), str(d.find_device_binary())]))"
    )
    init, scenarios, device = json.loads(installed.run("python", "-c", code).stdout)
    site = installed.venv / "lib"
    for path in (init, scenarios, device):
        assert Path(path).is_relative_to(site), path
    assert installed.run("icgt", "--version").stdout.startswith("icgt 0.1.0, protocol version")
    assert installed.run("icgt", "version", "-q").returncode == 0


def test_icgt_sim_runs_a_packaged_scenario(installed: Installed) -> None:
    out = installed.workdir / "sim"
    ports = ["--mavlink-port", str(_free_udp_port()), "--gcs-port", str(_free_udp_port())]
    run = installed.run("icgt", "sim", "hover", "--duration", "4", "--out", out, *ports, timeout=120)
    assert "scenario hover" in run.stdout and "icgt record --device" in run.stdout
    assert (out / "sensor_truth.csv").stat().st_size > 0
    assert (out / "truth_clocks.jsonl").exists()


def test_icgt_demo_flies_from_the_wheel(installed: Installed) -> None:
    out = installed.workdir / "demo"
    run = installed.run("icgt", "demo", "--scenario", HERE / "wheel_flight.toml", "--out", out, timeout=300)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["ok"], run.stdout
    assert "demo OK" in run.stdout
    # ~12 at 2 fps for 6 s; on a loaded machine the ground station's start arrives late and fewer are taken
    assert summary["camera_card_images"] >= summary["matched"] >= 1
    assert Path(summary["mcap"]).is_relative_to(out)


def test_sdist_carries_the_cpp_sources(tmp_path: Path) -> None:
    """The sdist holds what CMake needs under cpp/ (a wheel built from it compiles there: pyproject's override)."""
    import tarfile

    code = f"from scikit_build_core.build import build_sdist; print(build_sdist({str(tmp_path)!r}))"
    name = _run([sys.executable, "-c", code], timeout=300, cwd=ROOT / "host").stdout.split()[-1]
    with tarfile.open(tmp_path / name) as sdist:
        names = {n.split("/", 1)[1] for n in sdist.getnames() if "/" in n}
    assert {"cpp/CMakeLists.txt", "cpp/firmware/CMakeLists.txt", "cpp/hil_sim/CMakeLists.txt"} <= names
    assert {"cpp/hil_sim/device/main.cpp", "cpp/hil_sim/scenarios/pier_scan.toml", "LICENSE"} <= names
    assert {"icgt/cli.py", "icgt/export/msg/FrameRecord.msg", "pyproject.toml"} <= names
    assert not [n for n in names if "egg-info" in n or "__pycache__" in n]
