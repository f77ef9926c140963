"""The layout of an ICGT log: every topic name, what its messages are, and the JSON schemas of our own records.

The one place the writer (`icgt record`) and every reader (`icgt.read`, the recompute, the exports,
the simulator's scoring) take topic names from. Raw streams are kept as they came so that frames can
be recomputed later; derived ones (frames, clock estimates) say how they were made.

* ``/frames`` (JSON, `FrameRecord`): one geotagged record per exposure;
* ``/frames/location``, ``/frames/pose``, ``/tf`` (protobuf, Foxglove): the same frames for Foxglove's
  map and 3D panels;
* ``/vehicle/location``, ``/tf``, ``/tf_static``, ``/camera/calibration``, ``/icgt/device_log``
  (protobuf, Foxglove): the vehicle track at telemetry rate, the transform tree ``enu -> base_link ->
  camera_mount -> camera_optical``, the camera's calibration and the device's log
  (`icgt.recording.views`); an export adds ``/camera/image`` (CompressedImage, `icgt.export.foxglove`);
* ``/device/<message>`` (JSON): every device message (EXPOSURE, IMU, RANGE, PPS, HELLO, STATUS, LOG, ...)
  with its host receive time ``host_rx_ns``;
* ``/mavlink/<message>`` (JSON): every MAVLink message received from the vehicle's system and the
  configured ground stations, with ``host_rx_ns`` and the raw frame (base64);
* ``/mavlink/other_systems`` (JSON): every message from any other system, raw (type, ids, ``host_rx_ns``,
  frame in base64), several per record, so that a flood on a shared network costs no field expansion;
* ``/clock/device/exchanges`` (JSON): every device TIME_SYNC exchange (the device clock is refitted
  from these);
* ``/clock/autopilot/requests`` (JSON): every MAVLink TIMESYNC request sent (replies are paired
  against these);
* ``/clock/device``, ``/clock/autopilot``, ``/clock/utc`` (JSON): the clock estimates once a second;
* ``/icgt/link_events`` (JSON): link state changes, sequence gaps, rejected frames, synchroniser notices;
  the autopilot's presence (autopilot_seen / _lost / _back / _rebooted, under link "mavlink") once each,
  from the synchroniser's one account of it (`icgt.mavlink.autopilot_rules.AutopilotPresence`);
* ``/icgt/log`` (Foxglove Log): the recorder's own log;
* ``/icgt/counters`` (JSON): link, camera and synchroniser counters once a second;
* ``/camera/images`` (JSON): every CAMERA_IMAGE_CAPTURED published: its MAVLink image index, the frame
  (``frame_seq``) and device trigger number it belongs to, capture_result and why
  (`icgt.recorder.camera_link`).

Times: a message's log time is when the recorder handed it to the log (host CLOCK_MONOTONIC plus a
fixed offset to UTC, ns since the Unix epoch), so the file is in log-time order; its publish time is
the time of its data on the same base: the receipt of an input, the mid-exposure of a frame and of
its views, the emission of a log line. (Recordings made before the two were separated have publish
time = log time = the data's time.) Foxglove messages carry the publish time as their timestamp.

``icgt/recording/foxglove_layout.json`` (package data) is a Foxglove layout for these topics: map,
3D view, image, log and plots (`FOXGLOVE_LAYOUT`), made with the Foxglove SDK's layout types by
`icgt.recording.foxglove_layout`.

Metadata records: ``icgt.config`` (the effective configuration), ``icgt.sync`` (the synchroniser's
settings as JSON: `icgt.sync.SyncConfig`), ``icgt.calibration`` (camera and mounting, for people),
``icgt.device``, ``icgt.time_bases``, ``icgt.enu_origin``, ``icgt.device_link``, ``icgt.mavlink_signing``
(whether MAVLink 2 signing was on; never the key), ``icgt.flight`` (the recording id named to the device and
the file name; for a log of `icgt recover-device`, the flight it was recovered for).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from icgt.protocol import MESSAGE_TYPES, Message

FRAMES = "/frames"
FRAMES_LOCATION = "/frames/location"
FRAMES_POSE = "/frames/pose"
TF = "/tf"
TF_STATIC = "/tf_static"
VEHICLE_LOCATION = "/vehicle/location"
CAMERA_CALIBRATION = "/camera/calibration"
CAMERA_IMAGE = "/camera/image"
DEVICE_LOG_VIEW = "/icgt/device_log"
LOG = "/icgt/log"
LINK_EVENTS = "/icgt/link_events"
COUNTERS = "/icgt/counters"
CLOCK_DEVICE = "/clock/device"
CLOCK_DEVICE_EXCHANGES = "/clock/device/exchanges"
CLOCK_AUTOPILOT = "/clock/autopilot"
CLOCK_AUTOPILOT_REQUESTS = "/clock/autopilot/requests"
CLOCK_UTC = "/clock/utc"
DEVICE_PREFIX = "/device/"
MAVLINK_PREFIX = "/mavlink/"
MAVLINK_OTHER_SYSTEMS = "/mavlink/other_systems"
CAMERA_IMAGES = "/camera/images"
WORLD_FRAME = "enu"
BASE_FRAME = "base_link"
MOUNT_FRAME = "camera_mount"
CAMERA_FRAME = "camera_optical"
FOXGLOVE_LAYOUT = Path(__file__).with_name("foxglove_layout.json")

META_CONFIG = "icgt.config"
META_SYNC = "icgt.sync"
META_CALIBRATION = "icgt.calibration"
META_DEVICE = "icgt.device"
META_TIME_BASES = "icgt.time_bases"
META_ENU_ORIGIN = "icgt.enu_origin"
META_DEVICE_LINK = "icgt.device_link"
META_MAVLINK_SIGNING = "icgt.mavlink_signing"
# Which flight a log is: its recording id (the one HOST_RECEIVED names to the device) and file name; a log
# written by `icgt recover-device` names the flight it was recovered for. (icgt.recording is the MCAP
# writer's own.)
META_FLIGHT = "icgt.flight"


def device_topic(name: str) -> str:
    """Topic of a device message type (its table name, e.g. EXPOSURE -> /device/exposure)."""
    return f"{DEVICE_PREFIX}{name.lower()}"


def mavlink_topic(name: str) -> str:
    """Topic of a MAVLink message type (e.g. GLOBAL_POSITION_INT -> /mavlink/global_position_int)."""
    return f"{MAVLINK_PREFIX}{name.lower()}"


DEVICE_TOPIC_TYPES: dict[str, type[Message]] = {
    device_topic(cls.NAME): cls for cls in MESSAGE_TYPES.values() if cls.DIRECTION == "device_to_host"
}
"""Device message class of each /device/... topic."""

_NUM = {"type": "number"}
_INT = {"type": "integer"}

ESTIMATE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "clock line: host_ns = ref_host_ns + (clock_us - ref_clock_us) * 1000 / (1 + drift_ppm * 1e-6)",
    "properties": {
        "valid": {"type": "boolean"},
        "settled": {"type": "boolean"},
        "n_used": _INT,
        "ref_clock_us": _NUM,
        "ref_host_ns": _INT,
        "drift_ppm": _NUM,
        "uncertainty_ns": _INT,
        "t_host_ns": _INT,
        "min_rtt_ns": _INT,
        "span_s": _NUM,
        "resets": _INT,
    },
}
EXCHANGE_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "one TIME_SYNC exchange with the device",
    "properties": {
        "host_tx_ns": _INT,
        "device_rx_us": _INT,
        "device_tx_us": _INT,
        "host_rx_ns": _INT,
        "status": {"type": "string"},
    },
}
TIMESYNC_REQUEST_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "one MAVLink TIMESYNC request sent to the autopilot (ts1 = host_tx_ns)",
    "properties": {"host_tx_ns": _INT},
}
UTC_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "UTC of host_ns",
    "properties": {
        "valid": {"type": "boolean"},
        "utc_us": _NUM,
        "uncertainty_us": _NUM,
        "source": {"type": "string"},
        "fallback": {"type": "boolean"},
        "host_ns": _INT,
    },
}
LINK_EVENT_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "a link state change, sequence gap, rejected frames or a synchroniser notice",
    "properties": {
        "link": {"type": "string"},
        "kind": {"type": "string"},
        "detail": {"type": "string"},
        "count": _INT,
        "outage_ns": _INT,
        "host_ns": _INT,
    },
}
MAVLINK_RAW_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "MAVLink frames from systems other than the vehicle's and its ground stations, raw, in order",
    "properties": {
        "frames": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {
                    "msg_type": {"type": "string"},
                    "src_system": _INT,
                    "src_component": _INT,
                    "host_rx_ns": {"type": "integer", "description": "host CLOCK_MONOTONIC at receipt [ns]"},
                    "raw": {"type": "string", "contentEncoding": "base64", "description": "the frame as received"},
                },
            },
        }
    },
}
COUNTERS_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "counters of the links and the synchroniser (cumulative since start)",
    "properties": {
        "host_ns": _INT,
        "device": {"type": "object"},
        "mavlink": {"type": "object"},
        "camera": {"type": "object", "description": "refused commands by kind and images published"},
        "sync": {"type": "object"},
    },
}
