"""Reading the card: the JPEGs of a folder in the camera's numbering order and their EXIF capture times."""

from __future__ import annotations

import calendar
import logging
import re
from collections.abc import Callable, Sequence
from datetime import datetime
from pathlib import Path
from typing import Any

from icgt.ingest.matching.results import ImageTime, MatchError

_JPEG_SUFFIXES = (".jpg", ".jpeg")
_IFD_EXIF = 0x8769
_TAG_DATETIME_ORIGINAL = 0x9003
_TAG_SUBSEC_ORIGINAL = 0x9291

_EXIF_DT = re.compile(r"^\s*(\d{4}):(\d{2}):(\d{2})[ T](\d{2}):(\d{2}):(\d{2})")


def parse_exif_time(text: str | None, subsec: str | None) -> tuple[float, float] | None:
    """(seconds [local time read as UTC], resolution [s]) of DateTimeOriginal + SubSecTimeOriginal."""
    if not text:
        return None
    m = _EXIF_DT.match(text)
    if m is None:
        return None
    y, mo, d, h, mi, s = (int(g) for g in m.groups())
    try:
        whole = calendar.timegm(datetime(y, mo, d, h, mi, s).timetuple())
    except ValueError:
        return None  # "0000:00:00 00:00:00" and other placeholders
    digits = re.sub(r"\D", "", subsec or "")
    if not digits:
        return float(whole), 1.0
    return whole + int(digits) / 10 ** len(digits), 10.0 ** -len(digits)


def _exif_tags(path: Path) -> tuple[str | None, str | None]:
    """(DateTimeOriginal, SubSecTimeOriginal) as text; exifread if installed, else Pillow."""
    try:
        import exifread
    except ImportError:  # pragma: no cover - exifread is the documented reader, Pillow a fallback
        from PIL import Image

        with Image.open(path) as img:
            ifd = img.getexif().get_ifd(_IFD_EXIF)
            dto, sub = ifd.get(_TAG_DATETIME_ORIGINAL), ifd.get(_TAG_SUBSEC_ORIGINAL)
        return (str(dto) if dto is not None else None), (str(sub) if sub is not None else None)
    logging.getLogger("exifread").setLevel(logging.ERROR)  # it logs every file without EXIF
    with path.open("rb") as f:
        tags = exifread.process_file(f, details=False)
    dto, sub = tags.get("EXIF DateTimeOriginal"), tags.get("EXIF SubSecTimeOriginal")
    return (str(dto) if dto is not None else None), (str(sub) if sub is not None else None)


def read_image_time(path: Path) -> ImageTime:
    """The EXIF capture time of one image (no exception for a file without EXIF or a damaged one)."""
    try:
        dto, sub = _exif_tags(path)
    except OSError as exc:
        return ImageTime(path, None, None, f"cannot read: {exc.strerror or exc}")
    except Exception as exc:  # EXIF readers raise assorted errors on damaged files
        return ImageTime(path, None, None, f"EXIF unreadable: {exc}")
    parsed = parse_exif_time(dto, sub)
    if parsed is None:
        return ImageTime(path, None, None)
    return ImageTime(path, parsed[0], parsed[1])


def _natural_key(path: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", str(path))]


def list_images(directory: Path) -> list[Path]:
    """The JPEGs in a folder and its subfolders (DCIM/100MSDCF, 101MSDCF, ...) in the camera's numbering order.

    Hidden files and folders are not images: macOS writes an AppleDouble file ``._NAME.JPG`` next to
    every file it touches on a FAT card, and keeps ``.Trashes`` and ``.Spotlight-V100`` there.
    """
    if not directory.is_dir():
        raise MatchError(f"{directory}: not a folder")
    paths = [
        p
        for p in directory.rglob("*")
        if p.is_file()
        and p.suffix.lower() in _JPEG_SUFFIXES
        and not any(part.startswith(".") for part in p.relative_to(directory).parts)
    ]
    return sorted(paths, key=_natural_key)


def read_image_times(paths: Sequence[Path], progress: Callable[[int, int], None] | None = None) -> list[ImageTime]:
    """`read_image_time` of every path, in order; `progress(done, total)` after each."""
    times: list[ImageTime] = []
    for k, path in enumerate(paths):
        times.append(read_image_time(path))
        if progress is not None:
            progress(k + 1, len(paths))
    return times
