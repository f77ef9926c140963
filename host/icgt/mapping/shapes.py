"""Pixel shapes from detector output: masks and polygons to crack centrelines, widths and outlines.

A crack's centreline is taken along the principal axis of its pixels: the mask's pixels are binned
along that axis and each bin's mean across it is a vertex; the width is the mask's area divided by
the centreline's length. This is exact for straight and gently curved cracks (curving less than
about 90 degrees over their length, which a detector's per-crack instance masks are); a branched
crack or one that turns back on itself should come as separate instances or as polylines.
RLE and polygon rasterisation use pycocotools (the COCO reference implementation); mask outlines
are the union of each column's runs as pixel squares (shapely), so no pixel is lost or added.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import shapely
from pycocotools import mask as coco_mask

from icgt.geodesy import FloatArray
from icgt.mapping import MappingError


def _decode(obj: Any) -> np.ndarray:
    # pycocotools 2.0.11 under numpy 2 warns about its own array conversion (not ours to fix)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        out: np.ndarray = coco_mask.decode(obj)
    return out


def decode_rle(rle: dict[str, Any], where: str) -> np.ndarray:
    """A COCO RLE (compressed string or uncompressed counts list) -> bool mask (H, W)."""
    size = rle.get("size")
    counts = rle.get("counts")
    if not (isinstance(size, list) and len(size) == 2 and all(isinstance(v, int) and v > 0 for v in size)):
        raise MappingError(f"{where}: RLE size must be [height, width], got {size!r}")
    h, w = size
    if isinstance(counts, list):
        if not all(isinstance(c, int) and c >= 0 for c in counts) or sum(counts) != h * w:
            raise MappingError(f"{where}: uncompressed RLE counts must be non-negative and sum to {h}x{w}")
        obj = coco_mask.frPyObjects({"size": [h, w], "counts": counts}, h, w)
    elif isinstance(counts, str):
        obj = {"size": [h, w], "counts": counts.encode("ascii")}
    else:
        raise MappingError(f"{where}: RLE counts must be a string or a list of integers")
    try:
        m = _decode(obj)
    except Exception as exc:  # pycocotools raises bare exceptions on malformed strings
        raise MappingError(f"{where}: cannot decode the RLE mask: {exc}") from exc
    out: np.ndarray = m.astype(bool)
    if out.shape != (h, w) or int(coco_mask.area(obj)) != int(out.sum()):
        raise MappingError(f"{where}: the RLE mask does not decode to {h}x{w}")
    return out


def rasterize(polygon_px: FloatArray, height: int, width: int) -> np.ndarray:
    """Fill a polygon given in OpenCV pixel coordinates -> bool mask (H, W) (COCO's rasteriser)."""
    flat = (np.asarray(polygon_px, dtype=np.float64) + 0.5).ravel().tolist()
    rles = coco_mask.frPyObjects([flat], height, width)
    out: np.ndarray = _decode(coco_mask.merge(rles)).astype(bool)
    return out


def centreline(mask: np.ndarray, *, step_px: float = 2.0) -> tuple[FloatArray, float] | None:
    """(polyline (M, 2) in pixels, width [px]) of a crack mask; None for an empty mask."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    pts = np.stack([xs, ys], axis=1).astype(np.float64)
    if len(pts) == 1:
        return np.vstack([pts[0] - [0.5, 0.0], pts[0] + [0.5, 0.0]]), 1.0
    mean = pts.mean(axis=0)
    cov = np.cov((pts - mean).T)
    evals, evecs = np.linalg.eigh(cov)
    axis = evecs[:, int(np.argmax(evals))]
    normal = np.array([-axis[1], axis[0]])
    p = (pts - mean) @ axis
    q = (pts - mean) @ normal
    lo, hi = float(p.min()), float(p.max())
    n_bins = max(1, int(np.ceil((hi - lo) / step_px)))
    edges = np.linspace(lo, hi, n_bins + 1)
    idx = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, n_bins - 1)
    counts = np.bincount(idx, minlength=n_bins)
    q_mean = np.bincount(idx, weights=q, minlength=n_bins) / np.maximum(counts, 1)
    centres = (edges[:-1] + edges[1:]) / 2.0
    keep = counts > 0
    pc, qc = centres[keep], q_mean[keep]
    # the ends reach the extreme pixels' centres along the axis
    pc = np.concatenate([[lo], pc, [hi]])
    qc = np.concatenate([[qc[0]], qc, [qc[-1]]])
    line = mean + pc[:, None] * axis + qc[:, None] * normal
    length = float(np.sum(np.linalg.norm(np.diff(line, axis=0), axis=1)))
    # a pixel-wide run of n pixels spans n - 1 between centres plus half a pixel at each end
    width = float(len(pts)) / (length + 1.0)
    return line, width


def outlines(mask: np.ndarray) -> list[FloatArray]:
    """Outer outlines (K, 2) of a mask's connected parts, in OpenCV pixel coordinates, largest first."""
    boxes: list[Any] = []
    for x in np.flatnonzero(mask.any(axis=0)):
        col = np.concatenate([[False], mask[:, x], [False]])
        d = np.diff(col.astype(np.int8))
        starts, ends = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
        boxes.extend(shapely.box(x - 0.5, y0 - 0.5, x + 0.5, y1 - 0.5) for y0, y1 in zip(starts, ends, strict=True))
    if not boxes:
        return []
    union = shapely.union_all(boxes)
    parts = list(union.geoms) if hasattr(union, "geoms") else [union]
    parts.sort(key=lambda g: -g.area)
    out = []
    for g in parts:
        simple = g.simplify(0.25)
        out.append(np.asarray(simple.exterior.coords, dtype=np.float64)[:-1])
    return out
