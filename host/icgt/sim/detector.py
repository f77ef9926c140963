"""A simulated defect detector: the scenario's true defects projected into each card image, with noise.

For each rendered card image, every crack and spalled area of the scenario's `[surface]` is
projected with the exposure's true pose and the camera's distortion into the image's pixels
(icgt.sim.render's conventions); only what falls inside the image is kept (a crack cut by the image
border is detected as the visible piece, as a real detector would), and every vertex gets Gaussian
pixel noise. The same detections are written in the three formats `icgt map` reads:
polylines (icgt-detections JSON), COCO (cracks as polygons around the centreline, spalls as RLE
masks) and YOLO segmentation txt (polygons), so the map can be checked against the truth.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from pycocotools import mask as coco_mask

from icgt.geodesy import FloatArray
from icgt.sim.camera_card import file_name
from icgt.sim.face import FaceFrame
from icgt.sim.render import camera_to_enu, render_size, scenario_camera
from icgt.sim.scenario import Scenario, SimError
from icgt.sim.truth import ExposureTruth

CLASSES = ("crack", "spalling")


@dataclass(frozen=True)
class SimDetection:
    image: str
    kind: str
    defect_id: str
    points_px: FloatArray
    """crack: centreline; spalling: polygon outline (rendered-image pixels, OpenCV convention)."""
    width_px: float | None


def _to_pixels(scenario: Scenario, e: ExposureTruth, st: FloatArray) -> FloatArray:
    cam = scenario_camera(scenario)
    w, _ = render_size(scenario, scenario.surface)  # type: ignore[arg-type]
    f = cam.width_px / w
    enu = FaceFrame.from_scenario(scenario).to_enu(st)
    p_cam = (enu - np.asarray(e.position_enu_m)) @ camera_to_enu(e.q_optical_ned)
    uv = cam.project(p_cam)
    out: FloatArray = (uv + 0.5) / f - 0.5
    return out


def _densify(points: FloatArray, step: float) -> FloatArray:
    seg = np.linalg.norm(np.diff(points, axis=0), axis=1)
    cum = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.union1d(np.arange(0.0, cum[-1], step), cum)
    return np.stack([np.interp(s, cum, points[:, 0]), np.interp(s, cum, points[:, 1])], axis=1)


def detect(
    scenario: Scenario, e: ExposureTruth, rng: np.random.Generator, *, noise_px: float = 0.3, vertex_px: float = 4.0
) -> list[SimDetection]:
    """The detections one image gives (module docstring)."""
    surface = scenario.surface
    if surface is None:
        raise SimError(f"{scenario.source}: no [surface]: nothing to detect")
    w, h = render_size(scenario, surface)
    cam = scenario_camera(scenario)
    face = FaceFrame.from_scenario(scenario)
    depth = abs(float((np.asarray(e.position_enu_m) - face.origin) @ face.normal))
    px_per_m = cam.fx * w / cam.width_px / max(depth, 1e-6)  # about, for a frontal view
    step_m = 0.5 / px_per_m  # two samples per pixel
    name = file_name(scenario.camera.first_file_number + e.frame_number - 1)
    frame = shapely.box(0.0, 0.0, w - 1.0, h - 1.0)
    out: list[SimDetection] = []
    for c in surface.cracks:
        uv = _to_pixels(scenario, e, _densify(np.asarray(c.points_m), step_m))
        inside = (
            np.isfinite(uv).all(axis=1) & (uv[:, 0] >= 0) & (uv[:, 1] >= 0) & (uv[:, 0] <= w - 1) & (uv[:, 1] <= h - 1)
        )
        # contiguous visible runs
        edges = np.diff(np.concatenate([[0], inside.astype(np.int8), [0]]))
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            run = uv[a:b]
            length = float(np.sum(np.linalg.norm(np.diff(run, axis=0), axis=1)))
            if len(run) < 2 or length < 6.0:
                continue
            n = max(2, round(length / vertex_px) + 1)
            seg = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(run, axis=0), axis=1))])
            s = np.linspace(0.0, seg[-1], n)
            pts = np.stack([np.interp(s, seg, run[:, 0]), np.interp(s, seg, run[:, 1])], axis=1)
            pts = np.clip(pts + rng.normal(scale=noise_px, size=pts.shape), 0.0, [w - 1.0, h - 1.0])
            out.append(SimDetection(name, "crack", c.id, pts, c.width_mm / 1000.0 * px_per_m))
    for sp in surface.spalls:
        ring = np.asarray(sp.points_m)
        uv = _to_pixels(scenario, e, _densify(np.vstack([ring, ring[:1]]), step_m * 4))
        if not np.isfinite(uv).all():
            continue
        vis = shapely.Polygon(uv).intersection(frame)
        parts = list(vis.geoms) if hasattr(vis, "geoms") else [vis]
        for g in parts:
            if not isinstance(g, shapely.Polygon) or g.area < 9.0:
                continue
            pts = np.asarray(g.simplify(0.3).exterior.coords)[:-1]
            pts = np.clip(pts + rng.normal(scale=noise_px, size=pts.shape), 0.0, [w - 1.0, h - 1.0])
            out.append(SimDetection(name, "spalling", sp.id, pts, None))
    return out


def detect_all(
    scenario: Scenario, exposures: Sequence[ExposureTruth], *, seed: int = 0, noise_px: float = 0.3
) -> list[SimDetection]:
    rng = np.random.default_rng(seed)
    out: list[SimDetection] = []
    for e in sorted(exposures, key=lambda x: x.frame_number):
        out += detect(scenario, e, rng, noise_px=noise_px)
    return out


# --- writers ----------------------------------------------------------------------------------


def write_polylines(path: Path, dets: Sequence[SimDetection]) -> None:
    images: dict[str, list[dict[str, Any]]] = {}
    for d in dets:
        item: dict[str, Any] = {"kind": d.kind, "truth_id": d.defect_id}
        if d.kind == "crack":
            item["points_px"] = np.round(d.points_px, 3).tolist()
            item["width_px"] = d.width_px
        else:
            item["polygon_px"] = np.round(d.points_px, 3).tolist()
        images.setdefault(d.image, []).append(item)
    path.write_text(json.dumps({"format": "icgt-detections", "images": images}) + "\n", encoding="utf-8")


def _crack_polygon(d: SimDetection) -> FloatArray:
    half = max((d.width_px or 1.0) / 2.0, 0.5)  # a mask is at least a pixel wide
    poly = shapely.LineString(d.points_px).buffer(half, cap_style="flat")
    return np.asarray(poly.exterior.coords)[:-1]


def write_coco(path: Path, dets: Sequence[SimDetection], size: tuple[int, int], images: Sequence[str]) -> None:
    w, h = size
    ids = {name: k + 1 for k, name in enumerate(images)}
    anns = []
    for k, d in enumerate(dets, 1):
        ann: dict[str, Any] = {"id": k, "image_id": ids[d.image], "category_id": 1 if d.kind == "crack" else 2,
                               "score": 0.9, "iscrowd": 0}  # fmt: skip
        if d.kind == "crack":
            ann["segmentation"] = [(_crack_polygon(d) + 0.5).round(2).ravel().tolist()]
        else:
            rle = coco_mask.merge(coco_mask.frPyObjects([(d.points_px + 0.5).ravel().tolist()], h, w))
            ann["segmentation"] = {"size": [h, w], "counts": rle["counts"].decode("ascii")}
        anns.append(ann)
    data = {
        "images": [{"id": i, "file_name": n, "width": w, "height": h} for n, i in ids.items()],
        "categories": [{"id": 1, "name": "crack"}, {"id": 2, "name": "spalling"}],
        "annotations": anns,
    }
    path.write_text(json.dumps(data) + "\n", encoding="utf-8")


def write_yolo(folder: Path, dets: Sequence[SimDetection], size: tuple[int, int]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    w, h = size
    (folder / "classes.txt").write_text("\n".join(CLASSES) + "\n", encoding="utf-8")
    lines: dict[str, list[str]] = {}
    for d in dets:
        ring = _crack_polygon(d) if d.kind == "crack" else d.points_px
        xy = np.clip((ring + 0.5) / np.array([w, h]), 0.0, 1.0)
        lines.setdefault(d.image, []).append(f"{CLASSES.index(d.kind)} " + " ".join(f"{v:.6f}" for v in xy.ravel()))
    for image, rows in lines.items():
        (folder / (Path(image).stem + ".txt")).write_text("\n".join(rows) + "\n", encoding="utf-8")
