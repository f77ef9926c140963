"""Where `icgt sim` finds its device program and scenarios (icgt.sim.resources), in a checkout."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from icgt.sim import resources
from icgt.sim.scenario import SCENARIO_DIR, ScenarioError, load_scenario
from icgt.sim.session import SimError, find_device_binary

ROOT = Path(__file__).resolve().parents[2]


def test_checkout_uses_its_build_and_scenarios(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(resources.DEVICE_BINARY_ENV, raising=False)
    assert not resources.PACKAGED_DEVICE.exists()  # the editable install compiles nothing into the package
    assert find_device_binary() == ROOT / "build" / "host" / "hil_sim" / "icgt-sim-device"
    assert SCENARIO_DIR == ROOT / "hil_sim" / "scenarios"


def test_environment_variable_wins(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    program = tmp_path / "my-device"
    program.write_text("#!/bin/sh\n")
    os.chmod(program, 0o755)
    monkeypatch.setenv(resources.DEVICE_BINARY_ENV, str(program))
    assert find_device_binary() == program


def test_missing_program_says_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(resources.DEVICE_BINARY_ENV, str(tmp_path / "absent"))
    monkeypatch.setattr(resources, "BUILT_DEVICE", tmp_path / "no-build" / "icgt-sim-device")
    monkeypatch.setattr(resources, "PACKAGED_DEVICE", tmp_path / "no-wheel" / "icgt-sim-device")
    with pytest.raises(SimError) as exc:
        find_device_binary()
    text = str(exc.value)
    assert str(tmp_path / "absent") in text and "ICGT_SIM_DEVICE" in text and "make build" in text


def test_unknown_scenario_name_lists_the_known_ones() -> None:
    with pytest.raises(ScenarioError, match=r"unknown scenario 'pier_scna'.*deck_pass, hover, pier_scan"):
        load_scenario("pier_scna")
