"""The simulated autopilot's telemetry messages, built from the scenario and the truth (no I/O).

HEARTBEAT, SYSTEM_TIME, GPS_RAW_INT, GLOBAL_POSITION_INT, ATTITUDE, ATTITUDE_QUATERNION,
LOCAL_POSITION_NED, GPS_GLOBAL_ORIGIN and AUTOPILOT_VERSION, each at an autopilot boot-clock stamp, as
`icgt.sim.autopilot`'s docstring describes them (the GPS conditions, the fused estimate's noise and
drift, the EKF origin and its resets, the position gaps). Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import LocalFrame, enu_to_ned, q_to_euler_zyx
from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.scenario import Scenario
from icgt.sim.trajectory import Trajectory, TruthState

__all__ = ["TelemetryBuilder", "gps_condition"]

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
_UINT16_UNKNOWN = 65535


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


class TelemetryBuilder:
    """The messages of one simulated autopilot, encoded with its ``codec`` (see the module docstring)."""

    def __init__(
        self, scenario: Scenario, clock: AutopilotClock, trajectory: Trajectory, frame: LocalFrame, codec: Any
    ) -> None:
        self.scenario = scenario
        self.clock = clock
        self.trajectory = trajectory
        self.frame = frame
        self._codec = codec
        seed = scenario.seed
        self._outage_dirs = [
            float(np.random.default_rng([seed, 0xA9, 2, i]).uniform(0.0, 2.0 * math.pi))
            for i in range(len(scenario.gps.outages_s))
        ]
        self._cache_lock = threading.Lock()
        self._state_cache: dict[int, tuple[float, TruthState]] = {}

    def _state(self, stamp_us: int) -> tuple[float, TruthState]:
        """Truth at an autopilot stamp; cached because several streams share each stamp."""
        with self._cache_lock:
            hit = self._state_cache.get(stamp_us)
        if hit is not None:
            return hit
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
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
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
        return any(a <= tau < b for a, b in self.scenario.faults.position_gaps_s)

    def build(self, name: str, stamp_us: int, rng: np.random.Generator) -> Any:
        """Stream ``name``'s message at ``stamp_us`` with noise from ``rng``; None: nothing to send."""
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

    def origin_message(self, stamp_us: int) -> Any:
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
        lat, lon, alt, _ = self._geodetic(self._origin_shift_enu(tau))
        return self._codec.gps_global_origin_encode(lat, lon, alt, stamp_us)

    def _gps_global_origin(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
        if tau < self.scenario.gps.fix_acquired_after_s:
            return None  # the EKF has no origin before the first fix
        return self.origin_message(stamp_us)

    def _system_time(self, stamp_us: int, _rng: np.random.Generator) -> Any:
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
        unix_us = self.clock.maps.tau_to_utc_us(tau) if tau >= self.scenario.gps.fix_acquired_after_s else 0
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
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
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

    def autopilot_version(self) -> Any:
        caps = (
            mavlink2.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink2.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink2.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        )
        firmware = self.scenario.autopilot.firmware
        return self._codec.autopilot_version_encode(
            caps, _FLIGHT_SW_VERSION[firmware], 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 0x1C67
        )
