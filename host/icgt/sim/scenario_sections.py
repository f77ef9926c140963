"""The sections of a simulation scenario (`icgt.sim.scenario`), declared as msgspec Structs.

Each Struct is one TOML table: its fields are the table's keys, with their types, their units in their names
and their ranges (`msgspec.Meta`); a key that is not declared is refused. A rule between keys of one table is
checked in the Struct's ``__post_init__``, which names the key (``ValueError("top_m: ...")``; the scenario
reader puts the file and the table before it). Times are in seconds everywhere (``_s``), as in the recorder's
configuration. Frames: positions are ENU metres relative to ``[origin]``; body and camera axes are FRD (x
forward, y right, z down); the camera's x axis is its optical axis, image right is +y and image down is +z.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, TypeAlias

import msgspec
from msgspec import Meta

from icgt.sim.profiles import IDEAL_RATES_HZ

__all__ = [
    "LIDAR_MAX_RANGE_M",
    "STREAM_NAMES",
    "Autopilot",
    "AutopilotCamera",
    "AutopilotClock",
    "BoardImu",
    "Camera",
    "CameraClock",
    "Capture",
    "Clocks",
    "DeckPass",
    "DeviceClock",
    "Faults",
    "Gimbal",
    "Gps",
    "Hover",
    "Link",
    "Origin",
    "PierScan",
    "Section",
    "Sensors",
    "Structure",
    "Survey",
    "TrajectorySpec",
    "Vec3",
    "Window",
    "check_windows",
]

NonNegative: TypeAlias = Annotated[float, Meta(ge=0.0)]
Vec3: TypeAlias = tuple[float, float, float]
Window: TypeAlias = tuple[NonNegative, NonNegative]
"""[start_s, end_s] (or [start_s, duration_s] where the key says so), scenario time [s]."""

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


class Section(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A scenario table: immutable, keyword-built, no undeclared key."""


def check_windows(key: str, windows: tuple[Window, ...], *, second_is_duration: bool = False) -> None:
    """Each [a, b] ends after it starts (or, as [start, duration], lasts); ValueError naming `key[i]`."""
    for i, (a, b) in enumerate(windows):
        if second_is_duration and b <= 0.0:
            raise ValueError(f"{key}[{i}]: duration must be > 0, got {b:g}")
        if not second_is_duration and b <= a:
            raise ValueError(f"{key}[{i}]: end {b:g} must be after start {a:g}")


class Origin(Section, frozen=True, kw_only=True):
    """The ENU origin and home position. Ellipsoidal height = alt_m + geoid_separation_m."""

    lat_deg: Annotated[float, Meta(ge=-89.0, le=89.0)]
    lon_deg: Annotated[float, Meta(ge=-180.0, le=180.0)]
    alt_m: Annotated[float, Meta(ge=-500.0, le=9000.0)]
    """Height above mean sea level [m] (MAVLink `alt`)."""
    geoid_separation_m: Annotated[float, Meta(ge=-120.0, le=120.0)] = 0.0
    """Geoid height N above the WGS84 ellipsoid [m] (about +25 m in Korea)."""

    @property
    def ellipsoid_height_m(self) -> float:
        return self.alt_m + self.geoid_separation_m


class Structure(Section, frozen=True, kw_only=True):
    """The inspected surface: an infinite plane through point_m (ENU) with unit normal `normal`.

    The normal points to the side the drone flies on (out of the concrete).
    """

    point_m: Vec3
    normal: Vec3


class TrajectoryCommon(Section, frozen=True, kw_only=True, tag_field="kind"):
    start_hold_s: Annotated[float, Meta(ge=0.0)] = 3.0
    """Hover at the first point for this long before moving."""
    sway_m: Annotated[float, Meta(ge=0.0, le=5.0)] = 0.0
    """Amplitude of a smooth wind sway added to the path [m] (0 = none)."""
    sway_period_s: Annotated[float, Meta(gt=0.0)] = 6.0
    heading_deg: Annotated[float, Meta(ge=-360.0, le=360.0)] | None = None
    """Body yaw [deg, compass, 0 = north, 90 = east]; None: face the structure (or along the path
    under a horizontal surface)."""


class PierScan(TrajectoryCommon, frozen=True, kw_only=True, tag="pier_scan"):
    """Vertical passes up and down a pier face at standoff_m, stepping sideways between passes."""

    standoff_m: Annotated[float, Meta(gt=0.0)] = 2.5
    speed_m_s: Annotated[float, Meta(gt=0.0, le=20.0)] = 0.8
    side_overlap: Annotated[float, Meta(ge=0.0, le=0.95)] = 0.6
    """Overlap of the footprints of adjacent passes (0..1)."""
    width_m: Annotated[float, Meta(ge=0.0)] = 4.0
    """Width of the face to cover, centred on the structure point [m]."""
    bottom_m: float = 1.0
    top_m: float = 12.0
    """ENU heights of the camera at the ends of each pass [m]."""
    ramp_s: Annotated[float, Meta(gt=0.0)] = 1.5
    """Time to reach (or leave) the pass speed, smooth acceleration [s]."""
    step_speed_m_s: Annotated[float, Meta(gt=0.0)] = 0.5
    """Peak speed of the sideways step between passes [m/s]."""

    def __post_init__(self) -> None:
        if self.top_m <= self.bottom_m:
            raise ValueError(f"top_m: must be above bottom_m ({self.bottom_m:g}), got {self.top_m:g}")


class DeckPass(TrajectoryCommon, frozen=True, kw_only=True, tag="deck_pass"):
    """A straight pass along a deck at standoff_m from its surface, with smooth accel/decel."""

    standoff_m: Annotated[float, Meta(gt=0.0)] = 5.0
    speed_m_s: Annotated[float, Meta(gt=0.0, le=30.0)] = 10.0
    length_m: Annotated[float, Meta(gt=0.0)] = 160.0
    """Length of the whole pass (ramps included), centred on the structure point [m]."""
    ramp_s: Annotated[float, Meta(gt=0.0)] = 4.0
    along_deg: Annotated[float, Meta(ge=-360.0, le=360.0)] = 90.0
    """Direction of travel [deg, compass]; must lie in the structure plane."""

    def __post_init__(self) -> None:
        # the ramps must fit: the pass covers speed * (T - ramp) with T >= 2 ramps
        if self.length_m < self.speed_m_s * self.ramp_s:
            raise ValueError(f"length_m: too short to reach {self.speed_m_s:g} m/s with ramp_s {self.ramp_s:g}")


class Hover(TrajectoryCommon, frozen=True, kw_only=True, tag="hover"):
    """Station keeping at standoff_m in front of the structure point, at height_m (ENU up)."""

    standoff_m: Annotated[float, Meta(gt=0.0)] = 3.0
    height_m: float = 5.0
    lateral_m: float = 0.0
    """Offset to the right (seen from the drone) of the structure point [m]."""


class Survey(TrajectoryCommon, frozen=True, kw_only=True, tag="survey"):
    """A VTOL / fixed-wing survey in forward flight (`icgt.sim.survey`): ``legs`` straights of ``leg_s``
    joined by banked coordinated turns of ``turn_deg`` (alternately right and left, a lawn-mower pattern)."""

    speed_m_s: Annotated[float, Meta(ge=5.0, le=40.0)] = 22.0
    altitude_m: float = 30.0
    """ENU height of the flight [m]."""
    start_m: tuple[float, float] = (0.0, 0.0)
    """ENU east, north of the start [m]."""
    course_deg: Annotated[float, Meta(ge=-360.0, le=360.0)] = 90.0
    """Compass course of the first leg [deg]."""
    leg_s: Annotated[float, Meta(gt=0.0)] = 8.0
    legs: Annotated[int, Meta(ge=1, le=100)] = 3
    turn_deg: Annotated[float, Meta(ge=-360.0, le=360.0)] = 180.0
    bank_deg: Annotated[float, Meta(ge=5.0, le=60.0)] = 30.0


TrajectorySpec: TypeAlias = PierScan | DeckPass | Hover | Survey


class Capture(Section, frozen=True, kw_only=True):
    """When the camera is triggered. focus_burst: the paper's cycle (focus_s of half-press, then
    burst_s of shots at burst_fps), repeated; interval: one shot every interval_s."""

    mode: Literal["focus_burst", "interval"] = "focus_burst"
    start_s: Annotated[float, Meta(ge=0.0)] = 2.0
    """Scenario time of the "start capture" command [s]."""
    stop_s: Annotated[float, Meta(ge=0.0)] | None = None
    """Scenario time of "stop capture" [s]; None = the end of the scenario."""
    focus_s: Annotated[float, Meta(ge=0.0)] = 0.5
    """Half-press before each burst [s]."""
    burst_s: Annotated[float, Meta(gt=0.0)] = 2.0
    burst_fps: Annotated[float, Meta(gt=0.0, le=30.0)] = 5.0
    interval_s: Annotated[float, Meta(gt=0.0)] = 0.2
    count: Annotated[int, Meta(ge=0)] = 0
    """Shots the ground station asks for (MAV_CMD_IMAGE_START_CAPTURE param 3; 0 = until stopped, interval mode)."""

    def __post_init__(self) -> None:
        if self.stop_s is not None and self.stop_s <= self.start_s:
            raise ValueError(f"stop_s: must be after start_s ({self.start_s:g}), got {self.stop_s:g}")

    def nominal_trigger_taus_s(self, duration_s: float) -> list[float]:
        """Scenario times of the trigger pulses this plan asks for (before any shutter lag)."""
        stop = duration_s if self.stop_s is None else min(self.stop_s, duration_s)
        out: list[float] = []
        if self.mode == "interval":
            n = 0
            while (t := self.start_s + n * self.interval_s) < stop - 1e-9 and not (0 < self.count <= n):
                out.append(t)
                n += 1
            return out
        cycle_s = self.focus_s + self.burst_s
        per_burst = max(1, math.floor(self.burst_s * self.burst_fps + 1e-9))
        c = 0
        while (cycle_start := self.start_s + c * cycle_s) < stop - 1e-9:
            for k in range(per_burst):
                t = cycle_start + self.focus_s + k / self.burst_fps
                if t < stop - 1e-9:
                    out.append(t)
            c += 1
        return out


class Gimbal(Section, frozen=True, kw_only=True):
    """A MAVLink gimbal device (component 154) carrying the camera, as a Gremsy or SIYI gimbal in follow mode.

    It holds roll and pitch against the horizon and follows the vehicle's yaw with a lag; it reports its
    attitude as GIMBAL_DEVICE_ATTITUDE_STATUS (yaw in the vehicle frame) at ``rate_hz``, through the autopilot
    to the companion link, stamped on its own boot clock (``boot_offset_s`` after the scenario's start)."""

    pitch_deg: Annotated[float, Meta(ge=-90.0, le=90.0)] = 0.0
    """Above the horizon (+90: straight up, under a deck) [deg]."""
    pitch_sweep_deg: Annotated[float, Meta(ge=0.0, le=90.0)] = 0.0
    """The operator nods the camera: pitch_deg + pitch_sweep_deg sin(2 pi t / pitch_sweep_period_s) [deg]."""
    pitch_sweep_period_s: Annotated[float, Meta(gt=0.0, le=600.0)] = 6.0
    roll_deg: Annotated[float, Meta(ge=-45.0, le=45.0)] = 0.0
    yaw_lag_s: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.5
    """The gimbal's yaw is the vehicle's this long ago (follow mode)."""
    rate_hz: Annotated[float, Meta(gt=0.0, le=200.0)] = 20.0
    noise_deg: Annotated[float, Meta(ge=0.0, le=10.0)] = 0.03
    """Its own attitude error, per axis (1 sigma) [deg]."""
    boot_offset_s: Annotated[float, Meta(le=0.0)] = -3.7
    """The gimbal's boot clock: 0 at this scenario time [s] (it boots on its own)."""
    silent_s: tuple[Window, ...] = ()
    """Windows [s] in which it sends nothing (a loose cable, a gimbal reboot)."""

    def __post_init__(self) -> None:
        check_windows("silent_s", self.silent_s)


class BoardImu(Section, frozen=True, kw_only=True):
    """The board rides on the gimbal with the camera (`[camera.board_imu]`): its BNO055 reports the board's
    attitude in its own world frame, level by gravity but with its own north, and the board is not quite square
    to the camera. Without this table the simulated BNO055 reports the camera's axes -> NED exactly."""

    camera_on_board_deg: Vec3 = (0.0, 0.0, 0.0)
    """The camera's FRD axes on the board's sensor axes, roll pitch yaw (ZYX) [deg]: what a calibration finds."""
    heading_offset_deg: Annotated[float, Meta(ge=-180.0, le=180.0)] = 0.0
    """True north minus the BNO's north at the start [deg] (declination, its heading error, IMU-mode start)."""
    heading_drift_deg_per_min: Annotated[float, Meta(ge=-10.0, le=10.0)] = 0.0
    """The BNO's north turning with time (IMU mode: its gyro's bias) [deg/min]."""

    def __post_init__(self) -> None:
        if max(abs(a) for a in self.camera_on_board_deg) > 30.0:
            raise ValueError(
                f"camera_on_board_deg: each angle within 30 deg of square to the camera, got {self.camera_on_board_deg}"
            )


class Camera(Section, frozen=True, kw_only=True):
    make: str = "SONY"
    model: str = "ILCE-9"
    focal_length_mm: Annotated[float, Meta(gt=0.0)] = 35.0
    sensor_width_mm: Annotated[float, Meta(gt=0.0)] = 35.6
    sensor_height_mm: Annotated[float, Meta(gt=0.0)] = 23.8
    image_width_px: Annotated[int, Meta(ge=1)] = 6000
    image_height_px: Annotated[int, Meta(ge=1)] = 4000
    mount_roll_deg: Annotated[float, Meta(ge=-180.0, le=180.0)] = 0.0
    mount_pitch_deg: Annotated[float, Meta(ge=-90.0, le=90.0)] = 0.0
    """Camera relative to the body (stabilised: relative to the level, yawed body) [deg], ZYX."""
    mount_yaw_deg: Annotated[float, Meta(ge=-180.0, le=180.0)] = 0.0
    stabilised: bool = True
    """True: a gimbal holds roll and pitch level (only body yaw moves the camera)."""
    lever_arm_m: Vec3 = (0.25, 0.0, 0.10)
    """Camera (and LiDAR) position in body FRD axes relative to the autopilot's reference [m]."""
    exposure_s: Annotated[float, Meta(gt=0.0)] = 0.001
    shutter_latency_s: Annotated[float, Meta(ge=0.0)] = 0.048
    """Trigger to the exposure's start [s]."""
    shutter_jitter_s: Annotated[float, Meta(ge=0.0)] = 0.002
    max_fps: Annotated[float, Meta(ge=0.0, le=1000.0)] = 0.0
    """The body's top frame rate: a press sooner after the last is ignored (0 = no limit; Sony Alpha 9: 20)."""
    buffer_shots: Annotated[int, Meta(ge=0)] = 0
    """Frames the body's buffer holds before it stops answering (0 = unlimited; Alpha 9: ~362 JPEG, 241 RAW)."""
    write_s: Annotated[float, Meta(ge=0.0, le=60.0)] = 0.0
    """Card write time per frame: how fast the buffer empties [s]."""
    first_file_number: Annotated[int, Meta(ge=1, le=99999)] = 1
    """Number of the first file on the card (DSC00001.JPG for 1)."""
    k1: Annotated[float, Meta(ge=-1.0, le=1.0)] = 0.0
    """Lens distortion of the rendered images (Brown-Conrady, OpenCV's k1 k2 p1 p2 k3; icgt.geometry)."""
    k2: Annotated[float, Meta(ge=-1.0, le=1.0)] = 0.0
    p1: Annotated[float, Meta(ge=-0.1, le=0.1)] = 0.0
    p2: Annotated[float, Meta(ge=-0.1, le=0.1)] = 0.0
    k3: Annotated[float, Meta(ge=-1.0, le=1.0)] = 0.0
    capture: Capture = msgspec.field(default_factory=Capture)
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


class Sensors(Section, frozen=True, kw_only=True):
    imu_rate_hz: Annotated[float, Meta(gt=0.0, le=1000.0)] = 100.0
    range_rate_hz: Annotated[float, Meta(gt=0.0, le=1000.0)] = 100.0
    lidar_model: Literal["v3", "v3hp"] = "v3"
    range_noise_cm: Annotated[float, Meta(ge=0.0)] = 2.5
    pps: bool = False
    """The GPS receiver's PPS wired to the device: an edge at every whole UTC second."""

    @property
    def lidar_max_range_m(self) -> float:
        return LIDAR_MAX_RANGE_M[self.lidar_model]


class Gps(Section, frozen=True, kw_only=True):
    fix_type: Annotated[int, Meta(ge=2, le=6)] = 3
    """GPS_RAW_INT fix_type while the fix is good (3 = 3D, 6 = RTK fixed)."""
    fix_acquired_after_s: Annotated[float, Meta(ge=0.0)] = 0.0
    """Before this scenario time: fix_type 1, lat/lon 0, SYSTEM_TIME time_unix_usec 0."""
    noise_horizontal_m: Annotated[float, Meta(ge=0.0)] = 0.8
    noise_vertical_m: Annotated[float, Meta(ge=0.0)] = 1.5
    fused_noise_horizontal_m: Annotated[float, Meta(ge=0.0)] = 0.03
    """Noise of the autopilot's fused estimate (GLOBAL_POSITION_INT, LOCAL_POSITION_NED) [m]."""
    fused_noise_vertical_m: Annotated[float, Meta(ge=0.0)] = 0.05
    satellites: Annotated[int, Meta(ge=0, le=254)] = 14
    hdop: Annotated[float, Meta(gt=0.0)] = 0.8
    outages_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows: GPS_RAW_INT fix_type 1 with garbage non-zero lat/lon."""
    outage_drift_m_s: Annotated[float, Meta(ge=0.0)] = 0.2
    """Growth of the fused estimate's error while the GPS has no fix [m/s]."""
    denied_s: tuple[Window, ...] = ()
    """[start_s, end_s] windows without GPS: only LOCAL_POSITION_NED (no GLOBAL_POSITION_INT)."""
    denied_gps_raw: Literal["none", "no_fix"] = "none"
    """While denied: send no GPS_RAW_INT, or GPS_RAW_INT with fix_type 0 and lat/lon 0."""

    def __post_init__(self) -> None:
        check_windows("outages_s", self.outages_s)
        check_windows("denied_s", self.denied_s)


class Autopilot(Section, frozen=True, kw_only=True):
    """The simulated autopilot. `profile` sets the defaults of every other key (icgt.sim.profiles
    says what each profile does and where the numbers come from); a scenario may override any."""

    profile: Literal["ideal", "ardupilot", "px4"] = "ideal"
    rates_hz: dict[str, Annotated[float, Meta(ge=0.0, le=1000.0)]] = msgspec.field(
        default_factory=lambda: dict(IDEAL_RATES_HZ)
    )
    """Stream rates by lower-case message name (see STREAM_NAMES); 0 disables a stream."""
    latency_s: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.002
    """Time from an estimate's stamp to its message leaving the autopilot [s]."""
    latency_jitter_s: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.0005
    mavlink1_messages: tuple[str, ...] = ()
    """Upper-case message names sent as MAVLink 1 frames (real logs mix both)."""
    answer_timesync: bool = True
    """False: TIMESYNC requests are never answered (a radio or router that drops them, older firmware)."""
    honour_message_interval: bool = True
    """False: SET_MESSAGE_INTERVAL gets no COMMAND_ACK and the default rates stay (seen behind some routers)."""
    firmware: Literal["ardupilot", "px4"] = "ardupilot"
    """What the HEARTBEAT says (MAV_AUTOPILOT_ARDUPILOTMEGA or MAV_AUTOPILOT_PX4) and AUTOPILOT_VERSION."""
    system_id: Annotated[int, Meta(ge=1, le=255)] = 1
    """The vehicle's MAVLink system id (the autopilot is its component 1)."""
    stamp_jitter_s: Annotated[float, Meta(ge=0.0, le=0.02)] = 0.0
    """Each stamp lands uniformly in [grid, grid + this) (ArduPilot stamps at send time in its main loop)."""
    local_position_lag_s: Annotated[float, Meta(ge=0.0, le=0.1)] = 0.0
    """LOCAL_POSITION_NED is stamped (and written) up to this much after GLOBAL_POSITION_INT's grid point."""
    gps_fix_rate_hz: Annotated[float, Meta(ge=0.0, le=100.0)] = 0.0
    """> 0: GPS_RAW_INT carries the receiver's latest fix on this grid (time_usec = its boot time, whole ms,
    as ArduPilot); 0: each GPS_RAW_INT is its own sample at its own stamp."""
    own_timesync_hz: Annotated[float, Meta(ge=0.0, le=100.0)] = 0.0
    """Rate of the autopilot's own TIMESYNC requests (tc1 = 0, ts1 = its boot time [ns]); PX4 sends 10 Hz,
    ArduPilot one every 10 s on each link (GCS_MAVLINK _timesync_request.interval_ms)."""
    stream_reset_s: Annotated[float, Meta(ge=0.0, le=3600.0)] = 0.0
    """> 0: at this scenario time every stream goes back to the profile's rate, whatever SET_MESSAGE_INTERVAL
    asked (and ACCEPTED) before: ArduPilot applies its SRn_ stream rates when its boot ends (~2.4 s after
    start in SITL), undoing the requests it took during the boot."""
    origin_on_change: bool = False
    """Send GPS_GLOBAL_ORIGIN when the EKF origin is first set (first fix) and at each origin reset."""
    origin_resets_s: tuple[NonNegative, ...] = ()
    """Scenario times of EKF local-origin resets: LOCAL_POSITION_NED jumps by -origin_reset_shift_m."""
    origin_reset_shift_m: Vec3 = (300.0, 380.0, 0.0)
    """How far the local origin moves at each reset, ENU [m] (cumulative; 484 m as in issue 9's log)."""
    param_bursts_s: tuple[NonNegative, ...] = ()
    """Scenario times of parameter downloads: a burst of PARAM_VALUE on both links."""
    param_burst_count: Annotated[int, Meta(ge=1, le=100000)] = 1000
    """PARAM_VALUE messages per burst (ArduCopter 4.x has about a thousand parameters)."""
    param_burst_duration_s: Annotated[float, Meta(gt=0.0, le=600.0)] = 1.0
    """Time the burst is spread over [s]."""
    param_burst_stream_divisor: Annotated[int, Meta(ge=1, le=100)] = 1
    """During a burst only every n-th message of each stream is sent (ArduPilot: 4)."""
    gcs_heartbeat_systems: tuple[Annotated[int, Meta(ge=1, le=255)], ...] = ()
    """System ids of ground stations whose HEARTBEATs (1 Hz, MAV_TYPE_GCS, component 190) the autopilot
    forwards to the companion link: 245 MAVSDK, 250, 255 QGroundControl / MAVProxy / Mission Planner."""
    foreign_camera: bool = False
    """A second camera at component 100 of the vehicle (HEARTBEAT 1 Hz, MAV_TYPE_CAMERA) on both links."""
    camera: AutopilotCamera = msgspec.field(default_factory=lambda: AutopilotCamera())
    """How the autopilot itself commands the camera during the flight (none by default)."""

    def __post_init__(self) -> None:
        for name in self.rates_hz:
            if name not in STREAM_NAMES:
                raise ValueError(f"rates_hz.{name}: unknown key (the streams are {', '.join(STREAM_NAMES)})")
        for n in self.mavlink1_messages:
            if n.lower() not in STREAM_NAMES:
                names = ", ".join(s.upper() for s in STREAM_NAMES)
                raise ValueError(f"mavlink1_messages: {n!r} is not one of {names}")


class AutopilotCamera(Section, frozen=True, kw_only=True):
    """`[autopilot.camera]`: the autopilot commands the camera as ArduPilot's AP_Camera does
    (icgt.sim.camera_trigger says exactly how)."""

    backend: Literal["none", "mavlink_camv2", "mavlink", "px4"] = "none"
    """ArduPilot CAM1_TYPE "mavlink_camv2" (6): IMAGE_START_CAPTURE to component 100; "mavlink" (5):
    DO_DIGICAM_CONTROL; "px4": PX4's MAVLink camera trigger (CAMERA_TRIGGER, IMAGE_START_CAPTURE re-sent
    until acknowledged, and DO_DIGICAM_CONTROL, per shot)."""
    interval_s: Annotated[float, Meta(ge=0.0, le=3600.0)] = 0.0
    """Time trigger (mission IMAGE_START_CAPTURE with an interval) [s]; 0: none."""
    interval_window_s: Window = (0.0, 0.0)
    """[start_s, end_s] scenario times the time trigger runs."""
    distance_m: Annotated[float, Meta(ge=0.0, le=10000.0)] = 0.0
    """Distance trigger (DO_SET_CAM_TRIGG_DIST) [m]; 0: none."""
    distance_window_s: Window = (0.0, 0.0)
    min_interval_s: Annotated[float, Meta(ge=0.0, le=3600.0)] = 0.0
    """CAM1_INTRVAL_MIN [s]."""

    def __post_init__(self) -> None:
        for key, (start, end) in (
            ("interval_window_s", self.interval_window_s),
            ("distance_window_s", self.distance_window_s),
        ):
            if (start, end) != (0.0, 0.0) and end <= start:
                raise ValueError(f"{key}: expected [start_s, end_s] with the end after the start, got {[start, end]}")


class DeviceClock(Section, frozen=True, kw_only=True):
    offset_s: Annotated[float, Meta(ge=0.0)] = 0.0
    """Device clock at scenario time 0 [s]."""
    drift_ppm: Annotated[float, Meta(ge=-500.0, le=500.0)] = 0.0


class AutopilotClock(Section, frozen=True, kw_only=True):
    offset_s: Annotated[float, Meta(ge=0.0)] = 0.0
    """Autopilot boot time at scenario time 0 [s]."""
    drift_ppm: Annotated[float, Meta(ge=-500.0, le=500.0)] = 0.0


class CameraClock(Section, frozen=True, kw_only=True):
    offset_s: float = 0.0
    """Camera wall clock minus UTC at scenario time 0 [s] (a time zone goes in here too)."""
    drift_ppm: Annotated[float, Meta(ge=-500.0, le=500.0)] = 0.0
    exif_resolution: Literal["1s", "10ms"] = "1s"


class Clocks(Section, frozen=True, kw_only=True):
    device: DeviceClock = msgspec.field(default_factory=DeviceClock)
    autopilot: AutopilotClock = msgspec.field(default_factory=AutopilotClock)
    camera: CameraClock = msgspec.field(default_factory=CameraClock)


class Link(Section, frozen=True, kw_only=True):
    """Impairments of the USB serial link between the device and the host."""

    usb_latency_s: Annotated[float, Meta(ge=0.0)] = 0.0
    """Delay of each USB frame [s]."""
    usb_jitter_s: Annotated[float, Meta(ge=0.0)] = 0.0
    drop_probability: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.0
    """Per byte."""
    flip_probability: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.0
    """Per byte."""


class Faults(Section, frozen=True, kw_only=True):
    camera_missed_triggers: tuple[Annotated[int, Meta(ge=1)], ...] = ()
    """1-based trigger indices the camera ignores."""
    manual_shots_s: tuple[NonNegative, ...] = ()
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

    def __post_init__(self) -> None:
        check_windows("device_unplugs_s", self.device_unplugs_s, second_is_duration=True)
        check_windows("autopilot_link_drops_s", self.autopilot_link_drops_s)
        check_windows("position_gaps_s", self.position_gaps_s)
