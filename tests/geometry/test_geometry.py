"""icgt.geometry against analytic truth: camera model, calibration files, projection, scale, cracks.

No simulated flight: poses come either from construction or from the simulator's trajectory
(`icgt.sim.trajectory.Trajectory`, the same truth the simulated flights are scored against), and
the reference intersections are computed independently (the simulator's own ray-plane range, or
closed-form geometry written out here).
"""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from icgt.errors import IcgtError
from icgt.geodesy import LocalFrame, ned_to_enu, q_from_euler_zyx, q_multiply, q_rotate
from icgt.geometry import (
    CalibrationError,
    CameraModel,
    GeometryError,
    Plane,
    Projector,
    SurfaceSource,
    camera_angles_deg,
    load_calibration,
    origin_from_frames,
)
from icgt.geotag.config import GeotagConfig
from icgt.geotag.record import FrameRecord
from icgt.sim.scenario import load_scenario
from icgt.sim.trajectory import Trajectory

BASE = np.array([0.5, 0.5, 0.5, 0.5])  # optical camera axes -> FRD camera axes
ORIGIN = (37.8813, 127.7298, 76.0)


def make_frame(
    position_enu: tuple[float, float, float] | np.ndarray,
    q_frd_ned: np.ndarray,
    range_m: float | None,
    **kw: object,
) -> FrameRecord:
    """A FrameRecord with an exactly known pose: camera FRD->NED attitude, ENU position, range."""
    q = q_multiply(q_frd_ned, BASE)
    frame = LocalFrame(*ORIGIN)
    lat, lon, alt = frame.enu_to_geodetic(np.asarray(position_enu, dtype=float))
    fields: dict[str, object] = dict(
        frame_seq=1,
        image_index=1,
        camera_id=0,
        device_flags=16,
        trigger_device_us=0,
        start_device_us=0,
        mid_device_us=500,
        duration_us=1000,
        mid_host_ns=0,
        mid_host_uncertainty_ns=0,
        time_source="pps",
        flags=[],
        position_source="gps_3d",
        fix_type=3,
        pose_gap_before_ms=10.0,
        pose_gap_after_ms=10.0,
        mid_utc_us=1_795_305_954_455_960,
        lat_deg=float(lat),
        lon_deg=float(lon),
        alt_msl_m=float(alt),
        east_m=float(position_enu[0]),
        north_m=float(position_enu[1]),
        up_m=float(position_enu[2]),
        cam_qw=float(q[0]),
        cam_qx=float(q[1]),
        cam_qy=float(q[2]),
        cam_qz=float(q[3]),
        range_m=range_m,
        range_valid=range_m is not None,
    )
    fields.update(kw)
    return FrameRecord(**fields)  # type: ignore[arg-type]


def gimbal(yaw_deg: float, pitch_deg: float, roll_deg: float) -> np.ndarray:
    return np.asarray(q_from_euler_zyx(math.radians(roll_deg), math.radians(pitch_deg), math.radians(yaw_deg)))


CAM = CameraModel.from_sensor(35.0, 35.6, 6000, 4000)
LENS = replace(CAM, k1=-0.12, k2=0.05, p1=0.0008, p2=-0.0005, k3=-0.01, cx=3011.0, cy=1993.5, skew=0.0)


# --- camera model ---------------------------------------------------------------------------


def test_undistort_inverts_distort_over_the_image() -> None:
    u, v = np.meshgrid(np.linspace(-0.5, 5999.5, 41), np.linspace(-0.5, 3999.5, 31))
    x, y = LENS.pixel_to_normalized(u.ravel(), v.ravel())
    u2, v2 = LENS.normalized_to_pixel(x, y)
    assert np.max(np.abs(u2 - u.ravel())) < 1e-8
    assert np.max(np.abs(v2 - v.ravel())) < 1e-8


def test_project_and_rays_are_inverse() -> None:
    rng = np.random.default_rng(1)
    uv = rng.uniform([0, 0], [6000, 4000], size=(200, 2))
    rays = LENS.rays(uv[:, 0], uv[:, 1]) * rng.uniform(0.5, 30.0, size=(200, 1))
    back = LENS.project(rays)
    assert np.max(np.abs(back - uv)) < 1e-8


def test_from_geotag_config_matches_the_recorder_focal_length() -> None:
    cfg = GeotagConfig(focal_length_mm=24.0, sensor_width_mm=35.6, image_width_px=6000, image_height_px=4000)
    cam = CameraModel.from_geotag_config(cfg)
    assert cam.fx == pytest.approx(cfg.focal_length_px)
    assert cam.centre_px == (2999.5, 1999.5)


# --- calibration files ----------------------------------------------------------------------


def test_calibration_toml(tmp_path: Path) -> None:
    p = tmp_path / "cam.toml"
    p.write_text(
        "[camera]\nwidth_px = 6000\nheight_px = 4000\nfx = 5900.5\nfy = 5901.0\ncx = 3001.0\ncy = 1998.0\n"
        "[distortion]\nk1 = -0.1\np2 = 0.001\n[mounting]\nboresight_pitch_deg = 0.5\n"
        "lever_arm_camera_m = [0.0, 0.01, 0.0]\n"
    )
    cam = load_calibration(p)
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.k1, cam.p2) == (5900.5, 5901.0, 3001.0, 1998.0, -0.1, 0.001)
    assert cam.boresight_rpy_deg == (0.0, 0.5, 0.0)
    assert cam.lever_arm_camera_m == (0.0, 0.01, 0.0)
    p.write_text("[camera]\nwidth_px = 6000\nheight_px = 4000\nfocal_length_mm = 35.0\nsensor_width_mm = 35.6\n")
    assert load_calibration(p).fx == pytest.approx(CAM.fx)


def test_calibration_opencv_yaml(tmp_path: Path) -> None:
    p = tmp_path / "calib.yml"
    p.write_text(
        "%YAML:1.0\n---\n"
        'calibration_time: "Sat Nov 21 2026"\n'
        "image_width: 6000\nimage_height: 4000\n"
        "camera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n"
        "   data: [ 5.9e+03, 0., 3.0005e+03, 0., 5.9e+03,\n       1.9995e+03, 0., 0., 1. ]\n"
        "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
        "   data: [ -1.2e-01, 5.e-02, 8.e-04, -5.e-04, -1.e-02 ]\n"
        "avg_reprojection_error: 0.31\n"
    )
    cam = load_calibration(p)
    assert (cam.width_px, cam.height_px, cam.fx, cam.cx, cam.cy) == (6000, 4000, 5900.0, 3000.5, 1999.5)
    assert (cam.k1, cam.k2, cam.p1, cam.p2, cam.k3) == (-0.12, 0.05, 0.0008, -0.0005, -0.01)


def test_calibration_json_both_layouts(tmp_path: Path) -> None:
    fs = {
        "image_width": 6000,
        "image_height": 4000,
        "camera_matrix": {"type_id": "opencv-matrix", "rows": 3, "cols": 3, "dt": "d",
                          "data": [5900.0, 0.0, 3000.0, 0.0, 5900.0, 2000.0, 0.0, 0.0, 1.0]},
        "distortion_coefficients": {"type_id": "opencv-matrix", "rows": 5, "cols": 1, "dt": "d",
                                    "data": [-0.1, 0.0, 0.0, 0.0, 0.0]},
    }  # fmt: skip
    p = tmp_path / "fs.json"
    p.write_text(json.dumps(fs))
    assert load_calibration(p).k1 == -0.1
    plain = {"width": 6000, "height": 4000, "camera_matrix": [[5900, 0, 3000], [0, 5900, 2000], [0, 0, 1]],
             "dist_coeffs": [0.01, 0.0, 0.0, 0.0]}  # fmt: skip
    p.write_text(json.dumps(plain))
    cam = load_calibration(p)
    assert (cam.fx, cam.k1, cam.k3) == (5900.0, 0.01, 0.0)


@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("a.toml", "[camera]\nwidth_px = 10\nheight_px = 10\nfx = 5\nfyy = 3\n", "fyy: unknown key"),
        ("b.json", '{"image_width": 6000, "image_height": 4000}', "no camera_matrix"),
        (
            "c.json",
            '{"image_width": 6, "image_height": 4, "camera_matrix": [1,0,3,0,1,2,0,0,1],'
            ' "dist_coeffs": [0.1, 0, 0, 0, 0, 0.2, 0, 0]}',
            "only k1 k2 p1 p2 k3",
        ),
        ("d.yaml", "image_width: 6000\n  stray: 1\n", "indented key outside a matrix"),
        ("e.ini", "x", "unknown calibration format"),
    ],
)
def test_calibration_errors_name_the_problem(tmp_path: Path, name: str, text: str, message: str) -> None:
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(CalibrationError, match=message) as info:
        load_calibration(p)
    assert isinstance(info.value, IcgtError)
    assert str(p) in str(info.value)


# --- projection by construction -------------------------------------------------------------


def _analytic_hits(
    cam: CameraModel, c: np.ndarray, yaw: float, pitch: float, roll: float, u: np.ndarray, v: np.ndarray,
    p0: np.ndarray, n: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """Ray-plane intersections written out independently: rotation matrices from the gimbal angles."""
    cy, sy = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    cp, sp = math.cos(math.radians(pitch)), math.sin(math.radians(pitch))
    cr, sr = math.cos(math.radians(roll)), math.sin(math.radians(roll))
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    frd_to_ned = rz @ ry @ rx
    optical_to_frd = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0]])  # x right->y, y down->z, z fwd->x
    ned_to_enu_m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    r = ned_to_enu_m @ frd_to_ned @ optical_to_frd
    x, y = cam.pixel_to_normalized(u, v)
    d = (r @ np.stack([x, y, np.ones_like(x)])).T
    t = ((p0 - c) @ n) / (d @ n)
    return c + d * t[:, None]


@pytest.mark.parametrize("cam", [CAM, LENS], ids=["ideal", "distorted"])
@pytest.mark.parametrize(("yaw", "pitch", "roll"), [(0.0, 0.0, 0.0), (30.0, -20.0, 5.0), (200.0, 10.0, -8.0)])
def test_pixel_to_world_against_closed_form(cam: CameraModel, yaw: float, pitch: float, roll: float) -> None:
    c = np.array([1.0, -2.0, 7.0])
    heading = np.array([math.sin(math.radians(yaw)), math.cos(math.radians(yaw)), 0.0])
    plane = Plane(tuple(c + 4.0 * heading + [0, 0, 0.3]), tuple(-heading + [0.1, 0.0, 0.05]))  # type: ignore[arg-type]
    rec = make_frame(c, gimbal(yaw, pitch, roll), None)
    proj = Projector(cam, structure=plane, anchor="structure")
    rng = np.random.default_rng(7)
    u, v = rng.uniform(0, 6000, 50), rng.uniform(0, 4000, 50)
    got = proj.pixel_to_world(rec, u, v)
    want = _analytic_hits(cam, c, yaw, pitch, roll, u, v, np.array(plane.point), np.array(plane.normal))
    assert got.surface is SurfaceSource.STRUCTURE
    assert np.max(np.abs(got.enu - want)) < 1e-9
    # on the plane
    assert np.max(np.abs((got.enu - np.array(plane.point)) @ np.array(plane.normal))) < 1e-9


def test_fronto_parallel_footprint_scale_and_crack() -> None:
    d = 2.5
    rec = make_frame((0.0, 0.0, 5.0), gimbal(0.0, 0.0, 0.0), d)  # looking north, level
    proj = Projector(CAM)  # nothing known about the surface: perpendicular at the range
    sol = proj.solve(rec)
    assert sol.surface is SurfaceSource.PERPENDICULAR_AT_RANGE
    assert sol.incidence_deg == pytest.approx(0.0, abs=1e-9)
    fp = sol.footprint
    assert fp is not None
    width = d * 35.6 / 35.0  # icgt.sim.scenario.Camera.footprint_m
    height = d * 4000 * (35.6 / 6000) / 35.0
    e, n, u = fp.enu[:, 0], fp.enu[:, 1], fp.enu[:, 2]
    assert np.allclose(n, d, atol=1e-12)
    assert np.allclose(sorted(e), [-width / 2] * 2 + [width / 2] * 2, atol=1e-9)
    assert np.allclose(sorted(u), [5 - height / 2] * 2 + [5 + height / 2] * 2, atol=1e-9)
    # top-left corner is up and to the left (west) of the centre: the image is not mirrored
    assert e[0] < 0 and u[0] > 5
    assert sol.footprint_area_m2 == pytest.approx(width * height, rel=1e-9)
    gsd = d * 1000 / CAM.fx
    assert sol.scale_mm_per_px == pytest.approx(gsd, rel=1e-9)
    crack = [(1000.0, 2000.0), (1300.0, 2400.0), (1300.0, 2900.0)]
    assert proj.crack_length_mm(rec, crack) == pytest.approx(1000.0 * gsd, rel=1e-9)
    assert proj.crack_length_mm(rec, crack, method="paper") == pytest.approx(1000.0 * gsd, rel=1e-9)


@pytest.mark.parametrize("tilt", [0.0, 10.0, 25.0, 40.0])
def test_tilted_surface_scale_incidence_and_record_formula(tilt: float) -> None:
    """Camera pitched up by `tilt` at a vertical wall: incidence = tilt, scale along v = d / (f cos tilt)."""
    d = 3.0  # along the optical axis, as the LiDAR measures
    rec = make_frame((0.0, 0.0, 5.0), gimbal(0.0, tilt, 0.0), d)
    proj = Projector(CAM, surface_normal=(0.0, -1.0, 0.0))
    sol = proj.solve(rec)
    assert sol.surface is SurfaceSource.NORMAL_AT_RANGE
    assert sol.incidence_deg == pytest.approx(tilt, abs=1e-9)
    assert sol.scale_u_mm_per_px == pytest.approx(d * 1000 / CAM.fx, rel=1e-6)
    assert sol.scale_v_mm_per_px == pytest.approx(d * 1000 / CAM.fx / math.cos(math.radians(tilt)), rel=1e-6)
    # the recorder's formula (icgt.geotag.geotagger): range * pixel pitch / focal length / cos(incidence)
    cfg = GeotagConfig(focal_length_mm=35.0, sensor_width_mm=35.6, image_width_px=6000, image_height_px=4000)
    recorded = d * 1000 * cfg.pixel_pitch_mm / cfg.focal_length_mm / math.cos(math.radians(tilt))
    assert sol.scale_mm_per_px == pytest.approx(recorded, rel=1e-6)
    # a vertical crack through the centre: exact length from its end points on the wall; the
    # paper's estimate misses the tilt
    cu, cv = CAM.centre_px
    crack = [(cu, cv - 800.0), (cu, cv + 800.0)]
    ends = proj.pixel_to_world(rec, [cu, cu], [cv - 800.0, cv + 800.0]).enu
    exact = float(np.linalg.norm(ends[1] - ends[0])) * 1000
    assert proj.crack_length_mm(rec, crack) == pytest.approx(exact, rel=1e-12)
    paper = proj.crack_length_mm(rec, crack, method="paper")
    assert paper == pytest.approx(1600 * d * 1000 / CAM.fx, rel=1e-12)
    if tilt > 0:
        assert paper < exact


def test_crack_position_midpoint_and_map_coordinates() -> None:
    rec = make_frame((2.0, 0.0, 5.0), gimbal(0.0, 0.0, 0.0), 2.0)
    proj = Projector(CAM, surface_normal=(0.0, -1.0, 0.0), origin=ORIGIN)
    cu, cv = CAM.centre_px
    crack = proj.crack_position(rec, [(cu - 500, cv), (cu + 500, cv)])
    assert np.allclose(crack.midpoint_enu, [2.0, 2.0, 5.0], atol=1e-9)
    assert crack.length_mm == pytest.approx(1000 * 2.0 * 1000 / CAM.fx, rel=1e-9)
    assert crack.length_mm_paper == pytest.approx(crack.length_mm, rel=1e-9)
    # map axes on a wall facing south (seen from the south): s runs east, t up
    assert np.allclose(crack.points.plane_st[:, 1], 5.0, atol=1e-9)
    assert crack.points.plane_st[1, 0] > crack.points.plane_st[0, 0]
    lat, lon, alt = LocalFrame(*ORIGIN).enu_to_geodetic(crack.midpoint_enu)
    assert crack.midpoint_wgs84 is not None
    assert crack.midpoint_wgs84 == pytest.approx((float(lat), float(lon), float(alt)), abs=1e-10)


def test_wgs84_with_and_without_the_origin_agree() -> None:
    rec = make_frame((120.0, -80.0, 15.0), gimbal(45.0, -30.0, 0.0), 6.0)
    with_origin = Projector(CAM, origin=ORIGIN).pixel_to_world(rec, [0.0, 3000.0], [0.0, 2000.0])
    anchored = Projector(CAM).pixel_to_world(rec, [0.0, 3000.0], [0.0, 2000.0])
    assert with_origin.lat_deg is not None and anchored.lat_deg is not None
    assert anchored.lon_deg is not None and with_origin.lon_deg is not None
    assert anchored.alt_m is not None and with_origin.alt_m is not None
    m_per_deg = 111_320.0
    assert np.max(np.abs(anchored.lat_deg - with_origin.lat_deg)) * m_per_deg < 1e-3
    assert np.max(np.abs(anchored.lon_deg - with_origin.lon_deg)) * m_per_deg < 1e-3
    assert np.max(np.abs(anchored.alt_m - with_origin.alt_m)) < 1e-3
    origin = origin_from_frames([rec])
    assert origin is not None
    assert (origin.lat0_deg, origin.lon0_deg, origin.h0_m) == pytest.approx(ORIGIN, abs=1e-8)


def test_camera_angles_are_the_gimbal_angles() -> None:
    for angles in [(0.0, 0.0, 0.0), (123.0, -35.0, 4.0), (300.0, -89.0, 0.0), (10.0, 30.0, -12.0)]:
        rec = make_frame((0.0, 0.0, 0.0), gimbal(*angles), None)
        got = camera_angles_deg(rec)
        assert got is not None
        assert got == pytest.approx(angles, abs=1e-9)


def test_boresight_and_lever_arm_corrections() -> None:
    rec = make_frame((0.0, 0.0, 5.0), gimbal(0.0, 0.0, 0.0), 2.0)
    tilted = replace(CAM, boresight_rpy_deg=(0.0, 0.0, 10.0), lever_arm_camera_m=(0.1, 0.0, 0.0))
    # yawed 10 deg right, shifted 0.1 m to the camera's right (east): the centre ray hits the wall
    # plane (through the range return) at east 0.1 + 2 sin 10
    sol = Projector(tilted, surface_normal=(0.0, -1.0, 0.0)).solve(rec)
    assert np.allclose(sol.camera_enu, [0.1, 0.0, 5.0], atol=1e-12)
    assert sol.incidence_deg == pytest.approx(10.0, abs=1e-9)


def test_unusable_frames_raise_geometry_errors() -> None:
    good = make_frame((0.0, 0.0, 5.0), gimbal(0.0, 0.0, 0.0), 2.0)
    proj = Projector(CAM)
    no_fix = replace(good, lat_deg=None, lon_deg=None, alt_msl_m=None, east_m=None, north_m=None, up_m=None)
    with pytest.raises(GeometryError, match="no position"):
        proj.solve(no_fix)
    with pytest.raises(GeometryError, match="no camera attitude"):
        proj.solve(replace(good, cam_qw=None))
    with pytest.raises(GeometryError, match="surface is unknown"):
        proj.solve(replace(good, range_m=None, range_valid=False))
    # a camera looking at the horizon over a floor: the upper half of the image never meets it
    floor = Plane((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    level = make_frame((0.0, 0.0, 2.0), gimbal(0.0, -5.0, 0.0), None)
    floor_proj = Projector(CAM, structure=floor, anchor="structure")
    pts = floor_proj.pixel_to_world(level, [3000.0, 3000.0], [0.0, 3999.0]).enu
    assert np.isnan(pts[0]).all() and np.isfinite(pts[1]).all()
    sol = floor_proj.solve(level)
    assert sol.footprint is None and sol.footprint_area_m2 is None
    results = proj.solve_many([good, no_fix])
    assert not isinstance(results[0], GeometryError)
    assert isinstance(results[1], GeometryError)


# --- against the simulator's truth ----------------------------------------------------------


@pytest.mark.parametrize("name", ["pier_scan", "deck_pass", "hover"])
def test_projection_against_simulator_truth(name: str) -> None:
    """Truth poses of a simulated flight: image corners and random pixels hit the structure where the
    simulator's own ray-plane range says; with the true range the plane is exact, with LiDAR noise the
    error stays within what that noise implies for each ray."""
    sc = load_scenario(name)
    traj = Trajectory(sc)
    taus = np.linspace(sc.camera.capture.start_s + 1.0, sc.duration_s - 3.0, 12)
    st = traj.state(taus)
    cam = CameraModel.from_sensor(
        sc.camera.focal_length_mm, sc.camera.sensor_width_mm, sc.camera.image_width_px, sc.camera.image_height_px
    )
    structure = Plane(sc.structure.point_m, sc.structure.normal)
    rng = np.random.default_rng(3)
    sigma = sc.sensors.range_noise_cm / 100.0
    n = np.array(sc.structure.normal)
    checked = 0
    for i in range(len(taus)):
        if not st.range_valid[i]:
            continue
        rec = make_frame(st.camera_position_enu_m[i], st.q_camera_ned[i], float(st.range_m[i]))
        uv = np.vstack([cam.border_pixels(0), rng.uniform([0, 0], [cam.width_px, cam.height_px], size=(20, 2))])
        # reference: the simulator's range along each pixel's ray (rays rotated with the truth quaternion)
        rays_cam = cam.rays(uv[:, 0], uv[:, 1])
        rays_frd = rays_cam[:, [2, 0, 1]]
        d_enu = ned_to_enu(q_rotate(st.q_camera_ned[i], rays_frd))
        d_enu /= np.linalg.norm(d_enu, axis=1, keepdims=True)
        t, valid = traj.range_to_structure(np.repeat(st.camera_position_enu_m[i : i + 1], len(uv), 0), d_enu)
        want = st.camera_position_enu_m[i] + d_enu * t[:, None]
        for proj in (Projector(cam, structure=structure, anchor="structure"), Projector(cam, structure=structure)):
            got = proj.pixel_to_world(rec, uv[:, 0], uv[:, 1]).enu
            assert np.max(np.abs(got[valid] - want[valid])) < 1e-6
        # LiDAR noise: the range-anchored plane moves by dr (a.n) along n, each hit by dr (a.n)/(d.n) along its ray
        axis = st.optical_axis_enu[i]
        for dr in rng.normal(0.0, sigma, 5):
            noisy = replace(rec, range_m=float(st.range_m[i]) + float(dr))
            got = Projector(cam, structure=structure).pixel_to_world(noisy, uv[:, 0], uv[:, 1]).enu
            bound = abs(dr) * abs(axis @ n) / np.abs(d_enu @ n)
            err = np.linalg.norm(got - want, axis=1)
            assert np.all(err[valid] <= bound[valid] * (1 + 1e-6) + 1e-9)
        sol = Projector(cam, structure=structure).solve(rec)
        cos_inc = abs(axis @ n)
        assert sol.incidence_deg == pytest.approx(math.degrees(math.acos(min(1.0, cos_inc))), abs=1e-6)
        checked += 1
    assert checked >= 6
