"""The damage map against the simulator's truth: which mapped defect is which true one, and the errors.

Used by tests/mapping and benchmarks/damage_map.py. The truth (truth_defects.json, icgt.sim.surface)
is in the scenario's ENU frame; it is carried into the recording's through WGS84 (the recording's
ENU origin), where the map's defects are. A mapped defect is assigned to the nearest true defect of
its kind by midpoint (at most `max_distance_m` away); a true defect with more than one assigned is
counted once and the others are duplicates.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from icgt.geodesy import FloatArray, LocalFrame


@dataclass(frozen=True)
class TrueDefect:
    id: str
    kind: str
    midpoint_enu: FloatArray
    """In the recording's ENU frame [m]."""
    points_enu: FloatArray
    length_mm: float | None
    area_mm2: float | None
    width_mm: float | None


@dataclass(frozen=True)
class MappedItem:
    """What a method reports for one defect."""

    kind: str
    midpoint_enu: FloatArray
    length_mm: float | None
    area_mm2: float | None = None
    n_images: int = 1


@dataclass
class Comparison:
    truth: int
    reported: int
    matched: int
    duplicates: int
    false: int
    missed: list[str]
    position_err_mm: list[float] = field(default_factory=list)
    length_err_pct: list[float] = field(default_factory=list)
    area_err_pct: list[float] = field(default_factory=list)
    assignment: dict[str, list[int]] = field(default_factory=dict)

    @property
    def count_exact(self) -> bool:
        return self.reported == self.truth and self.matched == self.truth and not self.duplicates and not self.false


def load_truth(path: Path, recording_origin: LocalFrame) -> list[TrueDefect]:
    data: dict[str, Any] = json.loads(path.read_text(encoding="utf-8"))
    out = []
    for d in data["defects"]:
        pts = np.asarray(d["wgs84"], dtype=np.float64)
        mid = np.asarray(d["midpoint_wgs84"], dtype=np.float64)
        enu = recording_origin.geodetic_to_enu(pts[:, 0], pts[:, 1], pts[:, 2])
        m = recording_origin.geodetic_to_enu(mid[0], mid[1], mid[2])
        out.append(TrueDefect(d["id"], d["kind"], np.asarray(m).reshape(3), np.asarray(enu).reshape(-1, 3),
                              d.get("length_mm"), d.get("area_mm2"), d.get("width_mm")))  # fmt: skip
    return out


def compare(truth: Sequence[TrueDefect], items: Sequence[MappedItem], *, max_distance_m: float = 0.3) -> Comparison:
    assignment: dict[str, list[int]] = {t.id: [] for t in truth}
    false = 0
    for k, it in enumerate(items):
        cands = [(float(np.linalg.norm(t.midpoint_enu - it.midpoint_enu)), t) for t in truth if t.kind == it.kind]
        if not cands:
            false += 1
            continue
        dist, best = min(cands, key=lambda c: c[0])
        if dist > max_distance_m:
            false += 1
            continue
        assignment[best.id].append(k)
    c = Comparison(len(truth), len(items), 0, 0, false, [], assignment=assignment)
    for t in truth:
        ks = assignment[t.id]
        if not ks:
            c.missed.append(t.id)
            continue
        c.matched += 1
        c.duplicates += len(ks) - 1
        for k in ks:
            it = items[k]
            c.position_err_mm.append(float(np.linalg.norm(t.midpoint_enu - it.midpoint_enu)) * 1000.0)
            if t.length_mm and it.length_mm is not None:
                c.length_err_pct.append(abs(it.length_mm - t.length_mm) / t.length_mm * 100.0)
            if t.area_mm2 and it.area_mm2 is not None:
                c.area_err_pct.append(abs(it.area_mm2 - t.area_mm2) / t.area_mm2 * 100.0)
    return c


def p50_p95(values: Sequence[float]) -> tuple[float, float]:
    if not values:
        return (float("nan"), float("nan"))
    a = np.asarray(values)
    return float(np.percentile(a, 50)), float(np.percentile(a, 95))


def geotag_errors_m(
    frames: Sequence[Any], truth_exposures: Path, scenario: Any, recording_origin: LocalFrame
) -> list[float]:
    """|recorded camera position - true| [m] per frame, paired with its true exposure by start_device_us."""
    o = scenario.origin
    frame = LocalFrame(o.lat_deg, o.lon_deg, o.ellipsoid_height_m)
    true: dict[int, FloatArray] = {}
    for line in truth_exposures.read_text(encoding="utf-8").splitlines():
        if line.strip():
            d = json.loads(line)
            lat, lon, h = frame.enu_to_geodetic(np.asarray(d["position_enu_m"]))
            enu = recording_origin.geodetic_to_enu(lat, lon, np.asarray(h) - o.geoid_separation_m)
            true[int(d["start_device_us"])] = np.asarray(enu).reshape(3)
    out = []
    for f in frames:
        t = true.get(int(f.start_device_us))
        if t is None or f.east_m is None or f.north_m is None or f.up_m is None:
            continue
        out.append(float(np.linalg.norm(np.array([f.east_m, f.north_m, f.up_m]) - t)))
    return out
