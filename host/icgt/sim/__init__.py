"""The simulated world of `icgt sim`: scenarios, true trajectory, clocks, autopilot and camera card.

Modules: scenario (TOML scenarios), geodesy (WGS84/ENU/quaternions), trajectory (truth as a
function of scenario time), truth (clock maps, sensor truth CSV, exposure ground truth),
autopilot (a pymavlink autopilot on a real link), camera_card (JPEGs with EXIF as a camera writes).
"""

from icgt.sim.scenario import Scenario, ScenarioError, SimError, load_scenario

__all__ = ["Scenario", "ScenarioError", "SimError", "load_scenario"]
