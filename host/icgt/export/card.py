"""What is on a camera card besides the JPEGs the matcher pairs: hidden files, RAW, HEIC; and damaged JPEGs.

- Hidden files and macOS AppleDouble files (``._DSC00001.JPG``, resource forks written by a Mac
  on a FAT card) and anything inside a hidden folder (``.Trashes``, ``.Spotlight-V100``) are not
  images: `icgt.ingest.match.list_images` skips them and the export lists them (info rows).
- RAW files (`RAW_SUFFIXES`) get an XMP sidecar with the geotag of the JPEG with the same name
  in the same folder (the camera's RAW+JPEG mode); a RAW without such a JPEG is reported.
- HEIC/HEIF files are reported: the matcher does not read them (convert them to JPEG first).
- Other image files (`OTHER_IMAGE_SUFFIXES`: PNG, TIFF, ...) are reported as not read; files that are
  not images (videos, the camera's database and thumbnail files) are not the matcher's and not listed.
- `jpeg_damage` finds a JPEG that is cut off (no end-of-image marker after its image data) or
  whose markers are broken; such an image is a problem row and gets no copy.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

RAW_SUFFIXES = (".arw", ".srf", ".sr2", ".dng", ".nef", ".nrw", ".cr2", ".cr3", ".crw", ".orf", ".rw2",
                ".raf", ".pef", ".srw", ".3fr", ".iiq", ".erf", ".x3f")  # fmt: skip
HEIC_SUFFIXES = (".heic", ".heif", ".hif")
JPEG_SUFFIXES = (".jpg", ".jpeg")
OTHER_IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".webp", ".bmp", ".gif", ".jp2", ".jxl", ".avif")


def is_hidden(path: Path, root: Path) -> bool:
    """A dot file (AppleDouble ``._*`` included) or a file inside a dot folder below root."""
    try:
        parts = path.relative_to(root).parts
    except ValueError:
        parts = (path.name,)
    return any(p.startswith(".") for p in parts)


@dataclass
class CardScan:
    hidden: list[Path] = field(default_factory=list)
    raw: list[Path] = field(default_factory=list)
    heic: list[Path] = field(default_factory=list)
    unsupported: list[Path] = field(default_factory=list)  # images the matcher does not read (PNG, TIFF, ...)


def scan_card(root: Path) -> CardScan:
    """Hidden, RAW, HEIC and other image files below root (the JPEGs are the matcher's)."""
    scan = CardScan()
    for p in sorted(root.rglob("*")):
        if not p.is_file():
            continue
        if is_hidden(p, root):
            scan.hidden.append(p)
        elif p.suffix.lower() in RAW_SUFFIXES:
            scan.raw.append(p)
        elif p.suffix.lower() in HEIC_SUFFIXES:
            scan.heic.append(p)
        elif p.suffix.lower() in OTHER_IMAGE_SUFFIXES:
            scan.unsupported.append(p)
    return scan


def raw_siblings(jpeg: Path, raws: list[Path]) -> list[Path]:
    """The RAW files of the same shot as `jpeg` (same folder, same name before the suffix)."""
    return [r for r in raws if r.parent == jpeg.parent and r.stem.lower() == jpeg.stem.lower()]


_HEAD = 1 << 19  # metadata segments of camera JPEGs fit in the first 512 KiB (read more when they do not)
_TAIL = 1 << 20


def jpeg_header(path: Path) -> bytes:
    """The bytes of a JPEG from its start to its first start-of-scan segment included (all its metadata segments)."""
    with path.open("rb") as f:
        data = f.read(_HEAD)
        while True:
            end = _scan_start(data)
            if end is not None or len(data) % _HEAD:  # found, or the whole (short) file is in
                return data if end is None else data[:end]
            more = f.read(_HEAD)
            if not more:
                return data
            data += more


def _scan_start(data: bytes) -> int | None:
    """Offset just past the first SOS segment header, None if the data ends before it."""
    pos = 2
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xFF:
            pos += 1
            continue
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if marker == 0xDA:
            return pos + 2 + length if pos + 2 + length <= len(data) else None
        pos += 2 + length
    return None


def jpeg_file_damage(path: Path) -> str | None:
    """`jpeg_damage` of a file, reading its headers and then its end backwards (not the whole image data)."""
    head = jpeg_header(path)
    size = path.stat().st_size
    problem = jpeg_damage(head, whole=False)
    if problem is not None:
        return problem
    start = len(head)
    with path.open("rb") as f:
        end = size
        while end > start:
            lo = max(start, end - _TAIL)
            f.seek(lo)
            block = f.read(end - lo + 1)  # one byte of overlap: a marker across two blocks
            if b"\xff\xd9" in block:
                return None
            end = lo
    return f"cut off: the image data stops at byte {size} without an end-of-image marker (truncated file)"


def jpeg_damage(data: bytes, *, whole: bool = True) -> str | None:
    """Why a JPEG's bytes are not a whole image (cut off, broken markers), or None.

    Walks the marker segments to the first start-of-scan, then looks for the end-of-image marker:
    inside entropy-coded data 0xFF is always followed by 0x00 or a restart marker, so any FF D9
    after the scan header means the image data ended (a camera's trailer, MPF images, may follow);
    searched from the end, where it usually is.
    """
    if data[:2] != b"\xff\xd8":
        return "not a JPEG file (no start-of-image marker)"
    pos = 2
    while True:
        if pos + 4 > len(data):
            return f"cut off at byte {len(data)}: no image data (the file ends inside its headers)"
        if data[pos] != 0xFF:
            return f"damaged: no JPEG marker at byte {pos}"
        marker = data[pos + 1]
        if marker == 0xFF:
            pos += 1
            continue
        if marker == 0xD9:
            return "no image data (end-of-image before any scan)"
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if length < 2 or pos + 2 + length > len(data):
            return f"cut off at byte {len(data)}: segment {marker:#04x} at byte {pos} runs past the end"
        if marker == 0xDA:
            break
        pos += 2 + length
    if whole and data.rfind(b"\xff\xd9", pos + 2 + length) < 0:
        return f"cut off: the image data stops at byte {len(data)} without an end-of-image marker (truncated file)"
    return None
