"""MAVLink side of the host synchroniser: the autopilot link, its telemetry, and the camera component.

* `MavlinkLink` (link.py): one pymavlink connection with a stamping reader thread, a TIMESYNC client and
  SET_MESSAGE_INTERVAL stream-rate requests (link_scheduler.py), driven by the core's presence hints.
* `TelemetryStore` / `TelemetryBuffer` and the sample types (telemetry.py): SI-unit samples with the
  autopilot's boot-clock stamp and the host receipt time; "never a position without a 3D fix".
* `CameraComponent` (camera.py): MAVLink Camera Protocol v2 as component 100, driven by the recorder's
  `CaptureHandler`, publishing CAMERA_IMAGE_CAPTURED from `CapturedImage`.
"""

from icgt.mavlink.camera import (
    CameraComponent,
    CameraConfig,
    CameraError,
    CameraInfo,
    CapturedImage,
    CaptureHandler,
    CaptureStatus,
    CommandRecord,
    CommandResult,
    HandlerResult,
    RejectedCommand,
)
from icgt.mavlink.link import (
    DEFAULT_STREAM_RATES,
    LinkConfig,
    LinkError,
    LinkEventKind,
    LinkStats,
    MavlinkEvent,
    MavlinkLink,
    MavlinkMessage,
    RateRequestResult,
    StreamRate,
)
from icgt.mavlink.telemetry import (
    AttitudeSample,
    FusedPositionSample,
    GpsSample,
    LocalPositionSample,
    Sample,
    SystemTimeSample,
    TelemetryBuffer,
    TelemetryStore,
)

__all__ = [
    "DEFAULT_STREAM_RATES",
    "AttitudeSample",
    "CameraComponent",
    "CameraConfig",
    "CameraError",
    "CameraInfo",
    "CaptureHandler",
    "CaptureStatus",
    "CapturedImage",
    "CommandRecord",
    "CommandResult",
    "FusedPositionSample",
    "GpsSample",
    "HandlerResult",
    "LinkConfig",
    "LinkError",
    "LinkEventKind",
    "LinkStats",
    "LocalPositionSample",
    "MavlinkEvent",
    "MavlinkLink",
    "MavlinkMessage",
    "RateRequestResult",
    "RejectedCommand",
    "Sample",
    "StreamRate",
    "SystemTimeSample",
    "TelemetryBuffer",
    "TelemetryStore",
]
