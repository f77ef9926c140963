"""`icgt export --formats ros2`, read back by rosbags (an independent reader) message for message.

The bag of one simulated flight is checked for: the ros2 MCAP profile and CDR on every channel;
every topic's ROS type; one ROS message per source message (frames, IMU, range, telemetry, logs);
log-time order; the FrameRecords equal to what `icgt.read` gives; the tf chain enu -> base_link ->
camera_mount -> camera_optical giving back each frame's camera position and attitude; REP-145
axes of the IMU; /tf_static latched.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from export_exit import expected_export_exit
from mcap.reader import make_reader
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from icgt.cli import main
from icgt.export.ros2_msgs import MSG_TYPE, frame_record_msg_text, shipped_msg_text
from icgt.geodesy import Q_NED_TO_ENU, q_multiply, q_rotate
from icgt.ingest import read

TYPES = {
    "/vehicle/fix": "sensor_msgs/msg/NavSatFix",
    "/frames/fix": "sensor_msgs/msg/NavSatFix",
    "/frames": MSG_TYPE,
    "/camera/time_reference": "sensor_msgs/msg/TimeReference",
    "/imu": "sensor_msgs/msg/Imu",
    "/range": "sensor_msgs/msg/Range",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/tf_static": "tf2_msgs/msg/TFMessage",
    "/rosout": "rcl_interfaces/msg/Log",
}


@pytest.fixture(scope="module")
def bag(export_flight: Any, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("ros2")
    code = main(["export", str(export_flight.mcap), "--out", str(out), "--formats", "ros2", "--no-progress"])
    assert code == expected_export_exit(out)
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(shipped_msg_text(), MSG_TYPE))
    messages: list[tuple[str, str, int, Any]] = []
    with Reader(out / "ros2") as reader:
        conns = {c.topic: c for c in reader.connections}
        for conn, t, raw in reader.messages():
            messages.append((conn.topic, conn.msgtype, t, store.deserialize_cdr(raw, conn.msgtype)))
    return {"path": out / "ros2", "messages": messages, "connections": conns, "recording": read(export_flight.mcap)}


def _topic(bag: dict[str, Any], topic: str) -> list[Any]:
    return [m for t, _, _, m in bag["messages"] if t == topic]


def _ns(stamp: Any) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def test_shipped_definition_is_current() -> None:
    assert shipped_msg_text() == frame_record_msg_text(), "run python -m icgt.export.ros2_msgs"


def test_mcap_is_ros2_profile_and_cdr(bag: dict[str, Any]) -> None:
    with (bag["path"] / "ros2.mcap").open("rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        assert summary is not None
        assert {c.message_encoding for c in summary.channels.values()} == {"cdr"}
        assert {s.encoding for s in summary.schemas.values()} == {"ros2msg"}


def test_types_and_counts_match_the_recording(bag: dict[str, Any]) -> None:
    rec = bag["recording"]
    src = rec.topics()
    got: dict[str, int] = {}
    for topic, msgtype, _, _ in bag["messages"]:
        assert msgtype == TYPES[topic], topic
        got[topic] = got.get(topic, 0) + 1
    assert set(got) == set(TYPES)
    assert (
        got["/frames"] == got["/frames/fix"] == got["/camera/time_reference"] == src["/frames"] > 10
    )  # ~45 (5 fps), fewer on a loaded machine
    assert got["/imu"] == src["/device/imu"] > 100
    assert got["/range"] == src["/device/range"] > 100
    assert got["/vehicle/fix"] == src["/mavlink/global_position_int"] > 100
    assert got["/rosout"] == src.get("/icgt/log", 0) + src.get("/device/log", 0) > 0
    assert got["/tf_static"] == 1
    with (bag["path"] / "ros2.mcap").open("rb") as f:  # file order (rosbags' reader sorts by time itself)
        times = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert len(times) == len(bag["messages"])
    assert times == sorted(times), "messages not in log-time order"


def test_frame_records_round_trip(bag: dict[str, Any]) -> None:
    frames = list(bag["recording"].frames())
    msgs = _topic(bag, "/frames")
    fixes = _topic(bag, "/frames/fix")
    refs = _topic(bag, "/camera/time_reference")
    assert len(msgs) == len(frames)
    for rec, msg, fix, ref in zip(frames, msgs, fixes, refs, strict=True):
        for name in ("frame_seq", "image_index", "mid_host_ns", "flags", "position_source", "time_source"):
            assert getattr(msg, name) == getattr(rec, name), name
        for name in ("lat_deg", "lon_deg", "alt_msl_m", "range_m", "mid_utc_uncertainty_us", "blur_px"):
            want = getattr(rec, name)
            got = getattr(msg, name)
            assert (math.isnan(got) and want is None) or got == want, name
        assert msg.mid_utc_us == (rec.mid_utc_us if rec.mid_utc_us is not None else -1)
        assert (fix.latitude, fix.longitude, fix.altitude) == (rec.lat_deg, rec.lon_deg, rec.alt_msl_m)
        assert _ns(ref.time_ref) == rec.mid_utc_us * 1000
        assert _ns(ref.header.stamp) == _ns(msg.header.stamp) == _ns(fix.header.stamp)
        assert ref.source == rec.time_source


def _q(rot: Any) -> np.ndarray:
    return np.array([rot.w, rot.x, rot.y, rot.z])


def _v(t: Any) -> np.ndarray:
    return np.array([t.x, t.y, t.z])


def test_tf_chain_gives_the_camera_pose(bag: dict[str, Any]) -> None:
    (static,) = _topic(bag, "/tf_static")
    (mount,) = static.transforms
    assert (mount.header.frame_id, mount.child_frame_id) == ("base_link", "camera_mount")
    stamps = {_ns(m.header.stamp): m for m in _topic(bag, "/frames")}
    checked = 0
    for tf in _topic(bag, "/tf"):
        if len(tf.transforms) != 2:
            continue
        base, cam = tf.transforms
        assert (base.header.frame_id, base.child_frame_id) == ("enu", "base_link")
        assert (cam.header.frame_id, cam.child_frame_id) == ("camera_mount", "camera_optical")
        rec = stamps[_ns(base.header.stamp)]
        # compose enu <- base_link <- camera_mount <- camera_optical
        q_base = _q(base.transform.rotation)
        q = q_multiply(q_multiply(q_base, _q(mount.transform.rotation)), _q(cam.transform.rotation))
        pos = _v(base.transform.translation) + q_rotate(q_base, _v(mount.transform.translation))
        assert np.allclose(pos, [rec.east_m, rec.north_m, rec.up_m], atol=1e-9)
        want = q_multiply(Q_NED_TO_ENU, [rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz])
        assert abs(abs(float(np.dot(q, want))) - 1.0) < 1e-9
        checked += 1
    assert checked == len(stamps)
    telemetry = [m for m in _topic(bag, "/tf") if len(m.transforms) == 1]
    assert len(telemetry) > 100 and all(m.transforms[0].child_frame_id == "base_link" for m in telemetry)
    conn = bag["connections"]["/tf_static"]
    assert conn.ext.offered_qos_profiles[0].durability.name == "TRANSIENT_LOCAL"


def test_imu_is_rep145(bag: dict[str, Any]) -> None:
    imus = _topic(bag, "/imu")
    accel = np.array([[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in imus])
    # hovering: specific force is +g along the world's up; the camera is pitched up 12 deg on a gimbal
    up = np.array(
        [q_rotate(_q(m.orientation), a) for m, a in zip(imus, accel, strict=True) if m.orientation_covariance[0] >= 0]
    )
    assert len(up) > 100
    assert np.allclose(np.median(up, axis=0), [0.0, 0.0, 9.81], atol=0.3)
    assert all(m.header.frame_id == "imu_link" for m in imus)


def test_range_and_log(bag: dict[str, Any]) -> None:
    ranges = [m.range for m in _topic(bag, "/range")]
    valid = [r for r in ranges if not math.isnan(r)]
    assert len(valid) > 0.9 * len(ranges)
    assert 2.0 < float(np.median(valid)) < 4.5  # hovering 3 m from the face, camera pitched 12 deg
    logs = _topic(bag, "/rosout")
    assert all(m.level in (10, 20, 30, 40, 50) for m in logs)
    assert any("device link summary" in m.msg for m in logs)


def test_replaces_an_old_bag(bag: dict[str, Any], export_flight: Any, tmp_path: Path) -> None:
    args = ["export", str(export_flight.mcap), "--out", str(tmp_path), "--formats", "ros2", "--no-progress"]
    assert main(args) == expected_export_exit(tmp_path)
    assert main(args) == expected_export_exit(tmp_path)
    with Reader(tmp_path / "ros2") as reader:
        assert reader.message_count == len(bag["messages"])


class _FakeRecording:
    """Just what write_ros2_bag reads, with messages in a file order that strays from log-time order."""

    def __init__(self, path: Path, messages: list[tuple[str, int, dict[str, Any]]]) -> None:
        self.path = path
        self._messages = messages
        self.metadata: dict[str, dict[str, str]] = {}
        self.enu_origin = (37.0, 127.0, 50.0)
        self.monotonic_to_utc_offset_ns = 0

    def topics(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for t, _, _ in self._messages:
            out[t] = out.get(t, 0) + 1
        return out

    def records(self, topics: list[str]) -> Any:
        from icgt.ingest.reader import LogMessage

        return (LogMessage(t, ns, d) for t, ns, d in self._messages if t in topics)


def _range(cm: int) -> dict[str, Any]:
    return {"distance_cm": cm, "flags": 1, "signal_strength": 80}


def test_reorders_within_the_window_and_reports_later_ones(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    from icgt.export.ros2 import write_ros2_bag

    s = 1_000_000_000
    # 1 is 1 s out of order (reordered); 5 comes after 30 and 31 were written (40 s late: reported)
    order = [0, 2, 1, 3, 30, 31, 45, 5, 46]
    messages = [("/device/range", 1000 * s + i * s, _range(100 + i)) for i in order]
    result = write_ros2_bag(_FakeRecording(tmp_path / "fake.mcap", messages), tmp_path)
    assert result.counts == {"/range": 9, "/tf_static": 1}
    with (result.path / "ros2.mcap").open("rb") as f:  # in file order (rosbags' reader sorts by time)
        msgs = make_reader(f).iter_messages(topics=["/range"], log_time_order=False)
        times = [(m.log_time - 1000 * s) // s for _, _, m in msgs]
    assert times == [0, 1, 2, 3, 30, 31, 5, 45, 46]
    assert "1 messages came more than 10 s out of log-time order" in caplog.text


def test_a_recording_with_nothing_to_convert_is_refused(tmp_path: Path) -> None:
    from icgt.export.ros2 import Ros2ExportError, write_ros2_bag

    fake = _FakeRecording(tmp_path / "empty.mcap", [("/device/hello", 1, {})])
    with pytest.raises(Ros2ExportError, match="nothing to convert"):
        write_ros2_bag(fake, tmp_path)
    assert not (tmp_path / "ros2").exists()


def test_ros2_alone_needs_no_camera_model_nor_frames(tmp_path: Path) -> None:
    from icgt.recording import McapRecorder

    path = tmp_path / "log.mcap"
    with McapRecorder(path, fsync=False) as rec:  # a recording of range samples only: no frames, no calibration
        rec.add_metadata("icgt.config", {"source": "test", "config": "{}"})  # as the recorder writes
        rec.register_json("/device/range", "icgt.device.RANGE", {"type": "object"})
        for i in range(5):
            rec.write("/device/range", {"distance_cm": 300 + i, "flags": 1}, 1_700_000_000_000_000_000 + i * 10**7)
    out = tmp_path / "out"
    assert main(["export", str(path), "--out", str(out), "--formats", "ros2", "--no-progress"]) == 0
    with Reader(out / "ros2") as reader:
        assert {c.topic: c.msgcount for c in reader.connections} == {"/range": 5, "/tf_static": 1}
    assert main(["export", str(path), "--out", str(tmp_path / "o2"), "--formats", "csv", "--no-progress"]) == 1
