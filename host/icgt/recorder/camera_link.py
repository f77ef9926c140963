"""The recorder's side of the MAVLink camera: building the component, and turning frames into images.

`CameraImages` gets every GLOBAL_POSITION_INT of the vehicle (for home's altitude, `icgt.mavlink.home`)
and every frame the synchroniser emits, on the recorder's worker thread. For each frame it builds the
CAMERA_IMAGE_CAPTURED contents under the poor-pose policy (below), publishes it
(the camera gives it the next image index) and returns the record for the log's ``/camera/images``
topic: the MAVLink index next to the frame's ``frame_seq`` and the device's trigger number, what was
published and why. A frame that cannot be published (a value MAVLink cannot carry) gets no index and a
record saying so.

Poor poses: the synchroniser already holds a frame until its pose can be interpolated (the next position
sample came) or its bounded wait ran out; whatever flags the frame then carries are final. A frame whose
pose is missing or not trustworthy (`POOR_POSE_FLAGS`: no fix, no pose, telemetry expired, stale or
extrapolated pose, no attitude) or whose
exposure the camera did not confirm (feedback_missing) is published with ``capture_result`` 0 and, for a
poor pose, lat = lon = alt = relative_alt = 0 and the quaternion NaN: fields no ground station can take
for a good fix. ``/camera/images`` says for each image which rule applied, so the log and the ground
station agree on which images are good; `icgt map` uses the same flags to leave such images out.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from icgt.errors import IcgtError
from icgt.geodesy import q_conjugate, q_multiply
from icgt.geotag import FrameRecord
from icgt.geotag.record import POOR_POSE_FLAGS, FrameFlag
from icgt.mavlink.camera import CameraComponent, CameraConfig, CameraInfo, CaptureHandler
from icgt.mavlink.camera_images import CapturedImage
from icgt.mavlink.camera_settings import CameraSettings
from icgt.mavlink.home import HomeAltitude
from icgt.mavlink.link import MavlinkLink
from icgt.pose import Q_OPTICAL_TO_FRD
from icgt.recorder.config import RecorderConfig

__all__ = ["CAMERA_IMAGES_SCHEMA", "CameraImages", "build_camera", "pose_verdict"]

CAMERA_IMAGES_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": "one CAMERA_IMAGE_CAPTURED as the ground station got it, and the frame it came from",
    "properties": {
        "image_index": {"type": "integer", "description": "MAVLink image index (-1: not published)"},
        "frame_seq": {"type": "integer", "description": "the frame's frame_seq in /frames"},
        "device_image_index": {"type": "integer", "description": "the device's trigger number (0: unsolicited)"},
        "capture_result": {"type": "boolean", "description": "CAMERA_IMAGE_CAPTURED.capture_result"},
        "position_published": {"type": "boolean", "description": "false: lat/lon/alt/relative_alt sent as 0"},
        "relative_alt_m": {"type": ["number", "null"], "description": "height above home sent [m]"},
        "reason": {"type": "string", "description": "why capture_result / the position are what they are"},
        "host_ns": {"type": "integer", "description": "host CLOCK_MONOTONIC of mid-exposure [ns]"},
    },
}


def build_camera(
    config: RecorderConfig, link: MavlinkLink, handler: CaptureHandler, settings: CameraSettings | None = None
) -> CameraComponent:
    """The camera component the recorder runs on ``link`` (which carries the signing key if one is set), with
    the capture settings a ground station may change (`icgt.recorder.camera_settings`) if given."""
    c = config.camera
    info = CameraInfo(
        focal_length_mm=c.focal_length_mm,
        sensor_size_h_mm=c.sensor_width_mm,
        sensor_size_v_mm=c.sensor_width_mm * c.image_height_px / c.image_width_px,
        resolution_h=c.image_width_px,
        resolution_v=c.image_height_px,
    )
    return CameraComponent(
        link,
        CameraConfig(
            output_dir=config.output.dir,
            info=info,
            ground_station_systems=frozenset(config.mavlink.ground_station_systems),
            require_signing=link.signing is not None,
            settings=settings,
        ),
        handler,
    )


def pose_verdict(flags: list[str]) -> tuple[bool, bool, str]:
    """(capture_result, position published, reason) for a frame's flags, per the policy above."""
    poor = [f.value for f in POOR_POSE_FLAGS if f.value in flags]
    unconfirmed = FrameFlag.FEEDBACK_MISSING.value in flags
    reasons = []
    if poor:
        reasons.append("poor pose (" + ", ".join(poor) + "): no position published")
    if unconfirmed:
        reasons.append("the camera did not confirm the exposure (feedback_missing)")
    return (not poor and not unconfirmed), not poor, "; ".join(reasons) or "good"


class CameraImages:
    """Frames -> CAMERA_IMAGE_CAPTURED, with height above home. Worker thread only."""

    def __init__(self, vehicle_system: int) -> None:
        self._vehicle = vehicle_system
        self.home = HomeAltitude()

    def on_mavlink(self, msg: Any, src_system: int, rx_ns: int) -> None:
        if src_system == self._vehicle and msg.get_type() == "GLOBAL_POSITION_INT":
            self.home.on_global_position(msg, rx_ns)

    def image(self, rec: FrameRecord, time_boot_ms: int) -> tuple[CapturedImage, str, bool]:
        """(what to publish, the policy's reason, whether the position is published) for one frame."""
        capture_result, position_ok, reason = pose_verdict(rec.flags)
        if position_ok and (rec.lat_deg is None or rec.lon_deg is None or rec.alt_msl_m is None):
            # Every flag that leaves a frame without a position is a poor-pose flag; this guards a new one.
            capture_result, position_ok, reason = False, False, "no position in the frame record"
        q = None
        if rec.cam_qw is not None and position_ok:
            # MAVLink's camera quaternion is the camera body (x forward) in NED: undo the optical base.
            cq = np.array([rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz], dtype=float)
            q4 = [float(v) for v in q_multiply(cq, q_conjugate(Q_OPTICAL_TO_FRD))]
            q = (q4[0], q4[1], q4[2], q4[3])
        rel = self.home.relative_alt_m(rec.alt_msl_m, rec.mid_host_ns) if position_ok else None
        image = CapturedImage(
            time_boot_ms=time_boot_ms,
            time_utc_us=rec.mid_utc_us or 0,
            lat_deg=rec.lat_deg if position_ok else None,
            lon_deg=rec.lon_deg if position_ok else None,
            alt_msl_m=rec.alt_msl_m if position_ok else None,
            relative_alt_m=rel,
            q_wxyz=q,
            capture_result=capture_result,
            camera_id=rec.camera_id,
        )
        return image, reason, position_ok

    def publish(self, camera: CameraComponent, rec: FrameRecord) -> dict[str, Any]:
        """Publish one frame's image; the /camera/images record of it."""
        image, reason, position_ok = self.image(rec, camera.time_boot_ms(rec.mid_host_ns))
        index = -1
        try:
            index = camera.publish_image_captured(image).image_index
        except IcgtError as exc:
            reason = f"not published: {exc}"
        return {
            "image_index": index,
            "frame_seq": rec.frame_seq,
            "device_image_index": rec.image_index,
            "capture_result": image.capture_result,
            "position_published": position_ok,
            "relative_alt_m": image.relative_alt_m,
            "reason": reason,
            "host_ns": rec.mid_host_ns,
        }
