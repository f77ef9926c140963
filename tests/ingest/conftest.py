"""One simulated flight shared by the ingest tests (card_flight.toml: 1 s EXIF times, missed triggers,
manual shots, a USB unplug and an autopilot link loss), flown once per test session (~25 s)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from icgt.demo import Flight, fly
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("card_flight.toml")


@pytest.fixture(scope="session")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Flight:
    return fly(load_scenario(SCENARIO), tmp_path_factory.mktemp("ingest_flight"))


@pytest.fixture(scope="session")
def truth(flight: Flight) -> list[dict[str, Any]]:
    with flight.truth_exposures.open() as f:
        return [json.loads(line) for line in f if line.strip()]
