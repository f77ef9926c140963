"""One camera pose per frame, whoever computes or publishes it: the frame conventions agree to 1e-9.

Every axis convention of ICGT lives in `icgt.pose` (NED/ENU, FRD/FLU, the camera optical frame, the mount,
the gimbal, the lever arm, and `camera_fields`, the rule that turns a body pose into a frame's camera
fields). Several consumers build on it, each with its own glue around it: the simulator's truth
(`icgt.sim.trajectory`, `icgt.sim.truth`: the camera board's FRD axes with x along the optical axis, and
the optical frame on top), the geotagger (`camera_fields`, `icgt.geotag.parts.attitude_fields`, the gimbal
report through `icgt.geotag.gimbal_pose.gimbal_at`), ``icgt regeotag`` (`icgt.trajectories.regeotag` with a
sampled trajectory, a TUM file in FLU body axes with a 4-DoF alignment, and the recorded telemetry
`icgt.trajectories.recorded`), the ROS 2 export (`icgt.export.ros2`: /tf and /tf_static in REP-103 axes) and
the Foxglove views (`icgt.recording.views`, live and re-derived by `icgt.export.foxglove_mcap`: /frames/pose,
/tf, /tf_static). A change to one copy of a convention (a mount composed on the wrong side, an FLU flip
forgotten, a lever arm turned by the wrong attitude) would not reach the others, and each consumer's own
tests could still pass.

So, for a few exposures of shipped scenarios and of variants with a body-fixed tilted mount, a stabilised
mount and a gimbal, this takes the simulator's TRUE body pose at mid-exposure and checks that each consumer,
given exactly that pose, gives the same camera pose: the camera's attitude (optical -> NED, compared as a
rotation: the angle of R1^T R2) and its position [m, ENU], to 1e-9 rad and 1e-9 m. The expected values
are computed here with rotation matrices built from the conventions as the docstrings state them
(independently of `icgt.geodesy`'s quaternion code), and each published transform chain is composed back
(enu -> base_link -> camera_mount -> camera_optical) before it is compared. No flight is flown: the
exports read a recording of a handful of FrameRecords written by the recorder's own MCAP writer.
"""

from __future__ import annotations

import dataclasses
import json
import math
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.reader import make_reader

from icgt.export.foxglove_mcap import FOXGLOVE_FILE, write_foxglove_mcap
from icgt.export.ros2 import write_ros2_bag
from icgt.export.ros2_msgs import MSG_TYPE, shipped_msg_text
from icgt.geodesy import LocalFrame, q_from_matrix
from icgt.geotag.config import GeotagConfig
from icgt.geotag.gimbal_pose import gimbal_at
from icgt.geotag.parts import attitude_fields, range_fields
from icgt.geotag.record import FrameRecord, SensorSource
from icgt.ingest import read
from icgt.mavlink.gimbal import GimbalSample
from icgt.mavlink.telemetry_buffer import TelemetryBuffer
from icgt.pose import CameraFields, CameraMounting, camera_fields, euler_deg
from icgt.recorder.config import parse_config
from icgt.recording import McapRecorder, layout
from icgt.recording.views import FoxgloveViews
from icgt.sim.recorder_setup import recorder_config_text
from icgt.sim.scenario import Scenario, load_scenario
from icgt.sim.scenario_sections import Gimbal
from icgt.sim.trajectory import Trajectory
from icgt.sim.truth import ClockMaps, ExposureTruth, exposure_truth
from icgt.sync import SyncConfig
from icgt.trajectories.recorded import RecordedTelemetry
from icgt.trajectories.regeotag import RegeotagConfig, regeotag
from icgt.trajectories.source import SampledTrajectory
from icgt.trajectories.tum import Alignment4Dof, TumOptions, read_tum

TOL_RAD = 1e-9
TOL_M = 1e-9
TOL_GEODETIC_M = 1e-8
"""For a position that went through WGS84 (ECEF coordinates are ~6.4e6 m: one float64 ulp there is ~1e-9 m, and
a geodetic -> ECEF -> ENU round trip costs a few): the recorded-telemetry source reads the frame's lat/lon/alt."""
EPOCH_OFFSET_NS = 1_700_000_000_000_000_000
"""The recording's host CLOCK_MONOTONIC -> publish time offset [ns] (the recorder's fixed offset to UTC)."""

Matrix = np.ndarray[Any, np.dtype[np.float64]]

# --- the conventions as the docstrings state them, as matrices (independent of icgt.geodesy) -----------

R_NED_TO_ENU: Matrix = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""(e, n, u) = (n_E, n_N, -n_D)."""
R_FRD_TO_FLU: Matrix = np.diag([1.0, -1.0, -1.0])
"""Forward stays, right and down flip (its own inverse)."""
R_OPTICAL_TO_FRD: Matrix = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
"""Columns: optical x (right) = body y, optical y (down) = body z, optical z (forward) = body x."""


def rot(q: Sequence[float] | np.ndarray[Any, Any]) -> Matrix:
    """The rotation matrix of a Hamilton quaternion (w, x, y, z), normalised: it turns a-axes into b-axes."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    out: Matrix = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    return out


def angle_rad(a: Matrix, b: Matrix) -> float:
    """The angle of the rotation a^T b (precise near 0: from its skew part, not from acos of the trace)."""
    d = a.T @ b
    s = 0.5 * math.sqrt((d[2, 1] - d[1, 2]) ** 2 + (d[0, 2] - d[2, 0]) ** 2 + (d[1, 0] - d[0, 1]) ** 2)
    c = 0.5 * (float(np.trace(d)) - 1.0)
    return math.atan2(s, c)


def euler_zyx(r: Matrix) -> tuple[float, float, float]:
    """Roll, pitch, yaw [rad] of a body -> NED matrix (R = Rz(yaw) Ry(pitch) Rx(roll))."""
    return (
        math.atan2(r[2, 1], r[2, 2]),
        -math.asin(max(-1.0, min(1.0, r[2, 0]))),
        math.atan2(r[1, 0], r[0, 0]),
    )


def r_z(angle: float) -> Matrix:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def r_zyx(roll: float, pitch: float, yaw: float) -> Matrix:
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    out: Matrix = r_z(yaw) @ ry @ rx
    return out


def present(*values: float | None) -> list[float]:
    """The values, which must all be there (a record field left None fails here)."""
    out = [v for v in values if v is not None]
    assert len(out) == len(values), f"a field is missing: {values}"
    return out


def vec(v: Sequence[float] | np.ndarray[Any, Any]) -> Matrix:
    return np.asarray([float(c) for c in v], dtype=float)


WORST: dict[str, float] = {}
"""The largest disagreement seen per comparison (printed at the end with ``-s``)."""


def agree(what: str, got: float, tol: float) -> None:
    WORST[what] = max(WORST.get(what, 0.0), got)
    assert got <= tol, f"{what}: {got:.3e} > {tol:.0e}"


def same_rotation(what: str, a: Matrix, b: Matrix) -> None:
    agree(f"{what} [rad]", angle_rad(a, b), TOL_RAD)


def same_position(what: str, a: Matrix, b: Matrix, tol: float = TOL_M) -> None:
    agree(f"{what} [m]", float(np.linalg.norm(vec(a) - vec(b))), tol)


# --- the cases: shipped scenarios and variants with other mountings --------------------------------------


def _deck_pass() -> Scenario:
    return load_scenario("deck_pass")


def _deck_pass_tilted_mount() -> Scenario:
    """A camera fixed to the body (no stabilisation), rolled, pitched and yawed on it, off-axis lever arm;
    sway and a heading off the structure so the body's attitude has all three angles."""
    sc = load_scenario("deck_pass")
    camera = msgspec.structs.replace(
        sc.camera,
        stabilised=False,
        mount_roll_deg=4.0,
        mount_pitch_deg=-25.0,
        mount_yaw_deg=12.0,
        lever_arm_m=(0.31, -0.07, 0.18),
    )
    trajectory = msgspec.structs.replace(sc.trajectory, sway_m=0.4, heading_deg=20.0)
    return msgspec.structs.replace(sc, camera=camera, trajectory=trajectory)


def _deck_pass_stabilised_mount() -> Scenario:
    """A stabilised camera (only the body's yaw turns it) with mount angles on the level, yawed body."""
    sc = load_scenario("deck_pass")
    camera = msgspec.structs.replace(
        sc.camera, stabilised=True, mount_roll_deg=-3.0, mount_pitch_deg=15.0, mount_yaw_deg=-8.0
    )
    trajectory = msgspec.structs.replace(sc.trajectory, sway_m=0.3, heading_deg=-15.0)
    return msgspec.structs.replace(sc, camera=camera, trajectory=trajectory)


def _pier_scan_gimbal() -> Scenario:
    """A gimbal (follow mode, nodding, rolled) carries the camera, itself a little off square on it."""
    sc = load_scenario("pier_scan")
    gimbal = Gimbal(pitch_deg=12.0, pitch_sweep_deg=8.0, pitch_sweep_period_s=5.0, roll_deg=3.0, yaw_lag_s=0.5)
    camera = msgspec.structs.replace(
        sc.camera,
        gimbal=gimbal,
        mount_roll_deg=1.5,
        mount_pitch_deg=-2.0,
        mount_yaw_deg=3.0,
        lever_arm_m=(0.2, 0.05, 0.15),
    )
    trajectory = msgspec.structs.replace(sc.trajectory, sway_m=0.3)
    return msgspec.structs.replace(sc, camera=camera, trajectory=trajectory)


SCENARIOS = {
    "deck_pass": _deck_pass,
    "deck_pass_tilted_mount": _deck_pass_tilted_mount,
    "deck_pass_stabilised_mount": _deck_pass_stabilised_mount,
    "pier_scan_gimbal": _pier_scan_gimbal,
}
N_EXPOSURES = 6


@dataclass(frozen=True)
class Case:
    name: str
    scenario: Scenario
    trajectory: Trajectory
    config: GeotagConfig
    """The recorder's [camera] as `icgt demo` writes it for the scenario (`recorder_config_text`)."""
    mounting: CameraMounting
    origin: tuple[float, float, float]
    """The recording's ENU origin (lat, lon, alt MSL): the scenario's."""
    truths: list[ExposureTruth]
    carriers: list[Matrix | None]
    """The gimbal's device frame -> NED at each mid-exposure as the geotagger gets it (None: no gimbal)."""
    fields: list[CameraFields]
    """The geotagger's camera fields of each exposure, from the true body pose."""
    frames: list[FrameRecord]
    """The geotagger's frame records carrying those fields."""


def _exposure_taus(sc: Scenario, traj: Trajectory) -> list[float]:
    """Mid-exposure instants spread over the motion: ramps (the body tilts), cruise, and the sway."""
    t0 = sc.trajectory.start_hold_s + 0.4
    t1 = min(traj.motion_end_s, sc.duration_s) - 0.4
    return [float(t) + 0.0123 for t in np.linspace(t0, t1, N_EXPOSURES)]


def _device_events(sc: Scenario, clocks: ClockMaps, taus: Sequence[float]) -> list[dict[str, Any]]:
    half = sc.camera.exposure_s / 2.0
    out = []
    for k, tau in enumerate(taus, start=1):
        start = round(float(clocks.tau_to_device_us(tau - half)))
        end = round(float(clocks.tau_to_device_us(tau + half)))
        out.append({"event": "exposure", "start_t_us": start, "end_t_us": end, "frame_number": k, "trigger_index": k})
    return out


def _gimbal_carrier(traj: Trajectory, tau: float, body_q: Sequence[float]) -> Matrix:
    """The geotagger's gimbal attitude at mid (`gimbal_at`) from the report the simulated gimbal sends there
    (GIMBAL_DEVICE_ATTITUDE_STATUS, yaw in the vehicle frame), turned by the true body's yaw."""
    q_report = traj.gimbal_vehicle_frame(tau)
    buffer: TelemetryBuffer[GimbalSample] = TelemetryBuffer()
    boot_us = 1_000_000 + round(tau * 1e6)
    report = (float(q_report[0]), float(q_report[1]), float(q_report[2]), float(q_report[3]))
    buffer.push(GimbalSample(boot_us, 0, report, False, 0, 0, 154))
    yaw = euler_zyx(rot(body_q))[2]
    q = gimbal_at(buffer, float(boot_us), yaw, max_gap_s=0.5, max_hold_s=0.05)
    assert q is not None
    return np.asarray(q, dtype=float)


def _frame(seq: int, truth: ExposureTruth, cam: CameraFields, origin: tuple[float, float, float]) -> FrameRecord:
    enu = cam.enu
    assert enu is not None
    lat, lon, alt = LocalFrame(*origin).enu_to_geodetic(enu)
    rng = range_fields((truth.range_m, 0.0, SensorSource.SAMPLES) if truth.range_m is not None else None, cam)
    return FrameRecord(
        frame_seq=seq,
        image_index=truth.trigger_index,
        camera_id=0,
        device_flags=0,
        trigger_device_us=truth.trigger_device_us,
        start_device_us=truth.start_device_us,
        mid_device_us=round(truth.mid_device_us),
        duration_us=truth.end_device_us - truth.start_device_us,
        mid_host_ns=truth.mid_host_monotonic_ns,
        mid_host_uncertainty_ns=0,
        time_source="pps",
        flags=[],
        position_source="rtk_fixed",
        fix_type=6,
        pose_gap_before_ms=0.0,
        pose_gap_after_ms=0.0,
        mid_utc_us=truth.mid_utc_us,
        lat_deg=float(lat),
        lon_deg=float(lon),
        alt_msl_m=float(alt),
        east_m=cam.east_m,
        north_m=cam.north_m,
        up_m=cam.up_m,
        position_error_bound_m=0.02,
        horizontal_error_bound_m=0.015,
        vertical_error_bound_m=0.013,
        **attitude_fields(cam),
        **rng,
    )


def _case(name: str, tmp: Path) -> Case:
    sc = SCENARIOS[name]()
    traj = Trajectory(sc)
    config = parse_config(tomllib.loads(recorder_config_text(sc, tmp / "recordings")), f"{name} (icgt demo)").camera
    mounting = CameraMounting.of(config)
    origin = (sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_m)
    clocks = ClockMaps.from_scenario(sc, t0_monotonic_ns=7_000_000_000_000, utc0_us=1_700_000_000_000_000)
    truths = exposure_truth(sc, _device_events(sc, clocks, _exposure_taus(sc, traj)), clocks, trajectory=traj)
    assert len(truths) == N_EXPOSURES
    carriers: list[Matrix | None] = []
    fields: list[CameraFields] = []
    frames: list[FrameRecord] = []
    for seq, t in enumerate(truths, start=1):
        carrier = _gimbal_carrier(traj, t.mid_tau_s, t.q_body_ned) if sc.camera.gimbal is not None else None
        cam = camera_fields(np.array(t.body_position_enu_m), np.array(t.q_body_ned), t.range_m, mounting, carrier)
        carriers.append(carrier)
        fields.append(cam)
        frames.append(_frame(seq, t, cam, origin))
    return Case(name, sc, traj, config, mounting, origin, truths, carriers, fields, frames)


@pytest.fixture(scope="module", autouse=True)
def _report_worst() -> Iterator[None]:
    yield
    if WORST:
        width = max(len(k) for k in WORST)
        print("\nlargest disagreement per comparison:")
        for k, v in sorted(WORST.items()):
            print(f"  {k:<{width}}  {v:.3e}")


@pytest.fixture(scope="module", params=list(SCENARIOS))
def case(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Case:
    return _case(str(request.param), tmp_path_factory.mktemp(str(request.param)))


@pytest.fixture(scope="module")
def recording_path(case: Case, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The geotagger's frames as a recording (the recorder's MCAP writer, its sync and ENU-origin metadata)."""
    path = tmp_path_factory.mktemp(f"log_{case.name}") / "log.mcap"
    with McapRecorder(path, fsync=False) as rec:
        rec.add_metadata(layout.META_TIME_BASES, {"monotonic_to_utc_offset_ns": str(EPOCH_OFFSET_NS)})
        rec.add_metadata(layout.META_SYNC, {"json": json.dumps(SyncConfig(geotag=case.config).to_json())})
        lat, lon, alt = case.origin
        rec.add_metadata(layout.META_ENU_ORIGIN, {"lat_deg": repr(lat), "lon_deg": repr(lon), "alt_msl_m": repr(alt)})
        rec.register_dataclass(layout.FRAMES, FrameRecord)
        for f in case.frames:
            ns = EPOCH_OFFSET_NS + f.mid_host_ns
            rec.write(layout.FRAMES, f, ns, ns)
    return path


# --- what each frame's camera pose should be ------------------------------------------------------------


def expected_optical_to_ned(case: Case, k: int) -> Matrix:
    """The camera optical -> NED of exposure k by the documented rule, from the true body (or gimbal) attitude:
    carrier -> NED times the mount (ZYX Euler in the carrier's FRD axes) times optical -> FRD."""
    cfg, t = case.config, case.truths[k]
    mount = r_zyx(*(math.radians(a) for a in (cfg.mount_roll_deg, cfg.mount_pitch_deg, cfg.mount_yaw_deg)))
    body = rot(t.q_body_ned)
    carrier = case.carriers[k]
    if carrier is not None:
        r_carrier = rot(carrier)
    elif cfg.gimbal_stabilised:
        r_carrier = r_z(euler_zyx(body)[2])
    else:
        r_carrier = body
    return r_carrier @ mount @ R_OPTICAL_TO_FRD


def geotagger_pose(case: Case, k: int) -> tuple[Matrix, Matrix]:
    """(optical -> NED, camera position [m, ENU]) of exposure k as the geotagger gave it."""
    cam = case.fields[k]
    assert cam.cam_q is not None and cam.enu is not None
    return rot(cam.cam_q), cam.enu


def record_pose(f: FrameRecord) -> tuple[Matrix, Matrix]:
    """(optical -> NED, camera position [m, ENU]) of a frame record."""
    return rot(present(f.cam_qw, f.cam_qx, f.cam_qy, f.cam_qz)), vec(present(f.east_m, f.north_m, f.up_m))


# --- simulator truth vs the geotagger -------------------------------------------------------------------


def test_truth_camera_pose_is_the_geotaggers(case: Case) -> None:
    """The simulator's true camera (optical -> NED, position) at each exposure is what the geotagger's
    `camera_fields` gives from the true body pose, and what the documented rule gives independently."""
    for k, t in enumerate(case.truths):
        r_geo, p_geo = geotagger_pose(case, k)
        same_rotation("truth q_optical_ned vs geotagger cam_q", rot(t.q_optical_ned), r_geo)
        same_rotation("documented rule vs geotagger cam_q", expected_optical_to_ned(case, k), r_geo)
        # the truth's two camera frames: the board's FRD (x along the optical axis) and the optical frame
        same_rotation(
            "truth q_camera_ned (FRD) x optical->FRD vs q_optical_ned",
            rot(t.q_camera_ned) @ R_OPTICAL_TO_FRD,
            rot(t.q_optical_ned),
        )
        same_position("truth camera position vs geotagger", vec(t.position_enu_m), p_geo)
        lever_enu = R_NED_TO_ENU @ rot(t.q_body_ned) @ vec(case.config.lever_arm_body_m)
        same_position("truth body position + R lever arm vs geotagger", vec(t.body_position_enu_m) + lever_enu, p_geo)


def test_truth_optical_axis_and_range_follow_the_geotaggers_camera(case: Case) -> None:
    """The truth's optical axis (its camera x, ENU) is the geotagger's optical z, and the true range along it
    from the geotagger's camera position ends on the structure."""
    taus = np.array([t.mid_tau_s for t in case.truths])
    state = case.trajectory.state(taus)
    normal, point = vec(case.scenario.structure.normal), vec(case.scenario.structure.point_m)
    for k, t in enumerate(case.truths):
        r_geo, p_geo = geotagger_pose(case, k)
        axis = R_NED_TO_ENU @ r_geo @ np.array([0.0, 0.0, 1.0])
        agree(
            "truth optical axis vs geotagger optical z [rad]",
            float(np.linalg.norm(axis - state.optical_axis_enu[k])),
            TOL_RAD,
        )
        if t.range_m is not None:
            agree(
                "range end off the structure plane [m]", abs(float((p_geo + t.range_m * axis - point) @ normal)), TOL_M
            )


def test_geotagger_body_angles_are_the_true_bodys(case: Case) -> None:
    """The record's roll/pitch/yaw are the ZYX Euler angles of the true body attitude (yaw wrapped)."""
    for k, t in enumerate(case.truths):
        cam = case.fields[k]
        assert cam.roll_deg is not None and cam.pitch_deg is not None and cam.yaw_deg is not None
        want = [math.degrees(a) for a in euler_zyx(rot(t.q_body_ned))]
        for got, w in zip((cam.roll_deg, cam.pitch_deg, cam.yaw_deg), want, strict=True):
            agree("geotagger roll/pitch/yaw vs true body [deg]", abs((got - w + 180.0) % 360.0 - 180.0), 1e-9)


@pytest.fixture(scope="module")
def gimbal_case(tmp_path_factory: pytest.TempPathFactory) -> Case:
    return _case("pier_scan_gimbal", tmp_path_factory.mktemp("gimbal_only"))


def test_gimbal_report_gives_the_true_gimbal(gimbal_case: Case) -> None:
    """The vehicle-frame gimbal report the simulator sends, turned by the body's yaw the way the geotagger
    turns it, is the simulator's true gimbal attitude (the gimbal case only: the others carry no gimbal)."""
    case = gimbal_case
    assert case.scenario.camera.gimbal is not None
    for k, t in enumerate(case.truths):
        carrier = case.carriers[k]
        assert carrier is not None
        same_rotation(
            "gimbal report (vehicle frame) + body yaw vs truth gimbal",
            rot(carrier),
            rot(case.trajectory.gimbal_ned(t.mid_tau_s)[0]),
        )


# --- regeotag -------------------------------------------------------------------------------------------


def _regeotag_config(case: Case) -> RegeotagConfig:
    return RegeotagConfig(geotag=case.config, origin=case.origin)


def _assert_regeotagged(what: str, case: Case, frames: list[FrameRecord], tol_m: float = TOL_M) -> None:
    assert [f.frame_seq for f in frames] == [f.frame_seq for f in case.frames]
    for k, f in enumerate(frames):
        r_geo, p_geo = geotagger_pose(case, k)
        r, p = record_pose(f)
        same_rotation(f"{what}: cam_q vs geotagger", r, r_geo)
        same_position(f"{what}: camera position vs geotagger", p, p_geo, tol_m)
        body = rot(present(f.body_qw, f.body_qx, f.body_qy, f.body_qz))
        same_rotation(f"{what}: body_q vs truth", body, rot(case.truths[k].q_body_ned))


def _blanked(frames: Sequence[FrameRecord]) -> list[FrameRecord]:
    """The frames with the position and the body attitude removed (kept: times, range, a gimbal's camera
    attitude, which regeotag keeps as recorded): what regeotag must put back."""
    out = []
    for f in frames:
        out.append(
            dataclasses.replace(
                f,
                east_m=None,
                north_m=None,
                up_m=None,
                lat_deg=None,
                lon_deg=None,
                alt_msl_m=None,
                body_qw=None,
                body_qx=None,
                body_qy=None,
                body_qz=None,
                roll_deg=None,
                pitch_deg=None,
                yaw_deg=None,
            )
        )
    return out


def test_regeotag_from_a_sampled_trajectory(case: Case) -> None:
    """A trajectory holding the true reference point and FRD body attitude exactly at the frames' times."""
    t_s = np.array([f.mid_host_ns / 1e9 for f in case.frames])
    source = SampledTrajectory(
        name="truth",
        time_base="host",
        t_s=t_s,
        enu_m=np.array([t.body_position_enu_m for t in case.truths]),
        frame=LocalFrame(*case.origin),
        bound_m=np.zeros(len(t_s)),
        labels=["ppk_fixed"] * len(t_s),
        q_body_ned=np.array([t.q_body_ned for t in case.truths]),
    )
    frames = regeotag(_blanked(case.frames), source, _regeotag_config(case))
    _assert_regeotagged("regeotag (sampled, FRD)", case, frames)


def test_regeotag_from_a_tum_file_in_flu_axes(case: Case, tmp_path: Path) -> None:
    """The same poses as a SLAM system writes them: a TUM file, body FLU (REP-103), in a world frame turned by
    33 deg about up and shifted from the recording's ENU (the 4-DoF alignment undoes it)."""
    align = Alignment4Dof(yaw_deg=33.0, translation_enu_m=(12.5, -7.25, 3.0))
    r_align = r_z(math.radians(align.yaw_deg))
    lines = ["# timestamp tx ty tz qx qy qz qw (body FLU -> file world)"]
    for f, t in zip(case.frames, case.truths, strict=True):
        p_file = r_align.T @ (vec(t.body_position_enu_m) - vec(align.translation_enu_m))
        r_file = r_align.T @ R_NED_TO_ENU @ rot(t.q_body_ned) @ R_FRD_TO_FLU  # FLU -> file world
        q = np.asarray(q_from_matrix(r_file), dtype=float)
        assert angle_rad(rot(q), r_file) < 1e-12
        cells = [f.mid_host_ns / 1e9, *p_file, q[1], q[2], q[3], q[0]]
        lines.append(" ".join(repr(float(c)) for c in cells))
    path = tmp_path / "slam.tum"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    source = read_tum(path, case.origin, TumOptions(time_base="host", alignment=align, body_axes="flu"))
    frames = regeotag(_blanked(case.frames), source, _regeotag_config(case))
    _assert_regeotagged("regeotag (TUM, FLU, aligned)", case, frames)


def test_regeotag_from_the_recorded_telemetry_gives_the_frames_back(case: Case) -> None:
    """The recorded geotag as a pose source (camera position back to the reference point by the recorded
    attitude and lever arm, through the frame's WGS84 position): regeotag puts the same camera back."""
    source = RecordedTelemetry(case.origin, case.config.lever_arm_body_m)
    frames = regeotag(list(case.frames), source, _regeotag_config(case))
    _assert_regeotagged("regeotag (recorded telemetry, via WGS84)", case, frames, TOL_GEODETIC_M)


# --- the published transform trees ---------------------------------------------------------------------


@dataclass(frozen=True)
class Tf:
    parent: str
    child: str
    translation: Matrix
    rotation: Matrix
    """child -> parent axes."""


def _chain_check(what: str, case: Case, static: list[Tf], per_frame: dict[int, list[Tf]]) -> None:
    """enu -> base_link -> camera_mount -> camera_optical composed back gives the geotagger's camera pose;
    base_link is the true reference point in FLU axes (REP-103), the mount is the lever arm in FLU."""
    (mount,) = [t for t in static if (t.parent, t.child) == (layout.BASE_FRAME, layout.MOUNT_FRAME)]
    assert len(per_frame) == len(case.frames), f"{what}: {len(per_frame)} frame transforms"
    same_position(
        f"{what} base_link -> camera_mount: lever arm in FLU",
        mount.translation,
        R_FRD_TO_FLU @ vec(case.config.lever_arm_body_m),
    )
    for k, f in enumerate(case.frames):
        tfs = {(t.parent, t.child): t for t in per_frame[f.mid_host_ns]}
        base = tfs[(layout.WORLD_FRAME, layout.BASE_FRAME)]
        residual = tfs[(layout.MOUNT_FRAME, layout.CAMERA_FRAME)]
        truth = case.truths[k]
        same_rotation(
            f"{what} enu -> base_link vs true body in FLU/ENU",
            base.rotation,
            R_NED_TO_ENU @ rot(truth.q_body_ned) @ R_FRD_TO_FLU,
        )
        same_position(
            f"{what} enu -> base_link vs true reference point", base.translation, vec(truth.body_position_enu_m)
        )
        r_enu = base.rotation @ mount.rotation @ residual.rotation
        p_enu = base.translation + base.rotation @ (mount.translation + mount.rotation @ residual.translation)
        r_geo, p_geo = geotagger_pose(case, k)
        same_rotation(f"{what} tf chain camera_optical vs geotagger", R_NED_TO_ENU.T @ r_enu, r_geo)
        same_position(f"{what} tf chain camera_optical vs geotagger", p_enu, p_geo)


def _ros_tf(t: Any) -> Tf:
    tr, q = t.transform.translation, t.transform.rotation
    return Tf(t.header.frame_id, t.child_frame_id, vec([tr.x, tr.y, tr.z]), rot([q.w, q.x, q.y, q.z]))


def _fox_tf(t: Any) -> Tf:
    tr, q = t.translation, t.rotation
    return Tf(t.parent_frame_id, t.child_frame_id, vec([tr.x, tr.y, tr.z]), rot([q.w, q.x, q.y, q.z]))


def test_ros2_export_tf_tree(case: Case, recording_path: Path, tmp_path: Path) -> None:
    """`icgt export --formats ros2` (`write_ros2_bag`) on the recording, read back by rosbags: /tf_static and
    each frame's /tf compose to the geotagger's camera (REP-103 base_link, optical camera frame)."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    write_ros2_bag(read(recording_path), tmp_path)
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(shipped_msg_text(), MSG_TYPE))
    static: list[Tf] = []
    per_frame: dict[int, list[Tf]] = {}
    frames = 0
    with Reader(tmp_path / "ros2") as reader:
        for conn, _, raw in reader.messages():
            msg: Any = store.deserialize_cdr(raw, conn.msgtype)
            if conn.topic == "/tf_static":
                static.extend(_ros_tf(t) for t in msg.transforms)
            elif conn.topic == "/tf":
                for t in msg.transforms:
                    ns = int(t.header.stamp.sec) * 1_000_000_000 + int(t.header.stamp.nanosec) - EPOCH_OFFSET_NS
                    per_frame.setdefault(ns, []).append(_ros_tf(t))
            elif conn.topic == "/frames":
                frames += 1
                k = [f.frame_seq for f in case.frames].index(msg.frame_seq)
                got = rot([msg.cam_qw, msg.cam_qx, msg.cam_qy, msg.cam_qz])
                same_rotation("ros2 /frames cam_q vs geotagger", got, geotagger_pose(case, k)[0])
    assert frames == len(case.frames)
    _chain_check("ros2", case, static, per_frame)


def _foxglove_check(what: str, case: Case, messages: list[tuple[str, Any, int]]) -> None:
    static: list[Tf] = []
    per_frame: dict[int, list[Tf]] = {}
    poses: dict[int, Any] = {}
    for topic, msg, _ in messages:
        if topic == layout.TF_STATIC:
            static.extend(_fox_tf(t) for t in msg.transforms)
        elif topic == layout.TF:
            for t in msg.transforms:
                per_frame.setdefault(t.timestamp.ToNanoseconds() - EPOCH_OFFSET_NS, []).append(_fox_tf(t))
        elif topic == layout.FRAMES_POSE:
            poses[msg.timestamp.ToNanoseconds() - EPOCH_OFFSET_NS] = msg
    assert len(poses) == len(case.frames)
    for k, f in enumerate(case.frames):
        pose = poses[f.mid_host_ns]
        assert pose.frame_id == layout.WORLD_FRAME
        o, p = pose.pose.orientation, pose.pose.position
        r_geo, p_geo = geotagger_pose(case, k)
        # PoseInFrame in enu: camera optical -> ENU
        same_rotation(f"{what} /frames/pose vs geotagger", R_NED_TO_ENU.T @ rot([o.w, o.x, o.y, o.z]), r_geo)
        same_position(f"{what} /frames/pose vs geotagger", vec([p.x, p.y, p.z]), p_geo)
    _chain_check(what, case, static, per_frame)


def test_foxglove_views_live(case: Case) -> None:
    """The recorder's views fed the geotagger's frames (as the worker feeds them): /frames/pose in enu and the
    transform tree give the geotagger's camera."""
    out: list[tuple[str, Any, int]] = []
    views = FoxgloveViews(
        case.config, lambda t, m, ns: out.append((t, m, ns)), lambda ns: ns + EPOCH_OFFSET_NS, lambda: case.origin, 1
    )
    views.start(case.frames[0].mid_host_ns - 1_000_000_000)
    for f in case.frames:
        views.on_frame(f)
    _foxglove_check("foxglove views", case, out)


def test_foxglove_export_rederives_the_views(case: Case, recording_path: Path, tmp_path: Path) -> None:
    """`write_foxglove_mcap` on a recording without the views re-derives them from its /frames (through the
    JSON frame record): the file's /frames/pose, /tf and /tf_static give the geotagger's camera."""
    recording = read(recording_path)
    counts = write_foxglove_mcap(recording_path, tmp_path, {}, case.config, recording=recording)
    assert counts["derived"] > 0
    kinds: dict[str, Any] = {
        layout.TF: FrameTransforms,
        layout.TF_STATIC: FrameTransforms,
        layout.FRAMES_POSE: PoseInFrame,
    }
    messages: list[tuple[str, Any, int]] = []
    with (tmp_path / FOXGLOVE_FILE).open("rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(topics=list(kinds)):
            messages.append((channel.topic, kinds[channel.topic].FromString(message.data), message.publish_time))
    _foxglove_check("foxglove export", case, messages)


# --- the comparisons can fail ---------------------------------------------------------------------------


def test_a_microradian_or_a_micrometre_off_is_caught() -> None:
    """The comparison itself resolves far below the tolerance: 1e-6 rad and 1e-6 m are caught, 1e-11 are not."""
    base = r_zyx(0.3, -0.2, 2.9) @ R_OPTICAL_TO_FRD
    p = vec([10.0, -200.0, 17.0])
    for axis in (np.array([1.0, 0.0, 0.0]), np.array([0.0, 0.6, 0.8])):
        for small, caught in ((1e-6, True), (1e-11, False)):
            x, y, z = axis * math.sin(small / 2.0)
            turned = base @ rot([math.cos(small / 2.0), x, y, z])
            assert abs(angle_rad(base, turned) - small) < 1e-14
            if caught:
                with pytest.raises(AssertionError):
                    same_rotation("control", base, turned)
                with pytest.raises(AssertionError):
                    same_position("control", p, p + axis * small)
            else:
                same_rotation("control", base, turned)
                same_position("control", p, p + axis * small)
    WORST.pop("control [rad]", None)
    WORST.pop("control [m]", None)


def test_a_yaw_a_hair_west_of_north_is_0_not_360() -> None:
    """`euler_deg` promises yaw in [0, 360): -1e-18 deg % 360 is 360.0 in floating point, level deck frames hit it."""
    _, _, yaw = euler_deg(np.array([1.0, 0.0, 0.0, -1e-18]))
    assert 0.0 <= yaw < 360.0
