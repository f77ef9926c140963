"""The camera component's public types: what a handler returns, what the camera announces and reports.

Split from `icgt.mavlink.camera` (the component itself); import them from either module.
"""

from __future__ import annotations

import dataclasses
import enum
import math
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

if TYPE_CHECKING:
    from icgt.mavlink.camera_settings import CameraSettings

__all__ = [
    "DEFAULT_GROUND_STATIONS",
    "CameraConfig",
    "CameraInfo",
    "CaptureHandler",
    "CaptureStatus",
    "CommandRecord",
    "CommandResult",
    "HandlerResult",
    "RejectedCommand",
]


class CommandResult(enum.IntEnum):
    """MAV_RESULT values a handler may return."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


@dataclasses.dataclass(frozen=True, slots=True)
class HandlerResult:
    """A handler's answer with detail: ``reason`` goes to the log, ``progress`` and ``result_param2`` into
    the COMMAND_ACK (MAVLink uses progress as result_param1 for reasons of a denial)."""

    result: CommandResult
    reason: str = ""
    progress: int = 0
    result_param2: int = 0


class CaptureHandler(Protocol):
    """What the recorder provides. Called on the camera's worker thread; return promptly (< ~1 s)."""

    def start(self, interval_s: float, count: int) -> CommandResult | HandlerResult:
        """Start interval capture: one exposure every ``interval_s``, ``count`` in total (0 = until stopped)."""
        ...

    def stop(self) -> CommandResult | HandlerResult:
        """Stop interval capture."""
        ...

    def shoot(self) -> CommandResult | HandlerResult:
        """Take one exposure now."""
        ...


@dataclasses.dataclass(frozen=True, slots=True)
class CameraInfo:
    """What CAMERA_INFORMATION announces. Unknown focal length / sensor size: NaN; resolution: 0."""

    vendor: str = "ICGT"
    model: str = "ICGT geotagging camera"
    firmware_version: tuple[int, int, int, int] = (0, 1, 0, 0)  # major, minor, patch, dev
    focal_length_mm: float = math.nan
    sensor_size_h_mm: float = math.nan
    sensor_size_v_mm: float = math.nan
    resolution_h: int = 0
    resolution_v: int = 0
    lens_id: int = 0
    cam_definition_uri: str = ""
    cam_definition_version: int = 0


DEFAULT_GROUND_STATIONS = frozenset({255, 245})
"""QGroundControl, Mission Planner and MAVProxy use system id 255 by default, MAVSDK's ground-station mode 245."""


@dataclasses.dataclass(frozen=True, slots=True)
class CameraConfig:
    """``output_dir``: where images are stored (STORAGE_INFORMATION reports its file system).
    ``autopilot_system`` None: the link's autopilot system. ``require_signing``: refuse commands without a
    valid MAVLink 2 signature (the link must have the key)."""

    output_dir: Path
    info: CameraInfo = dataclasses.field(default_factory=CameraInfo)
    ground_station_systems: frozenset[int] = DEFAULT_GROUND_STATIONS
    autopilot_system: int | None = None
    require_signing: bool = False
    heartbeat_hz: float = 1.0
    status_hz: float = 1.0
    dedupe_window_s: float = 10.0  # how long an executed command is remembered for retransmissions
    retransmit_window_s: float = 2.0  # a repeated sequence number without confirmation > 0 within this
    command_queue: int = 256
    refusal_ack_hz: float = 5.0  # DENIED / TEMPORARILY_REJECTED answers to refused commands, at most
    log_period_s: float = 5.0  # one log line per kind of refusal per period, with counts
    resend_rate_hz: float = 100.0  # re-requested CAMERA_IMAGE_CAPTURED messages per second, at most
    client_gap_s: float = 2.5  # a ground station not heard this long was away (icgt.mavlink.camera_clients)
    client_push_delay_s: float = 0.3  # the images it missed are sent again this long after it is back
    settings: CameraSettings | None = None  # what ground stations may set (a definition file): camera_settings


@dataclasses.dataclass(frozen=True, slots=True)
class RejectedCommand:
    """A command addressed to us that was not executed: a system that may not command the camera, a
    missing or invalid signature, or a full queue (``reason`` says which)."""

    host_ns: int
    src_system: int
    src_component: int
    command: int
    reason: str


@dataclasses.dataclass(frozen=True, slots=True)
class CommandRecord:
    """A command the camera answered, for the log."""

    host_ns: int
    src_system: int
    src_component: int
    command: int
    params: tuple[float, ...]
    result: int | None  # MAV_RESULT sent, None when no ACK was sent (unknown broadcast)
    duplicate: bool
    reason: str


@dataclasses.dataclass(frozen=True, slots=True)
class CaptureStatus:
    image_status: int  # 0 idle, 1 capturing, 2 interval set idle, 3 interval set capturing
    interval_s: float
    image_count: int
