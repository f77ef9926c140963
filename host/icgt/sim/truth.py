"""Ground truth: the clock maps of the contract, the sensor truth table, true exposures and offsets.

Time axes (hil_sim/README.md): scenario time tau [s] is 0 at host CLOCK_MONOTONIC t0_monotonic_ns.

    host monotonic [ns] = t0_monotonic_ns + tau * 1e9
    UTC [us]            = utc0_us + tau * 1e6
    device [us]         = device_offset_us + tau * 1e6 * (1 + device_drift_ppm * 1e-6)
    autopilot boot [us] = ap_offset_us + tau * 1e6 * (1 + ap_drift_ppm * 1e-6)
    camera [s]          = utc0_us * 1e-6 + camera_offset_s + tau * (1 + camera_drift_ppm * 1e-6)

The camera clock is a wall clock (seconds since the Unix epoch as the camera believes them); EXIF
records it as local time truncated to 1 s or 10 ms.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from icgt.geodesy import FloatArray, LocalFrame, enu_to_ned, q_conjugate, q_from_euler_zyx, q_multiply, q_rotate
from icgt.pose import Q_OPTICAL_TO_FRD
from icgt.sim.scenario import Scenario, SimError
from icgt.sim.trajectory import GRAVITY_M_S2, Trajectory

SENSOR_TRUTH_PERIOD_S = 0.005
SENSOR_TRUTH_COLUMNS = (
    "tau_s",
    "qw",
    "qx",
    "qy",
    "qz",
    "gyro_x_rad_s",
    "gyro_y_rad_s",
    "gyro_z_rad_s",
    "accel_x_m_s2",
    "accel_y_m_s2",
    "accel_z_m_s2",
    "lin_accel_x_m_s2",
    "lin_accel_y_m_s2",
    "lin_accel_z_m_s2",
    "range_cm",
    "range_valid",
)


@dataclass(frozen=True)
class ClockMaps:
    """The true clocks of one run, as linear maps from and to scenario time tau [s]."""

    t0_monotonic_ns: int
    utc0_us: int
    device_offset_us: float = 0.0
    device_drift_ppm: float = 0.0
    autopilot_offset_us: float = 0.0
    autopilot_drift_ppm: float = 0.0
    camera_offset_s: float = 0.0
    camera_drift_ppm: float = 0.0
    exif_resolution: str = "1s"

    @classmethod
    def from_scenario(cls, scenario: Scenario, t0_monotonic_ns: int, utc0_us: int) -> ClockMaps:
        c = scenario.clocks
        return cls(
            t0_monotonic_ns=t0_monotonic_ns,
            utc0_us=utc0_us,
            device_offset_us=round(c.device.offset_s * 1e6),
            device_drift_ppm=c.device.drift_ppm,
            autopilot_offset_us=round(c.autopilot.offset_s * 1e6),
            autopilot_drift_ppm=c.autopilot.drift_ppm,
            camera_offset_s=c.camera.offset_s,
            camera_drift_ppm=c.camera.drift_ppm,
            exif_resolution=c.camera.exif_resolution,
        )

    # host monotonic
    def tau_to_host_ns(self, tau_s: float) -> int:
        return self.t0_monotonic_ns + round(tau_s * 1e9)

    def host_ns_to_tau(self, host_ns: int) -> float:
        return (host_ns - self.t0_monotonic_ns) * 1e-9

    # UTC
    def tau_to_utc_us(self, tau_s: float) -> int:
        return self.utc0_us + round(tau_s * 1e6)

    def utc_us_to_tau(self, utc_us: float) -> float:
        return (utc_us - self.utc0_us) * 1e-6

    # device
    def tau_to_device_us(self, tau_s: Any) -> Any:
        """Device clock [us] (float, or array for an array tau)."""
        return self.device_offset_us + np.asarray(tau_s) * 1e6 * (1.0 + self.device_drift_ppm * 1e-6)

    def device_us_to_tau(self, device_us: Any) -> Any:
        return (np.asarray(device_us, dtype=np.float64) - self.device_offset_us) / (
            1e6 * (1.0 + self.device_drift_ppm * 1e-6)
        )

    # autopilot boot clock
    def tau_to_autopilot_us(self, tau_s: Any) -> Any:
        """Autopilot boot time [us] (float, or array for an array tau)."""
        return self.autopilot_offset_us + np.asarray(tau_s) * 1e6 * (1.0 + self.autopilot_drift_ppm * 1e-6)

    def autopilot_us_to_tau(self, autopilot_us: Any) -> Any:
        return (np.asarray(autopilot_us, dtype=np.float64) - self.autopilot_offset_us) / (
            1e6 * (1.0 + self.autopilot_drift_ppm * 1e-6)
        )

    # camera wall clock
    def tau_to_camera_s(self, tau_s: float) -> float:
        """The camera's wall clock [s since the Unix epoch as the camera counts them]."""
        return self.utc0_us * 1e-6 + self.camera_offset_s + tau_s * (1.0 + self.camera_drift_ppm * 1e-6)

    def camera_s_to_tau(self, camera_s: float) -> float:
        return (camera_s - self.utc0_us * 1e-6 - self.camera_offset_s) / (1.0 + self.camera_drift_ppm * 1e-6)

    def exif_time(self, tau_s: float) -> tuple[str, str | None]:
        """(DateTimeOriginal "YYYY:MM:DD HH:MM:SS", SubSecTimeOriginal "00".."99" or None for 1 s)."""
        return exif_strings(self.tau_to_camera_s(tau_s), self.exif_resolution)


def exif_strings(camera_s: float, resolution: str) -> tuple[str, str | None]:
    """EXIF date/time strings of a camera clock reading, truncated as a camera does."""
    whole = math.floor(camera_s)
    text = datetime.fromtimestamp(whole, tz=UTC).strftime("%Y:%m:%d %H:%M:%S")
    if resolution == "1s":
        return text, None
    centis = min(99, math.floor((camera_s - whole) * 100.0 + 1e-6))
    return text, f"{centis:02d}"


# --- the device's sensor truth table --------------------------------------------------------


def _continuous_hemisphere(q: FloatArray) -> FloatArray:
    """Flip signs so consecutive quaternions are in the same hemisphere (for nlerp between rows)."""
    if len(q) < 2:
        return q
    dots = np.sum(q[1:] * q[:-1], axis=-1)
    sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0.0, -1.0, 1.0))])
    out: FloatArray = q * sign[:, None]
    return out


def sensor_truth_table(
    scenario: Scenario, *, margin_s: float = 5.0, trajectory: Trajectory | None = None
) -> FloatArray:
    """The rows of the sensor truth CSV (one per 5 ms from tau = 0 to duration + margin)."""
    traj = trajectory or Trajectory(scenario)
    n = round((scenario.duration_s + margin_s) / SENSOR_TRUTH_PERIOD_S) + 1
    tau: FloatArray = np.arange(n, dtype=np.float64) * SENSOR_TRUTH_PERIOD_S
    st = traj.state(tau)
    q_sensor, omega = st.q_camera_ned, st.omega_camera_rad_s
    board = scenario.camera.board_imu
    if board is not None:
        # the board's axes: the camera's turned back by its alignment on the board (q_cam = q_board q_cam_board)
        q_cam_board = q_from_euler_zyx(*np.radians(board.camera_on_board_deg))
        q_sensor = np.asarray(q_multiply(q_sensor, q_conjugate(q_cam_board)))
        omega = q_rotate(q_cam_board, omega)
    q_inv = q_conjugate(q_sensor)
    lin_ned = enu_to_ned(st.camera_accel_enu_m_s2)
    # an accelerometer measures specific force: acceleration minus gravity (gravity is +z in NED)
    specific_ned = lin_ned - np.array([0.0, 0.0, GRAVITY_M_S2])
    accel = q_rotate(q_inv, specific_ned)
    lin = q_rotate(q_inv, lin_ned)
    if board is not None:
        # what the BNO055 reports: the board's attitude in its own world frame, whose north is the true one
        # turned by -offset (true north minus its north), drifting
        offset_rad = np.radians(board.heading_offset_deg + board.heading_drift_deg_per_min * tau / 60.0)
        zero = np.zeros_like(tau)
        q_sensor = np.asarray(q_multiply(q_from_euler_zyx(zero, zero, -offset_rad), q_sensor))
    q = _continuous_hemisphere(q_sensor)
    range_cm = np.where(st.range_valid, st.range_m * 100.0, 0.0)
    return np.column_stack([tau, q, omega, accel, lin, range_cm, st.range_valid.astype(np.float64)])


def write_sensor_truth(
    scenario: Scenario, path: str | Path, *, margin_s: float = 5.0, trajectory: Trajectory | None = None
) -> int:
    """Write the sensor truth CSV of hil_sim/README.md; returns the number of data rows.

    Quaternion: camera (= sensor) axes to NED. Gyro: camera angular rate in camera axes [rad/s].
    accel: specific force in camera axes (a level, still sensor reads (0, 0, -9.80665) in its FRD
    axes); lin_accel: acceleration without gravity in camera axes. range_cm: true distance along
    the optical axis (0 where range_valid is 0).
    """
    rows = sensor_truth_table(scenario, margin_s=margin_s, trajectory=trajectory)
    fmt = ["%.3f"] + ["%.9f"] * 4 + ["%.7f"] * 3 + ["%.6f"] * 6 + ["%.2f", "%d"]
    try:
        np.savetxt(Path(path), rows, fmt=fmt, delimiter=",", header=",".join(SENSOR_TRUTH_COLUMNS), comments="")
    except OSError as exc:
        raise SimError(f"cannot write sensor truth {path}: {exc.strerror}") from exc
    return len(rows)


# --- true exposures -------------------------------------------------------------------------


@dataclass(frozen=True)
class ExposureTruth:
    """What really happened at one exposure (positions are the camera's)."""

    frame_number: int
    trigger_index: int
    manual: bool
    trigger_device_us: int
    start_device_us: int
    end_device_us: int
    mid_device_us: float
    start_tau_s: float
    mid_tau_s: float
    mid_host_monotonic_ns: int
    mid_utc_us: int
    start_camera_s: float
    """Camera wall clock at the start of the exposure (what EXIF records, before truncation)."""
    lat_deg: float
    lon_deg: float
    alt_msl_m: float
    alt_ellipsoid_m: float
    position_enu_m: tuple[float, float, float]
    body_position_enu_m: tuple[float, float, float]
    q_camera_ned: tuple[float, float, float, float]
    """The camera board's FRD axes (x along the optical axis; the BNO055's sensor frame) -> NED."""
    q_optical_ned: tuple[float, float, float, float]
    """Camera optical (x right, y down, z forward) -> NED: the frame record's ``cam_q*`` (`icgt.pose`)."""
    q_body_ned: tuple[float, float, float, float]
    omega_camera_rad_s: tuple[float, float, float]
    range_m: float | None
    """True distance along the optical axis to the structure (None: no return)."""

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        d["event"] = "exposure_truth"
        return d


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """The device program's --events-out file: one JSON object per line."""
    out: list[dict[str, Any]] = []
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise SimError(f"cannot read events {path}: {exc.strerror}") from exc
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            obj = json.loads(line)
        except json.JSONDecodeError as exc:
            raise SimError(f"{path}:{i}: not JSON: {exc.msg}") from exc
        if not isinstance(obj, dict):
            raise SimError(f"{path}:{i}: expected a JSON object")
        out.append(obj)
    return out


def _tuple3(a: FloatArray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def exposure_truth(
    scenario: Scenario,
    events: Iterable[Mapping[str, Any]],
    clocks: ClockMaps,
    *,
    trajectory: Trajectory | None = None,
) -> list[ExposureTruth]:
    """Ground truth for each `{"event": "exposure", ...}` record (device-clock times); others skipped.

    Mid-exposure = (start + end) / 2 on the device clock, mapped to tau and the other clocks.
    """
    exposures = [e for e in events if e.get("event") == "exposure"]
    if not exposures:
        return []
    try:
        start = np.array([int(e["start_t_us"]) for e in exposures], dtype=np.float64)
        end = np.array([int(e["end_t_us"]) for e in exposures], dtype=np.float64)
    except (KeyError, TypeError, ValueError) as exc:
        raise SimError(f"exposure event without a valid start_t_us/end_t_us: {exc}") from exc
    mid = (start + end) / 2.0
    mid_tau = np.asarray(clocks.device_us_to_tau(mid), dtype=np.float64)
    start_tau = np.asarray(clocks.device_us_to_tau(start), dtype=np.float64)
    traj = trajectory or Trajectory(scenario)
    st = traj.state(mid_tau)
    frame = LocalFrame(scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.ellipsoid_height_m)
    lat, lon, h = frame.enu_to_geodetic(st.camera_position_enu_m)
    out: list[ExposureTruth] = []
    for i, e in enumerate(exposures):
        tau = float(mid_tau[i])
        q_c = st.q_camera_ned[i]
        q_b = st.q_body_ned[i]
        q_o = q_multiply(q_c, Q_OPTICAL_TO_FRD)
        out.append(
            ExposureTruth(
                frame_number=int(e.get("frame_number", i + 1)),
                trigger_index=int(e.get("trigger_index", 0)),
                manual=bool(e.get("manual", False)),
                trigger_device_us=int(e.get("trigger_t_us", int(start[i]))),
                start_device_us=int(start[i]),
                end_device_us=int(end[i]),
                mid_device_us=float(mid[i]),
                start_tau_s=float(start_tau[i]),
                mid_tau_s=tau,
                mid_host_monotonic_ns=clocks.tau_to_host_ns(tau),
                mid_utc_us=clocks.tau_to_utc_us(tau),
                start_camera_s=clocks.tau_to_camera_s(float(start_tau[i])),
                lat_deg=float(lat[i]),
                lon_deg=float(lon[i]),
                alt_msl_m=float(h[i]) - scenario.origin.geoid_separation_m,
                alt_ellipsoid_m=float(h[i]),
                position_enu_m=_tuple3(st.camera_position_enu_m[i]),
                body_position_enu_m=_tuple3(st.position_enu_m[i]),
                q_camera_ned=(float(q_c[0]), float(q_c[1]), float(q_c[2]), float(q_c[3])),
                q_optical_ned=(float(q_o[0]), float(q_o[1]), float(q_o[2]), float(q_o[3])),
                q_body_ned=(float(q_b[0]), float(q_b[1]), float(q_b[2]), float(q_b[3])),
                omega_camera_rad_s=_tuple3(st.omega_camera_rad_s[i]),
                range_m=float(st.range_m[i]) if bool(st.range_valid[i]) else None,
            )
        )
    return out


def write_exposure_truth(path: str | Path, records: Sequence[ExposureTruth]) -> None:
    """Write exposure truth records as JSON lines (`"event": "exposure_truth"`)."""
    try:
        with Path(path).open("w", encoding="utf-8") as f:
            for r in records:
                f.write(json.dumps(r.to_json(), separators=(",", ":")) + "\n")
    except OSError as exc:
        raise SimError(f"cannot write exposure truth {path}: {exc.strerror}") from exc


# --- true clock offsets over time -----------------------------------------------------------

CLOCK_OFFSET_COLUMNS = (
    "tau_s",
    "host_monotonic_ns",
    "utc_us",
    "device_us",
    "autopilot_boot_us",
    "camera_s",
    "device_minus_host_us",
    "autopilot_minus_host_us",
    "camera_minus_utc_s",
)


def write_clock_offsets(path: str | Path, clocks: ClockMaps, duration_s: float, *, step_s: float = 1.0) -> int:
    """CSV of every clock at tau = 0, step_s, ... duration_s, with the true offsets between them.

    device_minus_host_us = device_us - host_monotonic_ns / 1000 (likewise for the autopilot);
    camera_minus_utc_s = camera_s - utc_us / 1e6. Returns the number of data rows.
    """
    n = math.floor(duration_s / step_s + 1e-9) + 1
    lines = [",".join(CLOCK_OFFSET_COLUMNS)]
    for k in range(n):
        tau = k * step_s
        host_ns = clocks.tau_to_host_ns(tau)
        utc_us = clocks.tau_to_utc_us(tau)
        dev = float(clocks.tau_to_device_us(tau))
        ap = float(clocks.tau_to_autopilot_us(tau))
        cam = clocks.tau_to_camera_s(tau)
        lines.append(
            f"{tau:.3f},{host_ns},{utc_us},{dev:.3f},{ap:.3f},{cam:.6f},"
            f"{dev - host_ns / 1000.0:.3f},{ap - host_ns / 1000.0:.3f},{cam - utc_us / 1e6:.6f}"
        )
    try:
        Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    except OSError as exc:
        raise SimError(f"cannot write clock offsets {path}: {exc.strerror}") from exc
    return n
