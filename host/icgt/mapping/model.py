"""The records the damage map passes between its steps."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from icgt.geodesy import FloatArray

CRACK = "crack"
SPALLING = "spalling"


def kind_of(category: str) -> str:
    """A detector's category name -> the map's kind: crack, spalling, or the category itself (area defect)."""
    name = category.strip().lower()
    if "crack" in name:
        return CRACK
    if "spall" in name:
        return SPALLING
    return name or "defect"


@dataclass(frozen=True)
class Detection:
    """One detection in one image, in that image file's pixels (OpenCV convention)."""

    image: str
    """File name of the image on the card (after tiles are mapped back)."""
    kind: str
    category: str
    points_px: FloatArray
    """crack: centreline (M, 2); other kinds: polygon outline (M, 2), not closed."""
    width_px: float | None = None
    """crack width [px] (mask area / centreline length, or as given), None if unknown."""
    score: float | None = None
    source: str = ""
    """Where it was read: file and index, for messages."""


@dataclass
class Placed:
    """A detection placed on the surface."""

    det: Detection
    frame_seq: int
    face: FloatArray
    """(M, 2) face coordinates [m] of the points."""
    enu: FloatArray
    """(M, 3) recording ENU [m]."""
    length_mm: float | None
    width_mm: float | None
    area_mm2: float | None
    sigma_pos_mm: float
    """1-sigma in-plane position error of this detection [mm] (pose and range errors)."""
    sigma_len_mm: float | None
    range_m: float
    truncated: bool
    """The detection touches the image border: the defect may go on outside the image."""
    cut_ends: tuple[bool, bool] = (False, False)
    """crack: its first / last point is at the image border (the crack may go on past it)."""
    index: int = -1


@dataclass
class Instance:
    """One defect on the structure, from one or more detections."""

    id: str
    kind: str
    face: FloatArray
    """crack: fused centreline (M, 2); area: outline (M, 2) [m]."""
    enu: FloatArray
    length_mm: float | None
    width_mm: float | None
    area_mm2: float | None
    sigma_pos_mm: float
    sigma_len_mm: float | None
    members: list[Placed] = field(default_factory=list)
    truncated: bool = False
    """Every contributing detection touched its image border (the defect may be larger)."""
    width_spread_mm: float | None = None
    """The spread of the images' widths (1.4826 x their median absolute deviation) [mm]."""
    n_seen: int = 0
    """How many images reported it where it was fused (icgt.mapping.consensus); 0: not asked."""
    n_could: int = 0
    """How many images could have seen it (icgt.mapping.consensus); 0: not asked."""
    status: str = "confirmed"
    """confirmed, or doubtful: too few of the images that could see it reported it (consensus)."""

    @property
    def images(self) -> list[str]:
        return sorted({m.det.image for m in self.members})


def midpoint(polyline: FloatArray) -> FloatArray:
    """The point half-way along a polyline (M, D)."""
    seg = np.linalg.norm(np.diff(polyline, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    half = cum[-1] / 2.0
    k = min(int(np.searchsorted(cum, half, side="right") - 1), len(seg) - 1)
    f = (half - cum[k]) / seg[k] if seg[k] > 0 else 0.0
    out: FloatArray = polyline[k] + (polyline[k + 1] - polyline[k]) * f
    return out
