"""One simulated flight for the damage-map tests, flown once per session (~45 s, ~20 s of CPU).

damage_flight.toml: two passes 2 m from a pier face after a 12 s hold (the recorder and the camera
start meanwhile), five cracks and two spalls rendered on the card.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import msgspec
import pytest

from icgt.demo import Flight, fly
from icgt.sim.detector import SimDetection, detect_all, write_coco, write_polylines, write_yolo
from icgt.sim.render import render_size
from icgt.sim.scenario import Scenario, load_scenario
from icgt.sim.surface import JointSpec, StainSpec, check_surface
from icgt.sim.truth import ExposureTruth

SCENARIO = Path(__file__).with_name("damage_flight.toml")

STAINS = (
    StainSpec("ST1", ((0.30, 2.30), (0.55, 2.32), (0.58, 3.00), (0.33, 3.02))),  # a water streak
    StainSpec("ST2", ((1.30, 3.60), (1.70, 3.62), (1.68, 3.98), (1.32, 4.00)), 0.22),  # a shadow
)
JOINTS = (JointSpec("J1", ((-2.4, 4.05), (2.4, 4.05)), 8.0),)  # a horizontal formwork joint
"""The look-alikes painted on the damage flight's face (none within 50 mm of a defect)."""


def with_lookalikes(sc: Scenario, *, defects: bool = True, render_width_px: int | None = None) -> Scenario:
    """The damage scenario with stains and a joint on its face; without its defects if not `defects`."""
    assert sc.surface is not None
    surf = msgspec.structs.replace(sc.surface, stains=STAINS, joints=JOINTS)
    if not defects:
        surf = msgspec.structs.replace(surf, cracks=(), spalls=())
    if render_width_px is not None:
        surf = msgspec.structs.replace(surf, render_width_px=render_width_px)
    check_surface(surf, sc.source)
    return msgspec.structs.replace(sc, surface=surf)


@dataclass
class DamageFlight:
    flight: Flight
    scenario: Scenario
    exposures: list[ExposureTruth]
    detections: list[SimDetection]
    det_dir: Path
    sim_dir: Path

    @property
    def calibration(self) -> Path:
        return self.sim_dir / "camera_calibration.toml"

    @property
    def truth(self) -> Path:
        return self.sim_dir / "truth_defects.json"


def read_exposures(path: Path) -> list[ExposureTruth]:
    out = []
    for line in path.read_text().splitlines():
        if line.strip():
            d = json.loads(line)
            d.pop("event")
            for k in (
                "position_enu_m",
                "body_position_enu_m",
                "q_camera_ned",
                "q_optical_ned",
                "q_body_ned",
                "omega_camera_rad_s",
            ):
                d[k] = tuple(d[k])
            out.append(ExposureTruth(**d))
    return out


LOOKAHEAD_S = 1.0
"""The map re-geotags the frames with this look-ahead (`icgt map --recompute-lookahead-s`): on a loaded
machine the live recorder extrapolates poses whose later sample came late; offline it need not."""


def flight_problem(flight: Flight) -> str | None:
    """Why a flown flight cannot test the map (the simulator starved on a loaded machine), or None."""
    from icgt.ingest.recompute import recompute

    if flight.recorder_exit != 0:
        return f"the recorder exited with {flight.recorder_exit} (see {flight.recorder_log})"
    frames = recompute(flight.mcap, lookahead_s=LOOKAHEAD_S).frames
    stale = [f.frame_seq for f in frames if "stale_pose" in f.flags or "pose_extrapolated" in f.flags]
    if len(stale) > 0.1 * len(frames):
        return f"{len(stale)} of {len(frames)} frames have stale poses even offline (the autopilot's stream stalled)"
    first = min(e.mid_tau_s for e in read_exposures(flight.truth_exposures))
    if first > 12.5:
        return f"capture began at tau {first:.1f} s, after the first pass had started"
    return None


def fly_healthy(sc: Scenario, out: Path, attempts: int = 3) -> Flight:
    """Fly until the simulator kept up (at most `attempts` times); fails naming what went wrong."""
    problems = []
    for k in range(attempts):
        flight = fly(sc, out / f"attempt{k + 1}")
        why = flight_problem(flight)
        if why is None:
            return flight
        problems.append(why)
        print(f"damage flight attempt {k + 1}: {why}; flying again", flush=True)
    raise AssertionError(f"no usable flight in {attempts} attempts (an overloaded machine?): {problems}")


@pytest.fixture(scope="session")
def damage_flight(tmp_path_factory: pytest.TempPathFactory) -> DamageFlight:
    sc = load_scenario(SCENARIO)
    base = tmp_path_factory.mktemp("damage_flight")
    flight = fly_healthy(sc, base / "flight")
    sim_dir = flight.truth_exposures.parent
    exposures = read_exposures(flight.truth_exposures)
    dets = detect_all(sc, exposures, seed=7)
    det_dir = base / "detections"
    det_dir.mkdir()
    assert sc.surface is not None
    size = render_size(sc, sc.surface)
    write_polylines(det_dir / "polylines.json", dets)
    write_coco(det_dir / "coco.json", dets, size, [p.name for p in sorted(flight.card.glob("*.JPG"))])
    write_yolo(det_dir / "yolo", dets, size)
    return DamageFlight(flight, sc, exposures, dets, det_dir, sim_dir)
