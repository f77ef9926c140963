"""`icgt tiles`: the paper's 512 x 512 detector tiles, each with its place in its image and on the face.

Every card image is cut into tiles of `size` pixels stepping by size - overlap; tiles at the right
and bottom edges are shifted inwards so that every tile is full size and inside the image (images
smaller than a tile give one tile of the image's size). Tiles are written as PNG (lossless, so the
detector sees the image's pixels) named <stem>_x<x0>_y<y0>.png, with tiles.json::

    {"format": "icgt-tiles", "tile_size_px": 512, "overlap_px": 0,
     "tiles": [{"tile": "DSC00001_x0_y0.png", "image": "DSC00001.JPG", "x0": 0, "y0": 0,
                "width": 512, "height": 512, "frame_seq": 12,
                "corners_face_m": [[s, t] x 4], "corners_wgs84": [[lon, lat] x 4]}]}

A tile pixel (u, v) is image pixel (x0 + u, y0 + v); the corners (the tile's outer pixel corners,
clockwise from the top left) are on the face frame of `icgt map` for the same log and options, or
null when the image has no frame or pose. `icgt map --tiles tiles.json` maps tile detections back.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from PIL import Image

from icgt.mapping import MappingError


@dataclass(frozen=True)
class TileRef:
    image: str
    x0: int
    y0: int
    width: int
    height: int


def tile_origins(length: int, size: int, overlap: int) -> list[int]:
    if length <= size:
        return [0]
    step = size - overlap
    out = list(range(0, length - size + 1, step))
    if out[-1] != length - size:
        out.append(length - size)
    return out


def cut(image: Path, out_dir: Path, size: int, overlap: int) -> list[dict[str, Any]]:
    if size < 16 or not 0 <= overlap < size:
        raise MappingError(f"tile size {size} px with overlap {overlap} px: need size >= 16 and 0 <= overlap < size")
    try:
        with Image.open(image) as im:
            im.load()
            rgb = im.convert("RGB")
    except OSError as exc:
        raise MappingError(f"{image}: cannot read: {exc}") from exc
    w, h = rgb.size
    rows = []
    for y0 in tile_origins(h, size, overlap):
        for x0 in tile_origins(w, size, overlap):
            tw, th = min(size, w), min(size, h)
            name = f"{image.stem}_x{x0}_y{y0}.png"
            try:
                rgb.crop((x0, y0, x0 + tw, y0 + th)).save(out_dir / name, format="PNG")
            except OSError as exc:
                raise MappingError(f"cannot write {out_dir / name}: {exc.strerror or exc}") from exc
            rows.append({"tile": name, "image": image.name, "x0": x0, "y0": y0, "width": tw, "height": th})
    return rows


def load_index(path: Path) -> dict[str, TileRef]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise MappingError(f"{path}: cannot read the tiles index: {exc}") from exc
    if not isinstance(data, dict) or data.get("format") != "icgt-tiles" or not isinstance(data.get("tiles"), list):
        raise MappingError(f"{path}: not an icgt-tiles index (written by icgt tiles)")
    out: dict[str, TileRef] = {}
    for i, t in enumerate(data["tiles"]):
        try:
            out[str(t["tile"])] = TileRef(
                str(t["image"]), int(t["x0"]), int(t["y0"]), int(t["width"]), int(t["height"])
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise MappingError(f"{path}: tiles[{i}] is malformed ({exc})") from None
    return out


def stems(index: Mapping[str, TileRef]) -> dict[str, str]:
    return {Path(name).stem: name for name in index}
