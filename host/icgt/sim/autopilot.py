"""A simulated autopilot on a real MAVLink link: the scenario's truth as ArduPilot or PX4 would report it.

`SimAutopilot` is component 1 of the scenario's vehicle system id (MAV_TYPE_QUADROTOR, armed,
MAV_AUTOPILOT_ARDUPILOTMEGA or MAV_AUTOPILOT_PX4 by `[autopilot] firmware`). The scenario's
`[autopilot] profile` (icgt.sim.profiles: "ideal", "ardupilot", "px4") sets what it streams and
how it stamps; every knob is a field of `icgt.sim.scenario.Autopilot`. It keeps its own boot clock
(truth.ClockMaps: autopilot boot us = offset + tau * 1e6 * (1 + drift)) and streams, on a companion
link and on an optional GCS link:

- HEARTBEAT, SYSTEM_TIME (time_unix_usec 0 until the first GPS fix),
- GPS_RAW_INT (time_usec = boot time of the measurement, or of the receiver's latest fix on a
  `gps_fix_rate_hz` grid; the scenario's noise, fix type, outages with fix_type 1 and garbage lat/lon,
  nothing (or fix_type 0) while GPS-denied),
- GLOBAL_POSITION_INT (the fused estimate at time_boot_ms: truth plus small noise, drifting during
  outages, absent while GPS-denied, lat/lon 0 before the first fix),
- ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED (local position keeps going without GPS, and
  jumps at each EKF origin reset `origin_resets_s`), GPS_GLOBAL_ORIGIN (as a stream, or once when
  the origin is set and at each reset with `origin_on_change`).

Each estimate is stamped on a grid of its stream interval on the boot clock (plus `stamp_jitter_s`,
and `local_position_lag_s` for LOCAL_POSITION_NED) and leaves the autopilot `latency_s` (+- jitter)
after its stamp, paced against time.monotonic_ns and the contract's t0. It answers TIMESYNC (tc1 =
boot time [ns] at microsecond granularity, as ArduPilot and PX4; ts1 echoed) unless
`answer_timesync` is false, and may send its own requests (`own_timesync_hz`, as PX4); COMMAND_LONG
MAV_CMD_SET_MESSAGE_INTERVAL (unless `honour_message_interval` is false: then no ACK) /
GET_MESSAGE_INTERVAL / REQUEST_MESSAGE / REQUEST_AUTOPILOT_CAPABILITIES with COMMAND_ACK, and
UNSUPPORTED for other commands addressed to it. Events: parameter downloads (`param_bursts_s`: a
burst of PARAM_VALUE on both links, the streams slowed down meanwhile), HEARTBEATs of ground stations
forwarded to the companion link (`gcs_heartbeat_systems`), a second camera at component 100 of the
vehicle (`foreign_camera`). Routing as ArduPilot does between its links: a message not addressed to
the autopilot alone (broadcasts, other components such as a camera at component 100, other systems)
is forwarded unchanged to the other link. During the scenario's "autopilot link drops" the companion
link sends nothing and ignores what arrives (the GCS link is unaffected).
"""

from __future__ import annotations

import contextlib
import heapq
import math
import select
import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink import mavutil
from pymavlink.dialects.v10 import common as mavlink1_dialect
from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import LocalFrame, enu_to_ned, q_from_euler_zyx, q_multiply, q_to_euler_zyx
from icgt.sim.camera_trigger import UPDATE_PERIOD_S, CameraTrigger, trigger_due
from icgt.sim.scenario import STREAM_NAMES, Scenario, SimError
from icgt.sim.trajectory import Trajectory, TruthState
from icgt.sim.truth import ClockMaps

SYSTEM_ID = 1
COMPONENT_ID = 1
STREAM_IDS: dict[str, int] = {
    "heartbeat": mavlink2.MAVLINK_MSG_ID_HEARTBEAT,
    "gps_raw_int": mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT,
    "global_position_int": mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "attitude": mavlink2.MAVLINK_MSG_ID_ATTITUDE,
    "attitude_quaternion": mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "local_position_ned": mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "system_time": mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME,
    "gps_global_origin": mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
}
_US_STAMPED = {"gps_raw_int"}  # the others carry time_boot_ms (or no stamp)
_BASE_MODE = (
    mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
    | mavlink2.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
    | mavlink2.MAV_MODE_FLAG_STABILIZE_ENABLED
    | mavlink2.MAV_MODE_FLAG_GUIDED_ENABLED
    | mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
)
_COPTER_MODE_LOITER = 5
_PX4_MODE_POSCTL = 3 << 16  # PX4 custom_mode: main mode in bits 16-23 (3 = POSCTL)
_FLIGHT_SW_VERSION = {
    "ardupilot": (4 << 24) | (5 << 16) | (0 << 8) | 255,  # 4.5.0 official
    "px4": (1 << 24) | (14 << 16) | (0 << 8) | 255,  # v1.14.0 release
}
GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: what QGroundControl, MAVProxy and MAVSDK ground stations use
CAMERA_COMPONENT = 100  # MAV_COMP_ID_CAMERA
GIMBAL_COMPONENT = 154  # MAV_COMP_ID_GIMBAL: a MAVLink gimbal device (`[camera.gimbal]`), routed to the companion
_GIMBAL_FLAGS = (
    mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME  # follow mode: yaw from the vehicle's heading
    | mavlink2.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
    | mavlink2.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
)
_EVENT_PERIOD_S = 1.0  # HEARTBEATs of forwarded ground stations and of the foreign camera
_BURST_CHUNK_S = 0.01  # a parameter burst goes out in chunks this far apart
_UINT16_UNKNOWN = 65535
_SELECT_TIMEOUT_S = 0.02
_BUILD_LEAD_NS = 10_000_000  # messages are built this long before they are due


def gps_condition(scenario: Scenario, tau_s: float) -> str:
    """GPS state at tau: "denied" (no GPS), "acquiring" (before the first fix), "outage", or "fix"."""
    g = scenario.gps
    if any(a <= tau_s < b for a, b in g.denied_s):
        return "denied"
    if tau_s < g.fix_acquired_after_s:
        return "acquiring"
    if any(a <= tau_s < b for a, b in g.outages_s):
        return "outage"
    return "fix"


@dataclass
class _Stream:
    name: str
    msg_id: int
    default_interval_us: int | None
    interval_us: int | None
    k: int = 0
    stamp_us: int = 0
    send_ns: int = 0


def _v1_payload_length(msg_id: int) -> int | None:
    cls = mavlink1_dialect.mavlink_map.get(msg_id)
    return None if cls is None else struct.calcsize(bytes(cls.native_format).decode())


def _mavlink1_frame(msg: Any, mav: Any) -> bytes:
    """A MAVLink 1 frame as a MAVLink 1 sender writes it: without the MAVLink 2 extension fields.

    (pymavlink's force_mavlink1 keeps the extensions in the payload; real v1 senders cannot.)
    """
    buf = bytes(msg.pack(mav, force_mavlink1=True))
    length = _v1_payload_length(msg.get_msgId())
    if length is None or length >= buf[1]:
        return buf
    header = bytes([buf[0], length]) + buf[2:6]
    payload = buf[6 : 6 + length]
    crc = mavlink2.x25crc(header[1:] + payload)
    crc.accumulate(bytes([msg.crc_extra]))
    return header + payload + struct.pack("<H", crc.crc)


class _Link:
    """One MAVLink connection: mavutil for the transport, a MAVLink 2 codec of our own."""

    def __init__(self, url: str, name: str, baud: int, system_id: int = SYSTEM_ID) -> None:
        self.url = url
        self.name = name
        try:
            self.conn: Any = mavutil.mavlink_connection(
                url, baud=baud, source_system=system_id, source_component=COMPONENT_ID, autoreconnect=False
            )
        except (OSError, ValueError) as exc:
            raise SimError(f"autopilot {name} link {url}: cannot open: {exc}") from exc
        self.tx = mavlink2.MAVLink(self.conn, srcSystem=system_id, srcComponent=COMPONENT_ID)
        self.rx = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=COMPONENT_ID)
        self.rx.robust_parsing = True
        self.lock = threading.Lock()

    def fileno(self) -> int | None:
        fd = getattr(self.conn, "fd", None)
        return fd if isinstance(fd, int) and fd >= 0 else None

    def local_address(self) -> tuple[str, int] | None:
        port = getattr(self.conn, "port", None)
        try:
            addr = port.getsockname() if port is not None else None
        except OSError:
            return None
        return (str(addr[0]), int(addr[1])) if isinstance(addr, tuple) else None

    def send(self, msg: Any, mavlink1: bool = False) -> None:
        with self.lock:
            if not mavlink1:
                self.tx.send(msg)
                return
            self.conn.write(_mavlink1_frame(msg, self.tx))
            self.tx.seq = (self.tx.seq + 1) % 256

    def send_as(self, msg: Any, codec: Any) -> None:
        """Send a message packed by another sender's codec (its own system/component and sequence)."""
        with self.lock:
            self.conn.write(bytes(msg.pack(codec)))
            codec.seq = (codec.seq + 1) % 256

    def forward(self, raw: bytes) -> None:
        with self.lock:
            self.conn.write(raw)

    def read(self) -> list[Any]:
        """Every complete message that has arrived (non-blocking)."""
        out: list[Any] = []
        for _ in range(64):
            try:
                data = self.conn.recv(4096)
            except OSError:
                break
            if not data:
                break
            if isinstance(data, str):
                data = data.encode("latin-1")
            msgs = self.rx.parse_buffer(data)
            if msgs:
                out.extend(m for m in msgs if m.get_type() != "BAD_DATA")
        return out

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.conn.close()


class SimAutopilot:
    """A simulated ArduPilot-like autopilot; see the module docstring. start() / stop() (or `with`)."""

    def __init__(
        self,
        scenario: Scenario,
        clocks: ClockMaps,
        companion_url: str,
        gcs_url: str | None = None,
        *,
        trajectory: Trajectory | None = None,
        latency_ms: float | None = None,
        latency_jitter_ms: float | None = None,
        mavlink1_messages: Iterable[str] | None = None,
        baud: int = 921_600,
    ) -> None:
        self.scenario = scenario
        self.clocks = clocks
        self.companion_url = companion_url
        self.gcs_url = gcs_url
        self.baud = baud
        self.trajectory = trajectory or Trajectory(scenario)
        ap = scenario.autopilot
        self.latency_ns = round((ap.latency_s * 1e3 if latency_ms is None else latency_ms) * 1e6)
        self.jitter_ns = round((ap.latency_jitter_s * 1e3 if latency_jitter_ms is None else latency_jitter_ms) * 1e6)
        names = ap.mavlink1_messages if mavlink1_messages is None else tuple(mavlink1_messages)
        self.mavlink1_messages = frozenset(n.upper() for n in names)
        self.frame = LocalFrame(scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.ellipsoid_height_m)
        self.system_id = ap.system_id
        self._codec = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=COMPONENT_ID)
        # other senders whose messages reach the companion link through this autopilot's routing
        self._gcs_codecs = [
            mavlink2.MAVLink(None, srcSystem=g, srcComponent=GCS_COMPONENT) for g in ap.gcs_heartbeat_systems
        ]
        self._camera_codec = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=CAMERA_COMPONENT)
        self._gimbal_codec = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=GIMBAL_COMPONENT)
        self._streams: dict[int, _Stream] = {}
        for name in STREAM_NAMES:
            rate = ap.rates_hz.get(name, 0.0)
            interval = round(1e6 / rate) if rate > 0.0 else None
            self._streams[STREAM_IDS[name]] = _Stream(name, STREAM_IDS[name], interval, interval)
        seed = scenario.seed
        self._noise = {mid: np.random.default_rng([seed, 0xA9, mid]) for mid in self._streams}
        self._oneoff_rng = np.random.default_rng([seed, 0xA9, 0])
        self._jitter_rng = np.random.default_rng([seed, 0xA9, 1])
        self._stamp_rng = np.random.default_rng([seed, 0xA9, 3])
        self._outage_dirs = [
            float(np.random.default_rng([seed, 0xA9, 2, i]).uniform(0.0, 2.0 * math.pi))
            for i in range(len(scenario.gps.outages_s))
        ]
        self._cond = threading.Condition()
        self._cache_lock = threading.Lock()
        self._state_cache: dict[int, tuple[float, TruthState]] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._companion: _Link | None = None
        self._gcs: _Link | None = None
        self.sent_counts: dict[str, int] = {}
        self.skipped_in_param_bursts = 0
        """Stream messages not sent because a parameter burst slowed the streams down."""
        self.forwarded_counts: dict[str, int] = {"to_companion": 0, "to_gcs": 0}
        self.errors: list[str] = []
        """Unexpected exceptions caught in the worker threads (empty in a healthy run)."""
        self.stream_resets = 0
        """Times every stream went back to its profile rate (`stream_reset_s`)."""
        self._trigger_lock = threading.Lock()
        self.camera_trigger: CameraTrigger | None = None
        """ArduPilot's camera backend commanding the camera (`[autopilot.camera]`), with its log."""
        if trigger_due(ap.camera):
            self.camera_trigger = CameraTrigger(
                ap.camera,
                self.system_id,
                self._codec,
                self._send_companion,
                lambda tau: np.asarray(self.trajectory.state(tau).position_enu_m[0], dtype=float),
            )

    # --- lifecycle ----------------------------------------------------------------------------

    def start(self) -> None:
        if self._threads:
            raise SimError("autopilot already started")
        self._stop.clear()
        try:
            self._companion = _Link(self.companion_url, "companion", self.baud, self.system_id)
            if self.gcs_url is not None:
                self._gcs = _Link(self.gcs_url, "gcs", self.baud, self.system_id)
        except SimError:
            self._close_links()
            raise
        now_ap = self._ap_now_us()
        with self._cond:
            for s in self._streams.values():
                self._restart_stream(s, now_ap)
        self._threads = [
            threading.Thread(target=self._run_sender, name="sim-autopilot-tx", daemon=True),
            threading.Thread(target=self._run_receiver, name="sim-autopilot-rx", daemon=True),
            threading.Thread(target=self._run_events, name="sim-autopilot-events", daemon=True),
        ]
        if self.scenario.camera.gimbal is not None:
            self._threads.append(threading.Thread(target=self._run_gimbal, name="sim-gimbal", daemon=True))
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop the threads and close the links; safe to call more than once."""
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        for t in self._threads:
            t.join(timeout=5.0)
        alive = [t.name for t in self._threads if t.is_alive()]
        self._threads = []
        self._close_links()
        if alive:
            raise SimError(f"autopilot threads did not stop: {', '.join(alive)}")

    def __enter__(self) -> SimAutopilot:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _close_links(self) -> None:
        for link in (self._companion, self._gcs):
            if link is not None:
                link.close()
        self._companion = None
        self._gcs = None

    @property
    def companion_address(self) -> tuple[str, int] | None:
        """Local (host, port) of the companion link's socket, once started."""
        return self._companion.local_address() if self._companion else None

    @property
    def gcs_address(self) -> tuple[str, int] | None:
        """Local (host, port) of the GCS link's socket (e.g. the port udpin:...:0 bound)."""
        return self._gcs.local_address() if self._gcs else None

    # --- clocks -------------------------------------------------------------------------------

    def _tau_now(self) -> float:
        return self.clocks.host_ns_to_tau(time.monotonic_ns())

    def _ap_now_us(self) -> int:
        return math.floor(float(self.clocks.tau_to_autopilot_us(self._tau_now())))

    def _send_companion(self, msg: Any) -> None:
        """A command of the autopilot's camera backend: on the companion link, where the camera is."""
        if self._companion is not None and not self._companion_dropped(self._tau_now()):
            self._companion.send(msg)

    def _companion_dropped(self, tau_s: float) -> bool:
        return any(a <= tau_s < b for a, b in self.scenario.faults.autopilot_link_drops_s)

    # --- scheduling ---------------------------------------------------------------------------

    def _stamp(self, s: _Stream) -> int:
        assert s.interval_us is not None
        if s.name in _US_STAMPED:
            return s.k * s.interval_us
        return (s.k * s.interval_us // 1000) * 1000

    def _stamp_offset_us(self, s: _Stream) -> int:
        """Where in its grid interval a stamp falls: the main-loop jitter, plus LOCAL_POSITION_NED's lag."""
        ap = self.scenario.autopilot
        assert s.interval_us is not None
        span_ms = 1e3 * (ap.stamp_jitter_s + (ap.local_position_lag_s if s.name == "local_position_ned" else 0.0))
        if span_ms <= 0.0:
            return 0
        limit_us = max(0, s.interval_us - 1000)  # stamps stay in order and one apart
        return min(limit_us, round(float(self._stamp_rng.uniform(0.0, span_ms)) * 1000.0))

    def _schedule(self, s: _Stream) -> None:
        s.stamp_us = self._stamp(s)
        offset_us = self._stamp_offset_us(s)
        if offset_us:
            s.stamp_us += offset_us if s.name in _US_STAMPED else (offset_us // 1000) * 1000
        tau = float(self.clocks.autopilot_us_to_tau(s.stamp_us))
        jitter = round(self._jitter_rng.uniform(-1.0, 1.0) * self.jitter_ns) if self.jitter_ns else 0
        s.send_ns = self.clocks.tau_to_host_ns(tau) + max(0, self.latency_ns + jitter)

    def _restart_stream(self, s: _Stream, now_ap_us: int) -> None:
        if s.interval_us is None:
            return
        s.k = -(-max(0, now_ap_us) // s.interval_us)  # first grid point at or after now (not before boot)
        self._schedule(s)

    def _run_sender(self) -> None:
        """Build each message _BUILD_LEAD_NS before it is due (the truth takes a while), send it on time."""
        pending: list[tuple[int, int, Any]] = []  # heap of (send_ns, sequence, message)
        sequence = 0
        while not self._stop.is_set():
            now = time.monotonic_ns()
            if pending and pending[0][0] <= now:
                _, _, msg = heapq.heappop(pending)
                try:
                    self._send_stream_message(msg)
                except Exception as exc:  # a broken link must not stop the other one
                    self.errors.append(f"send {msg.get_type()}: {exc!r}")
                continue
            with self._cond:
                active = [s for s in self._streams.values() if s.interval_us is not None]
                nxt = min(active, key=lambda s: s.send_ns) if active else None
                candidates = [pending[0][0]] if pending else []
                if nxt is not None:
                    candidates.append(nxt.send_ns - _BUILD_LEAD_NS)
                next_ns = min(candidates, default=None)
                if nxt is None or nxt.send_ns - _BUILD_LEAD_NS > now:
                    wait_ns = 100_000_000 if next_ns is None else min(100_000_000, next_ns - now)
                    if wait_ns > 0:
                        self._cond.wait(timeout=wait_ns * 1e-9)
                    continue
                name, stamp_us, send_ns, k = nxt.name, nxt.stamp_us, nxt.send_ns, nxt.k
                nxt.k += 1
                self._schedule(nxt)
            if self._slowed_by_param_burst(stamp_us, k):
                self.skipped_in_param_bursts += 1
                continue
            try:
                msg = self._build(name, stamp_us, self._noise[STREAM_IDS[name]])
            except Exception as exc:  # keep streaming; the error is reported in self.errors
                self.errors.append(f"{name}: {exc!r}")
                continue
            if msg is not None:
                heapq.heappush(pending, (send_ns, sequence, msg))
                sequence += 1

    def _slowed_by_param_burst(self, stamp_us: int, k: int) -> bool:
        ap = self.scenario.autopilot
        if ap.param_burst_stream_divisor <= 1 or not ap.param_bursts_s:
            return False
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        in_burst = any(t <= tau < t + ap.param_burst_duration_s for t in ap.param_bursts_s)
        return in_burst and k % ap.param_burst_stream_divisor != 0

    def _send_stream_message(self, msg: Any) -> None:
        """Send a telemetry message on every link (not the companion link while it is dropped)."""
        mav1 = msg.get_type() in self.mavlink1_messages
        dropped = self._companion_dropped(self._tau_now())
        for target in (self._companion, self._gcs):
            if target is None or (target is self._companion and dropped):
                continue
            target.send(msg, mavlink1=mav1)
        self.sent_counts[msg.get_type()] = self.sent_counts.get(msg.get_type(), 0) + 1

    # --- message content ----------------------------------------------------------------------

    def _state(self, stamp_us: int) -> tuple[float, TruthState]:
        """Truth at an autopilot stamp; cached because several streams share each stamp."""
        with self._cache_lock:
            hit = self._state_cache.get(stamp_us)
        if hit is not None:
            return hit
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        value = (tau, self.trajectory.state(tau))
        with self._cache_lock:
            if len(self._state_cache) >= 64:
                self._state_cache.clear()
            self._state_cache[stamp_us] = value
        return value

    def _outage_error_enu(self, tau: float) -> np.ndarray[Any, np.dtype[np.float64]]:
        g = self.scenario.gps
        for (a, b), direction in zip(g.outages_s, self._outage_dirs, strict=True):
            if a <= tau < b and tau >= g.fix_acquired_after_s:
                d = g.outage_drift_m_s * (tau - a)
                return np.array([d * math.sin(direction), d * math.cos(direction), 0.0])
        return np.zeros(3)

    def _geodetic(self, enu: np.ndarray[Any, np.dtype[np.float64]]) -> tuple[int, int, int, int]:
        """(lat degE7, lon degE7, alt MSL mm, alt ellipsoid mm)."""
        lat, lon, h = self.frame.enu_to_geodetic(enu)
        msl = float(h) - self.scenario.origin.geoid_separation_m
        return round(float(lat) * 1e7), round(float(lon) * 1e7), round(msl * 1000.0), round(float(h) * 1000.0)

    def _in_position_gap(self, stamp_us: int) -> bool:
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        return any(a <= tau < b for a, b in self.scenario.faults.position_gaps_s)

    def _build(self, name: str, stamp_us: int, rng: np.random.Generator) -> Any:
        if name in ("global_position_int", "local_position_ned") and self._in_position_gap(stamp_us):
            rng.normal(size=3)  # the noise sequence stays the same as without the gap
            return None
        builders: dict[str, Callable[[int, np.random.Generator], Any]] = {
            "heartbeat": self._heartbeat,
            "gps_raw_int": self._gps_raw_int,
            "global_position_int": self._global_position_int,
            "attitude": self._attitude,
            "attitude_quaternion": self._attitude_quaternion,
            "local_position_ned": self._local_position_ned,
            "system_time": self._system_time,
            "gps_global_origin": self._gps_global_origin,
        }
        return builders[name](stamp_us, rng)

    def _heartbeat(self, _stamp_us: int, _rng: np.random.Generator) -> Any:
        if self.scenario.autopilot.firmware == "px4":
            return self._codec.heartbeat_encode(
                mavlink2.MAV_TYPE_QUADROTOR,
                mavlink2.MAV_AUTOPILOT_PX4,
                _BASE_MODE,
                _PX4_MODE_POSCTL,
                mavlink2.MAV_STATE_ACTIVE,
            )
        return self._codec.heartbeat_encode(
            mavlink2.MAV_TYPE_QUADROTOR,
            mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA,
            _BASE_MODE,
            _COPTER_MODE_LOITER,
            mavlink2.MAV_STATE_ACTIVE,
        )

    # --- the EKF's local origin ---------------------------------------------------------------

    def _origin_resets_before(self, tau: float) -> int:
        return sum(1 for t in self.scenario.autopilot.origin_resets_s if t <= tau)

    def _origin_shift_enu(self, tau: float) -> np.ndarray[Any, np.dtype[np.float64]]:
        """How far the local origin has moved from the scenario origin by tau (ENU [m])."""
        return np.asarray(self.scenario.autopilot.origin_reset_shift_m, dtype=float) * self._origin_resets_before(tau)

    def _origin_message(self, stamp_us: int) -> Any:
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        lat, lon, alt, _ = self._geodetic(self._origin_shift_enu(tau))
        return self._codec.gps_global_origin_encode(lat, lon, alt, stamp_us)

    def _gps_global_origin(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        if tau < self.scenario.gps.fix_acquired_after_s:
            return None  # the EKF has no origin before the first fix
        return self._origin_message(stamp_us)

    def _system_time(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        unix_us = self.clocks.tau_to_utc_us(tau) if tau >= self.scenario.gps.fix_acquired_after_s else 0
        return self._codec.system_time_encode(unix_us, stamp_us // 1000)

    def _gps_raw_int(self, stamp_us: int, rng: np.random.Generator) -> Any:
        g = self.scenario.gps
        fix_hz = self.scenario.autopilot.gps_fix_rate_hz
        if fix_hz > 0.0:
            # The receiver's latest fix at the send time; time_usec is its boot time in whole ms (ArduPilot).
            fix_interval_us = round(1e6 / fix_hz)
            fix = stamp_us // fix_interval_us
            stamp_us = (fix * fix_interval_us // 1000) * 1000
            rng = np.random.default_rng([self.scenario.seed, 0xA9, 4, fix])  # a fix sent twice is the same fix
        tau, st = self._state(stamp_us)
        cond = gps_condition(self.scenario, tau)
        noise = rng.normal(size=3)  # drawn every sample so the sequence does not depend on the condition
        garbage = rng.uniform(-1.0, 1.0, size=2)
        if cond == "denied":
            if g.denied_gps_raw == "none":
                return None
            return self._codec.gps_raw_int_encode(stamp_us, 0, 0, 0, 0, _UINT16_UNKNOWN, _UINT16_UNKNOWN, 0, 0, 0)
        if cond == "acquiring":
            return self._codec.gps_raw_int_encode(stamp_us, 1, 0, 0, 0, _UINT16_UNKNOWN, _UINT16_UNKNOWN, 0, 0, 3)
        pos = st.position_enu_m[0].copy()
        if cond == "outage":
            # receivers in trouble report fix_type 1 with whatever position they last computed
            pos[:2] += np.sign(garbage) * (100.0 + 1900.0 * np.abs(garbage))  # 0.1 to 2 km off
            lat, lon, alt, alt_e = self._geodetic(pos)
            return self._codec.gps_raw_int_encode(
                stamp_us, 1, lat, lon, alt, _UINT16_UNKNOWN, _UINT16_UNKNOWN, 0, 0, 4, alt_e
            )
        pos += noise * np.array([g.noise_horizontal_m, g.noise_horizontal_m, g.noise_vertical_m])
        lat, lon, alt, alt_e = self._geodetic(pos)
        v = st.velocity_enu_m_s[0]
        speed = math.hypot(float(v[0]), float(v[1]))
        cog = round(math.degrees(math.atan2(float(v[0]), float(v[1]))) % 360.0 * 100.0) % 36000
        return self._codec.gps_raw_int_encode(
            stamp_us,
            g.fix_type,
            lat,
            lon,
            alt,
            round(g.hdop * 100),
            round(g.hdop * 150),
            round(speed * 100.0),
            cog,
            g.satellites,
            alt_e,
            round(g.noise_horizontal_m * 1000.0),
            round(g.noise_vertical_m * 1000.0),
            100,
            0,
            0,
        )

    def _fused_position(self, tau: float, st: TruthState, rng: np.random.Generator) -> Any:
        g = self.scenario.gps
        noise = rng.normal(size=3) * np.array(
            [g.fused_noise_horizontal_m, g.fused_noise_horizontal_m, g.fused_noise_vertical_m]
        )
        return st.position_enu_m[0] + noise + self._outage_error_enu(tau)

    def _global_position_int(self, stamp_us: int, rng: np.random.Generator) -> Any:
        tau, st = self._state(stamp_us)
        cond = gps_condition(self.scenario, tau)
        pos = self._fused_position(tau, st, rng)
        if cond == "denied":
            return None
        v_ned = enu_to_ned(st.velocity_enu_m_s[0])
        _, _, yaw = q_to_euler_zyx(st.q_body_ned[0])
        hdg = round(math.degrees(float(yaw)) % 360.0 * 100.0) % 36000
        rel_mm = round(float(pos[2]) * 1000.0)
        if cond == "acquiring":
            lat = lon = alt = 0
        else:
            lat, lon, alt, _ = self._geodetic(pos)
        vx, vy, vz = (round(float(c) * 100.0) for c in v_ned)
        return self._codec.global_position_int_encode(stamp_us // 1000, lat, lon, alt, rel_mm, vx, vy, vz, hdg)

    def _local_position_ned(self, stamp_us: int, rng: np.random.Generator) -> Any:
        _, st = self._state(stamp_us)  # relative to the EKF origin, which origin resets move
        g = self.scenario.gps
        noise = rng.normal(size=3) * np.array(
            [g.fused_noise_horizontal_m, g.fused_noise_horizontal_m, g.fused_noise_vertical_m]
        )
        tau = float(self.clocks.autopilot_us_to_tau(stamp_us))
        p = enu_to_ned(st.position_enu_m[0] + noise - self._origin_shift_enu(tau))
        v = enu_to_ned(st.velocity_enu_m_s[0])
        return self._codec.local_position_ned_encode(
            stamp_us // 1000, float(p[0]), float(p[1]), float(p[2]), float(v[0]), float(v[1]), float(v[2])
        )

    def _attitude(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        _, st = self._state(stamp_us)
        roll, pitch, yaw = q_to_euler_zyx(st.q_body_ned[0])
        w = st.omega_body_rad_s[0]
        return self._codec.attitude_encode(
            stamp_us // 1000, float(roll), float(pitch), float(yaw), float(w[0]), float(w[1]), float(w[2])
        )

    def _attitude_quaternion(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        _, st = self._state(stamp_us)
        q = st.q_body_ned[0]
        w = st.omega_body_rad_s[0]
        return self._codec.attitude_quaternion_encode(
            stamp_us // 1000, float(q[0]), float(q[1]), float(q[2]), float(q[3]), float(w[0]), float(w[1]), float(w[2])
        )

    def _autopilot_version(self) -> Any:
        caps = (
            mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        )
        firmware = self.scenario.autopilot.firmware
        return self._codec.autopilot_version_encode(
            caps, _FLIGHT_SW_VERSION[firmware], 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x1C67
        )

    # --- the gimbal device ----------------------------------------------------------------------

    def _run_gimbal(self) -> None:
        """GIMBAL_DEVICE_ATTITUDE_STATUS of the camera's gimbal at its rate, on the truth's grid, through this
        autopilot's routing to the companion link (the gimbal device is its own component, on its own boot
        clock), silent in its `silent_s` windows and while the companion link is down."""
        g = self.scenario.camera.gimbal
        assert g is not None
        rng = np.random.default_rng([self.scenario.seed, 0xA9, 154])
        period_s = 1.0 / g.rate_hz
        k = max(0, math.ceil(self._tau_now() / period_s))
        while not self._stop.is_set():
            tau = k * period_s
            wait_s = (self.clocks.tau_to_host_ns(tau) + self.latency_ns - time.monotonic_ns()) / 1e9
            if wait_s > 0:
                self._stop.wait(min(wait_s, 0.1))
                continue
            k += 1
            if tau > self.scenario.duration_s or any(a <= tau < b for a, b in g.silent_s):
                continue
            if self._companion is None or self._companion_dropped(tau):
                continue
            noise = np.radians(rng.normal(size=3) * g.noise_deg)
            q = q_multiply(self.trajectory.gimbal_vehicle_frame(tau), q_from_euler_zyx(*noise))
            boot_ms = round((tau - g.boot_offset_s) * 1000.0)
            msg = self._gimbal_codec.gimbal_device_attitude_status_encode(
                0, 0, boot_ms, _GIMBAL_FLAGS, [float(c) for c in q], 0.0, 0.0, 0.0, 0
            )
            try:
                self._companion.send_as(msg, self._gimbal_codec)
            except OSError as exc:
                self.errors.append(f"gimbal send: {exc!r}")
                continue
            self.sent_counts["gimbal_device_attitude_status"] = (
                self.sent_counts.get("gimbal_device_attitude_status", 0) + 1
            )

    # --- receiving, commands and routing ------------------------------------------------------

    def _run_receiver(self) -> None:
        while not self._stop.is_set():
            links = [link for link in (self._companion, self._gcs) if link is not None]
            fds = [fd for link in links if (fd := link.fileno()) is not None]
            try:
                if fds:
                    select.select(fds, [], [], _SELECT_TIMEOUT_S)
                else:
                    time.sleep(_SELECT_TIMEOUT_S)
            except (OSError, ValueError):
                time.sleep(_SELECT_TIMEOUT_S)
            for link in links:
                try:
                    for msg in link.read():
                        self._on_message(link, msg)
                except Exception as exc:  # keep serving; the error is reported in self.errors
                    self.errors.append(f"{link.name} receive: {exc!r}")

    def _on_message(self, link: _Link, msg: Any) -> None:
        if link is self._companion and self._companion_dropped(self._tau_now()):
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.system_id, COMPONENT_ID):
            return  # our own frames echoed back by a loop
        tgt_sys = int(getattr(msg, "target_system", 0))
        tgt_comp = int(getattr(msg, "target_component", 0))
        other = self._gcs if link is self._companion else self._companion
        addressed_to_me_only = tgt_sys == self.system_id and tgt_comp == COMPONENT_ID
        to_companion = other is self._companion
        if (
            other is not None
            and not addressed_to_me_only
            and not (to_companion and self._companion_dropped(self._tau_now()))
        ):
            other.forward(bytes(msg.get_msgbuf()))
            self.forwarded_counts["to_companion" if to_companion else "to_gcs"] += 1
        if self.camera_trigger is not None and link is self._companion:
            with self._trigger_lock:
                self.camera_trigger.on_message(msg)
        for_me = tgt_sys in (0, self.system_id) and tgt_comp in (0, COMPONENT_ID)
        if not for_me:
            return
        mtype = msg.get_type()
        if mtype == "TIMESYNC" and msg.tc1 == 0:
            if not self.scenario.autopilot.answer_timesync:
                return
            link.send(self._codec.timesync_encode(self._ap_now_us() * 1000, msg.ts1))
        elif mtype == "COMMAND_LONG":
            self._on_command(link, msg, addressed=tgt_comp == COMPONENT_ID)

    def _ack(self, link: _Link, msg: Any, result: int) -> None:
        link.send(
            self._codec.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        )

    def _on_command(self, link: _Link, msg: Any, *, addressed: bool) -> None:
        cmd = int(msg.command)
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not self.scenario.autopilot.honour_message_interval:
                return  # no COMMAND_ACK, the default rates stay
            self._ack(link, msg, self._set_interval(int(msg.param1), float(msg.param2)))
        elif cmd == mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL:
            mid = int(msg.param1)
            s = self._streams.get(mid)
            interval = 0 if s is None else (-1 if s.interval_us is None else s.interval_us)
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self._codec.message_interval_encode(mid, interval))
        elif cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            self._request_message(link, msg, int(msg.param1))
        elif cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self._autopilot_version())
        elif addressed:
            self._ack(link, msg, mavlink2.MAV_RESULT_UNSUPPORTED)

    def _set_interval(self, msg_id: int, interval_us: float) -> int:
        s = self._streams.get(msg_id)
        if s is None or interval_us < -1 or not math.isfinite(interval_us):
            return int(mavlink2.MAV_RESULT_DENIED)
        with self._cond:
            if interval_us == -1:
                s.interval_us = None
            elif interval_us == 0:
                s.interval_us = s.default_interval_us
            else:
                s.interval_us = max(1000, round(interval_us))
            self._restart_stream(s, self._ap_now_us())
            self._cond.notify_all()
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def _request_message(self, link: _Link, msg: Any, msg_id: int) -> None:
        if msg_id == mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self._autopilot_version())
            return
        s = self._streams.get(msg_id)
        if s is None:
            self._ack(link, msg, mavlink2.MAV_RESULT_DENIED)
            return
        stamp_us = self._ap_now_us()
        if s.name not in _US_STAMPED:
            stamp_us = (stamp_us // 1000) * 1000
        built = self._build(s.name, stamp_us, self._oneoff_rng)
        if built is None:  # e.g. GLOBAL_POSITION_INT while GPS-denied
            self._ack(link, msg, mavlink2.MAV_RESULT_FAILED)
            return
        self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
        link.send(built, mavlink1=built.get_type() in self.mavlink1_messages)

    # --- events: forwarded ground stations, a foreign camera, origin messages, parameter bursts ---

    def _event_plan(self) -> list[tuple[float, int, str, int]]:
        """The one-off and first periodic events as (tau, sequence, kind, argument)."""
        ap = self.scenario.autopilot
        start = max(0.0, self._tau_now())
        plan: list[tuple[float, str, int]] = []
        if ap.gcs_heartbeat_systems:
            plan.append((start, "gcs_heartbeats", 0))
        if ap.foreign_camera:
            plan.append((start, "camera_heartbeat", 0))
        if ap.own_timesync_hz > 0.0:
            plan.append((start, "own_timesync", 0))
        if ap.stream_reset_s > 0.0:
            plan.append((max(start, ap.stream_reset_s), "stream_reset", 0))
        if self.camera_trigger is not None:
            plan.append((start, "camera_update", 0))
        if ap.origin_on_change:
            plan.append((max(start, self.scenario.gps.fix_acquired_after_s), "origin", 0))
            plan += [(t, "origin", 0) for t in ap.origin_resets_s if t > self.scenario.gps.fix_acquired_after_s]
        for t in ap.param_bursts_s:
            n_chunks = max(1, math.ceil(ap.param_burst_duration_s / _BURST_CHUNK_S))
            per_chunk = -(-ap.param_burst_count // n_chunks)
            for c in range(n_chunks):
                first = c * per_chunk
                if first < ap.param_burst_count:
                    plan.append((t + c * _BURST_CHUNK_S, "params", first))
        return [(tau, i, kind, arg) for i, (tau, kind, arg) in enumerate(plan)]

    def _run_events(self) -> None:
        heap = self._event_plan()
        heapq.heapify(heap)
        sequence = len(heap)
        while heap and not self._stop.is_set():
            tau, _, kind, arg = heap[0]
            wait_s = tau - self._tau_now()
            if wait_s > 0.0:
                self._stop.wait(min(wait_s, 0.1))
                continue
            heapq.heappop(heap)
            try:
                again = self._event(kind, arg)
            except Exception as exc:  # keep going; the error is reported in self.errors
                self.errors.append(f"event {kind}: {exc!r}")
                again = None
            if again is not None:
                heapq.heappush(heap, (tau + again, sequence, kind, arg))
                sequence += 1

    def _links_now(self, *, companion_only: bool = False) -> list[_Link]:
        out: list[_Link] = []
        if self._companion is not None and not self._companion_dropped(self._tau_now()):
            out.append(self._companion)
        if self._gcs is not None and not companion_only:
            out.append(self._gcs)
        return out

    def _event(self, kind: str, arg: int) -> float | None:
        """Do one event; returns the period after which it repeats (None: once)."""
        ap = self.scenario.autopilot
        if kind == "gcs_heartbeats":
            # what the autopilot forwards from its GCS links: each ground station's HEARTBEAT
            for codec in self._gcs_codecs:
                hb = codec.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                for link in self._links_now(companion_only=True):
                    link.send_as(hb, codec)
            return _EVENT_PERIOD_S
        if kind == "camera_heartbeat":
            c = self._camera_codec
            hb = c.heartbeat_encode(
                mavlink2.MAV_TYPE_CAMERA, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
            )
            for link in self._links_now():
                link.send_as(hb, c)
            return _EVENT_PERIOD_S
        if kind == "own_timesync":
            if self._companion is not None and not self._companion_dropped(self._tau_now()):
                self._companion.send(self._codec.timesync_encode(0, self._ap_now_us() * 1000))
            return 1.0 / ap.own_timesync_hz
        if kind == "stream_reset":  # ArduPilot's boot ends: SRn_ rates applied over earlier requests
            with self._cond:
                for stream in self._streams.values():
                    stream.interval_us = stream.default_interval_us
                    self._restart_stream(stream, self._ap_now_us())
                self._cond.notify_all()
            self.stream_resets += 1
            return None
        if kind == "camera_update":
            if self.camera_trigger is not None:
                with self._trigger_lock:
                    self.camera_trigger.update(self._tau_now(), self._ap_now_us() // 1000)
            return UPDATE_PERIOD_S
        if kind == "origin":
            msg = self._origin_message(self._ap_now_us())
            for link in self._links_now():
                link.send(msg)
            self.sent_counts["GPS_GLOBAL_ORIGIN"] = self.sent_counts.get("GPS_GLOBAL_ORIGIN", 0) + 1
            return None
        if kind == "params":
            n_chunks = max(1, math.ceil(ap.param_burst_duration_s / _BURST_CHUNK_S))
            per_chunk = -(-ap.param_burst_count // n_chunks)
            for index in range(arg, min(arg + per_chunk, ap.param_burst_count)):
                msg = self._codec.param_value_encode(
                    f"SIM_P{index:05d}".encode(),
                    float(index),
                    mavlink2.MAV_PARAM_TYPE_REAL32,
                    ap.param_burst_count,
                    index,
                )
                for link in self._links_now():
                    link.send(msg)
                self.sent_counts["PARAM_VALUE"] = self.sent_counts.get("PARAM_VALUE", 0) + 1
            return None
        raise SimError(f"unknown autopilot event {kind!r}")
