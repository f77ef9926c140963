"""Per-frame geometry: camera angles, footprints, pixel -> world on the frame's surface, crack length.

Conventions and the surfaces a pixel is projected on: `icgt.geometry`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from icgt.geodesy import (
    FloatArray,
    LocalFrame,
    ecef_to_geodetic,
    geodetic_to_ecef,
    q_conjugate,
    q_multiply,
    q_to_euler_zyx,
    q_to_matrix,
)
from icgt.geometry.camera import CameraModel, GeometryError, SurfaceSource
from icgt.geometry.planes import Plane, plane_axes
from icgt.geotag.record import FrameRecord
from icgt.pose import Q_OPTICAL_TO_FRD, R_NED_TO_ENU

# --- per-frame geometry ---------------------------------------------------------------------


@dataclass(frozen=True)
class WorldPoints:
    """Points on the surface: ENU [m] (N, 3) and WGS84 (None when the frame has no geodetic anchor).

    Rows are NaN where the ray missed the surface (it points away from it or beyond the horizon).
    `alt_m` is above mean sea level, like the records' alt_msl_m.
    """

    enu: FloatArray
    lat_deg: FloatArray | None
    lon_deg: FloatArray | None
    alt_m: FloatArray | None
    plane_st: FloatArray
    """Map coordinates on the surface (N, 2) [m]: see plane_axes."""
    surface: SurfaceSource


@dataclass(frozen=True)
class FrameSolution:
    """Everything the exports need about one frame, computed once."""

    frame_seq: int
    surface: SurfaceSource
    plane: Plane
    camera_enu: FloatArray
    scale_mm_per_px: float
    """Surface length of one pixel at the image centre, in the steeper direction (as the record's)."""
    scale_u_mm_per_px: float
    scale_v_mm_per_px: float
    incidence_deg: float
    centre: WorldPoints
    footprint: WorldPoints | None
    """The image outline on the surface (None if part of it misses the surface)."""
    footprint_area_m2: float | None
    camera_yaw_deg: float
    camera_pitch_deg: float
    camera_roll_deg: float


@dataclass(frozen=True)
class CrackOnMap:
    """A crack polyline placed on the surface."""

    points: WorldPoints
    length_mm: float
    """Exact: the sum of the 3D segment lengths between the ray-plane intersections."""
    length_mm_paper: float | None
    """The paper's estimate (eqs 5-7 with the LiDAR distance as depth; None without a range)."""
    midpoint_enu: FloatArray
    """The point half-way along the polyline on the surface [m]."""
    midpoint_wgs84: tuple[float, float, float] | None


def camera_angles_deg(rec: FrameRecord) -> tuple[float, float, float] | None:
    """(yaw, pitch, roll) [deg] of the camera, gimbal convention; None without a camera attitude.

    yaw: compass heading of the optical axis (0 north, 90 east, in [0, 360)); pitch: elevation of
    the optical axis (0 level, -90 looking straight down, +90 up); roll: rotation of the image about
    the optical axis (positive: clockwise as seen from behind the camera). These are Euler ZYX angles
    of the camera's FRD axes (x optical axis, y image right, z image down) relative to NED, the
    convention of DJI's gimbal angles and of ODM's geo.txt.
    """
    if rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None:
        return None
    yaw, pitch, roll = _camera_angles(np.array([[rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz]]))
    return float(yaw[0]), float(pitch[0]), float(roll[0])


def camera_angles_deg_many(recs: Sequence[FrameRecord]) -> list[tuple[float, float, float] | None]:
    """camera_angles_deg for many frames at once (vectorised)."""
    q = np.array(
        [
            (r.cam_qw, r.cam_qx, r.cam_qy, r.cam_qz) if _has_attitude(r) else (np.nan, np.nan, np.nan, np.nan)
            for r in recs
        ],
        dtype=np.float64,
    ).reshape(-1, 4)
    yaw, pitch, roll = _camera_angles(q)
    return [(float(yaw[i]), float(pitch[i]), float(roll[i])) if _has_attitude(r) else None for i, r in enumerate(recs)]


def _has_attitude(rec: FrameRecord) -> bool:
    return not (rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None)


def _camera_angles(q_cam_ned: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Vectorised camera_angles_deg for camera->NED quaternions (N, 4): (yaw, pitch, roll) [deg]."""
    q = q_cam_ned / np.linalg.norm(q_cam_ned, axis=-1, keepdims=True)
    r, p, y = q_to_euler_zyx(q_multiply(q, q_conjugate(Q_OPTICAL_TO_FRD)))
    return np.degrees(y) % 360.0, np.degrees(p), np.degrees(r)


def _position_missing(rec: FrameRecord) -> str | None:
    if rec.east_m is None or rec.north_m is None or rec.up_m is None:
        return "no position (no fix at exposure)"
    if rec.cam_qw is None or rec.cam_qx is None or rec.cam_qy is None or rec.cam_qz is None:
        return "no camera attitude"
    return None


@dataclass
class _Batch:
    """Poses and surfaces of N frames (rows of frames that cannot be solved are NaN)."""

    recs: list[FrameRecord]
    ok: np.ndarray  # (N,) bool
    reasons: list[str | None]
    c: FloatArray  # (N, 3) camera ENU
    r: FloatArray  # (N, 3, 3) camera -> ENU
    p0: FloatArray  # (N, 3) plane point
    n: FloatArray  # (N, 3) plane normal (towards the camera)
    source: list[SurfaceSource | None]
    anchor_geo: FloatArray  # (N, 3) lat, lon, alt of the frame (NaN unknown)
    q: FloatArray  # (N, 4) camera -> NED


class Projector:
    """Projects pixels of recorded frames onto the inspected surface.

    camera: the camera model. origin: the recording's ENU origin (lat [deg], lon [deg], alt MSL [m]),
    if known; else each frame's own lat/lon/alt anchors its WGS84 output (exact to well below a
    millimetre within a few kilometres of the origin). structure: the structure plane in the
    recording's ENU frame; surface_normal: only its orientation (ENU). anchor: "range" places the
    plane through the LiDAR return when the range is valid (module docstring), "structure" uses
    the structure plane as given.
    """

    def __init__(
        self,
        camera: CameraModel,
        *,
        origin: tuple[float, float, float] | LocalFrame | None = None,
        structure: Plane | None = None,
        surface_normal: Sequence[float] | None = None,
        anchor: Literal["range", "structure"] = "range",
        footprint_points_per_edge: int | None = None,
    ) -> None:
        self.camera = camera
        if isinstance(origin, LocalFrame):
            self.origin: LocalFrame | None = origin
        elif origin is not None:
            self.origin = LocalFrame(float(origin[0]), float(origin[1]), float(origin[2]))
        else:
            self.origin = None
        self.structure = structure
        normal = structure.normal if structure is not None else surface_normal
        self.normal: FloatArray | None = None
        if normal is not None:
            nv = np.asarray(normal, dtype=np.float64)
            if nv.shape != (3,) or not np.isfinite(nv).all() or float(np.linalg.norm(nv)) < 1e-12:
                raise GeometryError(f"surface normal {normal!r} is not a direction")
            self.normal = nv / np.linalg.norm(nv)
        if anchor not in ("range", "structure"):
            raise GeometryError(f"anchor must be 'range' or 'structure', not {anchor!r}")
        if anchor == "structure" and structure is None:
            raise GeometryError("anchor='structure' needs the structure plane")
        self.anchor = anchor
        self._r_boresight = camera.boresight_matrix()
        self._lever = np.asarray(camera.lever_arm_camera_m, dtype=np.float64)
        n_edge = (
            footprint_points_per_edge if footprint_points_per_edge is not None else (8 if camera.has_distortion else 0)
        )
        self._border = camera.border_pixels(n_edge)
        cu, cv = camera.centre_px
        probe = np.array([[cu, cv], [cu - 0.5, cv], [cu + 0.5, cv], [cu, cv - 0.5], [cu, cv + 0.5]])
        self._probe_rays = camera.rays(probe[:, 0], probe[:, 1])  # (5, 3)
        self._border_rays = camera.rays(self._border[:, 0], self._border[:, 1])  # (K, 3)

    # --- batch core
    def _batch(self, recs: Sequence[FrameRecord]) -> _Batch:
        n = len(recs)
        c = np.full((n, 3), np.nan)
        q = np.full((n, 4), np.nan)
        rng = np.full(n, np.nan)
        geo = np.full((n, 3), np.nan)
        reasons: list[str | None] = []
        for i, rec in enumerate(recs):
            why = _position_missing(rec)
            reasons.append(why)
            if why is None:
                c[i] = (rec.east_m, rec.north_m, rec.up_m)
                q[i] = (rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz)
            if rec.range_valid and rec.range_m is not None and math.isfinite(rec.range_m) and rec.range_m > 0:
                rng[i] = rec.range_m
            if rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None:
                geo[i] = (rec.lat_deg, rec.lon_deg, rec.alt_msl_m)
        ok = np.array([r is None for r in reasons], dtype=bool)
        qn = q / np.linalg.norm(q, axis=-1, keepdims=True)
        r_recorded = R_NED_TO_ENU @ q_to_matrix(qn)  # (N, 3, 3) recorded camera axes -> ENU
        c = c + r_recorded @ self._lever
        r = r_recorded @ self._r_boresight  # real camera axes -> ENU
        axis = r[:, :, 2]  # optical axis in ENU
        p0 = np.full((n, 3), np.nan)
        nrm = np.full((n, 3), np.nan)
        sources: list[SurfaceSource | None] = [None] * n
        has_range = np.isfinite(rng)
        hit = c + axis * np.where(has_range, rng, np.nan)[:, None]
        for i in range(n):
            if not ok[i]:
                continue
            src = self._choose(bool(has_range[i]))
            if src is None:
                reasons[i] = "no valid LiDAR range and no structure plane: the surface is unknown"
                continue
            if src is SurfaceSource.STRUCTURE:
                assert self.structure is not None
                p0[i], nrm[i] = self.structure.point, self.structure.normal
            elif not has_range[i]:
                reasons[i] = "no valid LiDAR range"
                continue
            elif src is SurfaceSource.NORMAL_AT_RANGE:
                assert self.normal is not None
                p0[i], nrm[i] = hit[i], self.normal
            else:
                p0[i], nrm[i] = hit[i], -axis[i]
            sources[i] = src
        # normals towards the camera: a consistent side for incidence and map axes
        side = np.einsum("ij,ij->i", c - p0, nrm)
        nrm = np.where((side < 0)[:, None], -nrm, nrm)
        ok = ok & np.array([s is not None for s in sources], dtype=bool)
        return _Batch(list(recs), ok, reasons, c, r, p0, nrm, sources, geo, qn)

    def _choose(self, has_range: bool) -> SurfaceSource | None:
        if self.anchor == "structure":
            return SurfaceSource.STRUCTURE
        if has_range:
            return SurfaceSource.NORMAL_AT_RANGE if self.normal is not None else SurfaceSource.PERPENDICULAR_AT_RANGE
        return SurfaceSource.STRUCTURE if self.structure is not None else None

    @staticmethod
    def _intersect(b: _Batch, rays_cam: FloatArray) -> FloatArray:
        """Ray-plane intersections (N, M, 3) for camera rays (M, 3) or (N, M, 3); NaN for misses."""
        d = np.einsum("nij,nmj->nmi", b.r, np.broadcast_to(rays_cam, (len(b.recs), *rays_cam.shape[-2:])))
        num = np.einsum("ni,ni->n", b.p0 - b.c, b.n)  # < 0: the camera is on the normal's side
        den = np.einsum("nmi,ni->nm", d, b.n)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = num[:, None] / den
        t = np.where((t > 0) & np.isfinite(t), t, np.nan)
        out: FloatArray = b.c[:, None, :] + d * t[..., None]
        return out

    def _to_wgs84(self, b: _Batch, pts: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray] | None:
        """(lat, lon, alt) arrays shaped like pts[..., 0]; None if no frame has a geodetic anchor."""
        if self.origin is not None:
            return self.origin.enu_to_geodetic(pts)
        if not np.isfinite(b.anchor_geo).any():
            return None
        # anchor each frame at its own lat/lon/alt: ECEF of the camera + the ENU offset rotated at the camera
        lat0, lon0, alt0 = b.anchor_geo[:, 0], b.anchor_geo[:, 1], b.anchor_geo[:, 2]
        cam_ecef = geodetic_to_ecef(lat0, lon0, alt0)  # (N, 3)
        rot = _enu_to_ecef_rows(lat0, lon0)  # (N, 3, 3): ENU -> ECEF
        off = pts - b.c[:, None, :]
        ecef = cam_ecef[:, None, :] + np.einsum("nij,nmj->nmi", rot, off)
        return ecef_to_geodetic(ecef)

    def _world(self, b: _Batch, pts: FloatArray, i: int | None = None) -> list[WorldPoints]:
        geo = self._to_wgs84(b, pts)
        s_axis, t_axis = plane_axes(b.n)
        st = np.stack([np.einsum("nmi,ni->nm", pts, s_axis), np.einsum("nmi,ni->nm", pts, t_axis)], axis=-1)
        out: list[WorldPoints] = []
        for k in range(len(b.recs)):
            src = b.source[k] or SurfaceSource.STRUCTURE
            if geo is None or (self.origin is None and not np.isfinite(b.anchor_geo[k]).all()):
                out.append(WorldPoints(pts[k], None, None, None, st[k], src))
            else:
                out.append(WorldPoints(pts[k], geo[0][k], geo[1][k], geo[2][k], st[k], src))
        return out

    # --- public API
    def solve_many(self, recs: Sequence[FrameRecord]) -> list[FrameSolution | GeometryError]:
        """Solve every frame at once (vectorised); a frame that cannot be solved gives its error."""
        if not recs:
            return []
        b = self._batch(recs)
        probe = self._intersect(b, self._probe_rays)  # (N, 5, 3)
        border = self._intersect(b, self._border_rays)  # (N, K, 3)
        centre_w = self._world(b, probe[:, :1, :])
        border_w = self._world(b, border)
        su = np.linalg.norm(probe[:, 2] - probe[:, 1], axis=-1) * 1000.0
        sv = np.linalg.norm(probe[:, 4] - probe[:, 3], axis=-1) * 1000.0
        axis = b.r[:, :, 2]
        cos_inc = np.abs(np.einsum("ni,ni->n", axis, b.n))
        inc = np.degrees(np.arccos(np.clip(cos_inc, 0.0, 1.0)))
        yaw, pitch, roll = _camera_angles(b.q)
        areas = _polygon_areas(border, b.n)
        out: list[FrameSolution | GeometryError] = []
        for i, rec in enumerate(recs):
            if not b.ok[i]:
                out.append(GeometryError(b.reasons[i] or "cannot be solved"))
                continue
            if not np.isfinite(probe[i, 0]).all():
                out.append(GeometryError("the optical axis does not meet the surface"))
                continue
            src = b.source[i]
            assert src is not None
            fp: WorldPoints | None = border_w[i]
            area: float | None = None
            if not np.isfinite(border[i]).all():
                fp = None
            else:
                area = float(areas[i])
            out.append(
                FrameSolution(
                    frame_seq=rec.frame_seq,
                    surface=src,
                    plane=Plane(_vec3(b.p0[i]), _vec3(b.n[i])),
                    camera_enu=b.c[i].copy(),
                    scale_mm_per_px=float(max(su[i], sv[i])),
                    scale_u_mm_per_px=float(su[i]),
                    scale_v_mm_per_px=float(sv[i]),
                    incidence_deg=float(inc[i]),
                    centre=centre_w[i],
                    footprint=fp,
                    footprint_area_m2=area,
                    camera_yaw_deg=float(yaw[i]),
                    camera_pitch_deg=float(pitch[i]),
                    camera_roll_deg=float(roll[i]),
                )
            )
        return out

    def solve(self, rec: FrameRecord) -> FrameSolution:
        """Scale, incidence, footprint and centre of one frame; raises GeometryError."""
        result = self.solve_many([rec])[0]
        if isinstance(result, GeometryError):
            raise result
        return result

    def _single(self, rec: FrameRecord) -> _Batch:
        b = self._batch([rec])
        if not b.ok[0]:
            raise GeometryError(f"frame {rec.frame_seq}: {b.reasons[0]}")
        return b

    def pixel_to_world(self, rec: FrameRecord, u: Any, v: Any) -> WorldPoints:
        """Pixels (scalars or arrays) of one frame -> points on the surface (ENU and WGS84).

        Undistorts, turns the pixel into a ray in camera axes, rotates it into ENU with the frame's
        camera attitude and intersects it with the frame's surface plane. Raises GeometryError if
        the frame has no pose or no surface; rays that miss the surface give NaN rows.
        """
        ua = np.atleast_1d(np.asarray(u, dtype=np.float64))
        va = np.atleast_1d(np.asarray(v, dtype=np.float64))
        b = self._single(rec)
        pts = self._intersect(b, self.camera.rays(ua, va))
        return self._world(b, pts)[0]

    def footprint(self, rec: FrameRecord) -> WorldPoints:
        """The image outline on the surface (clockwise on the image from the top-left corner)."""
        sol = self.solve(rec)
        if sol.footprint is None:
            raise GeometryError(f"frame {rec.frame_seq}: part of the image does not see the surface (horizon)")
        return sol.footprint

    def scale_mm_per_px(self, rec: FrameRecord) -> float:
        return self.solve(rec).scale_mm_per_px

    def incidence_deg(self, rec: FrameRecord) -> float:
        return self.solve(rec).incidence_deg

    def crack_length_mm(
        self, rec: FrameRecord, polyline_px: Any, *, method: Literal["ray_plane", "paper"] = "ray_plane"
    ) -> float:
        """Length on the surface [mm] of a crack given as a pixel polyline (M, 2).

        ``ray_plane`` (exact for a plane): every vertex is undistorted, cast as a ray and intersected
        with the frame's surface; the length is the sum of the 3D distances between consecutive
        intersections, so incidence and perspective are accounted for.

        ``paper``: the estimate of the ICGT paper. Its eq. 5 is the pinhole projection
        x ~ K [R | T] X; eq. 6 expresses each image's rotation relative to a baseline image,
        R_new = R_b^T R_i; eq. 7 inverts the projection, X = R^-1 (K^-1 x - t), which fixes the
        point only up to its depth. With the LiDAR distance D as that depth, every image point lies on
        the plane perpendicular to the optical axis at D, and a crack's length is D times its length
        in ideal normalised image coordinates: L = D * sum |(x_k+1, y_k+1) - (x_k, y_k)|. It ignores
        the incidence angle (too short by cos(incidence) along the tilt) and needs a valid range.
        """
        poly = _polyline(polyline_px)
        if method == "paper":
            if rec.range_m is None or not rec.range_valid:
                raise GeometryError(f"frame {rec.frame_seq}: the paper's method needs a valid LiDAR range")
            x, y = self.camera.pixel_to_normalized(poly[:, 0], poly[:, 1])
            return float(rec.range_m * np.sum(np.hypot(np.diff(x), np.diff(y))) * 1000.0)
        pts = self.pixel_to_world(rec, poly[:, 0], poly[:, 1]).enu
        if not np.isfinite(pts).all():
            raise GeometryError(f"frame {rec.frame_seq}: part of the crack does not project onto the surface")
        return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=-1)) * 1000.0)

    def crack_position(self, rec: FrameRecord, polyline_px: Any) -> CrackOnMap:
        """A crack polyline (M, 2) placed on the map: its points, its lengths and its midpoint."""
        poly = _polyline(polyline_px)
        b = self._single(rec)
        pts = self._intersect(b, self.camera.rays(poly[:, 0], poly[:, 1]))
        world = self._world(b, pts)[0]
        p = world.enu
        if not np.isfinite(p).all():
            raise GeometryError(f"frame {rec.frame_seq}: part of the crack does not project onto the surface")
        seg = np.linalg.norm(np.diff(p, axis=0), axis=-1)
        length = float(seg.sum())
        if length > 0:
            cum = np.concatenate([[0.0], np.cumsum(seg)])
            k = int(np.searchsorted(cum, length / 2.0, side="right") - 1)
            k = min(k, len(seg) - 1)
            f = (length / 2.0 - cum[k]) / seg[k] if seg[k] > 0 else 0.0
            mid = p[k] + (p[k + 1] - p[k]) * f
        else:
            mid = p[0]
        mid_geo = self._to_wgs84(b, mid[None, None, :])
        mid_wgs84 = None
        if mid_geo is not None and np.isfinite(mid_geo[0]).all():
            mid_wgs84 = (float(mid_geo[0][0, 0]), float(mid_geo[1][0, 0]), float(mid_geo[2][0, 0]))
        paper = None
        if rec.range_m is not None and rec.range_valid:
            paper = self.crack_length_mm(rec, poly, method="paper")
        return CrackOnMap(world, length * 1000.0, paper, mid, mid_wgs84)


def _vec3(a: FloatArray) -> tuple[float, float, float]:
    return (float(a[0]), float(a[1]), float(a[2]))


def _polyline(polyline_px: Any) -> FloatArray:
    poly = np.asarray(polyline_px, dtype=np.float64)
    if poly.ndim != 2 or poly.shape[1] != 2 or len(poly) < 2 or not np.isfinite(poly).all():
        raise GeometryError("a crack polyline is a sequence of at least two (u, v) pixel points")
    return poly


def _enu_to_ecef_rows(lat_deg: FloatArray, lon_deg: FloatArray) -> FloatArray:
    """Per-frame ENU -> ECEF rotation matrices (N, 3, 3) (transposes of ecef_to_enu_matrix)."""
    lat = np.radians(lat_deg)
    lon = np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    m = np.stack(
        [
            np.stack([-so, -sl * co, cl * co], axis=-1),
            np.stack([co, -sl * so, cl * so], axis=-1),
            np.stack([z, cl, sl], axis=-1),
        ],
        axis=-2,
    )
    return m


def _polygon_areas(pts: FloatArray, normal: FloatArray) -> FloatArray:
    """Areas [m^2] of planar polygons (N, K, 3) with normals (N, 3)."""
    rel = pts - pts[:, :1, :]
    nxt = np.roll(rel, -1, axis=1)
    cross = np.cross(rel, nxt).sum(axis=1)
    out: FloatArray = np.abs(np.einsum("ni,ni->n", cross, normal)) / 2.0
    return out


def origin_from_frames(frames: Iterable[FrameRecord]) -> LocalFrame | None:
    """The recording's ENU origin recovered from a frame carrying both lat/lon/alt and east/north/up.

    For logs that do not store it (metadata icgt.enu_origin). The origin O solves
    LocalFrame(O).geodetic_to_enu(frame's lat/lon/alt) = frame's east/north/up; a few fixed-point
    steps (shift O by the residual in its own ENU frame) converge to well below a millimetre.
    """
    for rec in frames:
        if None in (rec.lat_deg, rec.lon_deg, rec.alt_msl_m, rec.east_m, rec.north_m, rec.up_m):
            continue
        assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
        enu = np.array([rec.east_m, rec.north_m, rec.up_m], dtype=np.float64)
        lat, lon, h = LocalFrame(rec.lat_deg, rec.lon_deg, rec.alt_msl_m).enu_to_geodetic(-enu)
        origin = LocalFrame(float(lat), float(lon), float(h))
        for _ in range(6):
            residual = origin.geodetic_to_enu(rec.lat_deg, rec.lon_deg, rec.alt_msl_m) - enu
            if float(np.linalg.norm(residual)) < 1e-7:
                break
            lat, lon, h = origin.enu_to_geodetic(residual)
            origin = LocalFrame(float(lat), float(lon), float(h))
        return origin
    return None
