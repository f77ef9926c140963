"""The recorder's configuration: a TOML file, with the command line overriding the links and output.

Every key names its unit. Example (all keys optional; these are the defaults)::

    [device]
    url = "/dev/ttyACM0"
    set_rtc = true                 # set the device RTC from the host's UTC at start

    [mavlink]
    url = "udpin:0.0.0.0:14550"
    system_id = 1                  # the vehicle's system id (the camera component joins it)
    component_id = 100             # our camera's component id (101-106 if the vehicle has a camera at 100)
    ground_station_systems = [255]
    global_position_hz = 50.0

    [capture]                      # what "start capture" from a ground station does
    mode = "interval"              # or "focus_burst" (the paper's cycle)
    interval_s = 0.2
    focus_lead_s = 0.5
    burst_s = 2.0
    shutter_pulse_s = 0.02

    [sensors]
    imu_rate_hz = 100
    imu_mode = "ndof"              # or "imuplus"
    range_rate_hz = 500
    lidar_model = "v3"             # "v3hp", or "none"
    lidar_preset = 0
    feedback = true                # hot-shoe line wired
    feedback_timeout_s = 0.15
    feedback_active_high = false

    [camera]                       # intrinsics and mounting (icgt.geotag.GeotagConfig)
    focal_length_mm = 35.0
    sensor_width_mm = 35.9
    image_width_px = 7952
    image_height_px = 5304
    mount_pitch_deg = 0.0
    lever_arm_body_m = [0.0, 0.0, 0.0]

    [output]
    dir = "recordings"
    chunk_interval_s = 1.0
"""

from __future__ import annotations

import dataclasses
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError
from icgt.geotag import GeotagConfig


class ConfigError(IcgtError):
    """The recorder configuration is invalid."""


@dataclass(frozen=True)
class DeviceSection:
    url: str = "/dev/ttyACM0"
    set_rtc: bool = True


@dataclass(frozen=True)
class MavlinkSection:
    url: str = "udpin:0.0.0.0:14550"
    system_id: int = 1
    component_id: int = 100  # MAV_COMP_ID_CAMERA; 101-106 (CAMERA2..6) when the vehicle has a camera at 100
    ground_station_systems: tuple[int, ...] = (255,)
    global_position_hz: float = 50.0


@dataclass(frozen=True)
class CaptureSection:
    mode: str = "interval"
    interval_s: float = 0.2
    focus_lead_s: float = 0.5
    burst_s: float = 2.0
    shutter_pulse_s: float = 0.02


@dataclass(frozen=True)
class SensorsSection:
    imu_rate_hz: int = 100
    imu_mode: str = "ndof"
    range_rate_hz: int = 500
    lidar_model: str = "v3"
    lidar_preset: int = 0
    lidar_bias_every: int = 100
    feedback: bool = True
    feedback_timeout_s: float = 0.15
    feedback_active_high: bool = False


@dataclass(frozen=True)
class OutputSection:
    dir: Path = Path("recordings")
    chunk_interval_s: float = 1.0


@dataclass(frozen=True)
class RecorderConfig:
    device: DeviceSection = field(default_factory=DeviceSection)
    mavlink: MavlinkSection = field(default_factory=MavlinkSection)
    capture: CaptureSection = field(default_factory=CaptureSection)
    sensors: SensorsSection = field(default_factory=SensorsSection)
    camera: GeotagConfig = field(default_factory=GeotagConfig)
    output: OutputSection = field(default_factory=OutputSection)
    source: str = "defaults"

    def with_overrides(
        self, *, device_url: str | None = None, mavlink_url: str | None = None, out_dir: Path | None = None
    ) -> RecorderConfig:
        cfg = self
        if device_url:
            cfg = dataclasses.replace(cfg, device=dataclasses.replace(cfg.device, url=device_url))
        if mavlink_url:
            cfg = dataclasses.replace(cfg, mavlink=dataclasses.replace(cfg.mavlink, url=mavlink_url))
        if out_dir is not None:
            cfg = dataclasses.replace(cfg, output=dataclasses.replace(cfg.output, dir=out_dir))
        return cfg

    def as_text(self) -> str:
        """The effective configuration, for the log's metadata."""
        return repr(self)


def _section(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{where}: expected a table")
    names = {f.name: f for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(names))})")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        default = getattr(cls(), key)
        if default is None and isinstance(value, list):
            value = tuple(value)
        elif isinstance(default, tuple):
            if not isinstance(value, list):
                raise ConfigError(f"{where}.{key}: expected a list")
            value = tuple(value)
        elif isinstance(default, Path):
            value = Path(value)
        elif isinstance(default, bool):
            if not isinstance(value, bool):
                raise ConfigError(f"{where}.{key}: expected true or false")
        elif isinstance(default, float):
            if not isinstance(value, (int, float)) or isinstance(value, bool):
                raise ConfigError(f"{where}.{key}: expected a number")
            value = float(value)
        elif isinstance(default, int) and (not isinstance(value, int) or isinstance(value, bool)):
            raise ConfigError(f"{where}.{key}: expected an integer")
        elif isinstance(default, str) and not isinstance(value, str):
            raise ConfigError(f"{where}.{key}: expected a string")
        kwargs[key] = value
    return cls(**kwargs)


def load_config(path: Path | None) -> RecorderConfig:
    """Read a config file (None: defaults). Errors name the file and the key."""
    if path is None:
        cfg = RecorderConfig()
    else:
        try:
            raw = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as exc:
            raise ConfigError(f"cannot read config {path}: {exc.strerror}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{path}: {exc}") from exc
        sections = {
            "device": DeviceSection,
            "mavlink": MavlinkSection,
            "capture": CaptureSection,
            "sensors": SensorsSection,
            "camera": GeotagConfig,
            "output": OutputSection,
        }
        unknown = sorted(set(raw) - set(sections))
        if unknown:
            raise ConfigError(f"{path}: unknown section(s) {', '.join(unknown)}")
        parts = {name: _section(cls, raw.get(name, {}), f"{path}: [{name}]") for name, cls in sections.items()}
        cfg = RecorderConfig(**parts, source=str(path))
    _validate(cfg)
    return cfg


def _validate(cfg: RecorderConfig) -> None:
    if cfg.capture.mode not in ("interval", "focus_burst"):
        raise ConfigError(f"{cfg.source}: [capture] mode must be interval or focus_burst, not {cfg.capture.mode!r}")
    if cfg.sensors.imu_mode not in ("ndof", "imuplus"):
        raise ConfigError(f"{cfg.source}: [sensors] imu_mode must be ndof or imuplus")
    if cfg.sensors.lidar_model not in ("v3", "v3hp", "none"):
        raise ConfigError(f"{cfg.source}: [sensors] lidar_model must be v3, v3hp or none")
    if not 0.05 <= cfg.capture.interval_s <= 3600:
        raise ConfigError(f"{cfg.source}: [capture] interval_s must be 0.05 .. 3600 s")
    if cfg.output.chunk_interval_s <= 0 or cfg.output.chunk_interval_s > 1.0:
        raise ConfigError(f"{cfg.source}: [output] chunk_interval_s must be in (0, 1] s (crash loss <= 1 s)")
