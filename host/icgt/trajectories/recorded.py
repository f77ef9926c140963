"""The autopilot's telemetry as a pose source: the pose the recorder's geotagger gave each frame.

The geotagger (`icgt.geotag`) already placed every frame from the autopilot's telemetry at
mid-exposure (its rules: `icgt.geotag.position`); this source hands that pose back through the
`PoseSource` interface, so a caller can treat the recorded geotag and an external trajectory alike
(compare them, fall back from one to the other). The recorded camera position is turned back into
the autopilot's reference point by the recorded attitude and lever arm (reference = camera -
R(body->NED) * lever arm); `regeotag` with this source gives back the recorded frames.

Time base: none is needed (the frame carries its own pose); it is declared ``host``, the clock the
geotagger worked on. Label and bound: the frame's own ``position_source`` and
``position_error_bound_m``; a frame without a position is a `PoseMiss` ``no_fix``.
"""

from __future__ import annotations

import math

import numpy as np

from icgt.geodesy import LocalFrame
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.pose import reference_position_enu
from icgt.trajectories.source import PoseFix, PoseMiss, TimeBase

__all__ = ["RecordedTelemetry"]


class RecordedTelemetry:
    """The recorded geotag of each frame, as a PoseSource (see the module docstring)."""

    def __init__(self, origin: tuple[float, float, float], lever_arm_body_m: tuple[float, float, float]) -> None:
        self.frame = LocalFrame(*origin)
        self.lever_arm = np.asarray(lever_arm_body_m, dtype=float)

    @property
    def name(self) -> str:
        return "the recorded autopilot telemetry"

    @property
    def time_base(self) -> TimeBase:
        return "host"

    @property
    def has_attitude(self) -> bool:
        return True

    def lookup(self, frame: FrameRecord) -> PoseFix | PoseMiss:
        if frame.lat_deg is None or frame.lon_deg is None or frame.alt_msl_m is None:
            return PoseMiss("no_fix", f"no recorded position ({frame.position_source})")
        enu = np.asarray(self.frame.geodetic_to_enu(frame.lat_deg, frame.lon_deg, frame.alt_msl_m), dtype=float)
        q = None
        if None not in (frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz):
            q = np.array([frame.body_qw, frame.body_qx, frame.body_qy, frame.body_qz], dtype=float)
            enu = reference_position_enu(enu, q, self.lever_arm)
        bound = frame.position_error_bound_m if frame.position_error_bound_m is not None else math.inf
        return PoseFix(
            enu,
            self.frame,
            q,
            bound,
            frame.position_source,
            frame.pose_gap_before_ms,
            frame.pose_gap_after_ms,
            extrapolated=FrameFlag.POSE_EXTRAPOLATED.value in frame.flags,
            horizontal_bound_m=frame.horizontal_error_bound_m,
            vertical_bound_m=frame.vertical_error_bound_m,
            stale=FrameFlag.STALE_POSE.value in frame.flags,
        )
