"""The recorder's Foxglove views: vehicle track, transform tree, camera calibration and device log.

Fed by the recorder's worker with the same inputs the synchroniser gets (telemetry, device LOG
messages, frames), it writes derived messages in Foxglove's schemas beside the raw streams, so that
Foxglove's Map, 3D, Image and Log panels show the flight with no conversion (and the live view,
which is fed what the file is fed, shows it during the flight):

* ``/vehicle/location`` (foxglove.LocationFix): every GLOBAL_POSITION_INT of the vehicle (MSL
  altitude; covariance from the last GPS_RAW_INT's h_acc / v_acc), frame ``base_link``;
* ``/tf`` (foxglove.FrameTransforms): ``enu -> base_link`` at every ATTITUDE_QUATERNION (position of
  the last GLOBAL_POSITION_INT) once the ENU origin is fixed (the geotagger fixes it at the first
  frame, from the oldest fix it holds, unless [camera] origin gives it; before that the vehicle is on
  the map only: an origin chosen here could differ from the frames'), and at every frame
  ``enu -> base_link`` from the frame's own geotagged pose plus ``camera_mount -> camera_optical``
  (what a gimbal turned the camera by; identity for a fixed mount);
* ``/tf_static`` (foxglove.FrameTransforms): ``base_link -> camera_mount`` (lever arm and mounting
  from [camera]), once at the start;
* ``/camera/calibration`` (foxglove.CameraCalibration): the pinhole model from [camera]
  (focal_length_mm, sensor_width_mm, image_width_px x image_height_px; principal point at the image
  centre, no distortion), at the start and with every frame, frame ``camera_optical``;
* ``/frames/location`` (LocationFix, ``camera_optical``) and ``/frames/pose`` (PoseInFrame, ``enu``):
  each frame's camera position and pose at mid-exposure;
* ``/icgt/device_log`` (foxglove.Log): the device's LOG messages (name ``icgt.device``).

Frames: ``enu`` is the recording's local east-north-up frame (origin: the geotagger's, metadata
``icgt.enu_origin``); ``base_link`` is the vehicle body in ROS's FLU axes (REP-103), ``camera_mount``
and ``camera_optical`` have the optical axes (x right, y down, z forward), as in the ROS 2 export.
Times: every message's timestamp is its publish time, host CLOCK_MONOTONIC plus the recording's fixed
offset [ns since the Unix epoch], one base for all topics so transform lookups between them hold; a
telemetry message is stamped at its receipt, a frame at its mid-exposure (its GPS-derived UTC is in
``/frames``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.Log_pb2 import Log as FoxgloveLog
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame

from icgt.geodesy import Q_NED_TO_ENU, LocalFrame, q_multiply
from icgt.geotag import FrameRecord
from icgt.geotag.config import GeotagConfig
from icgt.pose import (
    Q_FRD_TO_FLU,
    camera_to_body_quaternion,
    frame_tree,
    frd_to_flu,
    q_flu_to_enu_floats,
)
from icgt.recording import layout

Write = Callable[[str, Any, int], None]
"""The recorder's write: (topic, message, host CLOCK_MONOTONIC ns of the data)."""

_DEVICE_LOG_LEVELS = {1: FoxgloveLog.DEBUG, 2: FoxgloveLog.INFO, 3: FoxgloveLog.WARNING, 4: FoxgloveLog.ERROR}
_GPS_FIX_3D = 3


def camera_calibration(cfg: GeotagConfig, timestamp_ns: int) -> CameraCalibration:
    """The camera's pinhole model from [camera]: fx = fy = focal_length_mm * image_width_px / sensor_width_mm [px]."""
    w, h = cfg.image_width_px, cfg.image_height_px
    f = cfg.focal_length_mm * w / cfg.sensor_width_mm
    cx, cy = w / 2.0, h / 2.0
    cal = CameraCalibration(frame_id=layout.CAMERA_FRAME, width=w, height=h, distortion_model="plumb_bob")
    cal.timestamp.FromNanoseconds(timestamp_ns)
    cal.D.extend([0.0] * 5)
    cal.K.extend([f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0])
    cal.R.extend([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    cal.P.extend([f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0])
    return cal


def _transform(ns: int, parent: str, child: str, xyz: Any, q_wxyz: Any) -> FrameTransform:
    w, x, y, z = (float(c) for c in q_wxyz)
    norm = math.sqrt(w * w + x * x + y * y + z * z)
    tf = FrameTransform(parent_frame_id=parent, child_frame_id=child)
    tf.timestamp.FromNanoseconds(ns)
    tf.translation.x, tf.translation.y, tf.translation.z = (float(c) for c in xyz)
    tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z = w / norm, x / norm, y / norm, z / norm
    return tf


def _finite(*values: float | None) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


TOPICS: dict[str, type] = {
    layout.VEHICLE_LOCATION: LocationFix,
    layout.TF: FrameTransforms,
    layout.TF_STATIC: FrameTransforms,
    layout.CAMERA_CALIBRATION: CameraCalibration,
    layout.FRAMES_LOCATION: LocationFix,
    layout.FRAMES_POSE: PoseInFrame,
    layout.DEVICE_LOG_VIEW: FoxgloveLog,
}
"""Every topic the views write and its message type (declared when the log opens, so that a live client
can subscribe before the first message)."""


class FoxgloveViews:
    """Derives the Foxglove topics from the recorder's inputs; single-threaded (the recorder's worker).

    `write(topic, message, host_ns)` records a message whose data time is `host_ns` (host
    CLOCK_MONOTONIC); `to_epoch_ns` turns that into the recording's time base (its fixed offset);
    `origin()` is the geotagger's ENU origin (lat, lon, alt MSL) or None while it has none.
    """

    def __init__(
        self,
        camera: GeotagConfig,
        write: Write,
        to_epoch_ns: Callable[[int], int],
        origin: Callable[[], tuple[float, float, float] | None],
        vehicle_system: int,
    ) -> None:
        self._cfg = camera
        self._write = write
        self._epoch = to_epoch_ns
        self._origin = origin
        self._system = vehicle_system
        self._q_cam_to_body = np.asarray(camera_to_body_quaternion(camera))
        self._lever_frd = tuple(float(c) for c in camera.lever_arm_body_m)
        self._local: tuple[tuple[float, float, float], LocalFrame] | None = None  # (origin, its ENU frame)
        self._position_enu: tuple[float, float, float] | None = None
        self._last_fix: tuple[float, float, float] | None = None  # the last GLOBAL_POSITION_INT (lat, lon, alt)
        self._accuracy_m: tuple[float, float] | None = None
        self.counts: dict[str, int] = {}

    def _out(self, topic: str, message: Any, host_ns: int) -> None:
        self._write(topic, message, host_ns)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    # --- the start --------------------------------------------------------------------------------
    def start(self, host_ns: int) -> None:
        """The static mount transform and the calibration, once when the log opens."""
        ns = self._epoch(host_ns)
        self._out(layout.TF_STATIC, FrameTransforms(transforms=[self.mount_transform(ns)]), host_ns)
        self._out(layout.CAMERA_CALIBRATION, camera_calibration(self._cfg, ns), host_ns)

    def mount_transform(self, ns: int) -> FrameTransform:
        """base_link -> camera_mount: the lever arm (FRD, in FLU here) and the camera's mounting."""
        q = q_multiply(Q_FRD_TO_FLU, self._q_cam_to_body)  # camera (optical axes) -> base_link FLU
        return _transform(ns, layout.BASE_FRAME, layout.MOUNT_FRAME, frd_to_flu(self._lever_frd), q)

    # --- telemetry --------------------------------------------------------------------------------
    def on_mavlink(self, msg: Any, rx_ns: int) -> None:
        """One MAVLink message as the recorder received it (other systems' are ignored)."""
        if msg.get_srcSystem() != self._system:
            return
        name = msg.get_type()
        if name == "GLOBAL_POSITION_INT":
            self._global_position(msg, rx_ns)
        elif name == "ATTITUDE_QUATERNION":
            self._attitude(msg, rx_ns)
        elif name == "GPS_RAW_INT":
            h, v = getattr(msg, "h_acc", 0), getattr(msg, "v_acc", 0)  # MAVLink 2 extensions [mm]; 0: unknown
            self._accuracy_m = (h / 1000.0, v / 1000.0) if h and v else None
            if msg.fix_type < _GPS_FIX_3D:
                self._accuracy_m = None

    def _enu(self, lat: float, lon: float, alt: float) -> tuple[float, float, float] | None:
        origin = self._origin()
        if origin is None:
            return None
        if self._local is None or origin != self._local[0]:
            self._local = (origin, LocalFrame(*origin))
        return self._local[1].geodetic_to_enu_point(lat, lon, alt)

    def _global_position(self, msg: Any, rx_ns: int) -> None:
        if msg.lat == 0 and msg.lon == 0:
            return  # no position yet (PX4 and ArduPilot send zeros before a fix)
        lat, lon, alt = msg.lat / 1e7, msg.lon / 1e7, msg.alt / 1000.0
        fix = LocationFix(frame_id=layout.BASE_FRAME, latitude=lat, longitude=lon, altitude=alt)
        fix.timestamp.FromNanoseconds(self._epoch(rx_ns))
        if self._accuracy_m is not None:
            h, v = self._accuracy_m
            fix.position_covariance.extend([h * h, 0, 0, 0, h * h, 0, 0, 0, v * v])
            fix.position_covariance_type = LocationFix.DIAGONAL_KNOWN
        else:
            fix.position_covariance.extend([0.0] * 9)
            fix.position_covariance_type = LocationFix.UNKNOWN
        self._out(layout.VEHICLE_LOCATION, fix, rx_ns)
        self._last_fix = (lat, lon, alt)
        self._position_enu = self._enu(lat, lon, alt)

    def _attitude(self, msg: Any, rx_ns: int) -> None:
        q = (float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4))  # w, x, y, z: body FRD -> NED
        if self._position_enu is None and self._last_fix is not None:
            # The ENU origin was fixed (at the first frame) after the last position came: place base_link
            # there now, not only from the next GLOBAL_POSITION_INT (an attitude between the two had no /tf).
            self._position_enu = self._enu(*self._last_fix)
        if self._position_enu is None or not _finite(*q) or not 0.5 < math.sqrt(sum(c * c for c in q)) < 1.5:
            return
        pose = q_flu_to_enu_floats(q)
        tf = _transform(self._epoch(rx_ns), layout.WORLD_FRAME, layout.BASE_FRAME, self._position_enu, pose)
        self._out(layout.TF, FrameTransforms(transforms=[tf]), rx_ns)

    # --- the device's log -------------------------------------------------------------------------
    def on_device_log(self, level: int, text: str, rx_ns: int) -> None:
        """A device LOG message (protocol LogLevel; FATAL and unknown levels: FATAL / INFO)."""
        lvl = _DEVICE_LOG_LEVELS.get(level, FoxgloveLog.FATAL if level >= 5 else FoxgloveLog.INFO)
        entry = FoxgloveLog(level=lvl, message=text, name="icgt.device")
        entry.timestamp.FromNanoseconds(self._epoch(rx_ns))
        self._out(layout.DEVICE_LOG_VIEW, entry, rx_ns)

    # --- frames -----------------------------------------------------------------------------------
    def on_frame(self, rec: FrameRecord) -> None:
        """A frame's camera position, pose, transforms and calibration at its mid-exposure."""
        host = rec.mid_host_ns
        ns = self._epoch(host)
        if _finite(rec.lat_deg, rec.lon_deg, rec.alt_msl_m):
            assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
            fix = LocationFix(
                frame_id=layout.CAMERA_FRAME, latitude=rec.lat_deg, longitude=rec.lon_deg, altitude=rec.alt_msl_m
            )
            fix.timestamp.FromNanoseconds(ns)
            h = rec.h_acc_m if rec.h_acc_m is not None else 0.0
            v = rec.v_acc_m if rec.v_acc_m is not None else 0.0
            fix.position_covariance.extend([h * h, 0, 0, 0, h * h, 0, 0, 0, v * v])
            known = rec.h_acc_m is not None and rec.v_acc_m is not None
            fix.position_covariance_type = LocationFix.DIAGONAL_KNOWN if known else LocationFix.UNKNOWN
            self._out(layout.FRAMES_LOCATION, fix, host)
        body = (rec.body_qw, rec.body_qx, rec.body_qy, rec.body_qz)
        cam = (rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz)
        if _finite(*cam) and _finite(rec.east_m, rec.north_m, rec.up_m):
            cam_enu = np.array([rec.east_m, rec.north_m, rec.up_m], dtype=float)
            q_cam_enu = q_multiply(Q_NED_TO_ENU, cam)  # camera (optical) -> ENU
            pose = PoseInFrame(frame_id=layout.WORLD_FRAME)
            pose.timestamp.FromNanoseconds(ns)
            p, o = pose.pose.position, pose.pose.orientation
            p.x, p.y, p.z = (float(c) for c in cam_enu)
            o.w, o.x, o.y, o.z = (float(c) for c in q_cam_enu / np.linalg.norm(q_cam_enu))
            self._out(layout.FRAMES_POSE, pose, host)
            if _finite(*body):
                base_enu, q_base, residual = frame_tree(cam_enu, body, cam, self._q_cam_to_body, self._lever_frd)
                transforms = [
                    _transform(ns, layout.WORLD_FRAME, layout.BASE_FRAME, base_enu, q_base),
                    _transform(ns, layout.MOUNT_FRAME, layout.CAMERA_FRAME, (0.0, 0.0, 0.0), residual),
                ]
                self._out(layout.TF, FrameTransforms(transforms=transforms), host)
        self._out(layout.CAMERA_CALIBRATION, camera_calibration(self._cfg, ns), host)
