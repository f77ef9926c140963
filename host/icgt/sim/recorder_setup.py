"""The recorder's side of a simulated flight: the configuration a crew would write for a scenario's airframe.

`icgt demo`, `LiveRecorder`, the fault flights and the end-to-end tests run `icgt record` on the simulator
with this configuration (the scenario's camera, mounting and capture plan), on free local UDP ports.
"""

from __future__ import annotations

import socket
from pathlib import Path

from icgt.mavlink.camera_types import DEFAULT_GROUND_STATIONS
from icgt.sim.scenario import Camera, Scenario

__all__ = ["GCS_SYSTEM", "GROUND_STATIONS", "feedback_min_lag_s", "free_udp_port", "recorder_config_text"]

GCS_SYSTEM = 255
"""The ground station's MAVLink system id in the simulated flights (the recorder accepts its commands)."""

GROUND_STATIONS = tuple(sorted(DEFAULT_GROUND_STATIONS, reverse=True))
"""What the written configuration allows: every ground station on its default ids (255 QGroundControl,
Mission Planner, MAVProxy; 245 MAVSDK), as the recorder's own default does."""


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port: int = s.getsockname()[1]
        return port


def feedback_min_lag_s(cam: Camera) -> float:
    """The shortest shutter lag a crew would configure for this body: its lag less twice its jitter and 5 ms."""
    return max(0.0, cam.shutter_latency_s - 2 * cam.shutter_jitter_s - 0.005)


def recorder_config_text(
    sc: Scenario,
    out_dir: Path,
    *,
    ground_stations: tuple[int, ...] = GROUND_STATIONS,
    signing_key_file: Path | None = None,
    host_timeout_s: float | None = None,
) -> str:
    """The recorder configuration a crew would write for this airframe (from the scenario's camera);
    `host_timeout_s` None: the default ([capture] host_timeout_s)."""
    cam, cap, sen = sc.camera, sc.camera.capture, sc.sensors
    n = sc.structure.normal
    signing = f'signing_key_file = "{signing_key_file}"' if signing_key_file is not None else ""
    # the camera's attitude: the body's times the mount; the gimbal's report; or the board's BNO055, with the
    # camera's alignment on the board as its calibration flight found it (docs/board-imu.md)
    mount = (cam.mount_roll_deg, cam.mount_pitch_deg, cam.mount_yaw_deg)
    attitude_source = "mount" if cam.gimbal is None else "gimbal"
    if cam.board_imu is not None:
        mount, attitude_source = cam.board_imu.camera_on_board_deg, "board_imu"
    return f"""# written by icgt demo for scenario {sc.name}
[device]
set_rtc = true

[mavlink]
system_id = {sc.autopilot.system_id}
ground_station_systems = [{", ".join(str(g) for g in ground_stations)}]
global_position_hz = 50.0
{signing}

[capture]
mode = "{cap.mode}"
interval_s = {cap.interval_s if cap.mode == "interval" else 1.0 / cap.burst_fps}
focus_lead_s = {cap.focus_s}
burst_s = {cap.burst_s}
shutter_pulse_s = 0.02
{"" if host_timeout_s is None else f"host_timeout_s = {host_timeout_s}"}

[sensors]
feedback_min_lag_s = {feedback_min_lag_s(cam)}
imu_rate_hz = {int(sen.imu_rate_hz)}
range_rate_hz = {int(sen.range_rate_hz)}
lidar_model = "{sen.lidar_model}"

[camera]
focal_length_mm = {cam.focal_length_mm}
sensor_width_mm = {cam.sensor_width_mm}
image_width_px = {cam.image_width_px}
image_height_px = {cam.image_height_px}
mount_roll_deg = {mount[0]}
mount_pitch_deg = {mount[1]}
mount_yaw_deg = {mount[2]}
lever_arm_body_m = [{cam.lever_arm_m[0]}, {cam.lever_arm_m[1]}, {cam.lever_arm_m[2]}]
gimbal_stabilised = {"true" if cam.stabilised and cam.gimbal is None else "false"}
attitude_source = "{attitude_source}"
surface_normal_enu = [{n[0]}, {n[1]}, {n[2]}]

[output]
dir = "{out_dir}"
chunk_interval_s = 0.25
"""
