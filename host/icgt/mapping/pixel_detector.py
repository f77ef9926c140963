"""A classical crack detector that looks at pixels: ridge filter, threshold, skeleton; written as COCO.

It stands where a trained detector (YOLO-seg, a U-Net) would stand in front of `icgt map`: it reads
the card's JPEGs, nothing else (no pose, no camera model, nothing of icgt.geometry or the simulator),
and writes a COCO file with one polygon per crack, as such detectors do. It lives in icgt.mapping, not
in the simulator, because it is a detector like any other: it runs on any card (`detect_cards`), and
a disagreement between its map and the projected detections' map is a bug in one of them.

Per image, in grey levels:
1. **ridges**: the Sato tubeness filter (scikit-image) for dark ridges at `sigmas` pixels; the
   response is thresholded with hysteresis at `high_k` and `low_k` times a robust noise level
   (the median absolute deviation of the response over the image), so the threshold follows each
   image's texture and exposure;
2. **shape**: each connected part of the thresholded response, if at least `min_length_px` long, is
   skeletonised (scikit-image) and its longest path through the skeleton is the crack's centreline;
3. **line, not edge**: a crack is darker than the surface on *both* sides; the edge of a dark area
   (a spall, a stain, a shadow) is dark on one side only. Along the centreline the grey level is
   sampled at the line and `side_px` to either side; a part whose median darkening against the
   brighter side is not at least `edge_ratio` of the difference between the sides is an edge and is
   dropped;
4. **not a joint**: a formwork joint is a dark line too, but straight and long; a part whose
   chord is longer than `joint_fraction` of the image width and whose centreline stays within
   `straight_fraction` of the image width of that chord is dropped (cracks meander; a real detector
   learns this from its training data; the tolerance leaves room for the bow that lens distortion
   gives a straight line, 4 px at 1800 px wide here);
5. **width**: the darkness integrated across the line (sum over the profile of 1 - grey/surface) is
   the width a crack whose inside reflects `inside_albedo` of the surface's light has at that
   contrast; the median along the crack is its width in pixels.

The polygon written is the centreline grown by half that width (at least half a pixel): what a
segmenter's mask outline is. Regions given in `exclude` (e.g. a camera's text overlay) are not looked at.
"""

from __future__ import annotations

import heapq
import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image
from skimage.filters import apply_hysteresis_threshold, sato
from skimage.measure import label, regionprops
from skimage.morphology import skeletonize

from icgt.geodesy import FloatArray


@dataclass(frozen=True)
class PixelDetector:
    """The detector's settings (module docstring)."""

    sigmas: tuple[float, ...] = (1.0, 1.5)
    high_k: float = 12.0
    low_k: float = 5.0
    min_length_px: float = 15.0
    side_px: float = 4.0
    edge_ratio: float = 1.0
    straight_fraction: float = 0.01
    joint_fraction: float = 0.25
    inside_albedo: float = 0.2
    exclude: tuple[tuple[int, int, int, int], ...] = field(default_factory=tuple)
    """Boxes (x0, y0, x1, y1) [px, x1/y1 exclusive] not looked at."""


@dataclass(frozen=True)
class Crack:
    """One crack found in one image: centreline (M, 2) in OpenCV pixel coordinates, width [px]."""

    points_px: FloatArray
    width_px: float


def _grey(path: Path) -> FloatArray:
    with Image.open(path) as im:
        out: FloatArray = np.asarray(im.convert("L"), dtype=np.float64) / 255.0
    return out


def _farthest(start: int, nbrs: list[list[tuple[int, float]]]) -> tuple[int, list[int]]:
    """Dijkstra from start over a small pixel graph: (the farthest node, predecessors)."""
    dist = [math.inf] * len(nbrs)
    pred = [-1] * len(nbrs)
    dist[start] = 0.0
    heap = [(0.0, start)]
    while heap:
        d, u = heapq.heappop(heap)
        if d > dist[u]:
            continue
        for v, wt in nbrs[u]:
            if d + wt < dist[v]:
                dist[v] = d + wt
                pred[v] = u
                heapq.heappush(heap, (d + wt, v))
    far = max((k for k in range(len(nbrs)) if math.isfinite(dist[k])), key=lambda k: dist[k])
    return far, pred


def _longest_path(skel: np.ndarray) -> FloatArray:
    """The longest shortest path through a skeleton (8-connected pixels), as (x, y) points."""
    ys, xs = np.nonzero(skel)
    n = len(xs)
    if n < 2:
        return np.stack([xs, ys], axis=1).astype(np.float64)
    index = {(int(y), int(x)): k for k, (y, x) in enumerate(zip(ys, xs, strict=True))}
    nbrs: list[list[tuple[int, float]]] = [[] for _ in range(n)]
    for (y, x), k in index.items():
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                j = index.get((y + dy, x + dx))
                if j is not None and j != k:
                    nbrs[k].append((j, math.hypot(dy, dx)))
    a, _ = _farthest(0, nbrs)
    b, pred = _farthest(a, nbrs)
    path = [b]
    while path[-1] != a and pred[path[-1]] >= 0:
        path.append(pred[path[-1]])
    q = np.array(path[::-1])
    return np.stack([xs[q], ys[q]], axis=1).astype(np.float64)


def _smooth(points: FloatArray, step_px: float = 3.0) -> FloatArray:
    """The skeleton's pixel path resampled every step_px and smoothed (no pixel staircase)."""
    if len(points) < 3:
        return points
    k = 5
    pad = np.vstack([np.repeat(points[:1], k // 2, axis=0), points, np.repeat(points[-1:], k // 2, axis=0)])
    sm = np.stack([np.convolve(pad[:, j], np.ones(k) / k, mode="valid") for j in range(2)], axis=1)
    sm[0], sm[-1] = points[0], points[-1]
    seg = np.linalg.norm(np.diff(sm, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, cum[-1], max(2, int(np.ceil(cum[-1] / step_px)) + 1))
    return np.stack([np.interp(s, cum, sm[:, 0]), np.interp(s, cum, sm[:, 1])], axis=1)


def _profiles(grey: FloatArray, line: FloatArray, offsets: FloatArray) -> FloatArray:
    """Grey levels (M, K) at each centreline point, `offsets` px along its normal (bilinear)."""
    t = np.gradient(line, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    pts = line[:, None, :] + offsets[None, :, None] * n[:, None, :]
    h, w = grey.shape
    x = np.clip(pts[..., 0], 0.0, w - 1.0)
    y = np.clip(pts[..., 1], 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), w - 2)
    y0 = np.minimum(np.floor(y).astype(np.int64), h - 2)
    fx, fy = x - x0, y - y0
    out: FloatArray = (
        grey[y0, x0] * (1 - fx) * (1 - fy)
        + grey[y0, x0 + 1] * fx * (1 - fy)
        + grey[y0 + 1, x0] * (1 - fx) * fy
        + grey[y0 + 1, x0 + 1] * fx * fy
    )
    return out


def detect_image(path: Path, settings: PixelDetector = PixelDetector()) -> list[Crack]:
    """The cracks in one image (module docstring)."""
    grey = _grey(path)
    h, w = grey.shape
    resp = sato(grey, sigmas=settings.sigmas, black_ridges=True)  # type: ignore[no-untyped-call]
    for x0, y0, x1, y1 in settings.exclude:
        resp[max(y0, 0) : min(y1, h), max(x0, 0) : min(x1, w)] = 0.0
    med = float(np.median(resp))
    mad = float(np.median(np.abs(resp - med))) or 1e-6
    mask = apply_hysteresis_threshold(resp, med + settings.low_k * mad, med + settings.high_k * mad)  # type: ignore[no-untyped-call]
    out: list[Crack] = []
    for region in regionprops(label(mask, connectivity=2)):  # type: ignore[no-untyped-call]
        y0, x0, _, _ = region.bbox
        part = region.image
        if max(part.shape) < settings.min_length_px * 0.7:
            continue
        skel = skeletonize(part)  # type: ignore[no-untyped-call]
        line = _smooth(_longest_path(skel) + np.array([x0, y0], dtype=np.float64))
        length = float(np.sum(np.linalg.norm(np.diff(line, axis=0), axis=1)))
        if length < settings.min_length_px:
            continue
        # a line, not an edge
        d = settings.side_px
        prof = _profiles(grey, line, np.array([-d, 0.0, d]))
        left, centre, right = prof[:, 0], prof[:, 1], prof[:, 2]
        dark = float(np.median(np.minimum(left, right) - centre))
        step = float(np.median(np.abs(left - right)))
        if dark <= 0.0 or dark < settings.edge_ratio * step:
            continue
        # not a joint
        chord = line[-1] - line[0]
        c_len = float(np.linalg.norm(chord))
        if c_len > settings.joint_fraction * w:
            u = chord / c_len
            dev = np.abs((line - line[0]) @ np.array([-u[1], u[0]]))
            if float(dev.max()) <= settings.straight_fraction * w:
                continue
        # width from the darkness integrated across the line
        offs = np.arange(-3.0, 3.5, 0.5)
        across = _profiles(grey, line, offs)
        surface = np.maximum(np.maximum(left, right), 1e-3)
        darkness = np.clip(1.0 - across / surface[:, None], 0.0, None).sum(axis=1) * 0.5
        width = float(np.median(darkness)) / (1.0 - settings.inside_albedo)
        out.append(Crack(line, max(width, 0.3)))
    return out


def _polygon(c: Crack) -> FloatArray:
    poly = shapely.LineString(c.points_px).buffer(max(c.width_px / 2.0, 0.5), cap_style="flat")
    if not isinstance(poly, shapely.Polygon):
        poly = max(poly.geoms, key=lambda g: g.area)
    return np.asarray(poly.exterior.coords)[:-1]


def coco(images: Sequence[tuple[str, tuple[int, int], Sequence[Crack]]]) -> dict[str, Any]:
    """A COCO dataset: the images table, category crack, one polygon annotation per crack."""
    anns: list[dict[str, Any]] = []
    table: list[dict[str, Any]] = []
    for i, (name, (w, h), cracks) in enumerate(images, 1):
        table.append({"id": i, "file_name": name, "width": w, "height": h})
        for c in cracks:
            ring = _polygon(c) + 0.5  # COCO: pixel corners
            anns.append({"id": len(anns) + 1, "image_id": i, "category_id": 1, "iscrowd": 0, "score": 1.0,
                         "segmentation": [ring.round(2).ravel().tolist()]})  # fmt: skip
    return {"images": table, "categories": [{"id": 1, "name": "crack"}], "annotations": anns}


def detect_cards(paths: Sequence[Path], out: Path, settings: PixelDetector = PixelDetector()) -> int:
    """Detect cracks in every image; write the COCO file `out`; returns the number of cracks."""
    rows = []
    for p in sorted(paths):
        with Image.open(p) as im:
            size = im.size
        rows.append((p.name, size, detect_image(p, settings)))
    data = coco(rows)
    out.write_text(json.dumps(data) + "\n", encoding="utf-8")
    return len(data["annotations"])
