"""WGS84, ENU and quaternion conventions: known values and round trips."""

from __future__ import annotations

import math

import numpy as np
import pytest

from icgt import geodesy as g


def test_ecef_known_points() -> None:
    assert g.geodetic_to_ecef(0.0, 0.0, 0.0) == pytest.approx([g.WGS84_A_M, 0.0, 0.0], abs=1e-6)
    assert g.geodetic_to_ecef(0.0, 90.0, 100.0) == pytest.approx([0.0, g.WGS84_A_M + 100.0, 0.0], abs=1e-6)
    assert g.geodetic_to_ecef(90.0, 0.0, 0.0) == pytest.approx([0.0, 0.0, 6_356_752.314245], abs=1e-5)
    lat, _, h = g.ecef_to_geodetic([0.0, 0.0, 6_356_752.314245 + 10.0])
    assert (float(lat), float(h)) == pytest.approx((90.0, 10.0), abs=1e-6)


def test_degree_lengths_at_the_equator() -> None:
    # textbook values for WGS84: 1 deg of latitude at the equator 110 574 m, of longitude 111 319 m
    frame = g.LocalFrame(0.0, 0.0, 0.0)
    north = frame.geodetic_to_enu(0.01, 0.0, 0.0)
    east = frame.geodetic_to_enu(0.0, 0.01, 0.0)
    assert north[1] * 100 == pytest.approx(110_574.3, abs=0.5)
    assert east[0] * 100 == pytest.approx(111_319.5, abs=0.5)


def test_geodetic_round_trip_over_the_globe() -> None:
    rng = np.random.default_rng(1)
    lat = rng.uniform(-89.9, 89.9, 2000)
    lon = rng.uniform(-180.0, 180.0, 2000)
    h = rng.uniform(-500.0, 20_000.0, 2000)
    lat2, lon2, h2 = g.ecef_to_geodetic(g.geodetic_to_ecef(lat, lon, h))
    assert np.max(np.abs(lat2 - lat)) < 1e-10
    assert np.max(np.abs(lon2 - lon)) < 1e-10
    assert np.max(np.abs(h2 - h)) < 1e-5


def test_enu_axes_and_round_trip() -> None:
    frame = g.LocalFrame(37.8813, 127.7298, 100.9)
    assert frame.geodetic_to_enu(37.8813, 127.7298, 100.9) == pytest.approx([0, 0, 0], abs=1e-6)
    up = frame.geodetic_to_enu(37.8813, 127.7298, 150.9)
    assert up == pytest.approx([0.0, 0.0, 50.0], abs=1e-6)
    pts = np.array([[10.0, -20.0, 3.0], [1000.0, 2000.0, -50.0], [0.0, 0.0, 0.0]])
    lat, lon, h = frame.enu_to_geodetic(pts)
    assert frame.geodetic_to_enu(lat, lon, h) == pytest.approx(pts, abs=1e-6)
    assert float(lat[1]) > 37.8813 and float(lon[1]) > 127.7298  # north and east of the origin


def test_ned_enu_swap() -> None:
    assert g.ned_to_enu([1.0, 2.0, 3.0]) == pytest.approx([2.0, 1.0, -3.0])
    assert g.enu_to_ned(g.ned_to_enu([1.0, 2.0, 3.0])) == pytest.approx([1.0, 2.0, 3.0])
    # a body-to-NED attitude expressed body-to-ENU rotates vectors to the swapped components
    q = g.q_from_euler_zyx(0.1, -0.2, 0.7)
    v = np.array([0.3, -1.0, 2.0])
    assert g.q_rotate(g.q_body_ned_to_body_enu(q), v) == pytest.approx(g.ned_to_enu(g.q_rotate(q, v)))


def test_quaternion_conventions() -> None:
    yaw90 = g.q_from_euler_zyx(0.0, 0.0, math.pi / 2)
    # body-to-world: the body x axis (nose) points east (NED y) after a 90 deg yaw
    assert g.q_rotate(yaw90, [1.0, 0.0, 0.0]) == pytest.approx([0.0, 1.0, 0.0], abs=1e-12)
    pitch_up = g.q_from_euler_zyx(0.0, math.radians(30), 0.0)
    nose = g.q_rotate(pitch_up, [1.0, 0.0, 0.0])
    assert nose[2] == pytest.approx(-0.5)  # nose up is -z in NED
    q = g.q_from_euler_zyx(0.3, -0.4, 2.5)
    assert g.q_multiply(q, g.q_conjugate(q)) == pytest.approx([1, 0, 0, 0], abs=1e-12)
    # ZYX composition: q = qz * qy * qx
    qz = g.q_from_euler_zyx(0.0, 0.0, 2.5)
    qy = g.q_from_euler_zyx(0.0, -0.4, 0.0)
    qx = g.q_from_euler_zyx(0.3, 0.0, 0.0)
    assert g.q_multiply(qz, g.q_multiply(qy, qx)) == pytest.approx(q)
    roll, pitch, yaw = g.q_to_euler_zyx(q)
    assert (float(roll), float(pitch), float(yaw)) == pytest.approx((0.3, -0.4, 2.5))


def test_matrix_round_trip_and_rotation_agree() -> None:
    rng = np.random.default_rng(2)
    q = g.q_normalize(rng.normal(size=(500, 4)))
    q = np.where(q[:, :1] < 0, -q, q)
    m = g.q_to_matrix(q)
    assert g.q_from_matrix(m) == pytest.approx(q, abs=1e-12)
    v = rng.normal(size=(500, 3))
    assert np.einsum("nij,nj->ni", m, v) == pytest.approx(g.q_rotate(q, v), abs=1e-12)


def test_slerp_midpoint_and_ends() -> None:
    a = g.q_from_euler_zyx(0.0, 0.0, 0.0)
    b = g.q_from_euler_zyx(0.0, 0.0, 1.0)
    assert g.q_slerp(a, b, 0.5) == pytest.approx(g.q_from_euler_zyx(0.0, 0.0, 0.5))
    assert g.q_slerp(a, -b, 0.5) == pytest.approx(g.q_from_euler_zyx(0.0, 0.0, 0.5))  # shorter arc
    assert g.q_slerp(a, b, np.array([0.0, 1.0])) == pytest.approx(np.stack([a, b]))


def test_body_rates_from_quaternion_derivative() -> None:
    # constant yaw rate 0.5 rad/s about the body z axis, seen with a 20 deg roll
    def q_at(t: float) -> np.ndarray:
        return g.q_multiply(g.q_from_euler_zyx(0.0, 0.0, 0.5 * t), g.q_from_euler_zyx(0.35, 0.0, 0.0))

    h = 1e-5
    q = q_at(1.0)
    rates = g.body_rates_from_quaternions(q, (q_at(1.0 + h) - q_at(1.0 - h)) / (2 * h))
    expected = g.q_rotate(g.q_conjugate(q), [0.0, 0.0, 0.5])  # world z rate in body axes
    assert rates == pytest.approx(expected, abs=1e-8)


@pytest.mark.parametrize("seed", range(20))
def test_one_vector_paths_equal_the_array_paths(seed: int) -> None:
    """The `math` paths for one vector (the geotagger's) give what the numpy paths give for a batch of one."""
    rng = np.random.default_rng(seed)
    lat, lon, h = float(rng.uniform(-80, 80)), float(rng.uniform(-180, 180)), float(rng.uniform(-100, 3000))
    frame = g.LocalFrame(lat + 0.01, lon - 0.01, h + 5.0)
    q0, q1 = rng.normal(size=4), rng.normal(size=4)
    v, t = rng.normal(size=3) * 10.0, float(rng.uniform(0, 1))
    ecef = g.geodetic_to_ecef(lat, lon, h)
    assert np.allclose(ecef, g.geodetic_to_ecef([lat], [lon], [h])[0], rtol=0, atol=1e-8)
    assert np.allclose(g.ecef_to_geodetic(ecef), [x[0] for x in g.ecef_to_geodetic(ecef[None, :])], rtol=0, atol=1e-9)
    enu = frame.geodetic_to_enu(lat, lon, h)
    assert np.allclose(enu, frame.ecef_to_enu(ecef[None, :])[0], rtol=0, atol=1e-8)
    assert np.allclose(frame.enu_to_ecef(tuple(enu)), frame.enu_to_ecef(enu[None, :])[0], rtol=0, atol=1e-8)
    assert np.allclose(g.q_normalize(q0), g.q_normalize(q0[None, :])[0], atol=1e-15)
    assert np.allclose(g.q_multiply(q0, q1), g.q_multiply(q0[None, :], q1[None, :])[0], atol=1e-12)
    qn = g.q_normalize(q0)
    assert np.allclose(g.q_rotate(qn, v), g.q_rotate(qn[None, :], v[None, :])[0], atol=1e-12)
    assert np.allclose(g.q_slerp(q0, q1, t), g.q_slerp(q0[None, :], q1[None, :], np.array([t]))[0], atol=1e-12)
    near = qn + 1e-12  # the small-angle branch
    assert np.allclose(g.q_slerp(qn, near, t), g.q_slerp(qn[None, :], near[None, :], np.array([t]))[0], atol=1e-12)


def test_conversions_agree_with_proj() -> None:
    """WGS84 geodetic <-> ECEF, one point and arrays, against PROJ (through rasterio, EPSG:4979 -> EPSG:4978)."""
    from rasterio.crs import CRS
    from rasterio.warp import transform

    rng = np.random.default_rng(7)
    lat, lon, h = rng.uniform(-85, 85, 50), rng.uniform(-180, 180, 50), rng.uniform(-400, 9000, 50)
    x, y, z = transform(CRS.from_epsg(4979), CRS.from_epsg(4978), lon.tolist(), lat.tolist(), zs=h.tolist())
    proj = np.c_[x, y, z]
    assert np.abs(g.geodetic_to_ecef(lat, lon, h) - proj).max() < 1e-6  # [m]
    one = np.array([g.geodetic_to_ecef(float(a), float(b), float(c)) for a, b, c in zip(lat, lon, h, strict=True)])
    assert np.abs(one - proj).max() < 1e-6
    back = np.column_stack(g.ecef_to_geodetic(proj))
    assert np.abs(back[:, :2] - np.c_[lat, lon]).max() < 1e-9 and np.abs(back[:, 2] - h).max() < 1e-6  # [deg], [m]
    for i in range(len(lat)):
        p_lat, p_lon, p_h = g.ecef_to_geodetic(tuple(proj[i]))
        assert abs(p_lat - lat[i]) < 1e-9 and abs(p_lon - lon[i]) < 1e-9 and abs(p_h - h[i]) < 1e-6
