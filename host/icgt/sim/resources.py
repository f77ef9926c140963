"""Where the simulator's files are: the device program and the scenario files.

Installed from a wheel (host/pyproject.toml builds it with scikit-build-core and CMake), both live
inside the package: ``icgt/sim/bin/icgt-sim-device`` and ``icgt/sim/scenarios/*.toml``. In a
checkout of the repository (``make venv`` installs the package editable, without compiling), they
are the CMake build's program (``build/host/hil_sim/icgt-sim-device``, made by ``make build``) and
``hil_sim/scenarios/``. ``$ICGT_SIM_DEVICE`` names another device program and wins over both.
"""

from __future__ import annotations

import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
"""icgt/sim in site-packages (wheel) or in the checkout's host/ folder (editable install)."""
REPO_ROOT = PACKAGE_DIR.parents[2]
"""The repository root when the package runs from a checkout (meaningless in site-packages)."""
DEVICE_BINARY_ENV = "ICGT_SIM_DEVICE"
DEVICE_PROGRAM = "icgt-sim-device"
PACKAGED_DEVICE = PACKAGE_DIR / "bin" / DEVICE_PROGRAM
BUILT_DEVICE = REPO_ROOT / "build" / "host" / "hil_sim" / DEVICE_PROGRAM
PACKAGED_SCENARIOS = PACKAGE_DIR / "scenarios"
REPO_SCENARIOS = REPO_ROOT / "hil_sim" / "scenarios"


def scenario_dir() -> Path:
    """The packaged scenarios when the wheel installed them, else the repository's."""
    return PACKAGED_SCENARIOS if PACKAGED_SCENARIOS.is_dir() else REPO_SCENARIOS


def device_candidates() -> list[Path]:
    """Where the simulated device program is looked for, in order."""
    env = os.environ.get(DEVICE_BINARY_ENV)
    return ([Path(env)] if env else []) + [PACKAGED_DEVICE, BUILT_DEVICE]
