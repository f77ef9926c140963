"""Geotagged copies of real camera JPEGs keep everything but what we set (oracles: ExifTool, exiv2, Pillow).

Samples: `camera_samples` (Pillow's sdist, downloaded at test time). For each copy: every tag that
is not GPS, not ours and not a pointer to a position in the file reads back identical, tag type
included, in ExifTool's view (-a -G1, maker notes decoded) and in exiv2's (its own maker-note
decoders); thumbnails, previews and MPF images are byte-identical; `exiftool -validate` reports
no warning the original did not have; the decoded pixels of every frame are identical.
"""

from __future__ import annotations

import json
import math
import shutil
import subprocess
from pathlib import Path
from typing import Any

import exiv2
import numpy as np
import pytest
from PIL import Image

from icgt.export.common import ProblemLog, prepare_items
from icgt.export.geotag_writer import write_geotagged_copies
from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
from icgt.geotag.record import FrameRecord

from .camera_samples import DAMAGED, SAMPLES, camera_samples

ORIGIN = (46.2044, 6.1432, 375.0)
BASE = np.array([0.5, 0.5, 0.5, 0.5])

# Tags a geotagged copy changes on purpose: the GPS IFD, our XMP, the pose tags photogrammetry
# tools read, SubjectDistance (the LiDAR range), and tags that are positions in the file or
# describe the file rather than the image (ExifTool's own version, file dates and size).
WRITTEN_GROUPS = ("GPS:", "XMP-icgt:", "XMP-Camera:", "XMP-drone-dji:", "File:", "System:", "ExifTool:")
WRITTEN_TAGS = {"ExifIFD:SubjectDistance", "XMP-x:XMPToolkit", "IFD0:GPSInfo"}
COMPOSITE_FROM_GPS = ("Composite:GPS", "Composite:SubjectDistance", "Composite:DOF")  # DOF: from SubjectDistance
POINTERS = ("Offset", "Start", "Offsets")  # ThumbnailOffset, PreviewImageStart, MPImageStart ...
EXIV2_WRITTEN = ("Exif.GPSInfo.",)
EXIV2_POINTERS = {"Exif.Image.GPSTag", "Exif.Image.ExifTag", "Exif.Photo.InteroperabilityTag",
                  "Exif.Thumbnail.JPEGInterchangeFormat", "Exif.Photo.SubjectDistance", "Exif.MakerNote.Offset",
                  "Exif.Photo.MakerNote", "Exif.Image.0x8825"}  # fmt: skip


def frame(seq: int, yaw: float, pitch: float) -> FrameRecord:
    q = q_multiply(q_from_euler_zyx(0.0, math.radians(pitch), math.radians(yaw)), BASE)
    lat, lon, alt = LocalFrame(*ORIGIN).enu_to_geodetic(np.array([seq * 2.0, 3.0, 20.0]))
    return FrameRecord(
        frame_seq=seq, image_index=seq, camera_id=0, device_flags=16, trigger_device_us=seq * 200_000,
        start_device_us=seq * 200_000 + 48_000, mid_device_us=seq * 200_000 + 48_500, duration_us=1000,
        mid_host_ns=seq * 200_000_000, mid_host_uncertainty_ns=30_000, time_source="pps", flags=[],
        position_source="gps_3d", fix_type=3, pose_gap_before_ms=5.0, pose_gap_after_ms=15.0,
        mid_utc_us=1_795_305_954_000_000 + seq * 200_000, mid_utc_uncertainty_us=1.0,
        lat_deg=float(lat), lon_deg=float(lon), alt_msl_m=float(alt), east_m=seq * 2.0, north_m=3.0, up_m=20.0,
        h_acc_m=0.02, v_acc_m=0.03, satellites=20,
        cam_qw=float(q[0]), cam_qx=float(q[1]), cam_qy=float(q[2]), cam_qz=float(q[3]),
        range_m=4.5, range_valid=True,
    )  # fmt: skip


@pytest.fixture(scope="module")
def copies(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, ProblemLog]:
    samples = camera_samples()
    card = tmp_path_factory.mktemp("card")
    out = tmp_path_factory.mktemp("out")
    pairs = []
    for k, name in enumerate([*SAMPLES, *DAMAGED], 1):
        shutil.copy2(samples[name], card / name)
        pairs.append((card / name, frame(k, 30.0 * k + 0.7, -60.0 + k)))
    problems = ProblemLog()
    items = prepare_items(pairs, None, problems)
    written = write_geotagged_copies(items, out, problems, images_root=card)
    errors = [p for p in problems if p.severity == "error"]
    assert written == len(SAMPLES), errors
    assert {(p.image, p.code) for p in errors} == {(n, "damaged_image") for n in DAMAGED}
    return card, out, problems


def exiftool_view(path: Path) -> dict[str, Any]:
    cmd = ["exiftool", "-j", "-a", "-G1", "-n", "-u", "-struct", str(path)]
    row: dict[str, Any] = json.loads(subprocess.run(cmd, capture_output=True, check=True, text=True).stdout)[0]
    return {
        k: v
        for k, v in row.items()
        if not k.startswith(WRITTEN_GROUPS)
        and k not in WRITTEN_TAGS
        and not k.startswith(COMPOSITE_FROM_GPS)
        and not k.endswith(POINTERS)
        and k != "SourceFile"
    }


def exiv2_view(path: Path) -> dict[str, tuple[str, int, str]]:
    img = exiv2.ImageFactory.open(str(path))
    img.readMetadata()
    out: dict[str, tuple[str, int, str]] = {}
    for d in img.exifData():
        key = d.key()
        if key.startswith(EXIV2_WRITTEN) or key in EXIV2_POINTERS:
            continue
        n = 2
        while key in out:  # repeated keys (maker notes) keep their order
            key = f"{d.key()}#{n}"
            n += 1
        out[key] = (d.typeName(), d.count(), str(d.toString()))
    for d in img.iptcData():
        out[d.key()] = (d.typeName(), d.count(), str(d.toString()))
    return out


def binaries(path: Path) -> dict[str, str]:
    """Embedded images (base64, as ExifTool's -j -b gives them): thumbnail, previews, MPF images."""
    tags = ["-ThumbnailImage", "-PreviewImage", "-JpgFromRaw", "-OtherImage", "-MPImage2", "-MPImage3"]
    out = subprocess.run(["exiftool", "-j", "-b", *tags, str(path)], capture_output=True, check=True, text=True)
    row: dict[str, str] = json.loads(out.stdout)[0]
    return {k: v for k, v in row.items() if k != "SourceFile"}


def warnings(path: Path) -> set[str]:
    cmd = ["exiftool", "-validate", "-warning", "-a", "-j", str(path)]
    row = json.loads(subprocess.run(cmd, capture_output=True, text=True).stdout)[0]
    got = row.get("Warning", [])
    return set(got if isinstance(got, list) else [got])


def frames_of(path: Path) -> list[bytes]:
    with Image.open(path) as img:
        out = []
        for i in range(getattr(img, "n_frames", 1)):
            img.seek(i)
            out.append(img.convert("RGB").tobytes())
        return out


@pytest.mark.parametrize("name", list(SAMPLES))
def test_every_other_tag_is_kept_in_exiftools_view(copies: tuple[Path, Path, ProblemLog], name: str) -> None:
    card, out, _ = copies
    before, after = exiftool_view(card / name), exiftool_view(out / name)
    assert before.get("IFD0:Model") or before.get("IFD0:Make")
    changed = {k: (before.get(k), after.get(k)) for k in set(before) | set(after) if before.get(k) != after.get(k)}
    assert changed == {}


@pytest.mark.parametrize("name", list(SAMPLES))
def test_every_other_tag_is_kept_in_exiv2s_view(copies: tuple[Path, Path, ProblemLog], name: str) -> None:
    card, out, _ = copies
    before, after = exiv2_view(card / name), exiv2_view(out / name)
    changed = {k: (before.get(k), after.get(k)) for k in set(before) | set(after) if before.get(k) != after.get(k)}
    assert changed == {}
    assert len(before) > 20


@pytest.mark.parametrize("name", list(SAMPLES))
def test_thumbnails_previews_validation_and_pixels(copies: tuple[Path, Path, ProblemLog], name: str) -> None:
    card, out, _ = copies
    assert binaries(out / name) == binaries(card / name)
    assert warnings(out / name) - warnings(card / name) == set()
    assert frames_of(out / name) == frames_of(card / name)


def test_samples_have_what_the_checks_are_about(copies: tuple[Path, Path, ProblemLog]) -> None:
    """The checks above would pass on files with nothing in them: make sure these have maker notes etc."""
    card, out, _ = copies
    canon = exiftool_view(card / "flower.jpg")
    assert sum(1 for k in canon if k.startswith("Canon")) > 30
    assert "ThumbnailImage" in binaries(card / "flower.jpg")
    assert "MPImage2" in binaries(card / "fujifilm.mpo")
    assert sum(1 for k in exiftool_view(card / "fujifilm.mpo") if k.startswith("FujiFilm")) > 20
    gps = subprocess.run(["exiftool", "-j", "-n", "-GPS:all", str(out / "flower.jpg")], capture_output=True,
                         text=True, check=True).stdout  # fmt: skip
    assert json.loads(gps)[0]["GPSLatitude"] == pytest.approx(ORIGIN[0], abs=1e-3)


def test_cut_off_images_are_problem_rows_and_get_no_copy(copies: tuple[Path, Path, ProblemLog]) -> None:
    _, out, problems = copies
    for name in DAMAGED:
        (row,) = [p for p in problems if p.image == name]
        assert row.severity == "error" and "cut off" in row.detail and row.affects == "jpeg"
        assert not (out / name).exists()
    assert not list(out.glob(".*"))  # no temporary copies left behind
