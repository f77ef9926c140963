"""Merging detections of one defect seen in several images into one instance, and fusing their geometry.

Two cracks are the same crack when, in the face frame, they run along each other (at least half of
the shorter one, or 50 mm, lies within the tolerance of the other, and those parts are within 30
degrees of parallel: a false positive laid across a crack is near it but not along it) or meet end
to end (each has an end within the tolerance of the other, their last 50 mm within 45 degrees: the
pieces of one crack cut by image or tile borders, or broken by the detector).
Two area defects of a kind are the same when their outlines, grown by the tolerance, overlap by
at least a third of the smaller. The tolerance is 3 sigma of the two detections' relative position
error (place.py) plus the crack widths, and not below `min_tolerance_mm`. Links are transitive
(union-find): a crack seen piecewise along a pass is one crack; but a crack detection that no two
other images support (a stray false positive between two defects) does not link them
(`_split_bridges`).

Fusion: a crack's centreline is the mean of its detections' points at stations along the longest
detection (extended past its ends so pieces beyond it keep their place); its ends are the median of
the images' free ends, the pieces of one image taken together (a crack that a detector broke into
pieces keeps its extreme ends; the ends at the gaps are no ends); its length is that centreline's,
its width the median of the images' widths (each image's pieces length-weighted), with their
spread. An area defect is the median-area detection among those not touching their image border,
moved to the median of their centroids (else the union of all, flagged truncated). Positions and
lengths get sigma / sqrt(n) for the parts of the error that are independent between images
(attitude, range, pixels); the camera-position part is kept whole.

With the images' footprints, every defect is checked by multi-view consensus (icgt.mapping.consensus):
how many images reported it, how many could have, confirmed or doubtful.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import shapely
from shapely.strtree import STRtree

from icgt.geodesy import FloatArray
from icgt.mapping.consensus import Consensus, View, could_see
from icgt.mapping.model import CRACK, Instance, Placed
from icgt.mapping.surface import Face

STEP_M = 0.01
"""Resampling step along cracks [m]."""
ALONG_MAX_DEG = 30.0
"""Two cracks run along each other only if the parts near each other are this parallel."""
SEEN_WITHIN_M = 0.05
"""An image saw a merged defect if one of its detections comes this near the fused shape (consensus)."""
END_MAX_DEG = 45.0
"""Two cracks meeting end to end are one only if their ends point so alike."""


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


def _direction(points: FloatArray) -> FloatArray | None:
    """The principal direction (unit, sign-free) of points (N, 2), None for fewer than two distinct."""
    if len(points) < 2:
        return None
    c = points - points.mean(axis=0)
    _, sv, vt = np.linalg.svd(c, full_matrices=False)
    if sv[0] <= 1e-9:
        return None
    out: FloatArray = vt[0]
    return out


def _aligned(pa: FloatArray, pb: FloatArray, max_deg: float) -> bool:
    da, db = _direction(pa), _direction(pb)
    if da is None or db is None:
        return True  # too short to have a direction: the distance test alone decides
    return bool(abs(float(da @ db)) >= math.cos(math.radians(max_deg)))


def _cracks_linked(sa: np.ndarray, sb: np.ndarray, la: shapely.LineString, lb: shapely.LineString, tol: float) -> bool:
    near_a = shapely.distance(sa, lb) <= tol
    near_b = shapely.distance(sb, la) <= tol
    shorter = min(la.length, lb.length)
    along = max(near_a.sum(), near_b.sum()) * STEP_M
    xa, xb = shapely.get_coordinates(sa), shapely.get_coordinates(sb)
    if along >= min(0.5 * shorter, 0.05):
        # running along each other, not across: a detection that crosses a crack (a false positive
        # laid over it) comes as near as one along it, but at an angle
        return _aligned(xa[near_a], xb[near_b], ALONG_MAX_DEG)
    if (near_a[0] or near_a[-1]) and (near_b[0] or near_b[-1]):
        k = max(2, round(0.05 / STEP_M))  # the last 50 mm at the meeting ends
        ea = xa[:k] if near_a[0] else xa[-k:]
        eb = xb[:k] if near_b[0] else xb[-k:]
        return _aligned(ea, eb, END_MAX_DEG)
    return False


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
    edges: list[tuple[int, int]] = []
    if placed:
        tree = STRtree(geoms)
        max_tol = max(_tolerance_m(p, p, min_tolerance_mm) for p in placed)
        left, right = tree.query(geoms, predicate="dwithin", distance=max_tol)
        for i, j in zip(left.tolist(), right.tolist(), strict=True):
            if j <= i or placed[i].det.kind != placed[j].det.kind:
                continue
            tol = _tolerance_m(placed[i], placed[j], min_tolerance_mm)
            if placed[i].det.kind == CRACK:
                linked = _cracks_linked(samples[i], samples[j], geoms[i], geoms[j], tol)
            else:
                linked = _areas_linked(geoms[i], geoms[j], tol)
            if linked:
                uf.union(i, j)
                edges.append((i, j))
    clusters: dict[int, list[int]] = {}
    for i in range(len(placed)):
        clusters.setdefault(uf.find(i), []).append(i)
    by_cluster: dict[int, list[tuple[int, int]]] = {}
    for i, j in edges:
        by_cluster.setdefault(uf.find(i), []).append((i, j))
    out: list[list[int]] = []
    for root, members in clusters.items():
        out += _split_bridges(members, by_cluster.get(root, []), placed, samples, min_tolerance_mm)
    out.sort(key=min)
    return out


def _components(members: Sequence[int], edges: Sequence[tuple[int, int]]) -> list[list[int]]:
    index = {m: k for k, m in enumerate(members)}
    uf = _UnionFind(len(members))
    for i, j in edges:
        if i in index and j in index:
            uf.union(index[i], index[j])
    comps: dict[int, list[int]] = {}
    for m in members:
        comps.setdefault(uf.find(index[m]), []).append(m)
    return list(comps.values())


def _split_bridges(
    members: list[int],
    edges: list[tuple[int, int]],
    placed: Sequence[Placed],
    samples: Sequence[np.ndarray | None],
    min_tolerance_mm: float,
) -> list[list[int]]:
    """A cluster held together by stray detections is separate defects and the strays.

    A false positive of one image that lies between two defects (or a defect and a look-alike)
    links them, and no other image reports anything where it lies. So a crack detection counts for
    linking only if it is *supported*: at least half of its length lies within half the merge
    tolerance of the detections of two other images or more. If the supported detections alone fall
    into two parts or more that are each seen in two images or more, those are the defects; an
    unsupported detection joins the part it links to, or stands alone when it links to several (a
    bridge) or to none. Otherwise the cluster stays whole (a crack seen by three images in pieces).
    """
    if len({placed[m].det.image for m in members}) < 3 or placed[members[0]].det.kind != CRACK:
        return [members]
    weak = []
    for a in members:
        sa = samples[a]
        assert sa is not None
        near: dict[str, np.ndarray] = {}
        for b in members:
            im = placed[b].det.image
            if im == placed[a].det.image:
                continue
            tol = 0.5 * _tolerance_m(placed[a], placed[b], min_tolerance_mm)
            hit = shapely.distance(sa, shapely.LineString(placed[b].face)) <= tol
            near[im] = near[im] | hit if im in near else hit
        count = np.sum(np.stack(list(near.values())), axis=0) if near else np.zeros(len(sa))
        if float(np.mean(count >= 2)) < 0.5:
            weak.append(a)
    if not weak:
        return [members]
    weak_set = set(weak)
    strong = [m for m in members if m not in weak_set]
    comps = _components(strong, [(a, b) for a, b in edges if a not in weak_set and b not in weak_set])
    if sum(len({placed[m].det.image for m in c}) >= 2 for c in comps) < 2:
        return [members]  # the unsupported detections hold no two supported parts together
    where = {m: k for k, c in enumerate(comps) for m in c}
    for m in weak:
        linked = {where[o] for a, b in edges if m in (a, b) for o in ((b if a == m else a),) if o in where}
        if len(linked) == 1:
            comps[linked.pop()].append(m)
        else:
            comps.append([m])
    return comps


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
    line does not zigzag between the images' offsets as a median would). The fused ends are
    the median of the images' ends that are not cut by their image border, each image's pieces
    taken together (a misregistered detection would otherwise lengthen the crack by its offset, a
    detector's gap shorten it); the extreme ends when every image is cut there.
    """
    ref = max(members, key=lambda p: p.length_mm or 0.0)
    ext, by = _extended(shapely.LineString(ref.face), 2.0)
    tracks: list[tuple[FloatArray, FloatArray, FloatArray]] = []
    # the ends of each image's pieces together: a crack broken into pieces in one image (a detector's
    # gap) has that image's extreme ends as its ends, not the ends at the gaps
    ends: dict[str, tuple[tuple[float, bool], tuple[float, bool]]] = {}
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
        lo_e, hi_e = (float(p[0]), cut_lo), (float(p[-1]), cut_hi)
        if m.det.image in ends:
            (lo0, hi0) = ends[m.det.image]
            lo_e = min(lo0, lo_e, key=lambda v: v[0])
            hi_e = max(hi0, hi_e, key=lambda v: v[0])
        ends[m.det.image] = (lo_e, hi_e)
    lows = [lo for lo, _ in ends.values()]
    highs = [hi for _, hi in ends.values()]
    free_lo = [v for v, cut in lows if not cut]
    free_hi = [v for v, cut in highs if not cut]
    lo = float(np.median(free_lo)) if free_lo else min(v for v, _ in lows)
    hi = float(np.median(free_hi)) if free_hi else max(v for v, _ in highs)
    if hi <= lo:
        lo, hi = min(v for v, _ in lows), max(v for v, _ in highs)
    n = max(2, math.ceil((hi - lo) / STEP_M) + 1)
    stations = np.linspace(lo, hi, n)
    # the mean of the detections covering each station (a median would hop between the images' offsets)
    acc = np.full((len(tracks), n, 5), np.nan)
    for k, (p, r, e) in enumerate(tracks):
        covered = (stations >= p[0]) & (stations <= p[-1])
        if len(p) < 2 or not covered.any():
            continue
        x = stations[covered]
        acc[k, covered, :2] = np.stack([np.interp(x, p, r[:, j]) for j in range(2)], axis=1)
        acc[k, covered, 2:] = np.stack([np.interp(x, p, e[:, j]) for j in range(3)], axis=1)
    ok = np.isfinite(acc[:, :, 0]).any(axis=0)
    if not ok.any():
        longest = max(tracks, key=lambda t: t[0][-1] - t[0][0])
        return longest[1], longest[2]
    mean = np.nanmean(acc[:, ok, :], axis=0)
    return mean[:, :2], mean[:, 2:]


def _spread(values: Sequence[float]) -> float | None:
    if len(values) < 2:
        return None
    v = np.asarray(values, dtype=np.float64)
    return float(1.4826 * np.median(np.abs(v - np.median(v))))


def _per_image(members: Sequence[Placed], value: str) -> list[float]:
    """One value per image (the length-weighted mean of that image's pieces)."""
    acc: dict[str, list[tuple[float, float]]] = {}
    for m in members:
        v = getattr(m, value)
        if v is not None:
            acc.setdefault(m.det.image, []).append((float(v), max(m.length_mm or 1.0, 1e-6)))
    return [sum(v * w for v, w in vs) / sum(w for _, w in vs) for vs in acc.values()]


def build_instances(
    placed: Sequence[Placed],
    surface: Face,
    errors_position_mm: float,
    *,
    min_tolerance_mm: float = 10.0,
    views: Sequence[View] | None = None,
    consensus: Consensus = Consensus(),  # noqa: B008 (frozen)
) -> list[Instance]:
    """Merge and fuse (module docstring); instance ids C1.. for cracks, S1.. for spalling, D1.. others.

    With the images' footprints (`views`), each instance is checked against icgt.mapping.consensus:
    how many images could have seen it, and whether it is confirmed or doubtful.
    """
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
            widths = _per_image(members, "width_mm")
            sig = [m.sigma_len_mm for m in members if m.sigma_len_mm is not None]
            out.append(
                Instance(
                    iid, kind, face, enu, length, float(np.median(widths)) if widths else None, None,
                    sigma_pos, float(np.median(sig)) / math.sqrt(n) if sig else None, members, truncated,
                    _spread(widths),
                )
            )  # fmt: skip
            continue
        complete = [m for m in members if not m.truncated]
        if complete:
            complete.sort(key=lambda m: m.area_mm2 or 0.0)
            best = complete[len(complete) // 2]
            area = best.area_mm2
            # its outline, moved to the median of the complete detections' centroids (one image's
            # outline carries that image's whole position error; the median of many does not)
            cents = np.array([shapely.Polygon(m.face).centroid.coords[0] for m in complete])
            shift = np.median(cents, axis=0) - np.asarray(shapely.Polygon(best.face).centroid.coords[0])
            face = best.face + shift
            enu = surface.to_enu(face)
        else:
            union = shapely.union_all([_geometry(m) for m in members])
            poly = max(union.geoms, key=lambda g: g.area) if hasattr(union, "geoms") else union
            face = np.asarray(poly.exterior.coords)[:-1]
            area = float(union.area) * 1e6
            enu = surface.to_enu(face)
        out.append(Instance(iid, kind, face, enu, None, None, area, sigma_pos, None, members, truncated))
    if views is not None:
        for inst in out:
            geom = shapely.LineString(inst.face) if inst.kind == CRACK else shapely.Polygon(inst.face)
            if not geom.is_valid:
                geom = shapely.make_valid(geom)
            near = geom.buffer(SEEN_WITHIN_M)
            seen = {m.det.image for m in inst.members if _geometry(m).intersects(near)}
            could = could_see(geom, views, consensus) | seen
            inst.n_seen = len(seen)
            inst.n_could = len(could)
            inst.status = consensus.status(len(seen), len(could))
    return out
