"""Shared fixtures: where the C++ build lives (the Makefile builds it before pytest runs)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

ROOT = Path(__file__).resolve().parent.parent

# Property tests draw the same examples on every run ("deterministic": make test and CI give one answer);
# ICGT_HYPOTHESIS=explore draws new ones each run to hunt for fresh counterexamples (then add the one found
# as an explicit case). The examples depend on the Hypothesis version as well as on the test's source: dev
# pins it exactly (host/pyproject.toml), so a fresh CI install draws what a local run draws. Explore found
# the firmware's wrapping seq_missed counter (SPEC.md §3).
settings.register_profile("deterministic", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("ICGT_HYPOTHESIS", "deterministic"))


@pytest.fixture(scope="session")
def build_dir() -> Path:
    path = Path(os.environ.get("ICGT_BUILD_DIR", ROOT / "build" / "host"))
    if not path.is_absolute():
        path = ROOT / path
    return path


@pytest.fixture(scope="session")
def cpp_vector_runner(build_dir: Path) -> Path:
    runner = build_dir / "firmware" / "icgt-vector-runner"
    if not runner.exists():
        pytest.fail(f"{runner} is missing: build the C++ side first (make build, or make test)")
    return runner


@pytest.fixture(scope="session")
def export_flight(tmp_path_factory: pytest.TempPathFactory) -> object:
    """One flight of tests/export/export_flight.toml (~25 s) shared by the ros2, GIS and report tests."""
    from icgt.demo import fly
    from icgt.sim.scenario import load_scenario

    return fly(load_scenario(ROOT / "tests" / "export" / "export_flight.toml"), tmp_path_factory.mktemp("flight"))


@pytest.fixture(autouse=True, scope="session")
def _match_cache(tmp_path_factory: pytest.TempPathFactory) -> None:
    """Matches kept by `icgt match` for `icgt export` go to a per-session folder, never the user's cache."""
    os.environ["ICGT_MATCH_CACHE"] = str(tmp_path_factory.mktemp("match_cache"))


# Directories whose test files share one session fixture (a simulated flight flown once): under pytest-xdist
# their files go to one worker, so the flight is flown once, not once per worker.
_SHARED_FLIGHT_DIRS = {
    "ingest": "ingest_flight",
    "export": "export_flight",
    "report": "export_flight",
    "mapping": "damage_flight",
    "trajectories": "trajectory_flight",
}


def pytest_configure(config: pytest.Config) -> None:
    # declared here too: the lower-bound venv (.ci/min_versions.sh) runs without pytest-xdist
    config.addinivalue_line("markers", "xdist_group(name): tests run on one pytest-xdist worker (--dist loadgroup)")


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the groups into the test ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """xdist groups (`make test` runs `--dist loadgroup`): a module's tests stay together (its module-scoped
    flight is flown once), and the modules of a directory that shares a session flight stay together."""
    for item in items:
        rel = Path(str(item.fspath)).resolve().relative_to(ROOT / "tests")
        group = _SHARED_FLIGHT_DIRS.get(rel.parts[0], str(rel)) if len(rel.parts) > 1 else str(rel)
        item.add_marker(pytest.mark.xdist_group(group))
