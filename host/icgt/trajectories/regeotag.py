"""Re-geotag a recording's frames from an external trajectory (PPK, SLAM) after the flight.

Each frame's position (and attitude, when the source has one) is replaced from the source at the
frame's mid-exposure, the way the geotagger places it live (`icgt.geotag.geotagger`):

* camera position = reference point + R(body->NED) * lever arm, the lever arm in body FRD axes
  (the recording's ``lever_arm_body_m`` unless the config gives another: from the GNSS antenna for
  PPK, from the tracked point for SLAM), its NED components turned to ENU as (e, n, u) = (n_E, n_N, -n_D);
* the attitude used for the lever arm is the source's when it has one, else the recorded one, whose
  error turns the lever arm: ``|lever| * recorded_attitude_error_deg`` is added to the bound, the whole
  ``|lever|`` when the recorded pose was held across a telemetry gap (``pose_extrapolated``: its
  attitude is as old); with neither, the reference point is used and ``|lever|`` is added;
* camera attitude = body attitude * the camera mounting (`icgt.pose.camera_to_body_quaternion`), or only the
  body's yaw for a stabilised gimbal; roll/pitch/yaw and the incidence on the structure follow
  (the camera rule is the geotagger's own: `icgt.pose.camera_fields`).

Set from the source: lat/lon/alt (MSL), east/north/up, ``position_source`` (the source's label:
``ppk_fixed``, ``ppk_float``, ... or ``slam``), ``position_error_bound_m``, the pose gaps; flags
``no_fix``, ``stale_pose`` (bound above ``max_position_error_m``, or the recorded frame's own verdict when the
source is the recorded telemetry) and ``pose_extrapolated`` are
decided anew, ``no_attitude`` is cleared when the source supplies attitude. Everything else is kept
(times, LiDAR, the GPS receiver's own fields fix_type/h_acc/v_acc/satellites, which describe the
autopilot's receiver). A frame the source cannot place is kept exactly as recorded, and listed with
the reason.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from icgt.geodesy import LocalFrame, q_conjugate, q_multiply
from icgt.geotag.config import GeotagConfig
from icgt.geotag.parts import attitude_fields
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.pose import CARRIED_ATTITUDE_SOURCES, CameraMounting, camera_fields
from icgt.trajectories.source import PoseFix, PoseMiss, PoseSource, TrajectoryError

__all__ = ["RegeotagConfig", "RegeotagResult", "regeotag", "regeotag_detailed"]

_POSE_FLAGS = {FrameFlag.NO_FIX.value, FrameFlag.STALE_POSE.value, FrameFlag.POSE_EXTRAPOLATED.value}


@dataclass(frozen=True)
class RegeotagConfig:
    """The recording's camera and mounting (its GeotagConfig), its ENU origin, and overrides."""

    geotag: GeotagConfig
    origin: tuple[float, float, float]
    """The recording's ENU origin (lat [deg], lon [deg], alt MSL [m])."""
    lever_arm_body_m: tuple[float, float, float] | None = None
    """Camera from the source's reference point, body FRD [m]; None: the recording's lever arm."""
    recorded_attitude_error_deg: float = 2.0
    """Bound on the recorded attitude's error [deg] where a position-only source borrows it."""

    @classmethod
    def from_recording(cls, recording: Any, **overrides: Any) -> RegeotagConfig:
        from icgt.ingest.recompute import recording_config

        cfg = recording_config(recording)
        origin = recording.enu_origin or cfg.origin
        if origin is None:
            raise TrajectoryError(f"{recording.path}: no ENU origin in the recording (no frame was ever placed)")
        return cls(geotag=cfg, origin=origin, **overrides)

    @property
    def lever_arm(self) -> np.ndarray:
        arm = self.lever_arm_body_m if self.lever_arm_body_m is not None else self.geotag.lever_arm_body_m
        return np.asarray(arm, dtype=float)


@dataclass
class RegeotagResult:
    frames: list[FrameRecord]
    """Every input frame, in input order: placed ones replaced, the others as recorded."""
    placed: list[int] = field(default_factory=list)
    """frame_seq of the frames placed from the source."""
    unplaced: list[tuple[int, PoseMiss]] = field(default_factory=list)
    """(frame_seq, why) of the frames the source could not place."""
    labels: dict[str, int] = field(default_factory=dict)
    """Placed frames per position_source value."""


def _recorded_attitude(frame: FrameRecord) -> np.ndarray | None:
    if None in (frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz):
        return None
    return np.array([frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz], dtype=float)


def _place(frame: FrameRecord, fix: PoseFix, cfg: RegeotagConfig, local: LocalFrame) -> FrameRecord:
    g = cfg.geotag
    body_q = fix.q_body_ned if fix.q_body_ned is not None else _recorded_attitude(frame)
    flags = set(frame.flags) - _POSE_FLAGS
    mounting = CameraMounting.of(g, lever_arm_body_m=tuple(cfg.lever_arm))
    cam = camera_fields(
        np.asarray(fix.enu_m, dtype=float), body_q, _valid_range(frame), mounting, _recorded_gimbal(frame, mounting)
    )
    lever_part = 0.0
    if body_q is None or (fix.q_body_ned is None and FrameFlag.POSE_EXTRAPOLATED.value in frame.flags):
        lever_part = mounting.lever_arm_m  # no attitude, or one held from before a telemetry gap: on that sphere
    elif fix.q_body_ned is None:
        lever_part = mounting.lever_arm_m * math.radians(cfg.recorded_attitude_error_deg)  # the borrowed attitude's
    bound = fix.error_bound_m + lever_part
    if fix.stale if fix.stale is not None else bound > g.max_position_error_m:
        flags.add(FrameFlag.STALE_POSE.value)
    if fix.extrapolated:
        flags.add(FrameFlag.POSE_EXTRAPOLATED.value)
    enu = cam.enu
    assert enu is not None
    la, lo, al = local.enu_to_geodetic(enu)
    changes: dict[str, Any] = {
        "lat_deg": float(la),
        "lon_deg": float(lo),
        "alt_msl_m": float(al),
        "east_m": cam.east_m,
        "north_m": cam.north_m,
        "up_m": cam.up_m,
        "position_source": fix.label,
        "position_error_bound_m": bound,
        "horizontal_error_bound_m": (fix.horizontal_bound_m if fix.horizontal_bound_m is not None else bound)
        + lever_part,
        "vertical_error_bound_m": (fix.vertical_bound_m if fix.vertical_bound_m is not None else bound) + lever_part,
        "pose_gap_before_ms": fix.gap_before_ms,
        "pose_gap_after_ms": fix.gap_after_ms,
    }
    if fix.q_body_ned is not None:
        flags.discard(FrameFlag.NO_ATTITUDE.value)
        changes.update(attitude_fields(cam))
        if g.surface_normal_enu is not None and cam.scale_mm_per_px is not None:
            # incidence and scale follow the camera's attitude (the geotagger's rule, icgt.pose)
            changes.update(incidence_deg=cam.incidence_deg, scale_mm_per_px=cam.scale_mm_per_px)
    changes["flags"] = sorted(flags)
    return dataclasses.replace(frame, **changes)


def _recorded_gimbal(frame: FrameRecord, mounting: CameraMounting) -> np.ndarray | None:
    """A gimbal (or board IMU) camera's attitude stays as recorded (the gimbal's report or the board's BNO055,
    not the trajectory's): its carrier -> NED back from the recorded camera attitude. (A vehicle-frame gimbal's
    yaw was composed with the recorded body yaw, a board IMU's heading read off it; a trajectory with another
    yaw does not turn them.)"""
    if mounting.attitude_source not in CARRIED_ATTITUDE_SOURCES:
        return None
    if None in (frame.cam_qw, frame.cam_qx, frame.cam_qy, frame.cam_qz):
        return None
    cam_q = np.array([frame.cam_qw, frame.cam_qx, frame.cam_qy, frame.cam_qz], dtype=float)
    return np.asarray(q_multiply(cam_q, q_conjugate(mounting.q_cam_body)))


def _valid_range(frame: FrameRecord) -> float | None:
    return frame.range_m if frame.range_valid and frame.range_m is not None else None


def regeotag_detailed(frames: Iterable[FrameRecord], source: PoseSource, config: RegeotagConfig) -> RegeotagResult:
    """Re-geotag every frame from `source`; the result says which were placed and why the others were not."""
    local = LocalFrame(*config.origin)
    result = RegeotagResult(frames=[])
    for frame in frames:
        got = source.lookup(frame)
        if isinstance(got, PoseMiss):
            result.frames.append(frame)
            result.unplaced.append((frame.frame_seq, got))
            continue
        result.frames.append(_place(frame, got, config, local))
        result.placed.append(frame.frame_seq)
        result.labels[got.label] = result.labels.get(got.label, 0) + 1
    return result


def regeotag(recording_or_frames: Any, source: PoseSource, config: RegeotagConfig | None = None) -> list[FrameRecord]:
    """The frames of a recording (or a list of frames with `config`) re-geotagged from `source`."""
    if isinstance(recording_or_frames, list | tuple):
        if config is None:
            raise TrajectoryError("regeotag: frames without a recording need a RegeotagConfig")
        frames: Iterable[FrameRecord] = recording_or_frames
    else:
        frames = list(recording_or_frames.frames())
        if config is None:
            config = RegeotagConfig.from_recording(recording_or_frames)
    return regeotag_detailed(frames, source, config).frames
