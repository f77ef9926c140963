"""A simulated camera card: one small real JPEG per exposure, named and time-stamped as a camera does.

Files are DSC<number>.JPG in the camera's frame order (the device's `frame_number`, manual shots
included; a missed trigger has no exposure and so no file), numbered from the scenario's
`camera.first_file_number`. EXIF carries Make, Model, DateTime/DateTimeOriginal/DateTimeDigitized
from the camera's own clock at the start of the exposure, truncated to 1 s, and with 10 ms
resolution also SubSecTimeOriginal/SubSecTimeDigitized ("00".."99"). The frame number is written
into the pixels twice: as text, and as 16 black/white 8x8 blocks along the top (bit 15 first)
that survive JPEG compression (`read_frame_number`). With a scenario that has a `[surface]`,
the image is the face as the exposure saw it (icgt.sim.render, `surface.render_width_px` wide)
with the same tag over its top-left corner; otherwise a 64x48 grey tag.
"""

from __future__ import annotations

from collections.abc import Collection, Sequence
from pathlib import Path

from PIL import Image, ImageDraw

from icgt.sim.scenario import Camera, Scenario, SimError
from icgt.sim.truth import ClockMaps, ExposureTruth, exif_strings

IMAGE_SIZE_PX = (64, 48)
_BLOCK_PX = 8
_BITS = 16
_TAG_MAKE = 0x010F
_TAG_MODEL = 0x0110
_TAG_DATETIME = 0x0132
_IFD_EXIF = 0x8769
_TAG_DATETIME_ORIGINAL = 0x9003
_TAG_DATETIME_DIGITIZED = 0x9004
_TAG_SUBSEC_ORIGINAL = 0x9291
_TAG_SUBSEC_DIGITIZED = 0x9292


def file_name(file_number: int) -> str:
    """The name a camera gives its file_number-th image: DSC00001.JPG ..."""
    return f"DSC{file_number:05d}.JPG"


def _image(frame_number: int, base: Image.Image | None = None) -> Image.Image:
    img = base if base is not None else Image.new("RGB", IMAGE_SIZE_PX, (96, 96, 96))
    draw = ImageDraw.Draw(img)
    for bit in range(_BITS):
        on = (frame_number >> (_BITS - 1 - bit)) & 1
        x0 = (bit % 8) * _BLOCK_PX
        y0 = (bit // 8) * _BLOCK_PX
        draw.rectangle((x0, y0, x0 + _BLOCK_PX - 1, y0 + _BLOCK_PX - 1), fill=(255, 255, 255) if on else (0, 0, 0))
    draw.text((2, 2 * _BLOCK_PX + 6), f"{frame_number}", fill=(255, 255, 0))
    return img


def read_frame_number(path: str | Path) -> int:
    """The frame number encoded in the pixel blocks of a card image."""
    with Image.open(path) as img:
        gray = img.convert("L")
        value = 0
        for bit in range(_BITS):
            x0 = (bit % 8) * _BLOCK_PX
            y0 = (bit // 8) * _BLOCK_PX
            level = gray.getpixel((x0 + _BLOCK_PX // 2, y0 + _BLOCK_PX // 2))
            value = (value << 1) | (1 if isinstance(level, int | float) and level > 127 else 0)
    return value


def write_card(
    card_dir: str | Path,
    exposures: Sequence[ExposureTruth],
    clocks: ClockMaps,
    camera: Camera,
    *,
    omit_exif_time: Collection[int] = (),
    quality: int = 90,
    scenario: Scenario | None = None,
) -> list[Path]:
    """Write one JPEG per exposure into card_dir (created if needed); returns the paths in order.

    omit_exif_time: frame numbers whose images carry no date/time tags at all (as some cameras
    write after a clock reset or for images edited in camera).
    """
    out_dir = Path(card_dir)
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SimError(f"cannot create card folder {out_dir}: {exc.strerror}") from exc
    paths: list[Path] = []
    for e in sorted(exposures, key=lambda x: x.frame_number):
        number = camera.first_file_number + e.frame_number - 1
        if number > 99_999:
            raise SimError(f"frame {e.frame_number}: file number {number} exceeds DSC99999")
        base = None
        if scenario is not None and scenario.surface is not None:
            from icgt.sim.render import render

            base = render(scenario, scenario.surface, e)
        img = _image(e.frame_number, base)
        exif = img.getexif()
        exif[_TAG_MAKE] = camera.make
        exif[_TAG_MODEL] = camera.model
        if e.frame_number not in omit_exif_time:
            text, subsec = exif_strings(e.start_camera_s, clocks.exif_resolution)
            exif[_TAG_DATETIME] = text
            ifd = exif.get_ifd(_IFD_EXIF)
            ifd[_TAG_DATETIME_ORIGINAL] = text
            ifd[_TAG_DATETIME_DIGITIZED] = text
            if subsec is not None:
                ifd[_TAG_SUBSEC_ORIGINAL] = subsec
                ifd[_TAG_SUBSEC_DIGITIZED] = subsec
        path = out_dir / file_name(number)
        try:
            img.save(path, format="JPEG", quality=quality, exif=exif)
        except OSError as exc:
            raise SimError(f"cannot write {path}: {exc.strerror}") from exc
        paths.append(path)
    return paths


def rerender_card(scenario: Scenario, exposures: Sequence[ExposureTruth], card: Path, out: Path) -> list[Path]:
    """The flown card's images rendered again from `scenario`'s surface (another face, another size).

    Same file names, same EXIF (so `icgt map` matches them to the same frames), same frame tag; the
    pixels are the face of `scenario` (e.g. with look-alikes painted on, or rendered finer) as each
    exposure saw it. For benchmarks and tests: the flight need not be flown again.
    """
    from icgt.sim.render import render

    surface = scenario.surface
    if surface is None:
        raise ValueError("a scenario without [surface] renders no face")
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for e in sorted(exposures, key=lambda x: x.frame_number):
        name = file_name(scenario.camera.first_file_number + e.frame_number - 1)
        src = card / name
        if not src.is_file():
            continue
        with Image.open(src) as im:
            exif = im.info.get("exif", b"")
        img = _image(e.frame_number, render(scenario, surface, e))
        img.save(out / name, format="JPEG", quality=90, exif=exif)
        paths.append(out / name)
    return paths
