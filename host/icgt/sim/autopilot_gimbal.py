"""The camera's MAVLink gimbal device (`[camera.gimbal]`), as the simulated autopilot routes it.

`GimbalDevice.run` (the "sim-gimbal" thread) sends GIMBAL_DEVICE_ATTITUDE_STATUS as component 154 of
the vehicle on the companion link. Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import math
import threading
import time

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import q_from_euler_zyx, q_multiply
from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.autopilot_link import AutopilotLinks
from icgt.sim.scenario import Scenario
from icgt.sim.trajectory import Trajectory

__all__ = ["GIMBAL_COMPONENT", "GimbalDevice"]

GIMBAL_COMPONENT = 154  # MAV_COMP_ID_GIMBAL: a MAVLink gimbal device (`[camera.gimbal]`), routed to the companion
_GIMBAL_FLAGS = (
    mavlink2.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME  # follow mode: yaw from the vehicle's heading
    | mavlink2.GIMBAL_DEVICE_FLAGS_ROLL_LOCK
    | mavlink2.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
)


class GimbalDevice:
    """The gimbal device of one simulated autopilot's vehicle (see `run`)."""

    def __init__(
        self,
        scenario: Scenario,
        clock: AutopilotClock,
        links: AutopilotLinks,
        trajectory: Trajectory,
        stop: threading.Event,
        *,
        system_id: int,
        latency_ns: int,
        sent_counts: dict[str, int],
        errors: list[str],
    ) -> None:
        self.scenario = scenario
        self.clock = clock
        self.links = links
        self.trajectory = trajectory
        self._stop = stop
        self.latency_ns = latency_ns
        self.sent_counts = sent_counts
        self.errors = errors
        self._gimbal_codec = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=GIMBAL_COMPONENT)

    def run(self) -> None:
        """GIMBAL_DEVICE_ATTITUDE_STATUS of the camera's gimbal at its rate, on the truth's grid, through this
        autopilot's routing to the companion link (the gimbal device is its own component, on its own boot
        clock), silent in its `silent_s` windows and while the companion link is down."""
        g = self.scenario.camera.gimbal
        assert g is not None
        rng = np.random.default_rng([self.scenario.seed, 0xA9, 154])
        period_s = 1.0 / g.rate_hz
        k = max(0, math.ceil(self.clock.tau_now() / period_s))
        while not self._stop.is_set():
            tau = k * period_s
            wait_s = (self.clock.maps.tau_to_host_ns(tau) + self.latency_ns - time.monotonic_ns()) / 1e9
            if wait_s > 0:
                self._stop.wait(min(wait_s, 0.1))
                continue
            k += 1
            if tau > self.scenario.duration_s or any(a <= tau < b for a, b in g.silent_s):
                continue
            if self.links.companion is None or self.links.companion_dropped(tau):
                continue
            noise = np.radians(rng.normal(size=3) * g.noise_deg)
            q = q_multiply(self.trajectory.gimbal_vehicle_frame(tau), q_from_euler_zyx(*noise))
            boot_ms = round((tau - g.boot_offset_s) * 1000.0)
            msg = self._gimbal_codec.gimbal_device_attitude_status_encode(
                0, 0, boot_ms, _GIMBAL_FLAGS, [float(c) for c in q], 0.0, 0.0, 0.0, 0
            )
            try:
                self.links.companion.send_as(msg, self._gimbal_codec)
            except OSError as exc:
                self.errors.append(f"gimbal send: {exc!r}")
                continue
            self.sent_counts["gimbal_device_attitude_status"] = (
                self.sent_counts.get("gimbal_device_attitude_status", 0) + 1
            )
