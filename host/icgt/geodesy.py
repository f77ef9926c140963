"""WGS84 geodesy and rotations for the simulator (numpy, vectorised, no external geodesy library).

Conventions used everywhere in `icgt.sim`:

- Geodetic coordinates: latitude and longitude in degrees, height in metres above the WGS84
  ellipsoid (`h_m`). Heights above mean sea level (MSL, what MAVLink `alt` fields carry) are
  `h_m - geoid_separation_m`.
- ECEF: Earth-centred, Earth-fixed Cartesian coordinates in metres.
- ENU: a local tangent frame at an origin: x east, y north, z up, metres.
- NED: x north, y east, z down. `ned_to_enu` and `enu_to_ned` swap the first two axes and
  negate the third (the same operation both ways).
- Quaternions: Hamilton convention, scalar first `(w, x, y, z)`, arrays of shape `(..., 4)`.
  A quaternion `q` "body to world" rotates a vector given in body axes into world axes:
  `v_world = q * v_body * conj(q)` (`rotate(q, v_body)`). This is how MAVLink reports
  ATTITUDE_QUATERNION (body FRD to NED) and camera attitude (camera to NED).
- Euler angles ZYX (yaw, then pitch, then roll, intrinsic), radians:
  `q = qz(yaw) * qy(pitch) * qx(roll)`, as MAVLink ATTITUDE reports them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

WGS84_A_M = 6_378_137.0
"""Semi-major axis [m]."""
WGS84_F = 1.0 / 298.257223563
"""Flattening."""
WGS84_B_M = WGS84_A_M * (1.0 - WGS84_F)
"""Semi-minor axis [m]."""
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)
"""First eccentricity squared."""
WGS84_EP2 = (WGS84_A_M**2 - WGS84_B_M**2) / WGS84_B_M**2
"""Second eccentricity squared."""


def _arr(x: Any) -> FloatArray:
    return np.asarray(x, dtype=np.float64)


_SCALAR_TYPES = (float, int, np.floating, np.integer)


def _small(x: Any, n: int) -> tuple[float, ...] | None:
    """`x` as n floats when it is one vector (a tuple, a list or an array of shape (n,)), else None.

    The functions below take arrays of any shape; for one vector (the recorder's geotagger, one frame at
    a time) numpy's overhead per call (microseconds) is far more than the arithmetic, so they compute
    it with `math` instead: the same formulas, equal results to rounding (tested against the arrays).
    """
    if isinstance(x, np.ndarray):
        return tuple(x.tolist()) if x.shape == (n,) and x.dtype.kind in "fiu" else None
    if isinstance(x, tuple | list) and len(x) == n and all(isinstance(c, _SCALAR_TYPES) for c in x):
        return tuple(float(c) for c in x)
    return None


class _Ops(NamedTuple):
    """The functions the closed forms below need, from `math` (one point) or numpy (arrays)."""

    sin: Callable[[Any], Any]
    cos: Callable[[Any], Any]
    sqrt: Callable[[Any], Any]
    cbrt: Callable[[Any], Any]
    hypot: Callable[[Any, Any], Any]
    atan2: Callable[[Any, Any], Any]
    maximum: Callable[[Any, Any], Any]
    radians: Callable[[Any], Any]
    degrees: Callable[[Any], Any]


_MATH = _Ops(math.sin, math.cos, math.sqrt, math.cbrt, math.hypot, math.atan2, max, math.radians, math.degrees)
_NUMPY = _Ops(np.sin, np.cos, np.sqrt, np.cbrt, np.hypot, np.arctan2, np.maximum, np.radians, np.degrees)


def _ecef_of(lat_deg: Any, lon_deg: Any, h_m: Any, ops: _Ops) -> tuple[Any, Any, Any]:
    """X = (N + h) cos(lat) cos(lon), Y = (N + h) cos(lat) sin(lon), Z = (N (1 - e^2) + h) sin(lat),
    with N = a / sqrt(1 - e^2 sin^2(lat)) the prime vertical radius of curvature."""
    lat, lon = ops.radians(lat_deg), ops.radians(lon_deg)
    sin_lat, cos_lat = ops.sin(lat), ops.cos(lat)
    n = WGS84_A_M / ops.sqrt(1.0 - WGS84_E2 * sin_lat**2)
    return (
        (n + h_m) * cos_lat * ops.cos(lon),
        (n + h_m) * cos_lat * ops.sin(lon),
        (n * (1.0 - WGS84_E2) + h_m) * sin_lat,
    )


def _geodetic_of(x: Any, y: Any, z: Any, ops: _Ops) -> tuple[Any, Any, Any]:
    """Closed form (Heikkinen 1982), exact to well below a millimetre near the Earth's surface; no iteration."""
    a, b, e2 = WGS84_A_M, WGS84_B_M, WGS84_E2
    p = ops.hypot(x, y)
    f_term = 54.0 * b**2 * z**2
    g = p**2 + (1.0 - e2) * z**2 - e2 * (a**2 - b**2)
    c = e2**2 * f_term * p**2 / g**3
    s = ops.cbrt(1.0 + c + ops.sqrt(c**2 + 2.0 * c))
    k = s + 1.0 + 1.0 / s
    big_p = f_term / (3.0 * k**2 * g**2)
    q = ops.sqrt(1.0 + 2.0 * e2**2 * big_p)
    r0_sq = 0.5 * a**2 * (1.0 + 1.0 / q) - big_p * (1.0 - e2) * z**2 / (q * (1.0 + q)) - 0.5 * big_p * p**2
    r0 = -big_p * e2 * p / (1.0 + q) + ops.sqrt(ops.maximum(r0_sq, 0.0))
    u = ops.sqrt((p - e2 * r0) ** 2 + z**2)
    v = ops.sqrt((p - e2 * r0) ** 2 + (1.0 - e2) * z**2)
    z0 = b**2 * z / (a * v)
    h = u * (1.0 - b**2 / (a * v))
    return ops.degrees(ops.atan2(z + WGS84_EP2 * z0, p)), ops.degrees(ops.atan2(y, x)), h


def geodetic_to_ecef_point(lat_deg: float, lon_deg: float, h_m: float) -> tuple[float, float, float]:
    """`geodetic_to_ecef` of one point, as plain floats [m]."""
    x, y, z = _ecef_of(float(lat_deg), float(lon_deg), float(h_m), _MATH)
    return x, y, z


def q_multiply_tuple(p: Sequence[float], q: Sequence[float]) -> tuple[float, float, float, float]:
    """`q_multiply` of two quaternions given as 4 floats (w first), as plain floats."""
    return _q_product(p[0], p[1], p[2], p[3], q[0], q[1], q[2], q[3])


def _q_product(pw: Any, px: Any, py: Any, pz: Any, qw: Any, qx: Any, qy: Any, qz: Any) -> tuple[Any, Any, Any, Any]:
    """The Hamilton product's components (floats or arrays alike)."""
    return (
        pw * qw - px * qx - py * qy - pz * qz,
        pw * qx + px * qw + py * qz - pz * qy,
        pw * qy - px * qz + py * qw + pz * qx,
        pw * qz + px * qy - py * qx + pz * qw,
    )


def _q_normalize1(q: tuple[float, ...]) -> tuple[float, ...]:
    norm = math.sqrt(sum(c * c for c in q))
    return tuple(c / norm for c in q)


def _cross1(a: tuple[float, ...], b: tuple[float, ...]) -> tuple[float, float, float]:
    return a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]


# --- WGS84 <-> ECEF -------------------------------------------------------------------------


def geodetic_to_ecef(lat_deg: Any, lon_deg: Any, h_m: Any) -> FloatArray:
    """Geodetic (lat [deg], lon [deg], ellipsoidal height [m]) to ECEF [m], shape (..., 3) (see `_ecef_of`)."""
    if isinstance(lat_deg, _SCALAR_TYPES) and isinstance(lon_deg, _SCALAR_TYPES) and isinstance(h_m, _SCALAR_TYPES):
        return np.array(geodetic_to_ecef_point(float(lat_deg), float(lon_deg), float(h_m)), dtype=np.float64)
    x, y, z = _ecef_of(_arr(lat_deg), _arr(lon_deg), _arr(h_m), _NUMPY)
    return np.stack(np.broadcast_arrays(x, y, z), axis=-1)


def ecef_to_geodetic(ecef_m: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF [m] (..., 3) to (lat [deg], lon [deg], ellipsoidal height [m]) (see `_geodetic_of`)."""
    one = _small(ecef_m, 3)
    if one is not None:
        lat1, lon1, h1 = _geodetic_of(one[0], one[1], one[2], _MATH)
        return np.float64(lat1), np.float64(lon1), np.float64(h1)  # type: ignore[return-value]
    p_ecef = _arr(ecef_m)
    lat, lon, h = _geodetic_of(p_ecef[..., 0], p_ecef[..., 1], p_ecef[..., 2], _NUMPY)
    return lat, lon, h


# --- ECEF <-> local ENU ---------------------------------------------------------------------


def ecef_to_enu_matrix(lat0_deg: float, lon0_deg: float) -> FloatArray:
    """Rotation matrix (3, 3) taking ECEF vector components to ENU at (lat0, lon0): rows e, n, u."""
    lat = np.radians(lat0_deg)
    lon = np.radians(lon0_deg)
    sl, cl = np.sin(lat), np.cos(lat)
    so, co = np.sin(lon), np.cos(lon)
    return np.array(
        [
            [-so, co, 0.0],
            [-sl * co, -sl * so, cl],
            [cl * co, cl * so, sl],
        ]
    )


class LocalFrame:
    """A local ENU tangent frame at a WGS84 origin (lat [deg], lon [deg], ellipsoidal height [m])."""

    def __init__(self, lat0_deg: float, lon0_deg: float, h0_m: float) -> None:
        self.lat0_deg = lat0_deg
        self.lon0_deg = lon0_deg
        self.h0_m = h0_m
        self.origin_ecef_m = geodetic_to_ecef(lat0_deg, lon0_deg, h0_m)
        self.r_ecef_to_enu = ecef_to_enu_matrix(lat0_deg, lon0_deg)
        # For one point at a time (see _small): the origin and the matrix's rows as plain floats.
        self._origin1 = geodetic_to_ecef_point(lat0_deg, lon0_deg, h0_m)
        self._rows1 = tuple(tuple(row) for row in self.r_ecef_to_enu.tolist())

    def ecef_to_enu(self, ecef_m: Any) -> FloatArray:
        """ECEF [m] (..., 3) to ENU [m] (..., 3)."""
        one = _small(ecef_m, 3)
        if one is not None:
            return np.array(self._enu_of_ecef_point(one))
        d = _arr(ecef_m) - self.origin_ecef_m
        out: FloatArray = d @ self.r_ecef_to_enu.T
        return out

    def enu_to_ecef(self, enu_m: Any) -> FloatArray:
        """ENU [m] (..., 3) to ECEF [m] (..., 3)."""
        one = _small(enu_m, 3)
        if one is not None:
            rows = self._rows1
            return np.array([sum(one[i] * rows[i][j] for i in range(3)) + self._origin1[j] for j in range(3)])
        out: FloatArray = _arr(enu_m) @ self.r_ecef_to_enu + self.origin_ecef_m
        return out

    def enu_to_geodetic(self, enu_m: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
        """ENU [m] (..., 3) to (lat [deg], lon [deg], ellipsoidal height [m])."""
        return ecef_to_geodetic(self.enu_to_ecef(enu_m))

    def _enu_of_ecef_point(self, ecef: Sequence[float]) -> tuple[float, float, float]:
        dx, dy, dz = (c - o for c, o in zip(ecef, self._origin1, strict=True))
        e, n, u = (r[0] * dx + r[1] * dy + r[2] * dz for r in self._rows1)
        return e, n, u

    def geodetic_to_enu_point(self, lat_deg: float, lon_deg: float, h_m: float) -> tuple[float, float, float]:
        """`geodetic_to_enu` of one point, as plain floats [m]."""
        return self._enu_of_ecef_point(geodetic_to_ecef_point(lat_deg, lon_deg, h_m))

    def geodetic_to_enu(self, lat_deg: Any, lon_deg: Any, h_m: Any) -> FloatArray:
        """(lat [deg], lon [deg], ellipsoidal height [m]) to ENU [m] (..., 3)."""
        return self.ecef_to_enu(geodetic_to_ecef(lat_deg, lon_deg, h_m))


# --- NED <-> ENU ----------------------------------------------------------------------------


def ned_to_enu(v: Any) -> FloatArray:
    """Vector components NED -> ENU (..., 3): (n, e, d) -> (e, n, -d)."""
    a = _arr(v)
    return np.stack([a[..., 1], a[..., 0], -a[..., 2]], axis=-1)


def enu_to_ned(v: Any) -> FloatArray:
    """Vector components ENU -> NED (..., 3): (e, n, u) -> (n, e, -u)."""
    return ned_to_enu(v)


Q_NED_TO_ENU: FloatArray = np.array([0.0, np.sqrt(0.5), np.sqrt(0.5), 0.0])
"""Rotation taking NED components to ENU components (180 deg about the (1, 1, 0) axis)."""


def q_body_ned_to_body_enu(q_ned: Any) -> FloatArray:
    """A body-to-NED quaternion as the body-to-ENU quaternion of the same attitude."""
    return q_multiply(Q_NED_TO_ENU, q_ned)


# --- quaternions ----------------------------------------------------------------------------


def q_normalize(q: Any) -> FloatArray:
    """Unit quaternion(s) (..., 4), sign kept."""
    one = _small(q, 4)
    if one is not None:
        return np.array(_q_normalize1(one))
    a = _arr(q)
    out: FloatArray = a / np.linalg.norm(a, axis=-1, keepdims=True)
    return out


def q_multiply(p: Any, q: Any) -> FloatArray:
    """Hamilton product p * q (..., 4), w first: rotating by q, then by p."""
    p1, q1 = _small(p, 4), _small(q, 4)
    if p1 is not None and q1 is not None:
        return np.array(q_multiply_tuple(p1, q1))
    a, b = np.broadcast_arrays(_arr(p), _arr(q))
    return np.stack(_q_product(*(a[..., i] for i in range(4)), *(b[..., i] for i in range(4))), axis=-1)


def q_conjugate(q: Any) -> FloatArray:
    """Conjugate (the inverse of a unit quaternion): (w, -x, -y, -z)."""
    a = _arr(q)
    return np.concatenate([a[..., :1], -a[..., 1:]], axis=-1)


def q_rotate(q: Any, v: Any) -> FloatArray:
    """Rotate vector(s) v (..., 3) by unit quaternion(s) q: q * (0, v) * conj(q), vector part."""
    q1, v1 = _small(q, 4), _small(v, 3)
    if q1 is not None and v1 is not None:
        u1 = q1[1:]
        t1 = tuple(2.0 * c for c in _cross1(u1, v1))
        c1 = _cross1(u1, t1)
        return np.array([v1[i] + q1[0] * t1[i] + c1[i] for i in range(3)])
    qa = _arr(q)
    va = _arr(v)
    w = qa[..., :1]
    u = qa[..., 1:]
    t = 2.0 * np.cross(u, va)
    out: FloatArray = va + w * t + np.cross(u, t)
    return out


def q_from_euler_zyx(roll_rad: Any, pitch_rad: Any, yaw_rad: Any) -> FloatArray:
    """Quaternion qz(yaw) * qy(pitch) * qx(roll) (body to world), angles in radians."""
    hr, hp, hy = _arr(roll_rad) / 2.0, _arr(pitch_rad) / 2.0, _arr(yaw_rad) / 2.0
    cr, sr = np.cos(hr), np.sin(hr)
    cp, sp = np.cos(hp), np.sin(hp)
    cy, sy = np.cos(hy), np.sin(hy)
    return np.stack(
        np.broadcast_arrays(
            cy * cp * cr + sy * sp * sr,
            cy * cp * sr - sy * sp * cr,
            cy * sp * cr + sy * cp * sr,
            sy * cp * cr - cy * sp * sr,
        ),
        axis=-1,
    )


def q_to_euler_zyx(q: Any) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(roll, pitch, yaw) [rad] of unit quaternion(s); yaw in (-pi, pi], pitch in [-pi/2, pi/2]."""
    a = _arr(q)
    w, x, y, z = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


def q_to_matrix(q: Any) -> FloatArray:
    """Rotation matrix (..., 3, 3) of unit quaternion(s): columns are the body axes in world axes."""
    a = _arr(q)
    w, x, y, z = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    m = np.empty((*a.shape[:-1], 3, 3))
    m[..., 0, 0] = 1 - 2 * (y * y + z * z)
    m[..., 0, 1] = 2 * (x * y - w * z)
    m[..., 0, 2] = 2 * (x * z + w * y)
    m[..., 1, 0] = 2 * (x * y + w * z)
    m[..., 1, 1] = 1 - 2 * (x * x + z * z)
    m[..., 1, 2] = 2 * (y * z - w * x)
    m[..., 2, 0] = 2 * (x * z - w * y)
    m[..., 2, 1] = 2 * (y * z + w * x)
    m[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return m


def q_from_matrix(m: Any) -> FloatArray:
    """Unit quaternion(s) (..., 4) with w >= 0 of rotation matrix(-ces) (..., 3, 3).

    Picks, per matrix, the numerically largest of w, x, y, z to divide by (Shepperd's method).
    """
    r = _arr(m)
    m00, m11, m22 = r[..., 0, 0], r[..., 1, 1], r[..., 2, 2]
    trace = m00 + m11 + m22
    cand = np.stack([trace, m00, m11, m22], axis=-1)
    choice = np.argmax(cand, axis=-1)
    q = np.empty((*r.shape[:-2], 4))
    # w largest
    s = np.sqrt(np.maximum(1.0 + trace, 1e-300)) * 2.0
    qw = np.stack(
        [
            0.25 * s,
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 1, 0] - r[..., 0, 1]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1.0 + m00 - m11 - m22, 1e-300)) * 2.0
    qx = np.stack(
        [
            (r[..., 2, 1] - r[..., 1, 2]) / s,
            0.25 * s,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1.0 - m00 + m11 - m22, 1e-300)) * 2.0
    qy = np.stack(
        [
            (r[..., 0, 2] - r[..., 2, 0]) / s,
            (r[..., 0, 1] + r[..., 1, 0]) / s,
            0.25 * s,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
        ],
        axis=-1,
    )
    s = np.sqrt(np.maximum(1.0 - m00 - m11 + m22, 1e-300)) * 2.0
    qz = np.stack(
        [
            (r[..., 1, 0] - r[..., 0, 1]) / s,
            (r[..., 0, 2] + r[..., 2, 0]) / s,
            (r[..., 1, 2] + r[..., 2, 1]) / s,
            0.25 * s,
        ],
        axis=-1,
    )
    sel = choice[..., None]
    q = np.where(sel == 0, qw, np.where(sel == 1, qx, np.where(sel == 2, qy, qz)))
    q = np.where(q[..., :1] < 0.0, -q, q)
    return q_normalize(q)


def q_slerp(q0: Any, q1: Any, t: Any) -> FloatArray:
    """Spherical linear interpolation from q0 (t = 0) to q1 (t = 1) along the shorter arc."""
    a1, b1 = _small(q0, 4), _small(q1, 4)
    if a1 is not None and b1 is not None and isinstance(t, _SCALAR_TYPES):
        return np.array(_q_slerp1(_q_normalize1(a1), _q_normalize1(b1), float(t)))
    a = q_normalize(q0)
    b = q_normalize(q1)
    tt = _arr(t)[..., None]
    dot = np.sum(a * b, axis=-1, keepdims=True)
    b = np.where(dot < 0.0, -b, b)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_theta = np.sin(theta)
    small = sin_theta < 1e-9
    safe = np.where(small, 1.0, sin_theta)
    w0 = np.where(small, 1.0 - tt, np.sin((1.0 - tt) * theta) / safe)
    w1 = np.where(small, tt, np.sin(tt * theta) / safe)
    return q_normalize(w0 * a + w1 * b)


def body_rates_from_quaternions(q: Any, q_dot: Any) -> FloatArray:
    """Angular rate in body axes [rad/s] from a body-to-world quaternion and its time derivative.

    omega_body = 2 * conj(q) * q_dot (vector part).
    """
    out: FloatArray = 2.0 * q_multiply(q_conjugate(q), q_dot)[..., 1:]
    return out


def _q_slerp1(a: tuple[float, ...], b: tuple[float, ...], t: float) -> tuple[float, ...]:
    """`q_slerp` of two unit quaternions, in `math` (the same steps)."""
    dot = sum(x * y for x, y in zip(a, b, strict=True))
    if dot < 0.0:
        b = tuple(-c for c in b)
    theta = math.acos(min(max(abs(dot), -1.0), 1.0))
    sin_theta = math.sin(theta)
    if sin_theta < 1e-9:
        w0, w1 = 1.0 - t, t
    else:
        w0, w1 = math.sin((1.0 - t) * theta) / sin_theta, math.sin(t * theta) / sin_theta
    return _q_normalize1(tuple(w0 * x + w1 * y for x, y in zip(a, b, strict=True)))
