"""Merging detections of one defect seen in several images into one instance, and fusing their geometry.

Two cracks are the same crack when, in the face frame, they run along each other (at least half of
the shorter one, or 50 mm, lies within the tolerance of the other) or meet end to end (each has
an end within the tolerance of the other: the pieces of one crack cut by image or tile borders).
Two area defects of a kind are the same when their outlines, grown by the tolerance, overlap by
at least a third of the smaller. The tolerance is 3 sigma of the two detections' relative position
error (place.py) plus the crack widths, and not below `min_tolerance_mm`. Links are transitive
(union-find): a crack seen piecewise along a pass is one crack.

Fusion: a crack's centreline is the mean of its detections' points binned by arc length along the
longest detection (extended past its ends so pieces beyond it keep their place), smoothed over three
bins; its length is that centreline's, its width the median of the detections'. An area defect is the
median-area detection among those not touching their image border (else the union of all, flagged
truncated). Positions and lengths get sigma / sqrt(n) for the parts of the error that are
independent between images (attitude, range, pixels); the camera-position part is kept whole.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.strtree import STRtree

from icgt.geodesy import FloatArray
from icgt.mapping.model import CRACK, Instance, Placed
from icgt.mapping.surface import Face

STEP_M = 0.01
"""Resampling step along cracks [m]."""


class _UnionFind:
    def __init__(self, n: int) -> None:
        self.parent = list(range(n))

    def find(self, i: int) -> int:
        while self.parent[i] != i:
            self.parent[i] = self.parent[self.parent[i]]
            i = self.parent[i]
        return i

    def union(self, a: int, b: int) -> None:
        ra, rb = self.find(a), self.find(b)
        if ra != rb:
            self.parent[max(ra, rb)] = min(ra, rb)


def resample(line: FloatArray, step: float = STEP_M) -> FloatArray:
    seg = np.linalg.norm(np.diff(line, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    if cum[-1] <= 0:
        return line[:1].copy()
    n = max(2, math.ceil(cum[-1] / step) + 1)
    s = np.linspace(0.0, cum[-1], n)
    return np.stack([np.interp(s, cum, line[:, 0]), np.interp(s, cum, line[:, 1])], axis=1)


def _tolerance_m(a: Placed, b: Placed, min_tol_mm: float) -> float:
    width = max(a.width_mm or 0.0, b.width_mm or 0.0)
    return max(3.0 * math.hypot(a.sigma_pos_mm, b.sigma_pos_mm) + width, min_tol_mm) / 1000.0


def _cracks_linked(sa: np.ndarray, sb: np.ndarray, la: shapely.LineString, lb: shapely.LineString, tol: float) -> bool:
    near_a = shapely.distance(sa, lb) <= tol
    near_b = shapely.distance(sb, la) <= tol
    shorter = min(la.length, lb.length)
    along = max(near_a.sum(), near_b.sum()) * STEP_M
    if along >= min(0.5 * shorter, 0.05):
        return True
    return bool((near_a[0] or near_a[-1]) and (near_b[0] or near_b[-1]))


def _areas_linked(pa: shapely.Polygon, pb: shapely.Polygon, tol: float) -> bool:
    ga, gb = pa.buffer(tol), pb.buffer(tol)
    inter = ga.intersection(gb).area
    return bool(inter >= min(ga.area, gb.area) / 3.0)


def _geometry(p: Placed) -> shapely.Geometry:
    if p.det.kind == CRACK:
        return shapely.LineString(p.face)
    g = shapely.Polygon(p.face)
    return g if g.is_valid else shapely.make_valid(g)


def group(placed: Sequence[Placed], *, min_tolerance_mm: float = 10.0) -> list[list[int]]:
    """Indices of the detections of each defect (clusters), in order of their first detection."""
    geoms = [_geometry(p) for p in placed]
    samples = [shapely.points(resample(p.face)) if p.det.kind == CRACK else None for p in placed]
    uf = _UnionFind(len(placed))
    if placed:
        tree = STRtree(geoms)
        max_tol = max(_tolerance_m(p, p, min_tolerance_mm) for p in placed)
        left, right = tree.query(geoms, predicate="dwithin", distance=max_tol)
        for i, j in zip(left.tolist(), right.tolist(), strict=True):
            if j <= i or placed[i].det.kind != placed[j].det.kind or uf.find(i) == uf.find(j):
                continue  # (links are transitive: a pair already joined needs no test)
            tol = _tolerance_m(placed[i], placed[j], min_tolerance_mm)
            if placed[i].det.kind == CRACK:
                linked = _cracks_linked(samples[i], samples[j], geoms[i], geoms[j], tol)
            else:
                linked = _areas_linked(geoms[i], geoms[j], tol)
            if linked:
                uf.union(i, j)
    clusters: dict[int, list[int]] = {}
    for i in range(len(placed)):
        clusters.setdefault(uf.find(i), []).append(i)
    return list(clusters.values())


def _extended(line: shapely.LineString, by: float) -> tuple[shapely.LineString, float]:
    c = np.asarray(line.coords)
    d0 = c[0] - c[1]
    d1 = c[-1] - c[-2]
    d0 = d0 / max(float(np.linalg.norm(d0)), 1e-12)
    d1 = d1 / max(float(np.linalg.norm(d1)), 1e-12)
    return shapely.LineString(np.vstack([c[0] + d0 * by, c, c[-1] + d1 * by])), by


def fuse_crack(members: Sequence[Placed]) -> tuple[FloatArray, FloatArray]:
    """(fused centreline (M, 2) face [m], the matching ENU points (M, 3)).

    Stations every STEP_M along the longest detection (extended past its ends); at each station
    every detection that covers it is interpolated there by its own arc position, and the fused
    point is their mean (so the number of detections averaged changes only at their ends, and the
    line does not zigzag between them). The fused ends are the median of the detections' ends that
    are not cut by their image border (a misregistered detection would otherwise lengthen the
    crack by its offset); the extreme ends when every detection is cut there.
    """
    ref = max(members, key=lambda p: p.length_mm or 0.0)
    ext, by = _extended(shapely.LineString(ref.face), 2.0)
    tracks: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    lows: list[tuple[float, bool]] = []
    highs: list[tuple[float, bool]] = []
    for m in members:
        r = resample(m.face, STEP_M / 2.0)
        seg = np.linalg.norm(np.diff(m.face, axis=0), axis=1)
        cum = np.concatenate([[0.0], np.cumsum(seg)])
        s_r = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(r, axis=0), axis=1))])
        e = np.stack([np.interp(s_r, cum, m.enu[:, k]) for k in range(3)], axis=1)
        p = shapely.line_locate_point(ext, shapely.points(r)) - by
        cut_lo, cut_hi = m.cut_ends
        if p[-1] < p[0]:
            p, r, e = p[::-1], r[::-1], e[::-1]
            cut_lo, cut_hi = cut_hi, cut_lo
        order = np.argsort(p, kind="stable")
        p, r, e = p[order], r[order], e[order]
        tracks.append((p, r, e))
        lows.append((float(p[0]), cut_lo))
        highs.append((float(p[-1]), cut_hi))
    free_lo = [v for v, cut in lows if not cut]
    free_hi = [v for v, cut in highs if not cut]
    lo = float(np.median(free_lo)) if free_lo else min(v for v, _ in lows)
    hi = float(np.median(free_hi)) if free_hi else max(v for v, _ in highs)
    if hi <= lo:
        lo, hi = min(v for v, _ in lows), max(v for v, _ in highs)
    n = max(2, math.ceil((hi - lo) / STEP_M) + 1)
    stations = np.linspace(lo, hi, n)
    acc_st = np.zeros((n, 2))
    acc_e = np.zeros((n, 3))
    count = np.zeros(n)
    for p, r, e in tracks:
        covered = (stations >= p[0]) & (stations <= p[-1])
        if len(p) < 2 or not covered.any():
            continue
        x = stations[covered]
        acc_st[covered] += np.stack([np.interp(x, p, r[:, k]) for k in range(2)], axis=1)
        acc_e[covered] += np.stack([np.interp(x, p, e[:, k]) for k in range(3)], axis=1)
        count[covered] += 1
    # stations beyond every detection (the median end of a detection that lies past the others):
    # carry the nearest covered station's point along the line
    ok = count > 0
    if not ok.any():
        longest = max(tracks, key=lambda t: t[0][-1] - t[0][0])
        return longest[1], longest[2]
    mean_st = acc_st[ok] / count[ok, None]
    mean_e = acc_e[ok] / count[ok, None]
    return mean_st, mean_e


def build_instances(
    placed: Sequence[Placed], surface: Face, errors_position_mm: float, *, min_tolerance_mm: float = 10.0
) -> list[Instance]:
    """Merge and fuse (module docstring); instance ids C1.. for cracks, S1.. for spalling, D1.. others."""
    out: list[Instance] = []
    counters: dict[str, int] = {}
    for cluster in group(placed, min_tolerance_mm=min_tolerance_mm):
        members = [placed[i] for i in cluster]
        kind = members[0].det.kind
        n = len({m.det.image for m in members})
        indep = [math.sqrt(max(m.sigma_pos_mm**2 - errors_position_mm**2, 0.0)) for m in members]
        sigma_pos = math.sqrt(errors_position_mm**2 + (float(np.median(indep)) ** 2) / n)
        prefix = "C" if kind == CRACK else ("S" if kind == "spalling" else "D")
        counters[prefix] = counters.get(prefix, 0) + 1
        iid = f"{prefix}{counters[prefix]}"
        truncated = all(m.truncated for m in members)
        if kind == CRACK:
            face, enu = fuse_crack(members)
            # along the face: the detections' points scatter along the normal by each image's range
            # error (each image has its own plane through its LiDAR return), which is no length
            length = float(np.sum(np.linalg.norm(np.diff(face, axis=0), axis=1)) * 1000.0)
            widths = [m.width_mm for m in members if m.width_mm is not None]
            sig = [m.sigma_len_mm for m in members if m.sigma_len_mm is not None]
            out.append(
                Instance(
                    iid, kind, face, enu, length, float(np.median(widths)) if widths else None, None,
                    sigma_pos, float(np.median(sig)) / math.sqrt(n) if sig else None, members, truncated,
                )
            )  # fmt: skip
            continue
        complete = [m for m in members if not m.truncated]
        if complete:
            complete.sort(key=lambda m: m.area_mm2 or 0.0)
            best = complete[len(complete) // 2]
            face, enu, area = best.face, best.enu, best.area_mm2
        else:
            union = shapely.union_all([_geometry(m) for m in members])
            poly = max(union.geoms, key=lambda g: g.area) if hasattr(union, "geoms") else union
            face = np.asarray(poly.exterior.coords)[:-1]
            area = float(union.area) * 1e6
            enu = surface.to_enu(face)
        out.append(Instance(iid, kind, face, enu, None, None, area, sigma_pos, None, members, truncated))
    return out
