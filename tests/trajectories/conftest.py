"""One simulated flight shared by the trajectory tests (tests/e2e/short_flight.toml: hover with sway,
5 fps, a camera miss, a manual shot, a USB unplug and an autopilot link loss), flown once per session
(~25 s), and the truth helpers that write trajectories from it."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import icgt
from icgt.demo import Flight, fly
from icgt.geodesy import LocalFrame
from icgt.sim.scenario import load_scenario
from icgt.sim.trajectory import Trajectory

SCENARIO = Path(__file__).parents[1] / "e2e" / "short_flight.toml"


@dataclass
class Truth:
    """The flight's truth: exposures by start edge, clock maps, and the trajectory in the log's ENU."""

    flight: Flight
    exposures: dict[int, dict[str, Any]]
    utc0_us: float
    host0_ns: float
    trajectory: Trajectory
    scenario_frame: LocalFrame
    """The scenario's ENU at its ellipsoidal origin height (Trajectory positions)."""
    log_frame: LocalFrame
    """The recording's ENU (origin lat, lon, MSL altitude)."""
    geoid_m: float

    def state_in_log(self, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(reference point in the log's ENU, lat/lon/ellipsoidal height (N, 3), q body->NED, acceleration)."""
        st = self.trajectory.state(tau)
        lat, lon, h = self.scenario_frame.enu_to_geodetic(st.position_enu_m)
        enu = self.log_frame.geodetic_to_enu(lat, lon, h - self.geoid_m)
        return np.asarray(enu), np.stack([lat, lon, h], axis=-1), st.q_body_ned, st.accel_enu_m_s2

    def camera_error_m(self, frame: Any) -> float:
        """3D distance [m] of a frame's camera position from the true one at its exposure."""
        t = self.exposures[frame.start_device_us]
        got = self.scenario_frame.geodetic_to_enu(frame.lat_deg, frame.lon_deg, frame.alt_msl_m + self.geoid_m)
        want = self.scenario_frame.geodetic_to_enu(t["lat_deg"], t["lon_deg"], t["alt_ellipsoid_m"])
        return float(np.linalg.norm(np.asarray(got) - np.asarray(want)))


@pytest.fixture(scope="session")
def truth(tmp_path_factory: pytest.TempPathFactory) -> Truth:
    sc = load_scenario(SCENARIO)
    flight = fly(sc, tmp_path_factory.mktemp("trajectories_flight"))
    with flight.truth_exposures.open() as f:
        records = [json.loads(line) for line in f if line.strip()]
    utc0 = float(np.median([r["mid_utc_us"] - r["mid_tau_s"] * 1e6 for r in records]))
    host0 = float(np.median([r["mid_host_monotonic_ns"] - r["mid_tau_s"] * 1e9 for r in records]))
    origin = icgt.read(flight.mcap).enu_origin
    assert origin is not None
    o = sc.origin
    return Truth(
        flight=flight,
        exposures={int(r["start_device_us"]): r for r in records},
        utc0_us=utc0,
        host0_ns=host0,
        trajectory=Trajectory(sc),
        scenario_frame=LocalFrame(o.lat_deg, o.lon_deg, o.ellipsoid_height_m),
        log_frame=LocalFrame(*origin),
        geoid_m=o.geoid_separation_m,
    )
