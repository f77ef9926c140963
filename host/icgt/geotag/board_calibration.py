"""The board's alignment on the camera and its BNO055's north, from a calibration flight (docs/board-imu.md).

Each frame of a flight whose camera attitude came from something other than the board (the gimbal's reports,
``attitude_source = "gimbal"``) holds both that attitude (``cam_q``, optical -> NED) and the BNO055's report at mid
(``imu_q``, sensor -> its world). They are related by two unknown rotations (`icgt.geotag.board_imu`):

    cam_q = Rz(heading_offset) * imu_q * q_cam_board,   q_cam_board = q(mount angles) * Q_OPTICAL_TO_FRD

Solved as one nonlinear least-squares problem over the offset and the alignment (scipy's `least_squares` on
the rotation vectors of the per-frame residual rotations, scipy's `Rotation` for the algebra), started from the
alignment with no offset. The offset and the alignment's yaw trade off when the board never tilts (a rotation
about down commutes with the offset): the fit asks for the camera's pitch to change by at least
``MIN_PITCH_SPAN_DEG`` over the flight (nod the gimbal).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from icgt.errors import IcgtError
from icgt.geodesy import q_conjugate, q_multiply, q_to_euler_zyx
from icgt.geotag.record import FrameRecord
from icgt.pose import Q_OPTICAL_TO_FRD

__all__ = ["MIN_FRAMES", "MIN_PITCH_SPAN_DEG", "BoardCalibration", "BoardCalibrationError", "calibrate_board"]

MIN_FRAMES = 20
MIN_PITCH_SPAN_DEG = 10.0


class BoardCalibrationError(IcgtError):
    """The frames given cannot calibrate the board (too few, or the camera never tilted)."""


@dataclass(frozen=True)
class BoardCalibration:
    """The ``[camera]`` settings of a board IMU found by `calibrate_board`, and how well they fit."""

    mount_roll_deg: float
    mount_pitch_deg: float
    mount_yaw_deg: float
    heading_offset_deg: float  # true north minus the BNO's north (board_imu_heading = "magnetic")
    frames_used: int
    residual_p50_deg: float  # angle between each frame's camera attitude and the fitted board's
    residual_p95_deg: float
    pitch_span_deg: float  # how far the camera's pitch moved over the frames used

    def toml(self) -> str:
        """The lines to put under ``[camera]`` of the recorder's configuration."""
        return (
            'attitude_source = "board_imu"\n'
            f"mount_roll_deg = {self.mount_roll_deg:.3f}\n"
            f"mount_pitch_deg = {self.mount_pitch_deg:.3f}\n"
            f"mount_yaw_deg = {self.mount_yaw_deg:.3f}\n"
            f'# for board_imu_heading = "magnetic" (the autopilot\'s heading needs no offset):\n'
            f"board_imu_heading_offset_deg = {self.heading_offset_deg:.3f}\n"
        )


def _pairs(frames: Iterable[FrameRecord]) -> tuple[np.ndarray, np.ndarray]:
    cams, imus = [], []
    for f in frames:
        cam = (f.cam_qw, f.cam_qx, f.cam_qy, f.cam_qz)
        imu = (f.imu_qw, f.imu_qx, f.imu_qy, f.imu_qz)
        if None in cam or None in imu:
            continue
        q = np.array(imu, dtype=float)
        if abs(float(np.linalg.norm(q)) - 1.0) > 0.05:
            continue  # the BNO055's zeros before its fusion starts
        cams.append(np.array(cam, dtype=float))
        imus.append(q / np.linalg.norm(q))
    return np.array(cams).reshape(-1, 4), np.array(imus).reshape(-1, 4)


def _rotations(q_wxyz: np.ndarray) -> Rotation:
    return Rotation.from_quat(np.roll(q_wxyz, -1, axis=-1))  # scipy holds quaternions scalar last


def _wxyz(r: Rotation) -> np.ndarray:
    return np.asarray(np.roll(r.as_quat(), 1, axis=-1))


def calibrate_board(frames: Iterable[FrameRecord]) -> BoardCalibration:
    """Fit the board's alignment and its north (module docstring) to the frames holding both attitudes."""
    cam, imu = _pairs(frames)
    if len(cam) < MIN_FRAMES:
        raise BoardCalibrationError(
            f"{len(cam)} frames hold both a camera attitude and a BNO055 quaternion; the calibration needs at least "
            f'{MIN_FRAMES} (record the calibration flight with [camera] attitude_source = "gimbal")'
        )
    _, pitch, _ = q_to_euler_zyx(q_multiply(cam, q_conjugate(Q_OPTICAL_TO_FRD)))
    span = float(np.degrees(np.max(pitch) - np.min(pitch)))
    if span < MIN_PITCH_SPAN_DEG:
        raise BoardCalibrationError(
            f"the camera's pitch moved by {span:.1f} deg over the flight; the calibration needs at least "
            f"{MIN_PITCH_SPAN_DEG:g} deg (nod the gimbal up and down), else the board's yaw and its north trade off"
        )
    cams, imus = _rotations(cam), _rotations(imu)
    start = (imus.inv() * cams).mean()  # the alignment if the BNO's north were true north

    def residual(p: np.ndarray) -> np.ndarray:
        fitted = Rotation.from_euler("z", p[0]) * imus * start * Rotation.from_rotvec(p[1:])
        out: np.ndarray = (fitted.inv() * cams).as_rotvec().ravel()
        return out

    fit = least_squares(residual, np.zeros(4), method="lm", xtol=1e-12, ftol=1e-12)
    if not fit.success:
        raise BoardCalibrationError(f"the board calibration did not converge: {fit.message}")
    offset = float(fit.x[0])
    x = start * Rotation.from_rotvec(fit.x[1:])
    residual_deg = np.degrees(np.linalg.norm(residual(fit.x).reshape(-1, 3), axis=1))
    mount = x * _rotations(Q_OPTICAL_TO_FRD).inv()
    yaw, pitch_m, roll = (math.degrees(float(a)) for a in mount.as_euler("ZYX"))
    return BoardCalibration(
        mount_roll_deg=roll,
        mount_pitch_deg=pitch_m,
        mount_yaw_deg=yaw,
        heading_offset_deg=math.degrees(math.remainder(offset, 2.0 * math.pi)),
        frames_used=len(cam),
        residual_p50_deg=float(np.percentile(residual_deg, 50)),
        residual_p95_deg=float(np.percentile(residual_deg, 95)),
        pitch_span_deg=span,
    )
