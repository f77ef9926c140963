"""`icgt export --formats ros2`: the recording as a ROS 2 bag (rosbag2, MCAP storage, CDR).

Written with `rosbags` (pure Python, writes rosbag2 metadata.yaml and the ros2-profile MCAP that
`ros2 bag play` and rosbags read); the message types are ROS 2 Humble's, plus
``icgt_msgs/msg/FrameRecord`` whose definition ships with this package (`icgt.export.ros2_msgs`).

Topics (frames: ROS conventions REP-103 / REP-105 / REP-145; ``enu`` is the recording's local
east-north-up frame at metadata ``icgt.enu_origin``):

==========================  ==============================  =============================================
topic                       type                            from
==========================  ==============================  =============================================
/vehicle/fix                sensor_msgs/msg/NavSatFix       every GLOBAL_POSITION_INT (MSL altitude), status
                                                            and accuracy from the last GPS_RAW_INT
/frames/fix                 sensor_msgs/msg/NavSatFix       every frame: camera position at mid-exposure
/frames                     icgt_msgs/msg/FrameRecord       every frame, the whole record
/camera/time_reference      sensor_msgs/msg/TimeReference   every frame with UTC: header.stamp = log time of
                                                            mid-exposure, time_ref = its UTC, source =
                                                            the record's time_source
/imu                        sensor_msgs/msg/Imu             every device IMU sample, FLU axes, orientation
                                                            to ENU (REP-145)
/range                      sensor_msgs/msg/Range           every device LiDAR sample (NaN where invalid)
/tf                         tf2_msgs/msg/TFMessage          enu -> base_link at every ATTITUDE_QUATERNION
                                                            (position of the last GLOBAL_POSITION_INT); at
                                                            each frame enu -> base_link and
                                                            camera_mount -> camera_optical (gimbal residual)
/tf_static                  tf2_msgs/msg/TFMessage          base_link -> camera_mount (lever arm, mounting)
/rosout                     rcl_interfaces/msg/Log          the recorder's log (/icgt/log) and the device's
                                                            LOG messages (/device/log, name icgt.device)
==========================  ==============================  =============================================

One time base throughout, so tf lookups between topics hold: bag timestamps and every header
stamp are the recording's publish times (the data's time: host CLOCK_MONOTONIC plus the recording's
fixed offset, ns since the Unix epoch); messages are written in that order. A frame's stamp is its
mid-exposure on that base; /camera/time_reference gives its UTC (GPS-derived, which differs from
the host's clock). Raw device and telemetry messages carry their host receipt time, as recorded
(re-deriving device sample times is `icgt.ingest.recompute`'s job).

Conventions of the recording this converts from: the vehicle quaternion is body FRD -> NED,
the camera quaternion camera (x right, y down, z forward: ROS's optical frame) -> NED, the BNO055
sample is sensor FRD axes with its quaternion sensor -> NED (`icgt.sim.truth`), the lever arm is
in body FRD.
"""

from __future__ import annotations

import heapq
import logging
import math
import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from icgt.errors import IcgtError
from icgt.export import ExportError
from icgt.export.common import position_sigma_m
from icgt.export.ros2_msgs import MSG_TYPE, frame_record_fields, shipped_msg_text
from icgt.geodesy import LocalFrame, q_multiply
from icgt.geotag.record import FrameRecord
from icgt.pose import Q_FRD_TO_FLU, camera_to_body_quaternion, frame_tree, frd_to_flu, q_flu_to_enu
from icgt.recording import layout

log = logging.getLogger(__name__)

BAG_DIR = "ros2"
WORLD = "enu"
BASE = "base_link"
MOUNT = "camera_mount"
CAMERA = "camera_optical"
IMU_FRAME = "imu_link"
RANGE_FRAME = "range_link"

# LIDAR-Lite v3/v3HP: Garmin's datasheet gives 5 cm .. 40 m and an 8 mrad beam divergence.
_RANGE_MIN_M = 0.05
_RANGE_MAX_M = 40.0
_RANGE_FOV_RAD = 0.008
_RANGE_VALID_BIT = 1 << 0  # protocol RangeFlags.valid


# device LOG level (protocol LogLevel) and Python/foxglove level names -> rcl_interfaces/Log levels
_DEVICE_LEVEL = {1: 10, 2: 20, 3: 30, 4: 40, 5: 50}
_NAMED_LEVEL = {"DEBUG": 10, "INFO": 20, "WARNING": 30, "WARN": 30, "ERROR": 40, "FATAL": 50, "UNKNOWN": 20}

_SOURCE_TOPICS = (
    layout.FRAMES,
    layout.device_topic("IMU"),
    layout.device_topic("RANGE"),
    layout.device_topic("LOG"),
    layout.LOG,
    layout.mavlink_topic("GLOBAL_POSITION_INT"),
    layout.mavlink_topic("GPS_RAW_INT"),
    layout.mavlink_topic("ATTITUDE_QUATERNION"),
)


class Ros2ExportError(ExportError):
    """The ROS 2 bag cannot be written."""


@dataclass
class Ros2Result:
    path: Path
    counts: dict[str, int]
    """Messages written per ROS topic."""

    @property
    def total(self) -> int:
        return sum(self.counts.values())


def _stamp(ns: int) -> Any:
    return _Time(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


_Time: Any = None  # builtin_interfaces/msg/Time, set by _types()


def _vector(data: dict[str, Any], pattern: str) -> tuple[float, float, float]:
    """(x, y, z) of a device message's vector fields; NaN where the recorder left a value out (non-finite)."""
    x, y, z = (float(data.get(pattern.format(a), math.nan)) for a in "xyz")
    return (x, y, z)


def _finite(*values: float | None) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


class _Bag:
    """The typestore and the message classes, and the messages gathered before the sorted write."""

    def __init__(self) -> None:
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        global _Time
        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self.store.register(get_types_from_msg(shipped_msg_text(), MSG_TYPE))
        self.t: dict[str, Any] = dict(self.store.types)
        _Time = self.t["builtin_interfaces/msg/Time"]
        self.pending: list[tuple[int, int, str, bytes]] = []
        self.types: dict[str, str] = {}
        self._n = 0

    def header(self, ns: int, frame_id: str) -> Any:
        return self.t["std_msgs/msg/Header"](stamp=_stamp(ns), frame_id=frame_id)

    def add(self, topic: str, log_ns: int, msg: Any) -> None:
        msgtype = msg.__msgtype__
        known = self.types.setdefault(topic, msgtype)
        if known != msgtype:
            raise Ros2ExportError(f"topic {topic} would carry two types ({known}, {msgtype})")
        heapq.heappush(self.pending, (log_ns, self._n, topic, bytes(self.store.serialize_cdr(msg, msgtype))))
        self._n += 1

    def tf(self, ns: int, parent: str, child: str, xyz: Any, q_wxyz: Any) -> Any:
        t = self.t
        q = np.asarray(q_wxyz, dtype=float)
        q = q / np.linalg.norm(q)
        return t["geometry_msgs/msg/TransformStamped"](
            header=self.header(ns, parent),
            child_frame_id=child,
            transform=t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=float(xyz[0]), y=float(xyz[1]), z=float(xyz[2])),
                rotation=t["geometry_msgs/msg/Quaternion"](x=float(q[1]), y=float(q[2]), z=float(q[3]), w=float(q[0])),
            ),
        )


class _Converter:
    """Turns the recording's messages into ROS 2 messages on the bag."""

    def __init__(self, bag: _Bag, recording: Any) -> None:
        from icgt.ingest.recompute import recording_config

        self.bag = bag
        self.recording = recording
        try:
            self.cfg = recording_config(recording)
        except IcgtError as exc:
            log.warning("ros2 export: %s; camera mount taken as the default", exc)
            from icgt.geotag.config import GeotagConfig

            self.cfg = GeotagConfig(origin=recording.enu_origin)
        self.q_cam_to_body = np.asarray(camera_to_body_quaternion(self.cfg))
        self.lever_frd = tuple(float(c) for c in self.cfg.lever_arm_body_m)
        origin = recording.enu_origin
        # heights are MSL throughout (origin and fixes): the tangent frame's origin height only scales by ~1e-6
        self.local = LocalFrame(*origin) if origin is not None else None
        self.gps: dict[str, Any] | None = None
        self.position_enu: np.ndarray[Any, Any] | None = None

    # --- static ------------------------------------------------------------------------------
    def static_mount(self, ns: int) -> None:
        q = q_multiply(Q_FRD_TO_FLU, self.q_cam_to_body)  # camera_mount (optical axes) -> base_link FLU
        tf = self.bag.tf(ns, BASE, MOUNT, frd_to_flu(self.lever_frd), q)
        self.bag.add("/tf_static", ns, self.bag.t["tf2_msgs/msg/TFMessage"](transforms=[tf]))

    # --- per source topic ---------------------------------------------------------------------
    def convert(self, topic: str, ns: int, data: dict[str, Any]) -> None:
        handler = {
            layout.FRAMES: self._frame,
            layout.device_topic("IMU"): self._imu,
            layout.device_topic("RANGE"): self._range,
            layout.device_topic("LOG"): self._device_log,
            layout.LOG: self._host_log,
            layout.mavlink_topic("GLOBAL_POSITION_INT"): self._global_position,
            layout.mavlink_topic("GPS_RAW_INT"): self._gps_raw,
            layout.mavlink_topic("ATTITUDE_QUATERNION"): self._attitude,
        }[topic]
        handler(ns, data)

    def _navsat_status(self, fix_type: int | None) -> Any:
        s = self.bag.t["sensor_msgs/msg/NavSatStatus"]
        if fix_type is None or fix_type < 2:
            status = s.STATUS_NO_FIX
        elif fix_type in (5, 6):
            status = s.STATUS_GBAS_FIX  # RTK float / fixed: ground-based augmentation
        elif fix_type == 4:
            status = s.STATUS_SBAS_FIX  # DGPS
        else:
            status = s.STATUS_FIX
        return s(status=status, service=s.SERVICE_GPS)

    def _navsat(self, ns: int, frame_id: str, lat: float, lon: float, alt: float, fix_type: int | None, hv: Any) -> Any:
        t = self.bag.t["sensor_msgs/msg/NavSatFix"]
        cov = np.zeros(9)
        kind = t.COVARIANCE_TYPE_UNKNOWN
        if hv is not None:
            cov[0] = cov[4] = hv[0] ** 2
            cov[8] = hv[1] ** 2
            kind = t.COVARIANCE_TYPE_DIAGONAL_KNOWN
        return t(
            header=self.bag.header(ns, frame_id),
            status=self._navsat_status(fix_type),
            latitude=float(lat),
            longitude=float(lon),
            altitude=float(alt),
            position_covariance=cov,
            position_covariance_type=kind,
        )

    def _gps_raw(self, ns: int, data: dict[str, Any]) -> None:
        self.gps = data

    def _global_position(self, ns: int, data: dict[str, Any]) -> None:
        lat, lon, alt = data.get("lat"), data.get("lon"), data.get("alt")
        if not isinstance(lat, int) or not isinstance(lon, int) or not isinstance(alt, int):
            return
        lat_deg, lon_deg, alt_m = lat / 1e7, lon / 1e7, alt / 1000.0
        fix_type = int(self.gps["fix_type"]) if self.gps and "fix_type" in self.gps else None
        hv = None
        if self.gps and self.gps.get("h_acc") and self.gps.get("v_acc"):
            hv = (self.gps["h_acc"] / 1000.0, self.gps["v_acc"] / 1000.0)  # GPS_RAW_INT h_acc/v_acc [mm]
        self.bag.add("/vehicle/fix", ns, self._navsat(ns, BASE, lat_deg, lon_deg, alt_m, fix_type, hv))
        if self.local is not None:
            self.position_enu = self.local.geodetic_to_enu(lat_deg, lon_deg, alt_m)

    def _attitude(self, ns: int, data: dict[str, Any]) -> None:
        if self.position_enu is None:
            return
        q = [data.get(k) for k in ("q1", "q2", "q3", "q4")]  # ATTITUDE_QUATERNION: w, x, y, z (FRD -> NED)
        if not all(isinstance(v, int | float) and math.isfinite(v) for v in q):
            return
        tf = self.bag.tf(ns, WORLD, BASE, self.position_enu, q_flu_to_enu(q))
        self.bag.add("/tf", ns, self.bag.t["tf2_msgs/msg/TFMessage"](transforms=[tf]))

    def _frame(self, ns: int, data: dict[str, Any]) -> None:
        from icgt.ingest.reader import decode_frame

        rec = decode_frame(data)
        stamp = ns  # the recorder writes a frame at its mid-exposure host time
        t = self.bag.t
        fields = frame_record_fields(rec)
        self.bag.add("/frames", ns, t[MSG_TYPE](header=self.bag.header(stamp, CAMERA), **fields))
        if _finite(rec.lat_deg, rec.lon_deg, rec.alt_msl_m):
            assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
            sigma = position_sigma_m(rec)
            hv = (sigma[0], sigma[1]) if _finite(*sigma) else None
            fix = self._navsat(stamp, CAMERA, rec.lat_deg, rec.lon_deg, rec.alt_msl_m, rec.fix_type, hv)
            self.bag.add("/frames/fix", ns, fix)
        if rec.mid_utc_us is not None:
            ref = t["sensor_msgs/msg/TimeReference"](
                header=self.bag.header(stamp, CAMERA),
                time_ref=_stamp(rec.mid_utc_us * 1000),
                source=rec.time_source,
            )
            self.bag.add("/camera/time_reference", ns, ref)
        self._frame_tf(ns, stamp, rec)

    def _frame_tf(self, ns: int, stamp: int, rec: FrameRecord) -> None:
        body = (rec.body_qw, rec.body_qx, rec.body_qy, rec.body_qz)
        cam = (rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz)
        if not (_finite(*body) and _finite(*cam) and _finite(rec.east_m, rec.north_m, rec.up_m)):
            return
        cam_enu = np.array([rec.east_m, rec.north_m, rec.up_m], dtype=float)
        base_enu, q_base, residual = frame_tree(cam_enu, body, cam, self.q_cam_to_body, self.lever_frd)
        transforms = [
            self.bag.tf(stamp, WORLD, BASE, base_enu, q_base),
            self.bag.tf(stamp, MOUNT, CAMERA, (0.0, 0.0, 0.0), residual),
        ]
        self.bag.add("/tf", ns, self.bag.t["tf2_msgs/msg/TFMessage"](transforms=transforms))

    def _imu(self, ns: int, data: dict[str, Any]) -> None:
        t = self.bag.t
        q = np.array([float(data.get(f"quat_{a}", math.nan)) for a in "wxyz"])
        gyro = frd_to_flu(_vector(data, "gyro_{}_rad_s"))
        accel = frd_to_flu(_vector(data, "accel_{}_m_s2"))
        orientation_cov = np.zeros(9)
        if np.all(np.isfinite(q)) and np.linalg.norm(q) > 0.5:
            q_enu = q_flu_to_enu(q / np.linalg.norm(q))
        else:
            q_enu = np.array([1.0, 0.0, 0.0, 0.0])
            orientation_cov[0] = -1.0  # REP-145 / sensor_msgs: no orientation estimate
        # REP-145: an accelerometer reports specific force: +g up when level. The sample's FRD reading
        # of a level, still sensor is (0, 0, -g); in FLU that is (0, 0, +g).
        msg = t["sensor_msgs/msg/Imu"](
            header=self.bag.header(ns, IMU_FRAME),
            orientation=t["geometry_msgs/msg/Quaternion"](
                x=float(q_enu[1]), y=float(q_enu[2]), z=float(q_enu[3]), w=float(q_enu[0])
            ),
            orientation_covariance=orientation_cov,
            angular_velocity=t["geometry_msgs/msg/Vector3"](x=gyro[0], y=gyro[1], z=gyro[2]),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=t["geometry_msgs/msg/Vector3"](x=accel[0], y=accel[1], z=accel[2]),
            linear_acceleration_covariance=np.zeros(9),
        )
        self.bag.add("/imu", ns, msg)

    def _range(self, ns: int, data: dict[str, Any]) -> None:
        t = self.bag.t["sensor_msgs/msg/Range"]
        valid = int(data.get("flags", 0)) & _RANGE_VALID_BIT and int(data.get("distance_cm", 0)) > 0
        distance = int(data.get("distance_cm", 0)) / 100.0 if valid else math.nan
        msg = t(
            header=self.bag.header(ns, RANGE_FRAME),
            radiation_type=t.INFRARED,  # a 905 nm laser: the nearest of Range's two kinds
            field_of_view=_RANGE_FOV_RAD,
            min_range=_RANGE_MIN_M,
            max_range=_RANGE_MAX_M,
            range=distance,
        )
        self.bag.add("/range", ns, msg)

    def _log(self, ns: int, level: int, name: str, text: str, file: str = "", line: int = 0) -> None:
        msg = self.bag.t["rcl_interfaces/msg/Log"](
            stamp=_stamp(ns), level=level, name=name, msg=text, file=file, function="", line=line
        )
        self.bag.add("/rosout", ns, msg)

    def _device_log(self, ns: int, data: dict[str, Any]) -> None:
        self._log(ns, _DEVICE_LEVEL.get(int(data.get("level", 2)), 20), "icgt.device", str(data.get("text", "")))

    def _host_log(self, ns: int, data: dict[str, Any]) -> None:
        level = data.get("level", "INFO")
        lvl = _NAMED_LEVEL.get(str(level).upper(), 20) if not isinstance(level, int) else _DEVICE_LEVEL.get(level, 20)
        self._log(
            ns,
            lvl,
            str(data.get("name", "icgt")),
            str(data.get("message", "")),
            str(data.get("file", "")),
            int(data.get("line", 0)),
        )


def _source(recording: Any) -> Iterator[tuple[str, int, dict[str, Any]]]:
    present = set(recording.topics())
    wanted = [t for t in _SOURCE_TOPICS if t in present]
    for m in recording.records(wanted):
        yield m.topic, m.time_ns, m.data  # the data's time: a frame's mid-exposure, an input's receipt


_REORDER_WINDOW_NS = 10_000_000_000
"""Messages are held this long [ns of log time] to be written in log-time order: a recording's
file order strays from log-time order by less than a chunk (about a second)."""


def _latched_qos() -> Any:
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

    zero = QosTime(0, 0)
    return Qos(
        QosHistory.KEEP_LAST,
        1,
        QosReliability.RELIABLE,
        QosDurability.TRANSIENT_LOCAL,
        zero,
        zero,
        QosLiveliness.AUTOMATIC,
        zero,
        False,
    )


def _check_read_back(path: Path, counts: dict[str, int]) -> None:
    """Read the bag back with rosbags (every message of the MCAP file, not just metadata.yaml)."""
    from rosbags.rosbag2 import Reader

    got: dict[str, int] = {}
    try:
        with Reader(path) as reader:
            for conn, _, _ in reader.messages():
                got[conn.topic] = got.get(conn.topic, 0) + 1
    except Exception as exc:  # rosbags raises its own errors and MCAP decoding errors
        raise Ros2ExportError(f"cannot read back the ROS 2 bag {path}: {exc}") from exc
    if got != counts:
        raise Ros2ExportError(f"the ROS 2 bag {path} reads back {got}, {counts} were written")


def write_ros2_bag(recording: Any, out_dir: Path) -> Ros2Result:
    """Write the recording as a rosbag2 folder `out_dir / ros2` (MCAP storage); returns the counts written.

    Streams: the recording is read once in file order and converted as it goes; a reorder buffer of
    `_REORDER_WINDOW_NS` puts the bag in log-time order (a message later than that is written where
    it came, counted and reported). An existing bag folder there is replaced (rosbags refuses to
    write into one).
    """
    from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

    if not any(recording.topics().get(t) for t in _SOURCE_TOPICS):
        raise Ros2ExportError(f"{recording.path}: nothing to convert (no frames, sensor, telemetry or log messages)")
    bag = _Bag()
    conv = _Converter(bag, recording)
    path = out_dir / BAG_DIR
    if path.exists():
        shutil.rmtree(path)
    counts: dict[str, int] = {}
    late = 0
    last_ns = -1
    try:
        with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
            conns: dict[str, Any] = {}

            def flush(before_ns: int | None) -> None:
                nonlocal late, last_ns
                while bag.pending and (before_ns is None or bag.pending[0][0] < before_ns):
                    ns, _, topic, raw = heapq.heappop(bag.pending)
                    conn = conns.get(topic)
                    if conn is None:
                        qos = (_latched_qos(),) if topic == "/tf_static" else ()
                        conn = conns[topic] = writer.add_connection(
                            topic, bag.types[topic], typestore=bag.store, offered_qos_profiles=qos
                        )
                    if ns < last_ns:
                        late += 1
                    last_ns = max(last_ns, ns)
                    writer.write(conn, ns, raw)
                    counts[topic] = counts.get(topic, 0) + 1

            newest = None
            for topic, ns, data in _source(recording):
                if newest is None:
                    conv.static_mount(ns)
                newest = ns if newest is None else max(newest, ns)
                conv.convert(topic, ns, data)
                if bag.pending and bag.pending[0][0] < newest - _REORDER_WINDOW_NS:
                    flush(newest - _REORDER_WINDOW_NS)
            if newest is None:
                raise Ros2ExportError(
                    f"{recording.path}: nothing to convert (no frames, sensor, telemetry or log messages)"
                )
            flush(None)
    except (WriterError, OSError) as exc:
        raise Ros2ExportError(f"cannot write the ROS 2 bag {path}: {exc}") from exc
    _check_read_back(path, counts)
    if late:
        log.warning(
            "ros2 export: %d messages came more than %.0f s out of log-time order: written as they came",
            late,
            _REORDER_WINDOW_NS / 1e9,
        )
    return Ros2Result(path, counts)
