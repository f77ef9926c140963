"""Simulation scenarios: what is flown, what is seen, how good GPS is, how wrong the clocks are.

A scenario is a TOML file (hil_sim/scenarios/*.toml) loaded into frozen dataclasses. Every
field carries its unit in its name. Unknown keys, wrong types and out-of-range values raise
`ScenarioError` naming the file and the dotted key. Frames: positions are ENU metres relative to
`[origin]`; body and camera axes are FRD (x forward, y right, z down); the camera's x axis is its
optical axis, image right is +y and image down is +z. `[autopilot] profile` ("ideal", "ardupilot",
"px4") chooses what the simulated autopilot sends and how it stamps it; it gives the defaults of the
other `[autopilot]` keys (`Autopilot` below; sources in icgt.sim.profiles), which a scenario may set.

Example (the shortest valid file; every other section has defaults)::

    name = "hover"
    duration_s = 30.0
    [origin]
    lat_deg = 37.8813
    lon_deg = 127.7298
    alt_m = 76.0
    [structure]
    point_m = [0.0, 10.0, 0.0]
    normal = [0.0, -1.0, 0.0]
    [trajectory]
    kind = "hover"
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, TypeAlias

from icgt.sim.profiles import IDEAL_RATES_HZ, PROFILE_NAMES, PROFILES
from icgt.sim.resources import scenario_dir
from icgt.sim.scenario_reader import ScenarioError as ScenarioError
from icgt.sim.scenario_reader import SimError as SimError
from icgt.sim.scenario_reader import TableReader, Vec3, Window

if TYPE_CHECKING:
    from icgt.sim.surface import Surface


SCENARIO_DIR = scenario_dir()
"""Where the scenario files are: inside the installed wheel, else the repository's hil_sim/scenarios."""

TRAJECTORY_KINDS = ("pier_scan", "deck_pass", "hover", "survey")
LIDAR_MAX_RANGE_M = {"v3": 40.0, "v3hp": 40.0}
"""Longest range with a return [m] per LIDAR-Lite model."""

STREAM_NAMES = (
    "heartbeat",
    "gps_raw_int",
    "global_position_int",
    "attitude",
    "attitude_quaternion",
    "local_position_ned",
    "system_time",
    "gps_global_origin",
)
"""Telemetry streams of the simulated autopilot, by lower-case MAVLink message name."""
DEFAULT_RATES_HZ: Mapping[str, float] = IDEAL_RATES_HZ
"""Stream rates of the "ideal" profile (the default); see icgt.sim.profiles for the others."""


# --- sections -------------------------------------------------------------------------------


@dataclass(frozen=True, kw_only=True)
class Origin:
    """The ENU origin and home position. Ellipsoidal height = alt_m + geoid_separation_m."""

    lat_deg: float
    lon_deg: float
    alt_m: float
    """Height above mean sea level [m] (MAVLink `alt`)."""
    geoid_separation_m: float = 0.0
    """Geoid height N above the WGS84 ellipsoid [m] (about +25 m in Korea)."""

    @property
    def ellipsoid_height_m(self) -> float:
        return self.alt_m + self.geoid_separation_m


@dataclass(frozen=True, kw_only=True)
class Structure:
    """The inspected surface: an infinite plane through point_m (ENU) with unit normal `normal`.

    The normal points to the side the drone flies on (out of the concrete).
    """

    point_m: Vec3
    normal: Vec3


@dataclass(frozen=True, kw_only=True)
class TrajectoryCommon:
    start_hold_s: float = 3.0
    """Hover at the first point for this long before moving."""
    sway_m: float = 0.0
    """Amplitude of a smooth wind sway added to the path [m] (0 = none)."""
    sway_period_s: float = 6.0
    heading_deg: float | None = None
    """Body yaw [deg, compass, 0 = north, 90 = east]; None: face the structure (or along the path
    under a horizontal surface)."""


@dataclass(frozen=True, kw_only=True)
class PierScan(TrajectoryCommon):
    """Vertical passes up and down a pier face at standoff_m, stepping sideways between passes."""

    kind: Literal["pier_scan"] = "pier_scan"
    standoff_m: float = 2.5
    speed_m_s: float = 0.8
    side_overlap: float = 0.6
    """Overlap of the footprints of adjacent passes (0..1)."""
    width_m: float = 4.0
    """Width of the face to cover, centred on the structure point [m]."""
    bottom_m: float = 1.0
    top_m: float = 12.0
    """ENU heights of the camera at the ends of each pass [m]."""
    ramp_s: float = 1.5
    """Time to reach (or leave) the pass speed, smooth acceleration [s]."""
    step_speed_m_s: float = 0.5
    """Peak speed of the sideways step between passes [m/s]."""


@dataclass(frozen=True, kw_only=True)
class DeckPass(TrajectoryCommon):
    """A straight pass along a deck at standoff_m from its surface, with smooth accel/decel."""

    kind: Literal["deck_pass"] = "deck_pass"
    standoff_m: float = 5.0
    speed_m_s: float = 10.0
    length_m: float = 160.0
    """Length of the whole pass (ramps included), centred on the structure point [m]."""
    ramp_s: float = 4.0
    along_deg: float = 90.0
    """Direction of travel [deg, compass]; must lie in the structure plane."""


@dataclass(frozen=True, kw_only=True)
class Hover(TrajectoryCommon):
    """Station keeping at standoff_m in front of the structure point, at height_m (ENU up)."""

    kind: Literal["hover"] = "hover"
    standoff_m: float = 3.0
    height_m: float = 5.0
    lateral_m: float = 0.0
    """Offset to the right (seen from the drone) of the structure point [m]."""


@dataclass(frozen=True, kw_only=True)
class Survey(TrajectoryCommon):
    """A VTOL / fixed-wing survey in forward flight (`icgt.sim.survey`): ``legs`` straights of ``leg_s``
    joined by banked coordinated turns of ``turn_deg`` (alternately right and left, a lawn-mower pattern)."""

    kind: Literal["survey"] = "survey"
    speed_m_s: float = 22.0
    altitude_m: float = 30.0
    """ENU height of the flight [m]."""
    start_m: tuple[float, float] = (0.0, 0.0)
    """ENU east, north of the start [m]."""
    course_deg: float = 90.0
    """Compass course of the first leg [deg]."""
    leg_s: float = 8.0
    legs: int = 3
    turn_deg: float = 180.0
    bank_deg: float = 30.0


TrajectorySpec: TypeAlias = PierScan | DeckPass | Hover | Survey


@dataclass(frozen=True, kw_only=True)
class Capture:
    """When the camera is triggered. focus_burst: the paper's cycle (focus_ms of half-press, then
    burst_ms of shots at burst_fps), repeated; interval: one shot every interval_ms."""

    mode: Literal["focus_burst", "interval"] = "focus_burst"
    start_s: float = 2.0
    """Scenario time of the "start capture" command [s]."""
    stop_s: float | None = None
    """Scenario time of "stop capture" [s]; None = the end of the scenario."""
    focus_ms: int = 500
    burst_ms: int = 2000
    burst_fps: float = 5.0
    interval_ms: int = 200
    count: int = 0
    """Shots the ground station asks for (MAV_CMD_IMAGE_START_CAPTURE param 3; 0 = until stopped, interval mode)."""

    def nominal_trigger_taus_s(self, duration_s: float) -> list[float]:
        """Scenario times of the trigger pulses this plan asks for (before any shutter lag)."""
        stop = duration_s if self.stop_s is None else min(self.stop_s, duration_s)
        out: list[float] = []
        if self.mode == "interval":
            n = 0
            while (t := self.start_s + n * self.interval_ms * 1e-3) < stop - 1e-9 and not (0 < self.count <= n):
                out.append(t)
                n += 1
            return out
        cycle_s = (self.focus_ms + self.burst_ms) * 1e-3
        per_burst = max(1, math.floor(self.burst_ms * 1e-3 * self.burst_fps + 1e-9))
        c = 0
        while (cycle_start := self.start_s + c * cycle_s) < stop - 1e-9:
            for k in range(per_burst):
                t = cycle_start + self.focus_ms * 1e-3 + k / self.burst_fps
                if t < stop - 1e-9:
                    out.append(t)
            c += 1
        return out


@dataclass(frozen=True, kw_only=True)
class Gimbal:
    """A MAVLink gimbal device (component 154) carrying the camera, as a Gremsy or SIYI gimbal in follow mode.

    It holds roll and pitch against the horizon and follows the vehicle's yaw with a lag; it reports its
    attitude as GIMBAL_DEVICE_ATTITUDE_STATUS (yaw in the vehicle frame) at ``rate_hz``, through the autopilot
    to the companion link, stamped on its own boot clock (``boot_offset_s`` after the scenario's start)."""

    pitch_deg: float = 0.0
    """Above the horizon (+90: straight up, under a deck) [deg]."""
    pitch_sweep_deg: float = 0.0
    """The operator nods the camera: pitch_deg + pitch_sweep_deg sin(2 pi t / pitch_sweep_period_s) [deg]."""
    pitch_sweep_period_s: float = 6.0
    roll_deg: float = 0.0
    yaw_lag_s: float = 0.5
    """The gimbal's yaw is the vehicle's this long ago (follow mode)."""
    rate_hz: float = 20.0
    noise_deg: float = 0.03
    """Its own attitude error, per axis (1 sigma) [deg]."""
    boot_offset_s: float = -3.7
    """The gimbal's boot clock: 0 at this scenario time [s] (it boots on its own)."""
    silent_s: tuple[Window, ...] = ()
    """Windows [s] in which it sends nothing (a loose cable, a gimbal reboot)."""


@dataclass(frozen=True, kw_only=True)
class BoardImu:
    """The board rides on the gimbal with the camera (`[camera.board_imu]`): its BNO055 reports the board's
    attitude in its own world frame, level by gravity but with its own north, and the board is not quite square
    to the camera. Without this table the simulated BNO055 reports the camera's axes -> NED exactly."""

    camera_on_board_deg: Vec3 = (0.0, 0.0, 0.0)
    """The camera's FRD axes on the board's sensor axes, roll pitch yaw (ZYX) [deg]: what a calibration finds."""
    heading_offset_deg: float = 0.0
    """True north minus the BNO's north at the start [deg] (declination, its heading error, IMU-mode start)."""
    heading_drift_deg_per_min: float = 0.0
    """The BNO's north turning with time (IMU mode: its gyro's bias) [deg/min]."""


@dataclass(frozen=True, kw_only=True)
class Camera:
    make: str = "SONY"
    model: str = "ILCE-9"
    focal_length_mm: float = 35.0
    sensor_width_mm: float = 35.6
    sensor_height_mm: float = 23.8
    image_width_px: int = 6000
    image_height_px: int = 4000
    mount_roll_deg: float = 0.0
    mount_pitch_deg: float = 0.0
    """Camera relative to the body (stabilised: relative to the level, yawed body) [deg], ZYX."""
    mount_yaw_deg: float = 0.0
    stabilised: bool = True
    """True: a gimbal holds roll and pitch level (only body yaw moves the camera)."""
    lever_arm_m: Vec3 = (0.25, 0.0, 0.10)
    """Camera (and LiDAR) position in body FRD axes relative to the autopilot's reference [m]."""
    exposure_us: int = 1000
    shutter_latency_us: int = 48_000
    shutter_jitter_us: int = 2_000
    max_fps: float = 0.0
    """The body's top frame rate: a press sooner after the last is ignored (0 = no limit; Sony Alpha 9: 20)."""
    buffer_shots: int = 0
    """Frames the body's buffer holds before it stops answering (0 = unlimited; Alpha 9: ~362 JPEG, 241 RAW)."""
    write_ms: float = 0.0
    """Card write time per frame: how fast the buffer empties [ms]."""
    first_file_number: int = 1
    """Number of the first file on the card (DSC00001.JPG for 1)."""
    k1: float = 0.0
    """Lens distortion of the rendered images (Brown-Conrady, OpenCV's k1 k2 p1 p2 k3; icgt.geometry)."""
    k2: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    k3: float = 0.0
    capture: Capture = field(default_factory=Capture)
    gimbal: Gimbal | None = None
    """A gimbal carries the camera (`[camera.gimbal]`): its attitude is the gimbal's, not body times mount."""
    board_imu: BoardImu | None = None
    """The board's BNO055 on the gimbal with the camera, as it is really mounted (`[camera.board_imu]`)."""

    def footprint_m(self, distance_m: float) -> tuple[float, float]:
        """(width, height) of the image footprint [m] on a surface square to the optical axis."""
        return (
            distance_m * self.sensor_width_mm / self.focal_length_mm,
            distance_m * self.sensor_height_mm / self.focal_length_mm,
        )


@dataclass(frozen=True, kw_only=True)
class Sensors:
    imu_rate_hz: float = 100.0
    range_rate_hz: float = 100.0
    lidar_model: Literal["v3", "v3hp"] = "v3"
    range_noise_cm: float = 2.5
    pps: bool = False
    """The GPS receiver's PPS wired to the device: an edge at every whole UTC second."""

    @property
    def lidar_max_range_m(self) -> float:
        return LIDAR_MAX_RANGE_M[self.lidar_model]


@dataclass(frozen=True, kw_only=True)
class Gps:
    fix_type: int = 3
    """GPS_RAW_INT fix_type while the fix is good (3 = 3D, 6 = RTK fixed)."""
    fix_acquired_after_s: float = 0.0
    """Before this scenario time: fix_type 1, lat/lon 0, SYSTEM_TIME time_unix_usec 0."""
    noise_horizontal_m: float = 0.8
    noise_vertical_m: float = 1.5
    fused_noise_horizontal_m: float = 0.03
    """Noise of the autopilot's fused estimate (GLOBAL_POSITION_INT, LOCAL_POSITION_NED) [m]."""
    fused_noise_vertical_m: float = 0.05
    satellites: int = 14
    hdop: float = 0.8
    outages_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows: GPS_RAW_INT fix_type 1 with garbage non-zero lat/lon."""
    outage_drift_m_s: float = 0.2
    """Growth of the fused estimate's error while the GPS has no fix [m/s]."""
    denied_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows without GPS: only LOCAL_POSITION_NED (no GLOBAL_POSITION_INT)."""
    denied_gps_raw: Literal["none", "no_fix"] = "none"
    """While denied: send no GPS_RAW_INT, or GPS_RAW_INT with fix_type 0 and lat/lon 0."""


@dataclass(frozen=True, kw_only=True)
class Autopilot:
    """The simulated autopilot. `profile` sets the defaults of every other key (icgt.sim.profiles
    says what each profile does and where the numbers come from); a scenario may override any."""

    profile: Literal["ideal", "ardupilot", "px4"] = "ideal"
    rates_hz: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_RATES_HZ))
    """Stream rates by lower-case message name (see STREAM_NAMES); 0 disables a stream."""
    latency_ms: float = 2.0
    """Time from an estimate's stamp to its message leaving the autopilot [ms]."""
    latency_jitter_ms: float = 0.5
    mavlink1_messages: tuple[str, ...] = ()
    """Upper-case message names sent as MAVLink 1 frames (real logs mix both)."""
    answer_timesync: bool = True
    """False: TIMESYNC requests are never answered (a radio or router that drops them, older firmware)."""
    honour_message_interval: bool = True
    """False: SET_MESSAGE_INTERVAL gets no COMMAND_ACK and the default rates stay (seen behind some routers)."""
    firmware: Literal["ardupilot", "px4"] = "ardupilot"
    """What the HEARTBEAT says (MAV_AUTOPILOT_ARDUPILOTMEGA or MAV_AUTOPILOT_PX4) and AUTOPILOT_VERSION."""
    system_id: int = 1
    """The vehicle's MAVLink system id (the autopilot is its component 1)."""
    stamp_jitter_ms: float = 0.0
    """Each stamp lands uniformly in [grid, grid + this) (ArduPilot stamps at send time in its main loop)."""
    local_position_lag_ms: float = 0.0
    """LOCAL_POSITION_NED is stamped (and written) up to this much after GLOBAL_POSITION_INT's grid point."""
    gps_fix_rate_hz: float = 0.0
    """> 0: GPS_RAW_INT carries the receiver's latest fix on this grid (time_usec = its boot time, whole ms,
    as ArduPilot); 0: each GPS_RAW_INT is its own sample at its own stamp."""
    own_timesync_hz: float = 0.0
    """Rate of the autopilot's own TIMESYNC requests (tc1 = 0, ts1 = its boot time [ns]); PX4 sends 10 Hz,
    ArduPilot one every 10 s on each link (GCS_MAVLINK _timesync_request.interval_ms)."""
    stream_reset_s: float = 0.0
    """> 0: at this scenario time every stream goes back to the profile's rate, whatever SET_MESSAGE_INTERVAL
    asked (and ACCEPTED) before: ArduPilot applies its SRn_ stream rates when its boot ends (~2.4 s after
    start in SITL), undoing the requests it took during the boot."""
    origin_on_change: bool = False
    """Send GPS_GLOBAL_ORIGIN when the EKF origin is first set (first fix) and at each origin reset."""
    origin_resets_s: tuple[float, ...] = ()
    """Scenario times of EKF local-origin resets: LOCAL_POSITION_NED jumps by -origin_reset_shift_m."""
    origin_reset_shift_m: Vec3 = (300.0, 380.0, 0.0)
    """How far the local origin moves at each reset, ENU [m] (cumulative; 484 m as in issue 9's log)."""
    param_bursts_s: tuple[float, ...] = ()
    """Scenario times of parameter downloads: a burst of PARAM_VALUE on both links."""
    param_burst_count: int = 1000
    """PARAM_VALUE messages per burst (ArduCopter 4.x has about a thousand parameters)."""
    param_burst_duration_s: float = 1.0
    """Time the burst is spread over [s]."""
    param_burst_stream_divisor: int = 1
    """During a burst only every n-th message of each stream is sent (ArduPilot: 4)."""
    gcs_heartbeat_systems: tuple[int, ...] = ()
    """System ids of ground stations whose HEARTBEATs (1 Hz, MAV_TYPE_GCS, component 190) the autopilot
    forwards to the companion link: 245 MAVSDK, 250, 255 QGroundControl / MAVProxy / Mission Planner."""
    foreign_camera: bool = False
    """A second camera at component 100 of the vehicle (HEARTBEAT 1 Hz, MAV_TYPE_CAMERA) on both links."""
    camera: AutopilotCamera = field(default_factory=lambda: AutopilotCamera())
    """How the autopilot itself commands the camera during the flight (none by default)."""


@dataclass(frozen=True, kw_only=True)
class AutopilotCamera:
    """`[autopilot.camera]`: the autopilot commands the camera as ArduPilot's AP_Camera does
    (icgt.sim.camera_trigger says exactly how)."""

    backend: Literal["none", "mavlink_camv2", "mavlink", "px4"] = "none"
    """ArduPilot CAM1_TYPE "mavlink_camv2" (6): IMAGE_START_CAPTURE to component 100; "mavlink" (5):
    DO_DIGICAM_CONTROL; "px4": PX4's MAVLink camera trigger (CAMERA_TRIGGER, IMAGE_START_CAPTURE re-sent
    until acknowledged, and DO_DIGICAM_CONTROL, per shot)."""
    interval_s: float = 0.0
    """Time trigger (mission IMAGE_START_CAPTURE with an interval) [s]; 0: none."""
    interval_window_s: Window = (0.0, 0.0)
    """[start_s, end_s] scenario times the time trigger runs."""
    distance_m: float = 0.0
    """Distance trigger (DO_SET_CAM_TRIGG_DIST) [m]; 0: none."""
    distance_window_s: Window = (0.0, 0.0)
    min_interval_s: float = 0.0
    """CAM1_INTRVAL_MIN [s]."""


@dataclass(frozen=True, kw_only=True)
class DeviceClock:
    offset_us: int = 0
    """Device clock at scenario time 0 [us]."""
    drift_ppm: float = 0.0


@dataclass(frozen=True, kw_only=True)
class AutopilotClock:
    offset_us: int = 0
    """Autopilot boot time at scenario time 0 [us]."""
    drift_ppm: float = 0.0


@dataclass(frozen=True, kw_only=True)
class CameraClock:
    offset_s: float = 0.0
    """Camera wall clock minus UTC at scenario time 0 [s] (a time zone goes in here too)."""
    drift_ppm: float = 0.0
    exif_resolution: Literal["1s", "10ms"] = "1s"


@dataclass(frozen=True, kw_only=True)
class Clocks:
    device: DeviceClock = field(default_factory=DeviceClock)
    autopilot: AutopilotClock = field(default_factory=AutopilotClock)
    camera: CameraClock = field(default_factory=CameraClock)


@dataclass(frozen=True, kw_only=True)
class Link:
    """Impairments of the USB serial link between the device and the host."""

    usb_latency_us: int = 0
    usb_jitter_us: int = 0
    drop_probability: float = 0.0
    """Per byte."""
    flip_probability: float = 0.0
    """Per byte."""


@dataclass(frozen=True, kw_only=True)
class Faults:
    camera_missed_triggers: tuple[int, ...] = ()
    """1-based trigger indices the camera ignores."""
    manual_shots_s: tuple[float, ...] = ()
    """Scenario times of shots fired by hand on the camera."""
    manual_shots_between_triggers: bool = False
    """Each manual shot is held for the next trigger pulse and taken half-way between two triggered exposures
    (the device's `manual_shot between`): its phase to the trigger is then the same in every run, where a
    shot at a fixed scenario time lands anywhere in the trigger's interval (the capture's start comes over a
    real link). False: at the scenario time as written, which may fall within a trigger's shutter lag."""
    device_unplugs_s: tuple[Window, ...] = ()
    """[start_s, duration_s] of USB unplugs."""
    autopilot_link_drops_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows where the autopilot's companion link sends and hears nothing."""
    position_gaps_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows where GLOBAL_POSITION_INT and LOCAL_POSITION_NED are not sent while attitude,
    GPS_RAW_INT and the rest go on (real logs have such gaps of 3 s and more: an estimator or a radio that
    drops the position streams)."""


@dataclass(frozen=True, kw_only=True)
class Scenario:
    name: str
    description: str = ""
    duration_s: float
    seed: int = 0
    origin: Origin
    structure: Structure
    trajectory: TrajectorySpec
    camera: Camera = field(default_factory=Camera)
    sensors: Sensors = field(default_factory=Sensors)
    gps: Gps = field(default_factory=Gps)
    autopilot: Autopilot = field(default_factory=Autopilot)
    clocks: Clocks = field(default_factory=Clocks)
    link: Link = field(default_factory=Link)
    faults: Faults = field(default_factory=Faults)
    surface: Surface | None = None
    """The face's texture and defects for rendered camera images (icgt.sim.surface); None: tag images."""
    source: str = "<memory>"
    """Where the scenario was read from (for messages)."""


# --- loading --------------------------------------------------------------------------------


def _unit(r: TableReader, key: str, v: Vec3) -> Vec3:
    n = math.sqrt(v[0] ** 2 + v[1] ** 2 + v[2] ** 2)
    if n < 1e-9:
        r.fail(key, "must not be the zero vector")
    return (v[0] / n, v[1] / n, v[2] / n)


def _trajectory_common(r: TableReader) -> dict[str, Any]:
    return {
        "start_hold_s": r.number("start_hold_s", 3.0, min_value=0.0),
        "sway_m": r.number("sway_m", 0.0, min_value=0.0, max_value=5.0),
        "sway_period_s": r.number("sway_period_s", 6.0, positive=True),
        "heading_deg": r.optional_number("heading_deg", min_value=-360.0, max_value=360.0),
    }


def _read_trajectory(r: TableReader, structure: Structure) -> TrajectorySpec:
    kind = r.string("kind", choices=TRAJECTORY_KINDS)
    common = _trajectory_common(r)
    spec: TrajectorySpec
    if kind == "pier_scan":
        bottom = r.number("bottom_m", 1.0)
        top = r.number("top_m", 12.0)
        if top <= bottom:
            r.fail("top_m", f"must be above bottom_m ({bottom:g}), got {top:g}")
        spec = PierScan(
            standoff_m=r.number("standoff_m", 2.5, positive=True),
            speed_m_s=r.number("speed_m_s", 0.8, positive=True, max_value=20.0),
            side_overlap=r.number("side_overlap", 0.6, min_value=0.0, max_value=0.95),
            width_m=r.number("width_m", 4.0, min_value=0.0),
            bottom_m=bottom,
            top_m=top,
            ramp_s=r.number("ramp_s", 1.5, positive=True),
            step_speed_m_s=r.number("step_speed_m_s", 0.5, positive=True),
            **common,
        )
        if abs(structure.normal[2]) > 0.5:
            r.fail("kind", "a pier scan needs a vertical face: structure.normal must be mostly horizontal")
    elif kind == "deck_pass":
        along = r.number("along_deg", 90.0, min_value=-360.0, max_value=360.0)
        spec = DeckPass(
            standoff_m=r.number("standoff_m", 5.0, positive=True),
            speed_m_s=r.number("speed_m_s", 10.0, positive=True, max_value=30.0),
            length_m=r.number("length_m", 160.0, positive=True),
            ramp_s=r.number("ramp_s", 4.0, positive=True),
            along_deg=along,
            **common,
        )
        d = (math.sin(math.radians(along)), math.cos(math.radians(along)), 0.0)
        dot = sum(a * b for a, b in zip(d, structure.normal, strict=True))
        if abs(dot) > 1e-3:
            r.fail("along_deg", f"direction {along:g} deg is not parallel to the structure plane")
        # the ramps must fit: the pass covers speed * (T - ramp) with T >= 2 ramps
        if spec.length_m < spec.speed_m_s * spec.ramp_s:
            r.fail("length_m", f"too short to reach {spec.speed_m_s:g} m/s with ramp_s {spec.ramp_s:g}")
    elif kind == "survey":
        start = r.numbers("start_m")
        if start and len(start) != 2:
            r.fail("start_m", f"must be [east, north] in metres, got {list(start)}")
        spec = Survey(
            speed_m_s=r.number("speed_m_s", 22.0, min_value=5.0, max_value=40.0),
            altitude_m=r.number("altitude_m", 30.0),
            start_m=(float(start[0]), float(start[1])) if start else (0.0, 0.0),
            course_deg=r.number("course_deg", 90.0, min_value=-360.0, max_value=360.0),
            leg_s=r.number("leg_s", 8.0, positive=True),
            legs=r.integer("legs", 3, min_value=1, max_value=100),
            turn_deg=r.number("turn_deg", 180.0, min_value=-360.0, max_value=360.0),
            bank_deg=r.number("bank_deg", 30.0, min_value=5.0, max_value=60.0),
            **common,
        )
    else:
        spec = Hover(
            standoff_m=r.number("standoff_m", 3.0, positive=True),
            height_m=r.number("height_m", 5.0),
            lateral_m=r.number("lateral_m", 0.0),
            **common,
        )
    r.finish()
    return spec


def _read_camera(r: TableReader) -> Camera:
    c = r.table("capture")
    capture = Capture(
        mode=c.string("mode", "focus_burst", choices=("focus_burst", "interval")),  # type: ignore[arg-type]
        start_s=c.number("start_s", 2.0, min_value=0.0),
        stop_s=c.optional_number("stop_s", min_value=0.0),
        focus_ms=c.integer("focus_ms", 500, min_value=0),
        burst_ms=c.integer("burst_ms", 2000, min_value=1),
        burst_fps=c.number("burst_fps", 5.0, positive=True, max_value=30.0),
        interval_ms=c.integer("interval_ms", 200, min_value=1),
        count=c.integer("count", 0, min_value=0),
    )
    if capture.stop_s is not None and capture.stop_s <= capture.start_s:
        c.fail("stop_s", f"must be after start_s ({capture.start_s:g})")
    c.finish()
    cam = Camera(
        make=r.string("make", "SONY"),
        model=r.string("model", "ILCE-9"),
        focal_length_mm=r.number("focal_length_mm", 35.0, positive=True),
        sensor_width_mm=r.number("sensor_width_mm", 35.6, positive=True),
        sensor_height_mm=r.number("sensor_height_mm", 23.8, positive=True),
        image_width_px=r.integer("image_width_px", 6000, min_value=1),
        image_height_px=r.integer("image_height_px", 4000, min_value=1),
        mount_roll_deg=r.number("mount_roll_deg", 0.0, min_value=-180.0, max_value=180.0),
        mount_pitch_deg=r.number("mount_pitch_deg", 0.0, min_value=-90.0, max_value=90.0),
        mount_yaw_deg=r.number("mount_yaw_deg", 0.0, min_value=-180.0, max_value=180.0),
        stabilised=r.boolean("stabilised", True),
        lever_arm_m=r.vec3("lever_arm_m", (0.25, 0.0, 0.10)),
        exposure_us=r.integer("exposure_us", 1000, min_value=1),
        shutter_latency_us=r.integer("shutter_latency_us", 48_000, min_value=0),
        shutter_jitter_us=r.integer("shutter_jitter_us", 2_000, min_value=0),
        max_fps=r.number("max_fps", 0.0, min_value=0.0, max_value=1000.0),
        buffer_shots=r.integer("buffer_shots", 0, min_value=0),
        write_ms=r.number("write_ms", 0.0, min_value=0.0, max_value=60_000.0),
        first_file_number=r.integer("first_file_number", 1, min_value=1, max_value=99_999),
        k1=r.number("k1", 0.0, min_value=-1.0, max_value=1.0),
        k2=r.number("k2", 0.0, min_value=-1.0, max_value=1.0),
        p1=r.number("p1", 0.0, min_value=-0.1, max_value=0.1),
        p2=r.number("p2", 0.0, min_value=-0.1, max_value=0.1),
        k3=r.number("k3", 0.0, min_value=-1.0, max_value=1.0),
        capture=capture,
        gimbal=_read_gimbal(r.table("gimbal")) if r.has("gimbal") else None,
        board_imu=_read_board_imu(r.table("board_imu")) if r.has("board_imu") else None,
    )
    r.finish()
    return cam


def _read_board_imu(r: TableReader) -> BoardImu:
    b = BoardImu(
        camera_on_board_deg=r.vec3("camera_on_board_deg", (0.0, 0.0, 0.0)),
        heading_offset_deg=r.number("heading_offset_deg", 0.0, min_value=-180.0, max_value=180.0),
        heading_drift_deg_per_min=r.number("heading_drift_deg_per_min", 0.0, min_value=-10.0, max_value=10.0),
    )
    if max(abs(a) for a in b.camera_on_board_deg) > 30.0:
        r.fail("camera_on_board_deg", f"each angle within 30 deg of square to the camera, got {b.camera_on_board_deg}")
    r.finish()
    return b


def _read_gimbal(r: TableReader) -> Gimbal:
    g = Gimbal(
        pitch_deg=r.number("pitch_deg", 0.0, min_value=-90.0, max_value=90.0),
        pitch_sweep_deg=r.number("pitch_sweep_deg", 0.0, min_value=0.0, max_value=90.0),
        pitch_sweep_period_s=r.number("pitch_sweep_period_s", 6.0, positive=True, max_value=600.0),
        roll_deg=r.number("roll_deg", 0.0, min_value=-45.0, max_value=45.0),
        yaw_lag_s=r.number("yaw_lag_s", 0.5, min_value=0.0, max_value=10.0),
        rate_hz=r.number("rate_hz", 20.0, positive=True, max_value=200.0),
        noise_deg=r.number("noise_deg", 0.03, min_value=0.0, max_value=10.0),
        boot_offset_s=r.number("boot_offset_s", -3.7, max_value=0.0),
        silent_s=r.pairs("silent_s", second_after_first=True),
    )
    r.finish()
    return g


def _read_gps(r: TableReader) -> Gps:
    gps = Gps(
        fix_type=r.integer("fix_type", 3, min_value=2, max_value=6),
        fix_acquired_after_s=r.number("fix_acquired_after_s", 0.0, min_value=0.0),
        noise_horizontal_m=r.number("noise_horizontal_m", 0.8, min_value=0.0),
        noise_vertical_m=r.number("noise_vertical_m", 1.5, min_value=0.0),
        fused_noise_horizontal_m=r.number("fused_noise_horizontal_m", 0.03, min_value=0.0),
        fused_noise_vertical_m=r.number("fused_noise_vertical_m", 0.05, min_value=0.0),
        satellites=r.integer("satellites", 14, min_value=0, max_value=254),
        hdop=r.number("hdop", 0.8, positive=True),
        outages_s=r.pairs("outages_s", second_after_first=True),
        outage_drift_m_s=r.number("outage_drift_m_s", 0.2, min_value=0.0),
        denied_s=r.pairs("denied_s", second_after_first=True),
        denied_gps_raw=r.string("denied_gps_raw", "none", choices=("none", "no_fix")),  # type: ignore[arg-type]
    )
    r.finish()
    return gps


def _read_autopilot(r: TableReader) -> Autopilot:
    profile = r.string("profile", "ideal", choices=PROFILE_NAMES)
    base = PROFILES[profile]
    rt = r.table("rates_hz")
    rates = dict(base["rates_hz"])
    for name in STREAM_NAMES:
        if rt.has(name):
            rates[name] = rt.number(name, min_value=0.0, max_value=1000.0)
    rt.finish()
    names = r.strings("mavlink1_messages")
    for n in names:
        if n.lower() not in STREAM_NAMES:
            r.fail("mavlink1_messages", f"{n!r} is not one of {', '.join(s.upper() for s in STREAM_NAMES)}")
    gcs = r.integers("gcs_heartbeat_systems", min_value=1)
    for i, sysid in enumerate(gcs):
        if sysid > 255:
            r.fail(f"gcs_heartbeat_systems[{i}]", f"must be <= 255, got {sysid}")
    ap = Autopilot(
        profile=profile,  # type: ignore[arg-type]
        rates_hz=rates,
        latency_ms=r.number("latency_ms", base["latency_ms"], min_value=0.0, max_value=1000.0),
        latency_jitter_ms=r.number("latency_jitter_ms", base["latency_jitter_ms"], min_value=0.0, max_value=1000.0),
        mavlink1_messages=tuple(n.upper() for n in names),
        answer_timesync=r.boolean("answer_timesync", base["answer_timesync"]),
        honour_message_interval=r.boolean("honour_message_interval", base["honour_message_interval"]),
        firmware=r.string("firmware", base["firmware"], choices=("ardupilot", "px4")),  # type: ignore[arg-type]
        system_id=r.integer("system_id", 1, min_value=1, max_value=255),
        stamp_jitter_ms=r.number("stamp_jitter_ms", base["stamp_jitter_ms"], min_value=0.0, max_value=20.0),
        local_position_lag_ms=r.number(
            "local_position_lag_ms", base["local_position_lag_ms"], min_value=0.0, max_value=100.0
        ),
        gps_fix_rate_hz=r.number("gps_fix_rate_hz", base["gps_fix_rate_hz"], min_value=0.0, max_value=100.0),
        own_timesync_hz=r.number("own_timesync_hz", base["own_timesync_hz"], min_value=0.0, max_value=100.0),
        stream_reset_s=r.number("stream_reset_s", 0.0, min_value=0.0, max_value=3600.0),
        origin_on_change=r.boolean("origin_on_change", base["origin_on_change"]),
        origin_resets_s=r.numbers("origin_resets_s", min_value=0.0),
        origin_reset_shift_m=r.vec3("origin_reset_shift_m", (300.0, 380.0, 0.0)),
        param_bursts_s=r.numbers("param_bursts_s", min_value=0.0),
        param_burst_count=r.integer("param_burst_count", 1000, min_value=1, max_value=100_000),
        param_burst_duration_s=r.number("param_burst_duration_s", 1.0, positive=True, max_value=600.0),
        param_burst_stream_divisor=r.integer(
            "param_burst_stream_divisor", base["param_burst_stream_divisor"], min_value=1, max_value=100
        ),
        gcs_heartbeat_systems=gcs,
        foreign_camera=r.boolean("foreign_camera", False),
        camera=_read_autopilot_camera(r.table("camera")),
    )
    r.finish()
    return ap


def _read_autopilot_camera(r: TableReader) -> AutopilotCamera:
    def window(key: str) -> Window:
        v = r.numbers(key, min_value=0.0)
        if not v:
            return (0.0, 0.0)
        if len(v) != 2 or v[1] <= v[0]:
            r.fail(key, f"expected [start_s, end_s] with the end after the start, got {list(v)}")
        return (v[0], v[1])

    cam = AutopilotCamera(
        backend=r.string("backend", "none", choices=("none", "mavlink_camv2", "mavlink", "px4")),  # type: ignore[arg-type]
        interval_s=r.number("interval_s", 0.0, min_value=0.0, max_value=3600.0),
        interval_window_s=window("interval_window_s"),
        distance_m=r.number("distance_m", 0.0, min_value=0.0, max_value=10_000.0),
        distance_window_s=window("distance_window_s"),
        min_interval_s=r.number("min_interval_s", 0.0, min_value=0.0, max_value=3600.0),
    )
    r.finish()
    return cam


def _read_clocks(r: TableReader) -> Clocks:
    d = r.table("device")
    device = DeviceClock(
        offset_us=d.integer("offset_us", 0, min_value=0),
        drift_ppm=d.number("drift_ppm", 0.0, min_value=-500, max_value=500),
    )
    d.finish()
    a = r.table("autopilot")
    autopilot = AutopilotClock(
        offset_us=a.integer("offset_us", 0, min_value=0),
        drift_ppm=a.number("drift_ppm", 0.0, min_value=-500, max_value=500),
    )
    a.finish()
    c = r.table("camera")
    camera = CameraClock(
        offset_s=c.number("offset_s", 0.0),
        drift_ppm=c.number("drift_ppm", 0.0, min_value=-500, max_value=500),
        exif_resolution=c.string("exif_resolution", "1s", choices=("1s", "10ms")),  # type: ignore[arg-type]
    )
    c.finish()
    r.finish()
    return Clocks(device=device, autopilot=autopilot, camera=camera)


def parse_scenario(data: Mapping[str, Any], source: str = "<memory>") -> Scenario:
    """Build and validate a Scenario from parsed TOML data; errors name `source` and the key."""
    r = TableReader(data, source)
    name = r.string("name")
    description = r.string("description", "")
    duration_s = r.number("duration_s", positive=True, max_value=24 * 3600.0)
    seed = r.integer("seed", 0, min_value=0)

    o = r.table("origin", required=True)
    origin = Origin(
        lat_deg=o.number("lat_deg", min_value=-89.0, max_value=89.0),
        lon_deg=o.number("lon_deg", min_value=-180.0, max_value=180.0),
        alt_m=o.number("alt_m", min_value=-500.0, max_value=9000.0),
        geoid_separation_m=o.number("geoid_separation_m", 0.0, min_value=-120.0, max_value=120.0),
    )
    o.finish()

    s = r.table("structure", required=True)
    structure = Structure(point_m=s.vec3("point_m"), normal=_unit(s, "normal", s.vec3("normal")))
    s.finish()

    trajectory = _read_trajectory(r.table("trajectory", required=True), structure)
    camera = _read_camera(r.table("camera"))

    se = r.table("sensors")
    sensors = Sensors(
        imu_rate_hz=se.number("imu_rate_hz", 100.0, positive=True, max_value=1000.0),
        range_rate_hz=se.number("range_rate_hz", 100.0, positive=True, max_value=1000.0),
        lidar_model=se.string("lidar_model", "v3", choices=tuple(LIDAR_MAX_RANGE_M)),  # type: ignore[arg-type]
        range_noise_cm=se.number("range_noise_cm", 2.5, min_value=0.0),
        pps=se.boolean("pps", False),
    )
    se.finish()

    gps = _read_gps(r.table("gps"))
    autopilot = _read_autopilot(r.table("autopilot"))
    clocks = _read_clocks(r.table("clocks"))

    li = r.table("link")
    link = Link(
        usb_latency_us=li.integer("usb_latency_us", 0, min_value=0),
        usb_jitter_us=li.integer("usb_jitter_us", 0, min_value=0),
        drop_probability=li.number("drop_probability", 0.0, min_value=0.0, max_value=1.0),
        flip_probability=li.number("flip_probability", 0.0, min_value=0.0, max_value=1.0),
    )
    li.finish()

    f = r.table("faults")
    faults = Faults(
        camera_missed_triggers=f.integers("camera_missed_triggers", min_value=1),
        manual_shots_s=f.numbers("manual_shots_s", min_value=0.0),
        manual_shots_between_triggers=f.boolean("manual_shots_between_triggers", False),
        device_unplugs_s=f.pairs("device_unplugs_s", second_after_first=False),
        autopilot_link_drops_s=f.pairs("autopilot_link_drops_s", second_after_first=True),
        position_gaps_s=f.pairs("position_gaps_s", second_after_first=True),
    )
    f.finish()
    surface = None
    if r.has("surface"):
        from icgt.sim.surface import check_surface, parse_surface

        surface = parse_surface(r.table("surface"))
        check_surface(surface, source)
    r.finish()
    return Scenario(
        name=name,
        description=description,
        duration_s=duration_s,
        seed=seed,
        origin=origin,
        structure=structure,
        trajectory=trajectory,
        camera=camera,
        sensors=sensors,
        gps=gps,
        autopilot=autopilot,
        clocks=clocks,
        link=link,
        faults=faults,
        surface=surface,
        source=source,
    )


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file. A bare name ("hover") means SCENARIO_DIR/hover.toml."""
    p = Path(path)
    if not p.suffix and not p.exists() and p.parent == Path("."):
        p = SCENARIO_DIR / f"{p.name}.toml"
        if not p.is_file():
            known = ", ".join(sorted(q.stem for q in SCENARIO_DIR.glob("*.toml"))) or "none"
            raise ScenarioError(f"unknown scenario {str(path)!r}: the scenarios in {SCENARIO_DIR} are {known}")
    try:
        with p.open("rb") as f:
            data = tomllib.load(f)
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read: {exc.strerror}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise ScenarioError(
            f"{p}: not a TOML scenario: not UTF-8 text (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})"
        ) from exc
    return parse_scenario(data, str(p))
