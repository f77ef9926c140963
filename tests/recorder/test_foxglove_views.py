"""The recorder's Foxglove views fed by hand (pymavlink messages, a frame record): what each input gives."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.Log_pb2 import Log
from pymavlink.dialects.v20 import common as mav

from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply, q_rotate
from icgt.geotag import FrameRecord
from icgt.geotag.config import GeotagConfig
from icgt.pose import camera_to_body_quaternion, q_flu_to_enu
from icgt.recording import layout
from icgt.recording.views import TOPICS, FoxgloveViews, camera_calibration

ORIGIN = (37.8813, 127.7298, 82.0)
OFFSET = 1_700_000_000_000_000_000


def _packed(msg: Any, system: int = 1) -> Any:
    msg.pack(mav.MAVLink(None, srcSystem=system, srcComponent=1))
    return msg


def _views(cfg: GeotagConfig, origin: Any = ORIGIN) -> tuple[FoxgloveViews, list[tuple[str, Any, int]]]:
    out: list[tuple[str, Any, int]] = []
    views = FoxgloveViews(cfg, lambda t, m, ns: out.append((t, m, ns)), lambda ns: ns + OFFSET, lambda: origin, 1)
    return views, out


def test_telemetry_gives_the_track_and_base_link_in_the_enu_frame() -> None:
    views, out = _views(GeotagConfig())
    views.on_mavlink(_packed(mav.MAVLink_global_position_int_message(0, 0, 0, 0, 0, 0, 0, 0, 0)), 10)  # no fix yet
    views.on_mavlink(_packed(mav.MAVLink_attitude_quaternion_message(0, 1, 0, 0, 0, 0, 0, 0)), 11)  # no position
    assert out == []
    gps = mav.MAVLink_gps_raw_int_message(0, 3, 0, 0, 0, 0, 0, 0, 0, 12, h_acc=800, v_acc=1500)
    views.on_mavlink(_packed(gps), 20)
    views.on_mavlink(
        _packed(mav.MAVLink_global_position_int_message(0, 378814000, 1277299000, 88500, 0, 0, 0, 0, 0)), 30
    )
    q = q_from_euler_zyx(0.05, -0.02, math.radians(30))  # body FRD -> NED
    views.on_mavlink(_packed(mav.MAVLink_attitude_quaternion_message(0, *q, 0, 0, 0)), 40)
    views.on_mavlink(_packed(mav.MAVLink_global_position_int_message(0, 1, 1, 1, 0, 0, 0, 0, 0), system=7), 50)
    assert [t for t, _, _ in out] == [layout.VEHICLE_LOCATION, layout.TF]
    fix: LocationFix = out[0][1]
    assert (fix.latitude, fix.longitude, fix.altitude) == (37.8814, 127.7299, 88.5)
    assert fix.timestamp.ToNanoseconds() == 30 + OFFSET and fix.frame_id == layout.BASE_FRAME
    assert list(fix.position_covariance) == pytest.approx([0.64, 0, 0, 0, 0.64, 0, 0, 0, 2.25])
    tf = out[1][1].transforms[0]
    assert (tf.parent_frame_id, tf.child_frame_id) == (layout.WORLD_FRAME, layout.BASE_FRAME)
    enu = LocalFrame(*ORIGIN).geodetic_to_enu(37.8814, 127.7299, 88.5)
    assert [tf.translation.x, tf.translation.y, tf.translation.z] == pytest.approx(list(enu), abs=1e-9)
    rot = [tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z]
    assert rot == pytest.approx(list(q_flu_to_enu(q)), abs=1e-12)
    # base_link's x axis (forward) points 30 deg east of north in ENU
    fwd = q_rotate(rot, [1.0, 0.0, 0.0])
    assert math.degrees(math.atan2(fwd[0], fwd[1])) == pytest.approx(30.0, abs=0.5)
    assert out[1][2] == 40  # stamped with the attitude's receipt


def test_without_an_origin_the_vehicle_is_only_on_the_map() -> None:
    views, out = _views(GeotagConfig(), origin=None)
    views.on_mavlink(
        _packed(mav.MAVLink_global_position_int_message(0, 378814000, 1277299000, 88500, 0, 0, 0, 0, 0)), 1
    )
    views.on_mavlink(_packed(mav.MAVLink_attitude_quaternion_message(0, 1, 0, 0, 0, 0, 0, 0)), 2)
    assert [t for t, _, _ in out] == [layout.VEHICLE_LOCATION]
    assert out[0][1].position_covariance_type == LocationFix.UNKNOWN


def test_base_link_from_the_first_attitude_after_the_origin_is_fixed() -> None:
    """The origin is fixed (at the first frame) between a position and the next attitude: that attitude already
    has its /tf, at the last position (it used to wait for the next GLOBAL_POSITION_INT)."""
    origin: list[Any] = [None]
    out: list[tuple[str, Any, int]] = []
    views = FoxgloveViews(GeotagConfig(), lambda t, m, ns: out.append((t, m, ns)), lambda ns: ns, lambda: origin[0], 1)
    views.on_mavlink(
        _packed(mav.MAVLink_global_position_int_message(0, 378814000, 1277299000, 88500, 0, 0, 0, 0, 0)), 1
    )
    views.on_mavlink(_packed(mav.MAVLink_attitude_quaternion_message(0, 1, 0, 0, 0, 0, 0, 0)), 2)
    origin[0] = ORIGIN
    views.on_mavlink(_packed(mav.MAVLink_attitude_quaternion_message(0, 1, 0, 0, 0, 0, 0, 0)), 3)
    assert [(t, ns) for t, _, ns in out] == [(layout.VEHICLE_LOCATION, 1), (layout.TF, 3)]
    tf = out[1][1].transforms[0]
    enu = LocalFrame(*ORIGIN).geodetic_to_enu(37.8814, 127.7299, 88.5)
    assert [tf.translation.x, tf.translation.y, tf.translation.z] == pytest.approx(list(enu), abs=1e-9)


def test_the_start_gives_the_mount_and_the_calibration() -> None:
    cfg = GeotagConfig(
        focal_length_mm=24.0, sensor_width_mm=36.0, image_width_px=6000, image_height_px=4000,
        mount_pitch_deg=-90.0, lever_arm_body_m=(0.2, 0.05, 0.1),
    )  # fmt: skip
    views, out = _views(cfg)
    views.start(5)
    assert [t for t, _, _ in out] == [layout.TF_STATIC, layout.CAMERA_CALIBRATION]
    mount = out[0][1].transforms[0]
    assert [mount.translation.x, mount.translation.y, mount.translation.z] == pytest.approx([0.2, -0.05, -0.1])
    # the optical axis (z) of a camera pitched 90 deg down points down in base_link (FLU: -z)
    q = [mount.rotation.w, mount.rotation.x, mount.rotation.y, mount.rotation.z]
    assert q_rotate(q, [0.0, 0.0, 1.0]) == pytest.approx([0.0, 0.0, -1.0], abs=1e-9)
    cal: CameraCalibration = out[1][1]
    assert list(cal.K) == pytest.approx([4000.0, 0, 3000.0, 0, 4000.0, 2000.0, 0, 0, 1])
    assert list(cal.P)[:3] == pytest.approx([4000.0, 0, 3000.0]) and len(cal.D) == 5
    assert cal == camera_calibration(cfg, 5 + OFFSET)


def test_a_frame_gives_its_location_pose_transforms_and_calibration() -> None:
    cfg = GeotagConfig(lever_arm_body_m=(0.25, 0.0, 0.12), mount_pitch_deg=12.0)
    views, out = _views(cfg)
    body = q_from_euler_zyx(0.02, 0.01, 1.0)
    gimbal = q_from_euler_zyx(0.0, 0.1, 0.0)  # the camera turned a little further by a gimbal
    cam = q_multiply(q_multiply(body, gimbal), camera_to_body_quaternion(cfg))
    rec = FrameRecord(
        frame_seq=3, image_index=3, camera_id=0, device_flags=0, trigger_device_us=0, start_device_us=0,
        mid_device_us=0, duration_us=1000, mid_host_ns=1_000, mid_host_uncertainty_ns=100,
        time_source="host_realtime", flags=[], position_source="gps", fix_type=3, pose_gap_before_ms=0.0,
        pose_gap_after_ms=0.0, lat_deg=37.8814, lon_deg=127.7299, alt_msl_m=88.0,
        h_acc_m=0.5, v_acc_m=0.9, east_m=3.0, north_m=-2.0, up_m=6.0,
        body_qw=body[0], body_qx=body[1], body_qy=body[2], body_qz=body[3],
        cam_qw=cam[0], cam_qx=cam[1], cam_qy=cam[2], cam_qz=cam[3],
    )  # fmt: skip
    views.on_frame(rec)
    topics = [t for t, _, _ in out]
    assert topics == [layout.FRAMES_LOCATION, layout.FRAMES_POSE, layout.TF, layout.CAMERA_CALIBRATION]
    assert all(ns == 1_000 for _, _, ns in out) and all(type(m) is TOPICS[t] for t, m, _ in out)
    base, optical = out[2][1].transforms
    lever = [0.25, 0.0, -0.12]  # FLU
    qb = [base.rotation.w, base.rotation.x, base.rotation.y, base.rotation.z]
    cam_pos = np.array([base.translation.x, base.translation.y, base.translation.z]) + q_rotate(qb, lever)
    assert cam_pos == pytest.approx([3.0, -2.0, 6.0], abs=1e-9)
    # enu -> base_link -> camera_mount -> camera_optical composes to the recorded camera attitude
    mount = views.mount_transform(0)
    qm = [mount.rotation.w, mount.rotation.x, mount.rotation.y, mount.rotation.z]
    qo = [optical.rotation.w, optical.rotation.x, optical.rotation.y, optical.rotation.z]
    chain = q_multiply(q_multiply(qb, qm), qo)
    pose = out[1][1].pose.orientation
    assert abs(float(np.dot(chain, [pose.w, pose.x, pose.y, pose.z]))) == pytest.approx(1.0, abs=1e-9)
    assert out[3][1].timestamp.ToNanoseconds() == 1_000 + OFFSET


def test_device_log_levels() -> None:
    views, out = _views(GeotagConfig())
    for level in (1, 2, 3, 4, 5, 99):
        views.on_device_log(level, f"level {level}", 7)
    levels = [m.level for _, m, _ in out]
    assert levels == [Log.DEBUG, Log.INFO, Log.WARNING, Log.ERROR, Log.FATAL, Log.FATAL]
    assert {t for t, _, _ in out} == {layout.DEVICE_LOG_VIEW} and out[0][1].name == "icgt.device"


def test_the_shipped_layout_is_the_one_the_sdk_types_make() -> None:
    import json

    from icgt.recording.foxglove_layout import build_layout

    text = layout.FOXGLOVE_LAYOUT.read_text()
    assert text == build_layout(), "run python -m icgt.recording.foxglove_layout"

    def panels(node: Any) -> list[dict[str, Any]]:
        if node.get("type") == "panel":
            return [node]
        return [p for item in node["items"] for p in panels(item["content"])]

    kinds = sorted(p["panelType"] for p in panels(json.loads(text)["content"]))
    assert kinds == ["Image", "Log", "Log", "Map", "Plot", "Plot", "RawMessages", "ThreeDee"]
