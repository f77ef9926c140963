"""Direct-projection mosaic of the face: every image placed by its geotag, attitude and range, streamed.

Each mosaic pixel is a point of the face plane (face frame, icgt.mapping); it takes its colour from
the image that sees it closest to that image's centre (the most frontal, least distorted view),
sampled bilinearly at `pose.world_to_pixel` of the point (lens distortion included). No image is
warped whole: the mosaic is made in strips of rows, and an image is decoded only for the strips its
footprint covers, at the reduced size the mosaic's resolution needs (libjpeg's DCT scaling through
Pillow's draft mode: 1/2, 1/4 or 1/8), through a cache bounded in bytes. The PNG is written row by
row as the strips come (pypng), so memory is bounded by the strip and the cache, not by the number
or the size of the images.

Outputs: mosaic.png (RGB, 8 bit; uncovered pixels black) with mosaic.pgw (an ESRI world file in face
metres: GDAL/QGIS place the PNG in the face frame with it), or mosaic.tif (a tiled GeoTIFF with the
same transform, written window by window through rasterio/GDAL), defects drawn on top (cracks red,
area defects orange, with their ids).
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import png
from PIL import Image, ImageDraw

from icgt.geodesy import FloatArray
from icgt.geometry import CameraModel
from icgt.geotag.record import FrameRecord
from icgt.mapping import MappingError
from icgt.mapping.model import CRACK, Instance
from icgt.mapping.pose import face_grid_to_pixel
from icgt.mapping.surface import Face

MAX_PIXELS = 2_000_000_000


@dataclass(frozen=True)
class MosaicImage:
    path: Path
    frame: FrameRecord
    size: tuple[int, int]
    """(width, height) of the image file [px]."""
    bbox: tuple[float, float, float, float]
    """(s0, t0, s1, t1) of its footprint on the face [m]."""
    gsd_mm: float
    """Centre GSD in file pixels [mm/px]."""


@dataclass(frozen=True)
class MosaicInfo:
    path: Path
    width_px: int
    height_px: int
    mm_per_px: float
    extent: tuple[float, float, float, float]
    """(s0, t0, s1, t1) [m] of the mosaic's outer edges."""
    images_used: int
    decodes: int
    covered_fraction: float


class _Cache:
    """Decoded images by path, least recently used out first, bounded in bytes."""

    def __init__(self, limit_bytes: int) -> None:
        self.limit = limit_bytes
        self.items: OrderedDict[Path, tuple[np.ndarray, float]] = OrderedDict()
        self.bytes = 0
        self.decodes = 0

    def get(self, img: MosaicImage, wanted_scale: int) -> tuple[np.ndarray, float]:
        hit = self.items.get(img.path)
        if hit is not None:
            self.items.move_to_end(img.path)
            return hit
        try:
            with Image.open(img.path) as im:
                if wanted_scale > 1:
                    im.draft("RGB", (img.size[0] // wanted_scale, img.size[1] // wanted_scale))
                arr = np.asarray(im.convert("RGB"))
        except OSError as exc:
            raise MappingError(f"{img.path}: cannot decode: {exc}") from exc
        self.decodes += 1
        scale = img.size[0] / arr.shape[1]
        self.items[img.path] = (arr, scale)
        self.bytes += arr.nbytes
        while self.bytes > self.limit and len(self.items) > 1:
            _, (old, _) = self.items.popitem(last=False)
            self.bytes -= old.nbytes
        return arr, scale


def _bilinear(arr: np.ndarray, u: FloatArray, v: FloatArray) -> np.ndarray:
    h, w = arr.shape[:2]
    u0 = np.clip(np.floor(u).astype(np.int64), 0, w - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, h - 2)
    fu = np.clip(u - u0, 0.0, 1.0)[:, None]
    fv = np.clip(v - v0, 0.0, 1.0)[:, None]
    a = arr[v0, u0].astype(np.float32)
    b = arr[v0, u0 + 1].astype(np.float32)
    c = arr[v0 + 1, u0].astype(np.float32)
    d = arr[v0 + 1, u0 + 1].astype(np.float32)
    out: np.ndarray = (a * (1 - fu) + b * fu) * (1 - fv) + (c * (1 - fu) + d * fu) * fv
    return out


def _draw(strip: Image.Image, instances: Sequence[Instance], s0: float, t1: float, res: float, row0: int) -> None:
    draw = ImageDraw.Draw(strip)
    for inst in instances:
        cols = (inst.face[:, 0] - s0) / res - 0.5
        rows = (t1 - inst.face[:, 1]) / res - 0.5 - row0
        xy = [(float(c), float(r)) for c, r in zip(cols, rows, strict=True)]
        if inst.kind == CRACK:
            draw.line(xy, fill=(255, 0, 0), width=2)
        else:
            draw.polygon(xy, outline=(255, 150, 0), width=2)
        draw.text((xy[0][0] + 4, xy[0][1] + 4), inst.id, fill=(255, 255, 0))


def build_mosaic(
    out_png: Path,
    images: Sequence[MosaicImage],
    camera: CameraModel,
    face: Face,
    mm_per_px: float,
    instances: Sequence[Instance] = (),
    *,
    extent: tuple[float, float, float, float] | None = None,
    strip_rows: int = 256,
    cache_mb: float = 512.0,
) -> MosaicInfo:
    if mm_per_px <= 0 or not math.isfinite(mm_per_px):
        raise MappingError(f"--mm-per-px must be a positive number, got {mm_per_px}")
    if not images:
        raise MappingError("no placed image to make a mosaic of")
    res = mm_per_px / 1000.0
    if extent is None:
        b = np.asarray([im.bbox for im in images])
        extent = (float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max()))
    s0, t0, s1, t1 = extent
    width = max(1, math.ceil((s1 - s0) / res))
    height = max(1, math.ceil((t1 - t0) / res))
    if width * height > MAX_PIXELS:
        raise MappingError(
            f"a {width} x {height} px mosaic is too large at {mm_per_px} mm/px: choose a coarser --mm-per-px"
        )
    s1, t0 = s0 + width * res, t1 - height * res
    bboxes = np.asarray([im.bbox for im in images])
    cache = _Cache(int(cache_mb * 1024 * 1024))
    used: set[Path] = set()
    covered = 0

    def strips() -> Iterator[tuple[int, np.ndarray]]:
        nonlocal covered
        cols: FloatArray = s0 + (np.arange(width, dtype=np.float64) + 0.5) * res
        for row0 in range(0, height, strip_rows):
            n = min(strip_rows, height - row0)
            t_hi = t1 - row0 * res
            t_lo = t1 - (row0 + n) * res
            rows: FloatArray = t1 - (row0 + np.arange(n, dtype=np.float64) + 0.5) * res
            best = np.full((n, width), np.inf, dtype=np.float32)
            rgb = np.zeros((n, width, 3), dtype=np.float32)
            cand = np.flatnonzero((bboxes[:, 1] < t_hi) & (bboxes[:, 3] > t_lo))
            for k in cand:
                im = images[int(k)]
                c_lo = max(0, int((im.bbox[0] - s0) / res) - 1)
                c_hi = min(width, math.ceil((im.bbox[2] - s0) / res) + 1)
                r_lo = max(0, int((t1 - im.bbox[3]) / res) - 1 - row0)
                r_hi = min(n, math.ceil((t1 - im.bbox[1]) / res) + 1 - row0)
                if c_hi <= c_lo or r_hi <= r_lo:
                    continue
                uu, vv = face_grid_to_pixel(
                    camera, im.frame, face.origin, face.s_axis, face.t_axis, cols[c_lo:c_hi], rows[r_lo:r_hi]
                )
                f = camera.width_px / im.size[0]
                u = (uu + 0.5) / f - 0.5
                v = (vv + 0.5) / f - 0.5
                w_i, h_i = im.size
                with np.errstate(invalid="ignore"):
                    inside = (u >= 0) & (v >= 0) & (u <= w_i - 1) & (v <= h_i - 1)
                if not inside.any():
                    continue
                score = np.hypot((u - (w_i - 1) / 2) / w_i, (v - (h_i - 1) / 2) / h_i).astype(np.float32)
                score = np.where(inside, score, np.inf)
                view = best[r_lo:r_hi, c_lo:c_hi]
                better = score < view
                if not better.any():
                    continue
                scale_wanted = 1
                ratio = mm_per_px / max(im.gsd_mm, 1e-9)
                while scale_wanted * 2 <= min(ratio, 8.0):
                    scale_wanted *= 2
                arr, scale = cache.get(im, scale_wanted)
                vals = _bilinear(arr, (u[better] + 0.5) / scale - 0.5, (v[better] + 0.5) / scale - 0.5)
                rgb[r_lo:r_hi, c_lo:c_hi][better] = vals
                view[better] = score[better]
                used.add(im.path)
            covered += int(np.isfinite(best).sum())
            strip = Image.fromarray(np.clip(np.rint(rgb), 0, 255).astype(np.uint8), mode="RGB")
            if instances:
                _draw(strip, instances, s0, t1, res, row0)
            yield row0, np.asarray(strip)

    if out_png.suffix.lower() in (".tif", ".tiff"):
        _write_geotiff(out_png, width, height, res, s0, t1, strips(), strip_rows)
    else:
        _write_png(out_png, width, height, strips())
        _world_file(out_png.with_suffix(".pgw"), res, s0 + res / 2, t1 - res / 2)
        _check_png(out_png, width, height)
    return MosaicInfo(
        out_png, width, height, mm_per_px, (s0, t0, s1, t1), len(used), cache.decodes, covered / (width * height)
    )


def _write_png(path: Path, width: int, height: int, strips: Iterator[tuple[int, np.ndarray]]) -> None:
    def rows() -> Iterator[np.ndarray]:
        for _, strip in strips:
            yield from strip.reshape(strip.shape[0], width * 3)

    try:
        with path.open("wb") as fh:
            png.Writer(width=width, height=height, greyscale=False, bitdepth=8, compression=6).write(fh, rows())
    except OSError as exc:
        raise MappingError(f"cannot write {path}: {exc.strerror or exc}") from exc


def _write_geotiff(
    path: Path,
    width: int,
    height: int,
    res: float,
    s0: float,
    t1: float,
    strips: Iterator[tuple[int, np.ndarray]],
    strip_rows: int,
) -> None:
    """A tiled, deflate-compressed GeoTIFF written strip by strip (GDAL through rasterio).

    Its transform is in face metres (s right, t up) and it has no CRS: the face is a local
    engineering frame (map.json describes it), not a map projection.
    """
    import rasterio
    from rasterio.errors import RasterioError
    from rasterio.transform import Affine
    from rasterio.windows import Window

    profile = {
        "driver": "GTiff", "width": width, "height": height, "count": 3, "dtype": "uint8",
        "transform": Affine(res, 0.0, s0, 0.0, -res, t1), "tiled": True, "blockxsize": 256,
        "blockysize": 256 if strip_rows % 256 == 0 else 16, "compress": "deflate", "photometric": "RGB",
        "BIGTIFF": "IF_SAFER",
    }  # fmt: skip
    try:
        with rasterio.open(path, "w", **profile) as ds:
            for row0, strip in strips:
                ds.write(strip.transpose(2, 0, 1), window=Window(0, row0, width, strip.shape[0]))
        with rasterio.open(path) as ds:
            if (ds.width, ds.height, ds.count) != (width, height, 3):
                raise MappingError(f"{path}: reads back as {ds.width}x{ds.height}x{ds.count}")
    except RasterioError as exc:
        raise MappingError(f"cannot write {path}: {exc}") from exc


def _world_file(path: Path, res: float, s_centre: float, t_centre: float) -> None:
    text = f"{res:.9f}\n0.0\n0.0\n{-res:.9f}\n{s_centre:.6f}\n{t_centre:.6f}\n"
    try:
        path.write_text(text, encoding="ascii")
    except OSError as exc:
        raise MappingError(f"cannot write {path}: {exc.strerror or exc}") from exc


def _check_png(path: Path, width: int, height: int) -> None:
    """Read the header back (the whole file is decoded by the tests)."""
    try:
        r = png.Reader(filename=str(path))
        w, h, _, _ = r.read()
    except (OSError, png.Error) as exc:
        raise MappingError(f"{path} does not read back as PNG: {exc}") from exc
    if (w, h) != (width, height):
        raise MappingError(f"{path}: reads back as {w}x{h}, written {width}x{height}")
