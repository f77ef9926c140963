"""Simulation scenarios: what is flown, what is seen, how good GPS is, how wrong the clocks are.

A scenario is a TOML file (hil_sim/scenarios/*.toml) read into frozen msgspec Structs: `Scenario` below,
its tables in icgt.sim.scenario_sections, the ``[surface]`` table in icgt.sim.surface. Every field carries its
unit in its name; times are seconds (``_s``) at this boundary, as in the recorder's configuration. Unknown
keys, wrong types and out-of-range values raise `ScenarioError` naming the file and the dotted key; a key of
an older version (``latency_ms``, ``offset_us``, ...) is refused naming its new name and the value converted.
Frames: positions are ENU metres relative to ``[origin]``; body and camera axes are FRD (x forward, y right,
z down); the camera's x axis is its optical axis, image right is +y and image down is +z. ``[autopilot]
profile`` ("ideal", "ardupilot", "px4") chooses what the simulated autopilot sends and how it stamps it; it
gives the defaults of the other ``[autopilot]`` keys (sources in icgt.sim.profiles), which a scenario may set.

Example (the shortest valid file; every other section has defaults)::

    name = "hover"
    duration_s = 30.0
    [origin]
    lat_deg = 37.8813
    lon_deg = 127.7298
    alt_m = 76.0
    [structure]
    point_m = [0.0, 10.0, 0.0]
    normal = [0.0, -1.0, 0.0]
    [trajectory]
    kind = "hover"
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from icgt.geotag.config import renamed_message
from icgt.settings_errors import explain, first_non_finite
from icgt.sim.errors import ScenarioError, SimError
from icgt.sim.profiles import IDEAL_RATES_HZ, PROFILES
from icgt.sim.resources import scenario_dir
from icgt.sim.scenario_sections import (
    LIDAR_MAX_RANGE_M,
    STREAM_NAMES,
    Autopilot,
    AutopilotCamera,
    AutopilotClock,
    BoardImu,
    Camera,
    CameraClock,
    Capture,
    Clocks,
    DeckPass,
    DeviceClock,
    Faults,
    Gimbal,
    Gps,
    Hover,
    Link,
    Origin,
    PierScan,
    Section,
    Sensors,
    Structure,
    Survey,
    TrajectorySpec,
    Vec3,
    Window,
)
from icgt.sim.surface import Surface, check_surface, with_default_ids

__all__ = [
    "DEFAULT_RATES_HZ",
    "LIDAR_MAX_RANGE_M",
    "RENAMED",
    "SCENARIO_DIR",
    "STREAM_NAMES",
    "TRAJECTORY_KINDS",
    "Autopilot",
    "AutopilotCamera",
    "AutopilotClock",
    "BoardImu",
    "Camera",
    "CameraClock",
    "Capture",
    "Clocks",
    "DeckPass",
    "DeviceClock",
    "Faults",
    "Gimbal",
    "Gps",
    "Hover",
    "Link",
    "Origin",
    "PierScan",
    "Scenario",
    "ScenarioError",
    "Sensors",
    "SimError",
    "Structure",
    "Survey",
    "TrajectorySpec",
    "Vec3",
    "Window",
    "load_scenario",
    "parse_scenario",
]

SCENARIO_DIR = scenario_dir()
"""Where the scenario files are: inside the installed wheel, else the repository's hil_sim/scenarios."""

TRAJECTORY_KINDS = ("pier_scan", "deck_pass", "hover", "survey")
DEFAULT_RATES_HZ: Mapping[str, float] = IDEAL_RATES_HZ
"""Stream rates of the "ideal" profile (the default); see icgt.sim.profiles for the others."""

_MS, _US = 1e-3, 1e-6
RENAMED: Mapping[str, Mapping[str, tuple[str, float]]] = {
    "camera": {
        "exposure_us": ("exposure_s", _US),
        "shutter_latency_us": ("shutter_latency_s", _US),
        "shutter_jitter_us": ("shutter_jitter_s", _US),
        "write_ms": ("write_s", _MS),
    },
    "camera.capture": {"focus_ms": ("focus_s", _MS), "burst_ms": ("burst_s", _MS), "interval_ms": ("interval_s", _MS)},
    "autopilot": {
        "latency_ms": ("latency_s", _MS),
        "latency_jitter_ms": ("latency_jitter_s", _MS),
        "stamp_jitter_ms": ("stamp_jitter_s", _MS),
        "local_position_lag_ms": ("local_position_lag_s", _MS),
    },
    "clocks.device": {"offset_us": ("offset_s", _US)},
    "clocks.autopilot": {"offset_us": ("offset_s", _US)},
    "link": {"usb_latency_us": ("usb_latency_s", _US), "usb_jitter_us": ("usb_jitter_s", _US)},
}
"""Keys of older scenario files by table: (new key, factor to seconds). Such a key is refused naming the new one."""


class Scenario(Section, frozen=True, kw_only=True):
    name: str
    description: str = ""
    duration_s: Annotated[float, Meta(gt=0.0, le=24 * 3600.0)]
    seed: Annotated[int, Meta(ge=0)] = 0
    origin: Origin
    structure: Structure
    trajectory: TrajectorySpec
    camera: Camera = msgspec.field(default_factory=Camera)
    sensors: Sensors = msgspec.field(default_factory=Sensors)
    gps: Gps = msgspec.field(default_factory=Gps)
    autopilot: Autopilot = msgspec.field(default_factory=Autopilot)
    clocks: Clocks = msgspec.field(default_factory=Clocks)
    link: Link = msgspec.field(default_factory=Link)
    faults: Faults = msgspec.field(default_factory=Faults)
    surface: Surface | None = None
    """The face's texture and defects for rendered camera images (icgt.sim.surface); None: tag images."""
    source: str = "<memory>"
    """Where the scenario was read from (for messages)."""

    def __post_init__(self) -> None:
        # rules between tables: the trajectory must fit the structure it flies along
        normal = self.structure.normal
        if isinstance(self.trajectory, PierScan) and abs(normal[2]) > 0.5:
            raise ValueError(
                "trajectory.kind: a pier scan needs a vertical face: structure.normal must be mostly horizontal"
            )
        if isinstance(self.trajectory, DeckPass):
            along = math.radians(self.trajectory.along_deg)
            dot = math.sin(along) * normal[0] + math.cos(along) * normal[1]
            if abs(dot) > 1e-3:
                raise ValueError(
                    f"trajectory.along_deg: direction {self.trajectory.along_deg:g} deg"
                    " is not parallel to the structure plane"
                )


# --- loading --------------------------------------------------------------------------------


def _table(data: Mapping[str, Any], dotted: str) -> Mapping[str, Any]:
    table: Any = data
    for part in dotted.split("."):
        table = table.get(part) if isinstance(table, Mapping) else None
    return table if isinstance(table, Mapping) else {}


def _with_profile(autopilot: Any) -> Any:
    """The [autopilot] table with its profile's defaults under the keys it does not set (icgt.sim.profiles)."""
    if not isinstance(autopilot, Mapping):
        return autopilot
    base = PROFILES.get(autopilot.get("profile", "ideal"))
    if base is None:  # an unknown profile: the Struct's check names it
        return autopilot
    out = {**base, **autopilot}
    rates = autopilot.get("rates_hz", {})
    if isinstance(rates, Mapping):
        out["rates_hz"] = {**base["rates_hz"], **rates}
    return out


def _unit_normal(structure: Any) -> Any:
    """The [structure] table with its normal scaled to unit length (a zero or malformed one passed on to be named)."""
    normal = structure.get("normal") if isinstance(structure, Mapping) else None
    if not isinstance(normal, list) or len(normal) != 3:
        return structure
    if not all(isinstance(v, int | float) and not isinstance(v, bool) for v in normal):
        return structure
    n = math.sqrt(sum(float(v) ** 2 for v in normal))
    if n < 1e-9:
        raise ScenarioError("structure.normal: must not be the zero vector")
    return {**structure, "normal": [float(v) / n for v in normal]}


def parse_scenario(data: Mapping[str, Any], source: str = "<memory>") -> Scenario:
    """Build and validate a Scenario from parsed TOML data; errors name `source` and the key."""
    if not isinstance(data, Mapping):
        raise ScenarioError(f"{source}: expected a table of scenario keys, got {type(data).__name__}")
    bad = first_non_finite(data)
    if bad is not None:
        raise ScenarioError(f"{source}: {bad}: expected a finite number")
    for dotted, renamed in RENAMED.items():
        for key, value in _table(data, dotted).items():
            why = renamed_message(key, value, renamed)
            if why is not None:
                raise ScenarioError(f"{source}: {dotted}.{key}: {why}")
    raw = dict(data)
    try:
        if "structure" in raw:
            raw["structure"] = _unit_normal(raw["structure"])
    except ScenarioError as exc:
        raise ScenarioError(f"{source}: {exc}") from None
    if "autopilot" in raw:
        raw["autopilot"] = _with_profile(raw["autopilot"])
    if "surface" in raw:
        raw["surface"] = with_default_ids(raw["surface"])
    raw["source"] = source
    try:
        scenario = msgspec.convert(raw, Scenario)
    except msgspec.ValidationError as exc:
        e = explain(exc, raw, Scenario)
        raise ScenarioError(f"{source}: {e.key}: {e.why}" if e.key else f"{source}: {e.why}") from None
    if scenario.surface is not None:
        check_surface(scenario.surface, source)
    return scenario


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file. A bare name ("hover") means SCENARIO_DIR/hover.toml."""
    p = Path(path)
    if not p.suffix and not p.exists() and p.parent == Path("."):
        p = SCENARIO_DIR / f"{p.name}.toml"
        if not p.is_file():
            known = ", ".join(sorted(q.stem for q in SCENARIO_DIR.glob("*.toml"))) or "none"
            raise ScenarioError(f"unknown scenario {str(path)!r}: the scenarios in {SCENARIO_DIR} are {known}")
    try:
        with p.open("rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            f"{p}: not a TOML scenario: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})"
        ) from exc
    return parse_scenario(data, str(p))
