"""Repeat inspections compared on the structure's face: every defect new, grown, unchanged, repaired or not seen.

    from icgt.catalog.compare import compare
    result = compare("catalog", "pier-7", before="1234567-00002025", after="1234567-00002026")

Both flights' defects and footprints are read from the catalogue (their `geometry_face`, in each flight's own
face frame, `face_frame`) and placed in the BEFORE flight's face frame: (s, t) -> ENU of its flight -> ECEF ->
ENU of the before flight -> (s, t). Two flights of one face agree there up to the residual alignment, mostly
the difference of their GPS biases (years apart, another receiver, another base): a shift in the face plane.

Alignment (estimated from the data): every pair of same-kind defects proposes the shift between their
midpoints; the shift most pairs agree on (within `CONSENSUS_M`) starts a point-to-line fit (ICP, a few
rounds): the before defects' points are moved onto the nearest after defect's line, each matched defect one
observation with the weight of its length sigmas; a weak prior (sigma `search_m`) keeps a direction no
defect constrains (all cracks parallel) at the consensus. Its covariance is that fit's.

Classification, after the shift: a before and an after defect of one kind are the same defect when every
point of the before one lies within the gate of the after one (3 sigma of the alignment and both lengths, at
least `min_gate_mm`), one to one, nearest first. The same defect is grown when its length (an area defect:
its area) grew by more than `k_sigma` sigma of the change, else unchanged. A before defect without a match is
repaired when the after flight's footprints covered it (it was looked at and is not there), not_seen
otherwise; an after defect without a match is new (`seen_before` says whether the before flight's footprints
covered the place).

Uncertainty of a change: length sigma of the difference = hypot of both flights' `length_sigma_mm` (the damage
map's model: position, attitude and range errors, and the detector's pixel error, per detection, merged);
width: both widths' relative scale error (length_sigma / length: the catalogue stores no width sigma); area:
5 % of the larger area (no area sigma is stored either).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely

from icgt.catalog import CatalogError
from icgt.geodesy import LocalFrame

CONSENSUS_M = 0.15
"""Two defect pairs agree on a shift when their midpoint shifts are this close [m] (a crack grown at one end
moves its midpoint by half its growth)."""
SAMPLE_M = 0.01
"""Spacing of the points sampled along a defect for the fit and the gate [m]."""
AREA_SIGMA_REL = 0.05
CHANGES = ("new", "grown", "unchanged", "repaired", "not_seen")


@dataclass(frozen=True)
class FaceFrame:
    """A flight's face frame (icgt.mapping face_frame_json): point = origin + s * s_axis + t * t_axis, ENU."""

    local: LocalFrame
    origin: np.ndarray
    s_axis: np.ndarray
    t_axis: np.ndarray
    normal: np.ndarray

    @classmethod
    def from_json(cls, text: str) -> FaceFrame:
        d = json.loads(text)
        o = d["enu_origin_wgs84"]
        return cls(
            LocalFrame(float(o["lat_deg"]), float(o["lon_deg"]), float(o["alt_msl_m"])),
            np.asarray(d["origin_enu_m"], dtype=float),
            np.asarray(d["s_axis_enu"], dtype=float),
            np.asarray(d["t_axis_enu"], dtype=float),
            np.asarray(d["normal_enu"], dtype=float),
        )

    def to_ecef(self, st: np.ndarray) -> np.ndarray:
        enu = self.origin + st[:, :1] * self.s_axis + st[:, 1:2] * self.t_axis
        return np.asarray(self.local.enu_to_ecef(enu))

    def from_ecef(self, ecef: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s, t) [m] and the distance off the face's plane [m] of ECEF points."""
        d = np.asarray(self.local.ecef_to_enu(ecef)) - self.origin
        return np.stack([d @ self.s_axis, d @ self.t_axis], axis=1), d @ self.normal


@dataclass(frozen=True)
class Defect:
    id: str
    kind: str
    geom: Any
    """shapely LineString (crack) or Polygon on the reference face [m]."""
    length_mm: float | None
    width_mm: float | None
    area_mm2: float | None
    length_sigma_mm: float | None
    truncated: bool

    def points(self, shift: np.ndarray | None = None) -> np.ndarray:
        line = self.geom if self.geom.geom_type == "LineString" else self.geom.exterior
        n = max(2, math.ceil(line.length / SAMPLE_M) + 1)
        pts = np.asarray(shapely.get_coordinates(line.interpolate(np.linspace(0.0, line.length, n))), dtype=float)
        return pts if shift is None else np.asarray(pts + shift, dtype=float)


@dataclass(frozen=True)
class Inspection:
    structure: str
    flight: str
    start_utc: Any
    defects: list[Defect]
    coverage: Any
    """The union of the flight's footprints on the reference face (shapely)."""
    off_face_m: float
    """The largest distance of its defects and footprints from the reference face's plane [m]."""


@dataclass(frozen=True)
class Alignment:
    shift_m: np.ndarray
    """Added to the after flight's face coordinates to put them on the before flight's [m]."""
    cov_m2: np.ndarray
    pairs: int
    rms_mm: float

    @property
    def sigma_m(self) -> tuple[float, float]:
        return float(math.sqrt(self.cov_m2[0, 0])), float(math.sqrt(self.cov_m2[1, 1]))


@dataclass(frozen=True)
class Change:
    change: str
    before: Defect | None
    after: Defect | None
    """The after defect with the alignment applied (on the before flight's face)."""
    length_change_mm: float | None = None
    length_change_sigma_mm: float | None = None
    width_change_mm: float | None = None
    width_change_sigma_mm: float | None = None
    area_change_mm2: float | None = None
    area_change_sigma_mm2: float | None = None
    distance_mm: float | None = None
    seen_before: bool | None = None


@dataclass
class Comparison:
    before: Inspection
    after: Inspection
    alignment: Alignment
    changes: list[Change] = field(default_factory=list)
    face_frame: dict[str, Any] = field(default_factory=dict)

    def counts(self) -> dict[str, int]:
        return {c: sum(1 for x in self.changes if x.change == c) for c in CHANGES}


def _read(root: Path, structure: str, flight: str, table: str) -> list[dict[str, Any]]:
    from icgt.catalog.store import Catalog

    cat = Catalog(root)
    found = cat.read_flight(structure, flight, table)  # from its partition or the group it was compacted into
    if found is None:
        known = cat.flights(structure) if (root / f"structure={structure}").is_dir() else []
        raise CatalogError(
            f"{root}: no flight {flight!r} of structure {structure!r} (its flights: {', '.join(known) or 'none'})"
        )
    rows: list[dict[str, Any]] = found.to_pylist()
    return rows


def _to_reference(geom: Any, own: FaceFrame, ref: FaceFrame) -> tuple[Any, float]:
    def move(coords: np.ndarray) -> np.ndarray:
        st, off = ref.from_ecef(own.to_ecef(coords))
        move.off = max(move.off, float(np.max(np.abs(off))) if len(off) else 0.0)  # type: ignore[attr-defined]
        return st

    move.off = 0.0  # type: ignore[attr-defined]
    out = shapely.transform(geom, move)
    return out, float(move.off)  # type: ignore[attr-defined]


def load(root: Path, structure: str, flight: str, ref: FaceFrame | None = None) -> tuple[Inspection, FaceFrame, str]:
    """One flight's defects and footprints on `ref` (its own face frame when None); (inspection, its frame,
    its face frame's JSON)."""
    row = _read(root, structure, flight, "flights")[0]
    if not row.get("face_frame"):
        raise CatalogError(f"flight {flight}: no face frame in the catalogue (the log placed nothing on a surface)")
    if row.get("defects") is None:
        raise CatalogError(f"flight {flight}: added without --detections, so it has no defects to compare")
    own = FaceFrame.from_json(row["face_frame"])
    ref = ref or own
    off_face = 0.0
    defects = []
    for d in _read(root, structure, flight, "defects"):
        g, off = _to_reference(shapely.from_wkb(d["geometry_face"]), own, ref)
        off_face = max(off_face, off)
        defects.append(Defect(d["defect_id"], d["kind"], g, d["length_mm"], d["width_mm"], d["area_mm2"],
                              d["length_sigma_mm"], bool(d["truncated"])))  # fmt: skip
    polys = []
    for fp in _read(root, structure, flight, "footprints"):
        g, off = _to_reference(shapely.from_wkb(fp["geometry_face"]), own, ref)
        off_face = max(off_face, off)
        polys.append(g)
    coverage = shapely.union_all(polys) if polys else shapely.Polygon()
    return Inspection(structure, flight, row.get("start_utc"), defects, coverage, off_face), own, row["face_frame"]


def _mid(d: Defect) -> np.ndarray:
    g = d.geom if d.geom.geom_type == "LineString" else d.geom.exterior
    return np.asarray(shapely.get_coordinates(g.interpolate(0.5, normalized=True))[0])


def _pair_sigma_m(b: Defect, a: Defect) -> float:
    sig = [s for s in (b.length_sigma_mm, a.length_sigma_mm) if s is not None]
    return max(math.hypot(*sig) if sig else 10.0, 1.0) / 1000.0


def _nearest(line: Any, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each point, the nearest point on `line` and the unit normal of the line there."""
    along = line.project(shapely.points(pts))
    q = shapely.get_coordinates(line.interpolate(along))
    step = min(SAMPLE_M, line.length / 4)
    ahead = shapely.get_coordinates(line.interpolate(np.minimum(along + step, line.length)))
    back = shapely.get_coordinates(line.interpolate(np.maximum(along - step, 0.0)))
    tangent = ahead - back
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    return q, np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)


def _outline(d: Defect) -> Any:
    return d.geom if d.geom.geom_type == "LineString" else d.geom.exterior


def align(before: Inspection, after: Inspection, *, search_m: float = 2.0, rounds: int = 8) -> Alignment:
    """The shift of the after flight's face coordinates onto the before flight's (see the module's doc)."""
    pairs = [(b, a) for b in before.defects for a in after.defects if a.kind == b.kind]
    shifts = [(_mid(b) - _mid(a)) for b, a in pairs]
    shifts = [s for s in shifts if np.linalg.norm(s) <= search_m]
    prior = np.eye(2) / search_m**2
    if not shifts:
        return Alignment(np.zeros(2), np.linalg.inv(prior), 0, math.nan)
    support = [sum(1 for t in shifts if np.linalg.norm(t - s) <= CONSENSUS_M) for s in shifts]
    best = shifts[int(np.argmax(support))]
    shift = np.mean([t for t in shifts if np.linalg.norm(t - best) <= CONSENSUS_M], axis=0)
    prior_mean = shift.copy()
    cov = np.linalg.inv(prior)
    used, rms = 0, math.nan
    for _ in range(rounds):
        normal_eq = prior.copy()
        rhs = prior @ prior_mean
        residuals: list[float] = []
        used = 0
        taken: set[str] = set()
        for b in before.defects:
            cands = [a for a in after.defects if a.kind == b.kind and a.id not in taken]
            if not cands:
                continue
            pts = b.points()
            lines = [shapely.transform(_outline(a), lambda c: c + shift) for a in cands]  # noqa: B023 (used here)
            dist = [float(np.max(shapely.distance(shapely.points(pts), line))) for line in lines]
            k = int(np.argmin(dist))
            if dist[k] > CONSENSUS_M:
                continue
            a = cands[k]
            taken.add(a.id)
            q, n = _nearest(lines[k], pts)
            r = np.einsum("ij,ij->i", n, pts - q)  # signed distances of the before points from the shifted line
            w = 1.0 / _pair_sigma_m(b, a) ** 2 / len(pts)  # one observation per defect
            # r(shift + delta) = r - n . delta: the normal equations of the shift itself
            normal_eq += w * (n.T @ n)
            rhs += w * (n.T @ (r + n @ shift))
            residuals += list(r)
            used += 1
        cov = np.linalg.inv(normal_eq)
        new = cov @ rhs
        done = float(np.linalg.norm(new - shift)) < 1e-5
        shift = new
        rms = float(np.sqrt(np.mean(np.square(residuals)))) * 1000.0 if residuals else math.nan
        if done:
            break
    return Alignment(shift, cov, used, rms)


def _gate_m(b: Defect, a: Defect, al: Alignment, k_sigma: float, min_gate_mm: float) -> float:
    s = math.hypot(_pair_sigma_m(b, a), *al.sigma_m)
    return max(k_sigma * s, min_gate_mm / 1000.0)


def classify(
    before: Inspection, after: Inspection, al: Alignment, *, k_sigma: float = 3.0, min_gate_mm: float = 20.0
) -> list[Change]:
    """Every defect of both flights as a Change (see the module's doc)."""
    moved = {a.id: Defect(a.id, a.kind, shapely.transform(a.geom, lambda c: c + al.shift_m), a.length_mm,
                          a.width_mm, a.area_mm2, a.length_sigma_mm, a.truncated) for a in after.defects}  # fmt: skip
    cover_after = shapely.transform(after.coverage, lambda c: c + al.shift_m)
    cands = []
    for b in before.defects:
        pts = shapely.points(b.points())
        for a in moved.values():
            if a.kind != b.kind:
                continue
            d = float(np.max(shapely.distance(pts, _outline(a) if a.kind == "crack" else a.geom)))
            if d <= _gate_m(b, a, al, k_sigma, min_gate_mm):
                cands.append((d, b.id, a.id))
    matched_b: dict[str, tuple[str, float]] = {}
    matched_a: set[str] = set()
    for d, bid, aid in sorted(cands):
        if bid not in matched_b and aid not in matched_a:
            matched_b[bid] = (aid, d)
            matched_a.add(aid)
    out = []
    for b in before.defects:
        if b.id not in matched_b:
            covered = bool(cover_after.covers(b.geom))
            out.append(Change("repaired" if covered else "not_seen", b, None))
            continue
        aid, d = matched_b[b.id]
        out.append(_same(b, moved[aid], d, k_sigma))
    for a in moved.values():
        if a.id not in matched_a:
            out.append(Change("new", None, a, seen_before=bool(before.coverage.covers(a.geom))))
    return out


def _same(b: Defect, a: Defect, d_m: float, k_sigma: float) -> Change:
    dl = sl = dw = sw = da = sa = None
    grown = False
    if b.length_mm is not None and a.length_mm is not None:
        dl = a.length_mm - b.length_mm
        sl = math.hypot(b.length_sigma_mm or 0.0, a.length_sigma_mm or 0.0)
        grown = dl > k_sigma * sl
        if b.width_mm is not None and a.width_mm is not None:
            dw = a.width_mm - b.width_mm
            sw = math.hypot(*(x.width_mm * (x.length_sigma_mm or 0.0) / max(x.length_mm or 1.0, 1e-9)  # type: ignore[operator]
                              for x in (a, b)))  # fmt: skip
    if b.area_mm2 is not None and a.area_mm2 is not None:
        da = a.area_mm2 - b.area_mm2
        sa = AREA_SIGMA_REL * max(a.area_mm2, b.area_mm2)
        grown = grown or da > k_sigma * sa
    return Change("grown" if grown else "unchanged", b, a, dl, sl, dw, sw, da, sa, d_m * 1000.0)


def compare(
    root: Path | str,
    structure: str,
    *,
    before: str,
    after: str,
    k_sigma: float = 3.0,
    search_m: float = 2.0,
    min_gate_mm: float = 20.0,
    max_off_face_m: float = 0.5,
) -> Comparison:
    """The two flights' defects compared on the before flight's face (see the module's doc)."""
    root = Path(root)
    if before == after:
        raise CatalogError(f"--before and --after are the same flight ({before})")
    b, ref, frame_json = load(root, structure, before)
    a, _, _ = load(root, structure, after, ref)
    if a.off_face_m > max_off_face_m:
        raise CatalogError(
            f"flight {after} lies {a.off_face_m:.2f} m off the face of flight {before} (more than {max_off_face_m} m): "
            "not the same face of the structure"
        )
    al = align(b, a, search_m=search_m)
    changes = classify(b, a, al, k_sigma=k_sigma, min_gate_mm=min_gate_mm)
    return Comparison(b, a, al, changes, json.loads(frame_json))
