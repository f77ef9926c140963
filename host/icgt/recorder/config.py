"""The recorder's configuration: one declared schema, a TOML file, the command line overriding links and output.

Every key names its unit (``_s``, ``_hz``, ``_mm``, ``_m``, ``_deg``, ``_px``); every value is checked when
the file is loaded, before any device or autopilot is contacted, against the range declared with its
field here, the device's limits (`icgt.device.limits`: trigger rate, pulse widths, the feedback window,
the rates the sensors deliver) and, for [camera] and [sync], `icgt.geotag.GeotagConfig` and
`icgt.sync.SyncTuning`. The schema is declared with msgspec
(types, fixed-length arrays, numeric ranges); what a range cannot say (one value against another) is
checked in ``__post_init__``. An error names the file, the key, the value and what is allowed.

Example (all keys optional; these are the defaults)::

    [device]
    url = "/dev/ttyACM0"
    set_rtc = true                 # set the device RTC from the host's UTC at start
    wait_s = 30.0                  # wait this long for a device that is not there yet
    running_capture = "adopt"      # a device already capturing at start: "adopt" it, or "stop" it

    [mavlink]
    url = "udpin:0.0.0.0:14550"
    system_id = 1                  # the vehicle's system id (the camera component joins it)
    component_id = 100             # our camera's component id (101-106 if the vehicle has a camera at 100)
    ground_station_systems = [255, 245]  # who may command the camera (the autopilot always may): system
                                   # ids 255 = QGroundControl, Mission Planner, MAVProxy (their default
                                   # --source-system), 245 = MAVSDK as a ground station. Others: COMMAND_ACK DENIED
    global_position_hz = 50.0
    udp_receive_buffer_bytes = 4194304  # SO_RCVBUF asked for a UDP link (4 MiB: ~1 s of a 10 k msg/s flood); the
                                   # kernel grants at most net.core.rmem_max. Granted size and kernel drops: in
                                   # /icgt/counters, kernel_drops link events and `icgt info`
    # signing_key_file = "/etc/icgt/mavlink.key"   # MAVLink 2 signing (off when absent): a file holding a
                                   # passphrase; the key is its SHA-256, as QGroundControl and MAVProxy derive it.
                                   # Our messages are signed; commands without a valid signature are ignored.
                                   # The recording says whether signing was on, never the key.

    [capture]                      # what "start capture" from a ground station does
    mode = "interval"              # or "focus_burst" (the paper's cycle)
    interval_s = 0.2
    focus_lead_s = 0.5
    burst_s = 2.0
    shutter_pulse_s = 0.02
    host_timeout_s = 600.0         # the device stops capture by itself after this long without a word from
                                   # the recorder (it died, the cable came out); 0: never, the camera goes on

    [sensors]
    imu_rate_hz = 100
    imu_mode = "ndof"              # or "imuplus"
    range_rate_hz = 200
    lidar_model = "v3"             # "v3hp", or "none"
    lidar_preset = 0
    feedback = true                # hot-shoe line wired
    # feedback_timeout_s = 0.15    # unset: derived per capture, feedback_min_lag_s + 7/8 of the interval
    feedback_min_lag_s = 0.0       # the camera's shortest shutter lag (e.g. 0.04 for a body at 48 +- 2 ms)
    feedback_active_high = false

    [camera]                       # intrinsics, mounting, limits (icgt.geotag.GeotagConfig: every key there)
    focal_length_mm = 35.0
    sensor_width_mm = 35.9
    image_width_px = 7952
    image_height_px = 5304
    mount_pitch_deg = 0.0
    lever_arm_body_m = [0.0, 0.0, 0.0]
    max_wait_s = 0.5               # a frame waits this long for the telemetry sample after its mid-exposure

    [sync]                         # how the autopilot's stream is believed (icgt.sync.SyncTuning)
    # autopilot_component = 1      # unset: the first HEARTBEAT of a flight controller of system_id names it
    autopilot_timeout_s = 3.0      # silence after which the autopilot counts as gone (back / rebooted when heard)
    timesync_timeout_s = 1.0       # an unanswered TIMESYNC request is forgotten after this
    one_way_min_delay_allowance_s = 0.002  # without TIMESYNC answers: the link's minimum delay (radios: more)
    # telemetry_retention_s = 120  # unset: the device's history horizon at its rates (never shorter)

    [output]
    dir = "recordings"
    chunk_interval_s = 0.25         # the open chunk goes to disk this often: kill -9 loses <= this + 0.25 s
"""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from icgt.device.limits import (
    CORE,
    BoardLimits,
    LimitError,
    check_capture,
    check_feedback,
    check_host_timeout,
    check_sensors,
)
from icgt.errors import IcgtError
from icgt.geotag import GeotagConfig
from icgt.geotag.config import RENAMED as CAMERA_RENAMED
from icgt.geotag.config import renamed_message
from icgt.protocol.messages import LidarModel
from icgt.settings_errors import error_at, lookup
from icgt.sync.config import RENAMED as SYNC_RENAMED
from icgt.sync.config import SyncTuning

__all__ = [
    "CaptureSection",
    "ConfigError",
    "DeviceSection",
    "MavlinkSection",
    "OutputSection",
    "RecorderConfig",
    "SensorsSection",
    "load_config",
    "parse_config",
]


class ConfigError(IcgtError):
    """The recorder configuration is invalid."""


# Limits the firmware enforces (firmware/lib/core: trigger, exposure pairing, BNO055 and LIDAR-Lite
# drivers) and the wire types of CONFIGURE / START_CAPTURE: refused here, before anything is contacted.
HOST_TIMEOUT_DEFAULT_S = 600.0  # [capture] host_timeout_s (see CaptureSection)
_SystemId = Annotated[int, Meta(ge=1, le=255)]
_ComponentId = Annotated[int, Meta(ge=1, le=255)]


class _Section(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


class DeviceSection(_Section, frozen=True, kw_only=True):
    url: Annotated[str, Meta(min_length=1)] = "/dev/ttyACM0"
    set_rtc: bool = True
    wait_s: Annotated[float, Meta(ge=0.0, le=86_400.0)] = 30.0  # for a device not plugged in (or enumerated) yet
    # A device found capturing at start (the previous recorder was killed): "adopt" records the running
    # capture as it is (its configuration is kept), "stop" stops it first. Either way what it sent while no
    # recorder listened is asked back from its history (RESEND).
    running_capture: Literal["adopt", "stop"] = "adopt"


class MavlinkSection(_Section, frozen=True, kw_only=True):
    url: Annotated[str, Meta(min_length=1)] = "udpin:0.0.0.0:14550"
    system_id: _SystemId = 1
    component_id: _ComponentId = 100  # MAV_COMP_ID_CAMERA; 101-106 (CAMERA2..6) when 100 is taken
    ground_station_systems: Annotated[tuple[_SystemId, ...], Meta(min_length=1)] = (255, 245)
    global_position_hz: Annotated[float, Meta(gt=0.0, le=200.0)] = 50.0
    udp_receive_buffer_bytes: Annotated[int, Meta(ge=65_536, le=1 << 30)] = 4 * 1024 * 1024
    signing_key_file: Path | None = None  # a passphrase file (icgt.mavlink.signing); None: no signing


class CaptureSection(_Section, frozen=True, kw_only=True):
    mode: Literal["interval", "focus_burst"] = "interval"
    interval_s: Annotated[float, Meta(ge=0.05, le=3600.0)] = 0.2
    focus_lead_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.5
    burst_s: Annotated[float, Meta(ge=0.0, le=3600.0)] = 2.0
    shutter_pulse_s: Annotated[float, Meta(ge=0.001, le=1.0)] = 0.02
    # The device stops a capture by itself once this recorder has been silent this long (it died, or the cable
    # came out): the camera does not shoot on with nobody logging. 0: never (the camera goes on); 5 .. 86400 s.
    # 600 s: a cable back within 10 minutes costs nothing (every exposure comes back by RESEND), and at 5 fps
    # the device's history holds 11.4 min of exposures (Teensy 4.1), so every exposure it took stays there for
    # `icgt recover-device`. Faster captures reach back less (20 fps: 3.2 min): set it lower for them.
    host_timeout_s: Annotated[float, Meta(ge=0.0, le=86_400.0)] = HOST_TIMEOUT_DEFAULT_S

    def __post_init__(self) -> None:
        try:
            check_host_timeout(self.host_timeout_s)
        except LimitError as exc:
            raise ValueError(str(exc)) from None
        if self.shutter_pulse_s >= self.interval_s:
            raise ValueError(
                f"shutter_pulse_s ({self.shutter_pulse_s}) must be shorter than interval_s ({self.interval_s}): "
                "the line must go inactive between shots (limit pulse_vs_interval)"
            )
        if self.mode == "focus_burst" and self.burst_s < self.interval_s:
            raise ValueError(
                f"burst_s ({self.burst_s}) must be at least interval_s ({self.interval_s}) in focus_burst (limit burst)"
            )


class SensorsSection(_Section, frozen=True, kw_only=True):
    imu_rate_hz: Annotated[int, Meta(ge=0, le=100)] = 100  # BNO055 fusion output: 100 Hz at most; 0 off
    imu_mode: Literal["ndof", "imuplus"] = "ndof"
    range_rate_hz: Annotated[int, Meta(ge=0, le=500)] = 200  # LIDAR-Lite v3 delivers ~270 Hz at most; 0 off
    lidar_model: Literal["v3", "v3hp", "none"] = "v3"
    lidar_preset: Annotated[int, Meta(ge=0, le=6)] = 0  # v3: 0-5, v3HP: 0-6
    lidar_bias_every: Annotated[int, Meta(ge=1, le=255)] = 100
    feedback: bool = True
    # None: derived at each capture from its interval (icgt.device.limits.auto_feedback_timeout_s)
    feedback_timeout_s: Annotated[float, Meta(ge=0.001, le=2.0)] | None = None
    feedback_min_lag_s: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.0  # the camera's shortest shutter lag
    feedback_active_high: bool = False

    @property
    def imu_mode_code(self) -> int:
        """BNO055 OPR_MODE of `imu_mode`."""
        return 0x0C if self.imu_mode == "ndof" else 0x08

    @property
    def lidar_model_code(self) -> LidarModel:
        return {"none": LidarModel.NONE, "v3": LidarModel.V3, "v3hp": LidarModel.V3HP}[self.lidar_model]

    def check_limits(self, limits: BoardLimits = CORE) -> None:
        """LimitError unless a board with these limits (default: what every board allows) takes these settings."""
        check_sensors(
            imu_rate_hz=self.imu_rate_hz,
            imu_mode=self.imu_mode_code,
            range_rate_hz=self.range_rate_hz,
            lidar_model=self.lidar_model_code,
            lidar_preset=self.lidar_preset,
            lidar_bias_every=self.lidar_bias_every,
            limits=limits,
        )
        check_feedback(self.feedback_timeout_s, self.feedback_min_lag_s, limits)

    def __post_init__(self) -> None:
        try:
            self.check_limits()
        except LimitError as exc:
            raise ValueError(str(exc)) from None


class OutputSection(_Section, frozen=True, kw_only=True):
    dir: Path = Path("recordings")
    # kill -9 / power cut loses at most this + WRITE_ALLOWANCE_S (0.25 s) of log: <= 1 s (icgt.recording.writer)
    chunk_interval_s: Annotated[float, Meta(gt=0.0, le=0.75)] = 0.25
    file_mode: Annotated[int, Meta(ge=0, le=0o777)] = 0o600  # recordings are private by default


class RecorderConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    device: DeviceSection = msgspec.field(default_factory=DeviceSection)
    mavlink: MavlinkSection = msgspec.field(default_factory=MavlinkSection)
    capture: CaptureSection = msgspec.field(default_factory=CaptureSection)
    sensors: SensorsSection = msgspec.field(default_factory=SensorsSection)
    camera: GeotagConfig = msgspec.field(default_factory=GeotagConfig)
    sync: SyncTuning = msgspec.field(default_factory=SyncTuning)
    output: OutputSection = msgspec.field(default_factory=OutputSection)
    source: str = "defaults"

    def __post_init__(self) -> None:
        c, s = self.capture, self.sensors
        try:  # the configured capture, paired with the configured feedback, as the device will check it
            check_capture(
                mode=c.mode,
                interval_s=c.interval_s,
                shutter_pulse_s=c.shutter_pulse_s,
                burst_s=c.burst_s,
                feedback=s.feedback,
                feedback_timeout_s=s.feedback_timeout_s,
                feedback_min_lag_s=s.feedback_min_lag_s,
            )
        except LimitError as exc:
            raise ValueError(f"[capture] with [sensors]: {exc}") from None

    def with_overrides(
        self, *, device_url: str | None = None, mavlink_url: str | None = None, out_dir: Path | None = None
    ) -> RecorderConfig:
        cfg = self
        if device_url:
            cfg = msgspec.structs.replace(cfg, device=msgspec.structs.replace(cfg.device, url=device_url))
        if mavlink_url:
            cfg = msgspec.structs.replace(cfg, mavlink=msgspec.structs.replace(cfg.mavlink, url=mavlink_url))
        if out_dir is not None:
            cfg = msgspec.structs.replace(cfg, output=msgspec.structs.replace(cfg.output, dir=out_dir))
        return cfg

    def as_text(self) -> str:
        """The effective configuration as JSON (for the log's metadata; `parse_config` reads it back)."""
        return json.dumps(msgspec.to_builtins(self, enc_hook=str), indent=1, sort_keys=True)


def _dec_hook(kind: type, value: Any) -> Any:
    if kind is Path:
        if isinstance(value, str) and value:
            return Path(value)
        raise ValueError(f"expected a path (a non-empty string), got {type(value).__name__}")
    raise NotImplementedError(f"{kind}")


def _explain(exc: msgspec.ValidationError, data: Any, source: str) -> ConfigError:
    why, path = error_at(exc)
    parts = [p for p in re.split(r"\.", path) if p]
    where = f"[{parts[0]}] {'.'.join(parts[1:])}" if len(parts) > 1 else (f"[{parts[0]}]" if parts else "")
    found, value = lookup(data, path)
    shown = f" = {value!r}" if found and not isinstance(value, dict) else ""
    why = why.replace("Object contains unknown field", "unknown key").replace("Expected", "expected")
    return ConfigError(f"{source}: {where}{shown}: {why}" if where else f"{source}: {why}")


def parse_config(data: dict[str, Any], source: str) -> RecorderConfig:
    """A configuration from parsed TOML (or JSON) `data`; ConfigError names the key, the value and the rule."""
    # A key renamed since (old files, the old docs): refused with its new name rather than "unknown key".
    for section, renamed in (("camera", CAMERA_RENAMED), ("sync", SYNC_RENAMED)):
        table = data.get(section)
        for key, value in table.items() if isinstance(table, dict) else ():
            why = renamed_message(key, value, renamed)
            if why is not None:
                raise ConfigError(f"{source}: [{section}] {why}")
    try:
        cfg = msgspec.convert({**data, "source": source}, RecorderConfig, dec_hook=_dec_hook)
    except msgspec.ValidationError as exc:
        raise _explain(exc, data, source) from None
    return cfg


def load_config(path: Path | None) -> RecorderConfig:
    """Read a config file (None: defaults). Errors name the file, the key and the value."""
    if path is None:
        return RecorderConfig()
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise ConfigError(f"cannot read config {path}: {exc.strerror}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{path}: not UTF-8 text ({exc.reason})") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    return parse_config(raw, str(path))
