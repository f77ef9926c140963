"""Reading a detector's output: COCO JSON, YOLO segmentation txt, and per-image polyline JSON.

- COCO (a dataset/annotation file, as detectron2, mmdetection and labelling tools write): the
  ``images`` table names the files; each annotation's ``segmentation`` is a polygon list (one or more
  rings, COCO pixel-corner coordinates) or an RLE mask (``{"size": [h, w], "counts": ...}``,
  compressed or not); ``categories`` names the classes; ``score`` is kept when present. A bare list
  of results (no ``images`` table) cannot name its images and is refused.
- YOLO segmentation (Ultralytics ``*.txt``): a folder with one file per image (same stem), each line
  ``class x1 y1 x2 y2 ...`` normalised to the image size, optionally a trailing confidence when the
  number of coordinates is odd. Class names come from ``classes.txt`` (one per line) or ``data.yaml``
  (``names:`` list or mapping) in that folder, or from ``--classes``.
- Polylines (ours): ``{"format": "icgt-detections", "images": {"DSC00001.JPG": [{"kind": "crack",
  "points_px": [[u, v], ...], "width_px": 3.0, "score": 0.9}, {"kind": "spalling", "polygon_px":
  [[u, v], ...]}]}}`` in OpenCV pixel coordinates.

Crack instances given as masks or polygons become centrelines (icgt.mapping.shapes); other kinds
keep their outline. Every annotation becomes one Detection or an error naming it; nothing is skipped.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from icgt.geodesy import FloatArray
from icgt.mapping import MappingError
from icgt.mapping.model import CRACK, Detection, kind_of
from icgt.mapping.shapes import centreline, decode_rle, outlines, rasterize

ImageSize = Callable[[str], tuple[int, int]]
"""(width, height) [px] of a card image by file name."""


def _load_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise MappingError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise MappingError(f"{path}: not valid JSON: {exc}") from exc


def _points(value: Any, where: str, minimum: int) -> FloatArray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise MappingError(f"{where}: expected a list of [u, v] points") from None
    if arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < minimum or not np.isfinite(arr).all():
        raise MappingError(f"{where}: expected at least {minimum} finite [u, v] points, got {value!r:.80}")
    return arr


def _from_mask(mask: np.ndarray, image: str, category: str, score: float | None, where: str) -> list[Detection]:
    kind = kind_of(category)
    if not mask.any():
        raise MappingError(f"{where}: the mask is empty")
    if kind == CRACK:
        line = centreline(mask)
        assert line is not None
        return [Detection(image, kind, category, line[0], line[1], score, where)]
    return [
        Detection(image, kind, category, ring, None, score, f"{where} part {k}" if k else where)
        for k, ring in enumerate(outlines(mask))
    ]


def _from_polygons(
    rings: list[FloatArray], image: str, category: str, score: float | None, where: str, size: tuple[int, int]
) -> list[Detection]:
    kind = kind_of(category)
    if kind == CRACK:
        w, h = size
        mask = np.zeros((h, w), dtype=bool)
        for ring in rings:
            mask |= rasterize(ring, h, w)
        if not mask.any():
            raise MappingError(f"{where}: the crack polygon covers no pixel of the {w}x{h} image")
        return _from_mask(mask, image, category, score, where)
    return [
        Detection(image, kind, category, ring, None, score, f"{where} ring {k}" if k else where)
        for k, ring in enumerate(rings)
    ]


# --- COCO -----------------------------------------------------------------------------------


def read_coco(path: Path, data: Mapping[str, Any], image_size: ImageSize) -> list[Detection]:
    images = data.get("images")
    if not isinstance(images, list):
        raise MappingError(f"{path}: a COCO file needs its images table (a bare results list cannot name its images)")
    files: dict[Any, tuple[str, int | None, int | None]] = {}
    for i, im in enumerate(images):
        if not isinstance(im, dict) or "id" not in im or not isinstance(im.get("file_name"), str):
            raise MappingError(f"{path}: images[{i}] needs an id and a file_name")
        files[im["id"]] = (Path(im["file_name"]).name, im.get("width"), im.get("height"))
    cats = {c.get("id"): str(c.get("name", c.get("id"))) for c in data.get("categories", []) if isinstance(c, dict)}
    out: list[Detection] = []
    for i, ann in enumerate(data.get("annotations", [])):
        where = f"{path} annotations[{i}]"
        if not isinstance(ann, dict):
            raise MappingError(f"{where}: not an object")
        if ann.get("image_id") not in files:
            raise MappingError(f"{where}: image_id {ann.get('image_id')!r} is not in the images table")
        name, w_decl, h_decl = files[ann["image_id"]]
        cat = ann.get("category_id")
        if cat not in cats:
            raise MappingError(f"{where}: category_id {cat!r} is not in the categories table")
        score = float(ann["score"]) if isinstance(ann.get("score"), int | float) else None
        seg = ann.get("segmentation")
        size = image_size(name)
        if isinstance(w_decl, int) and isinstance(h_decl, int) and (w_decl, h_decl) != size:
            raise MappingError(
                f"{where}: the images table says {name} is {w_decl}x{h_decl}, the file is {size[0]}x{size[1]}"
            )
        if isinstance(seg, dict):
            mask = decode_rle(seg, where)
            if (mask.shape[1], mask.shape[0]) != size:
                raise MappingError(f"{where}: mask is {mask.shape[1]}x{mask.shape[0]}, {name} is {size[0]}x{size[1]}")
            out += _from_mask(mask, name, cats[cat], score, where)
        elif isinstance(seg, list) and seg:
            rings = []
            for k, ring in enumerate(seg):
                if not isinstance(ring, list) or len(ring) < 6 or len(ring) % 2:
                    raise MappingError(f"{where}: segmentation[{k}] must be x1, y1, x2, y2, ... (3 points or more)")
                rings.append(_points(np.asarray(ring, dtype=np.float64).reshape(-1, 2) - 0.5, where, 3))
            out += _from_polygons(rings, name, cats[cat], score, where, size)
        else:
            raise MappingError(f"{where}: no segmentation (polygons or RLE); a bounding box alone cannot be measured")
    return out


# --- polylines ------------------------------------------------------------------------------


def read_polylines(path: Path, data: Mapping[str, Any]) -> list[Detection]:
    images = data.get("images")
    if not isinstance(images, dict):
        raise MappingError(f"{path}: expected an 'images' object mapping file names to detection lists")
    out: list[Detection] = []
    for name, items in images.items():
        if not isinstance(items, list):
            raise MappingError(f"{path}: images[{name!r}] must be a list")
        for i, d in enumerate(items):
            where = f"{path} images[{name!r}][{i}]"
            if not isinstance(d, dict) or not isinstance(d.get("kind"), str):
                raise MappingError(f"{where}: needs a kind")
            category = d["kind"]
            kind = kind_of(category)
            score = float(d["score"]) if isinstance(d.get("score"), int | float) else None
            if kind == CRACK:
                pts = _points(d.get("points_px"), f"{where}.points_px", 2)
                w = d.get("width_px")
                width = float(w) if isinstance(w, int | float) and w > 0 else None
                out.append(Detection(Path(name).name, kind, category, pts, width, score, where))
            else:
                pts = _points(d.get("polygon_px"), f"{where}.polygon_px", 3)
                out.append(Detection(Path(name).name, kind, category, pts, None, score, where))
    return out


# --- YOLO -----------------------------------------------------------------------------------


def yolo_class_names(folder: Path, given: Sequence[str] | None) -> list[str]:
    if given:
        return list(given)
    txt = folder / "classes.txt"
    if txt.is_file():
        return [line.strip() for line in txt.read_text(encoding="utf-8").splitlines() if line.strip()]
    yaml = folder / "data.yaml"
    if yaml.is_file():
        return _yaml_names(yaml)
    raise MappingError(f"{folder}: YOLO labels need class names: classes.txt or data.yaml there, or --classes")


def _yaml_names(path: Path) -> list[str]:
    """The ``names:`` of an Ultralytics data.yaml: an inline list, a block list or an index mapping."""
    lines = path.read_text(encoding="utf-8").splitlines()
    for i, line in enumerate(lines):
        m = re.match(r"^names\s*:\s*(.*)$", line)
        if not m:
            continue
        rest = m.group(1).split("#", 1)[0].strip()
        if rest.startswith("["):
            return [n.strip().strip("'\"") for n in rest.strip("[]").split(",") if n.strip()]
        names: dict[int, str] = {}
        listed: list[str] = []
        for sub in lines[i + 1 :]:
            if sub and not sub[0].isspace():
                break
            s = sub.split("#", 1)[0].strip()
            if not s:
                continue
            km = re.match(r"^(\d+)\s*:\s*(.+)$", s)
            if km:
                names[int(km.group(1))] = km.group(2).strip().strip("'\"")
            elif s.startswith("-"):
                listed.append(s[1:].strip().strip("'\""))
        if names:
            return [names.get(k, str(k)) for k in range(max(names) + 1)]
        if listed:
            return listed
    raise MappingError(f"{path}: no names: list or mapping")


def read_yolo(
    folder: Path, names: Sequence[str], image_for_stem: Mapping[str, str], image_size: ImageSize
) -> list[Detection]:
    out: list[Detection] = []
    for txt in sorted(folder.glob("*.txt")):
        if txt.name == "classes.txt":
            continue
        image = image_for_stem.get(txt.stem)
        if image is None:
            raise MappingError(f"{txt}: no image with the stem {txt.stem!r} on the card (or in the tiles index)")
        w, h = image_size(image)
        for n, line in enumerate(txt.read_text(encoding="utf-8").splitlines(), 1):
            if not line.strip():
                continue
            where = f"{txt}:{n}"
            parts = line.split()
            try:
                cls = int(parts[0])
                values = [float(v) for v in parts[1:]]
            except ValueError:
                raise MappingError(f"{where}: expected 'class x1 y1 x2 y2 ...'") from None
            if not 0 <= cls < len(names):
                raise MappingError(f"{where}: class {cls} has no name ({len(names)} names known)")
            score = None
            if len(values) % 2:
                score = values.pop()
            if len(values) < 6:
                raise MappingError(f"{where}: a segment needs at least 3 points")
            xy = np.asarray(values).reshape(-1, 2)
            if (xy < -1e-6).any() or (xy > 1 + 1e-6).any():
                raise MappingError(f"{where}: YOLO coordinates are normalised to 0..1")
            ring = xy * np.array([w, h]) - 0.5
            out += _from_polygons([ring], image, names[cls], score, where, (w, h))
    return out


def read_detections(
    path: Path,
    image_size: ImageSize,
    image_for_stem: Mapping[str, str],
    classes: Sequence[str] | None = None,
) -> list[Detection]:
    """Every detection in a COCO or polyline JSON file, or a folder of YOLO txt files."""
    if path.is_dir():
        return read_yolo(path, yolo_class_names(path, classes), image_for_stem, image_size)
    data = _load_json(path)
    if isinstance(data, list):
        raise MappingError(
            f"{path}: a bare COCO results list cannot name its images: give the file with its images table"
        )
    if not isinstance(data, dict):
        raise MappingError(f"{path}: expected a JSON object")
    if data.get("format") == "icgt-detections":
        return read_polylines(path, data)
    if "annotations" in data:
        return read_coco(path, data, image_size)
    raise MappingError(f"{path}: neither COCO (annotations, images) nor icgt-detections polylines")
