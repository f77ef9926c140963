"""The true flight: pose, motion, camera attitude and LiDAR range as functions of scenario time.

`Trajectory(scenario).state(tau_s)` evaluates everything for an array of scenario times at once.
Frames (see geodesy.py): positions, velocities and accelerations in ENU [m, m/s, m/s^2] relative
to the scenario origin; attitudes as Hamilton quaternions (w first) body-to-NED, as MAVLink
reports them; body and camera axes FRD (camera x = optical axis = LiDAR axis).

Motion model. The path is a chain of straight segments between waypoints of the *camera*; the
autopilot's reference point sits `lever_arm_m` behind it. Along a segment of length D and
duration T the travelled fraction follows a speed profile that ramps up over r*T with the
"smootherstep" S(w) = 10w^3 - 15w^4 + 6w^5, cruises, and ramps down symmetrically; position,
velocity, acceleration and jerk are continuous everywhere (velocity and acceleration are zero
at every waypoint), so accelerations and angular rates stay finite. With ramp time T_r the cruise
speed is V = D / (T - T_r), i.e. T = D / V + T_r. A point-to-point move is the case r = 1/2
(peak speed 2D/T). A multirotor tilts to produce its specific force: the body z axis is
-(a - g)/|a - g| (NED), yaw is held at the heading; the body angular rate is 2 conj(q) dq/dt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from icgt.geodesy import (
    FloatArray,
    body_rates_from_quaternions,
    enu_to_ned,
    ned_to_enu,
    q_from_euler_zyx,
    q_from_matrix,
    q_multiply,
    q_rotate,
    q_to_euler_zyx,
)
from icgt.pose import camera_quaternion
from icgt.sim.scenario import DeckPass, Hover, PierScan, Scenario, Survey
from icgt.sim.survey import Leg, SurveyFlight

BoolArray = npt.NDArray[np.bool_]
GRAVITY_M_S2 = 9.80665
_UP = np.array([0.0, 0.0, 1.0])
_FD_H_S = 1e-3  # finite-difference step for rates [s]


@dataclass(frozen=True)
class TruthState:
    """True state at N scenario times (arrays have N rows)."""

    tau_s: FloatArray
    position_enu_m: FloatArray
    """The autopilot's reference point (what GLOBAL_POSITION_INT reports)."""
    velocity_enu_m_s: FloatArray
    accel_enu_m_s2: FloatArray
    q_body_ned: FloatArray
    omega_body_rad_s: FloatArray
    """Body angular rate in body axes (what ATTITUDE rollspeed/pitchspeed/yawspeed report)."""
    camera_position_enu_m: FloatArray
    camera_accel_enu_m_s2: FloatArray
    q_camera_ned: FloatArray
    omega_camera_rad_s: FloatArray
    """Camera angular rate in camera axes (what the BNO055 on the camera senses)."""
    optical_axis_enu: FloatArray
    range_m: FloatArray
    """Distance along the optical axis from the camera to the structure plane (nan: no return)."""
    range_valid: BoolArray


@dataclass(frozen=True)
class PierScanPlan:
    """Geometry of a pier scan (see pier_scan_plan)."""

    footprint_width_m: float
    footprint_height_m: float
    step_m: float
    pass_offsets_m: tuple[float, ...]
    """Lateral offsets of the passes to the right of the structure point (seen from the drone)."""
    along_track_overlap: float
    """Overlap of consecutive frames within a burst (1 - speed / (fps * footprint height))."""


def pier_scan_plan(scenario: Scenario) -> PierScanPlan:
    """Where the passes of a pier scan go.

    At standoff d a camera with focal length f and sensor width w_s sees a strip of width
    W = d * w_s / f (height H = d * h_s / f) on a face square to its optical axis. Passes are
    vertical, so adjacent passes overlap by the fraction p when their lateral step is

        step = W * (1 - p).

    The passes are centred on the structure point; their number is the smallest n with
    W + (n - 1) * step >= width_m, i.e. n = ceil((width_m - W) / step) + 1 (1 if width_m <= W).
    Along a pass, frames taken at fps while moving at v overlap by 1 - v / (fps * H).
    """
    spec = scenario.trajectory
    if not isinstance(spec, PierScan):
        raise TypeError("pier_scan_plan needs a pier_scan scenario")
    cam = scenario.camera
    w, h = cam.footprint_m(spec.standoff_m)
    step = w * (1.0 - spec.side_overlap)
    n = 1 if spec.width_m <= w else math.ceil((spec.width_m - w) / step - 1e-9) + 1
    offsets = tuple((n - 1) / 2.0 * step - k * step for k in range(n))
    fps = cam.capture.burst_fps if cam.capture.mode == "focus_burst" else 1.0 / cam.capture.interval_s
    along = 1.0 - spec.speed_m_s / (fps * h)
    return PierScanPlan(w, h, step, offsets, along)


# --- 1-D speed profile ----------------------------------------------------------------------


def _smootherstep(w: FloatArray) -> FloatArray:
    out: FloatArray = w**3 * (10.0 + w * (-15.0 + 6.0 * w))
    return out


def _smootherstep_integral(w: FloatArray) -> FloatArray:
    out: FloatArray = w**4 * (2.5 + w * (-3.0 + w))
    return out


def _smootherstep_slope(w: FloatArray) -> FloatArray:
    out: FloatArray = 30.0 * w**2 * (1.0 - w) ** 2
    return out


def _profile(u: FloatArray, r: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Fraction travelled x(u), dx/du, d2x/du2 for normalised time u in [0, 1] and ramp fraction r."""
    norm = 1.0 - r
    up = u < r
    down = u > 1.0 - r
    wu = np.clip(u / r, 0.0, 1.0)
    wd = np.clip((1.0 - u) / r, 0.0, 1.0)
    x = np.where(
        up, r * _smootherstep_integral(wu), np.where(down, norm - r * _smootherstep_integral(wd), 0.5 * r + (u - r))
    )
    g = np.where(up, _smootherstep(wu), np.where(down, _smootherstep(wd), 1.0))
    gp = np.where(up, _smootherstep_slope(wu) / r, np.where(down, -_smootherstep_slope(wd) / r, 0.0))
    return x / norm, g / norm, gp / norm


# --- waypoint paths -------------------------------------------------------------------------


@dataclass(frozen=True)
class _Segment:
    start_s: float
    duration_s: float
    p0: tuple[float, float, float]
    p1: tuple[float, float, float]
    ramp_fraction: float


class _Path:
    def __init__(self, segments: list[_Segment]) -> None:
        self.starts = np.array([s.start_s for s in segments])
        self.durations = np.array([s.duration_s for s in segments])
        self.p0 = np.array([s.p0 for s in segments])
        self.p1 = np.array([s.p1 for s in segments])
        self.r = np.array([s.ramp_fraction for s in segments])

    @property
    def end_s(self) -> float:
        return float(self.starts[-1] + self.durations[-1])

    def evaluate(self, tau: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        idx = np.clip(np.searchsorted(self.starts, tau, side="right") - 1, 0, len(self.starts) - 1)
        t_rel = tau - self.starts[idx]
        dur = self.durations[idx]
        inside = (t_rel >= 0.0) & (t_rel <= dur)
        u = np.clip(t_rel / dur, 0.0, 1.0)
        x, dx, ddx = _profile(u, self.r[idx])
        delta = self.p1[idx] - self.p0[idx]
        pos = self.p0[idx] + delta * x[:, None]
        vel = np.where(inside[:, None], delta * (dx / dur)[:, None], 0.0)
        acc = np.where(inside[:, None], delta * (ddx / dur**2)[:, None], 0.0)
        return pos, vel, acc


class _Builder:
    def __init__(self, start: FloatArray, t0_s: float) -> None:
        self.segments: list[_Segment] = []
        self.pos = start
        self.t = t0_s

    def _add(self, target: FloatArray, duration_s: float, ramp_fraction: float) -> None:
        p0 = (float(self.pos[0]), float(self.pos[1]), float(self.pos[2]))
        p1 = (float(target[0]), float(target[1]), float(target[2]))
        self.segments.append(_Segment(self.t, duration_s, p0, p1, ramp_fraction))
        self.t += duration_s
        self.pos = target

    def hold(self, duration_s: float) -> None:
        if duration_s > 0.0:
            self._add(self.pos.copy(), duration_s, 0.5)

    def cruise(self, target: FloatArray, speed_m_s: float, ramp_s: float) -> None:
        d = float(np.linalg.norm(target - self.pos))
        if d <= 0.0:
            return
        duration = d / speed_m_s + ramp_s
        self._add(target, duration, min(0.5, ramp_s / duration))

    def move(self, target: FloatArray, peak_speed_m_s: float) -> None:
        d = float(np.linalg.norm(target - self.pos))
        if d > 0.0:
            self._add(target, 2.0 * d / peak_speed_m_s, 0.5)


# --- geometry of the structure --------------------------------------------------------------


@dataclass(frozen=True)
class _PlaneAxes:
    normal: FloatArray
    facing: FloatArray
    """Horizontal direction looking at the surface (ENU)."""
    right: FloatArray
    """Horizontal, in the plane, to the right of a viewer facing the surface."""
    up_in_plane: FloatArray
    vertical_face: bool


def _plane_axes(scenario: Scenario) -> _PlaneAxes:
    n = np.array(scenario.structure.normal)
    n_h = np.array([n[0], n[1], 0.0])
    if np.linalg.norm(n_h) > 1e-6:
        facing = -n_h / np.linalg.norm(n_h)
        right = np.cross(facing, _UP)
    else:
        facing = np.array([0.0, 1.0, 0.0])
        right = np.array([1.0, 0.0, 0.0])
    w = _UP - np.dot(_UP, n) * n
    up_in_plane = w / np.linalg.norm(w) if np.linalg.norm(w) > 1e-6 else np.array([0.0, 1.0, 0.0])
    return _PlaneAxes(n, facing, right, up_in_plane, bool(abs(n[2]) < 0.7))


def _compass_deg(direction_enu: FloatArray) -> float:
    return math.degrees(math.atan2(float(direction_enu[0]), float(direction_enu[1])))


def _direction(compass_deg: float) -> FloatArray:
    a = math.radians(compass_deg)
    return np.array([math.sin(a), math.cos(a), 0.0])


def _face_point(
    scenario: Scenario, axes: _PlaneAxes, lateral_m: float, height_m: float, standoff_m: float
) -> FloatArray:
    """Camera position at standoff in front of the face point at (lateral, ENU height)."""
    p = np.array(scenario.structure.point_m)
    wz = axes.up_in_plane[2]
    t = (height_m - p[2]) / wz if abs(wz) > 0.1 else 0.0
    out: FloatArray = p + lateral_m * axes.right + t * axes.up_in_plane + standoff_m * axes.normal
    return out


def _camera_path(scenario: Scenario, axes: _PlaneAxes) -> tuple[_Path, float]:
    """The camera's waypoint path and the heading [deg compass]."""
    spec = scenario.trajectory
    heading = _compass_deg(axes.facing)
    if isinstance(spec, PierScan):
        plan = pier_scan_plan(scenario)
        heights = (spec.bottom_m, spec.top_m)
        b = _Builder(_face_point(scenario, axes, plan.pass_offsets_m[0], heights[0], spec.standoff_m), 0.0)
        b.hold(spec.start_hold_s)
        for k, offset in enumerate(plan.pass_offsets_m):
            if k > 0:
                b.move(_face_point(scenario, axes, offset, heights[k % 2 == 1], spec.standoff_m), spec.step_speed_m_s)
            b.cruise(
                _face_point(scenario, axes, offset, heights[k % 2 == 0], spec.standoff_m), spec.speed_m_s, spec.ramp_s
            )
        path_builder = b
    elif isinstance(spec, DeckPass):
        d = _direction(spec.along_deg)
        centre = np.array(scenario.structure.point_m) + spec.standoff_m * axes.normal
        b = _Builder(centre - 0.5 * spec.length_m * d, 0.0)
        b.hold(spec.start_hold_s)
        b.cruise(centre + 0.5 * spec.length_m * d, spec.speed_m_s, spec.ramp_s)
        path_builder = b
        if not axes.vertical_face:
            heading = spec.along_deg
    else:
        assert isinstance(spec, Hover)
        b = _Builder(_face_point(scenario, axes, spec.lateral_m, spec.height_m, spec.standoff_m), 0.0)
        b.hold(max(spec.start_hold_s, 1.0))
        path_builder = b
    if spec.heading_deg is not None:
        heading = spec.heading_deg
    return _Path(path_builder.segments), heading


# --- the trajectory -------------------------------------------------------------------------


class Trajectory:
    """Truth as a function of scenario time for one scenario (vectorised over tau)."""

    def __init__(self, scenario: Scenario) -> None:
        self.scenario = scenario
        self.axes = _plane_axes(scenario)
        spec = scenario.trajectory
        self.survey = _survey_flight(spec) if isinstance(spec, Survey) else None
        if self.survey is not None:  # a placeholder path: the survey flight gives the kinematics
            self.path, self.heading_deg = _Path([_Segment(0.0, self.survey.duration_s, (0, 0, 0), (0, 0, 0), 0.5)]), 0.0
        else:
            self.path, self.heading_deg = _camera_path(scenario, self.axes)
        cam = scenario.camera
        self.lever_arm_body = np.array(cam.lever_arm_m)
        self.q_mount = q_from_euler_zyx(
            math.radians(cam.mount_roll_deg), math.radians(cam.mount_pitch_deg), math.radians(cam.mount_yaw_deg)
        )
        yaw = math.radians(self.heading_deg)
        # the waypoints are for the camera; the body is the lever arm behind it at level attitude
        level_lever_ned = q_rotate(q_from_euler_zyx(0.0, 0.0, yaw), self.lever_arm_body)
        self.level_lever_enu = ned_to_enu(level_lever_ned)
        rng = np.random.default_rng([scenario.seed, 0x5A1])
        self.sway_phase = rng.uniform(0.0, 2.0 * math.pi, size=(3, 2))
        self.max_range_m = scenario.sensors.lidar_max_range_m

    @property
    def motion_end_s(self) -> float:
        """Scenario time at which the planned path ends (the drone then holds its last point)."""
        return self.path.end_s

    def _sway(self, tau: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        spec = self.scenario.trajectory
        pos = np.zeros((tau.size, 3))
        vel = np.zeros_like(pos)
        acc = np.zeros_like(pos)
        if spec.sway_m <= 0.0:
            return pos, vel, acc
        # two incommensurate sinusoids per axis; the vertical one smaller (altitude hold is stiffer)
        amp = np.array([1.0, 1.0, 0.3]) * spec.sway_m / 2.0
        for k, factor in enumerate((1.0, 0.618)):
            om = 2.0 * math.pi / (spec.sway_period_s * factor)
            ph = om * tau[:, None] + self.sway_phase[None, :, k]
            pos += amp * np.sin(ph)
            vel += amp * om * np.cos(ph)
            acc += -amp * om**2 * np.sin(ph)
        return pos, vel, acc

    def _kinematics(self, tau: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        cam_pos, vel, acc = self.path.evaluate(tau)
        sp, sv, sa = self._sway(tau)
        return cam_pos - self.level_lever_enu + sp, vel + sv, acc + sa

    def _body_attitude(self, acc_enu: FloatArray) -> FloatArray:
        f_ned = enu_to_ned(acc_enu) - np.array([0.0, 0.0, GRAVITY_M_S2])
        z_b = -f_ned / np.linalg.norm(f_ned, axis=-1, keepdims=True)
        yaw = math.radians(self.heading_deg)
        c = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        y_b = np.cross(z_b, c)
        y_b /= np.linalg.norm(y_b, axis=-1, keepdims=True)
        x_b = np.cross(y_b, z_b)
        return q_from_matrix(np.stack([x_b, y_b, z_b], axis=-1))

    def _camera_attitude(self, q_body: FloatArray, taus: FloatArray) -> FloatArray:
        """The camera board's FRD axes -> NED: the geotagger's camera rule (`icgt.pose.camera_quaternion`) with
        the mounting in FRD camera axes (the optical frame is `Q_OPTICAL_TO_FRD` on top); on a gimbal, the
        gimbal's attitude (`gimbal_ned`) times the mounting on it."""
        if self.scenario.camera.gimbal is not None:
            return np.asarray(q_multiply(self.gimbal_ned(taus), self.q_mount))
        return camera_quaternion(q_body, self.q_mount, gimbal_stabilised=self.scenario.camera.stabilised)

    def _body_at(self, taus: FloatArray) -> FloatArray:
        if self.survey is not None:
            return np.asarray(self.survey.state(taus).q_body_ned)
        return self._body_attitude(self._kinematics(taus)[2])

    def gimbal_ned(self, tau_s: FloatArray | float) -> FloatArray:
        """The gimbal's device frame (x along the camera's pointing) -> NED: its roll and pitch held against the
        horizon (the pitch nodding by ``pitch_sweep_deg``), its yaw the body's ``yaw_lag_s`` earlier (follow
        mode). (..., 4)."""
        g = self.scenario.camera.gimbal
        assert g is not None
        tau = np.atleast_1d(np.asarray(tau_s, dtype=np.float64))
        _, _, yaw = q_to_euler_zyx(self._body_at(tau - g.yaw_lag_s))
        roll = np.full_like(tau, math.radians(g.roll_deg))
        sweep = g.pitch_sweep_deg * np.sin(2.0 * math.pi * tau / g.pitch_sweep_period_s)
        pitch = np.radians(g.pitch_deg + sweep)
        return np.asarray(q_from_euler_zyx(roll, pitch, yaw))

    def gimbal_vehicle_frame(self, tau_s: float) -> FloatArray:
        """What the gimbal reports (GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME): its attitude with the yaw from the
        vehicle's heading at ``tau_s`` (q_earth = q(yaw_vehicle) q_vehicle, as common.xml defines it)."""
        tau = np.array([float(tau_s)])
        _, _, yaw_body = q_to_euler_zyx(self._body_at(tau))
        back = q_from_euler_zyx(np.zeros(1), np.zeros(1), -yaw_body)
        out: FloatArray = np.asarray(q_multiply(back, self.gimbal_ned(tau)), dtype=float)[0]
        return out

    def state(self, tau_s: FloatArray | float) -> TruthState:
        """The true state at each scenario time in tau_s (1-D array or scalar -> arrays of N rows)."""
        tau = np.atleast_1d(np.asarray(tau_s, dtype=np.float64)).ravel()
        n = tau.size
        h = _FD_H_S
        taus = np.concatenate([tau - h, tau, tau + h])
        if self.survey is not None:
            st = self.survey.state(taus)
            pos, vel, acc = st.position_enu_m, st.velocity_enu_m_s, st.accel_enu_m_s2
            q_b = _align_signs(st.q_body_ned, n)
        else:
            pos, vel, acc = self._kinematics(taus)
            q_b = _align_signs(self._body_attitude(acc), n)
        q_c = _align_signs(self._camera_attitude(q_b, taus), n)
        lever_enu = ned_to_enu(q_rotate(q_b, self.lever_arm_body))
        cam_pos = pos + lever_enu
        sl_m, sl_0, sl_p = slice(0, n), slice(n, 2 * n), slice(2 * n, 3 * n)
        omega_b = body_rates_from_quaternions(q_b[sl_0], (q_b[sl_p] - q_b[sl_m]) / (2 * h))
        omega_c = body_rates_from_quaternions(q_c[sl_0], (q_c[sl_p] - q_c[sl_m]) / (2 * h))
        lever_acc = (lever_enu[sl_p] - 2 * lever_enu[sl_0] + lever_enu[sl_m]) / h**2
        axis_enu = ned_to_enu(q_rotate(q_c[sl_0], np.array([1.0, 0.0, 0.0])))
        rng, valid = self.range_to_structure(cam_pos[sl_0], axis_enu)
        return TruthState(
            tau_s=tau,
            position_enu_m=pos[sl_0],
            velocity_enu_m_s=vel[sl_0],
            accel_enu_m_s2=acc[sl_0],
            q_body_ned=q_b[sl_0],
            omega_body_rad_s=omega_b,
            camera_position_enu_m=cam_pos[sl_0],
            camera_accel_enu_m_s2=acc[sl_0] + lever_acc,
            q_camera_ned=q_c[sl_0],
            omega_camera_rad_s=omega_c,
            optical_axis_enu=axis_enu,
            range_m=rng,
            range_valid=valid,
        )

    def range_to_structure(self, origin_enu: FloatArray, direction_enu: FloatArray) -> tuple[FloatArray, BoolArray]:
        """Ray-plane distance [m] from origin along unit direction; (range with nan where invalid, valid).

        t = n . (p0 - o) / (n . d); no return when the ray is parallel to the plane, points away
        from it, or t exceeds the LiDAR's maximum range.
        """
        n = np.array(self.scenario.structure.normal)
        p0 = np.array(self.scenario.structure.point_m)
        denom = direction_enu @ n
        num = (p0 - origin_enu) @ n
        safe = np.where(np.abs(denom) < 1e-12, np.nan, denom)
        t = num / safe
        valid = np.isfinite(t) & (t > 0.0) & (t <= self.max_range_m)
        return np.where(valid, t, np.nan), valid


def _survey_flight(spec: Survey) -> SurveyFlight:
    """The survey's legs: a straight, then a turn (alternately right and left) and a straight, ``legs`` times."""
    legs = [Leg("straight", spec.leg_s)]
    for k in range(spec.legs):
        legs.append(Leg("turn", turn_deg=spec.turn_deg * (1 if k % 2 == 0 else -1), bank_deg=spec.bank_deg))
        legs.append(Leg("straight", spec.leg_s))
    return SurveyFlight(
        legs,
        speed_m_s=spec.speed_m_s,
        heading_deg=spec.course_deg,
        start_enu_m=(spec.start_m[0], spec.start_m[1], spec.altitude_m),
    )


def _align_signs(q: FloatArray, n: int) -> FloatArray:
    """Make the quaternions at tau - h and tau + h the same hemisphere as at tau (for differences)."""
    mid = q[n : 2 * n]
    out = q.copy()
    for sl in (slice(0, n), slice(2 * n, 3 * n)):
        flip = np.sum(out[sl] * mid, axis=-1) < 0.0
        out[sl] = np.where(flip[:, None], -out[sl], out[sl])
    return out
