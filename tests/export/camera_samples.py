"""Real camera JPEGs with maker notes, from Pillow's source distribution on PyPI, downloaded at test time.

Pillow's sdist carries its test images (Tests/images): a Canon PowerShot S40 JPEG with Canon maker
notes and an IFD1 thumbnail, Fujifilm FinePix REAL 3D W3 and Nintendo 3DS MPO files (two images,
MPF, maker notes), a Canon EOS Rebel T6 JPEG with a Lightroom XMP packet, a Google Pixel 6 Ultra
a Samsung NX1000 MPO, a Nikon D800 JPEG and a Nokia N70 JPEG with IPTC; and two cut-off files (`DAMAGED`:
a Google Pixel 6 Ultra HDR JPEG whose scan data stops after its headers, and a truncated JPEG). They are fetched
once with `pip download` into a cache folder (``$ICGT_TEST_DATA``, else ~/.cache/icgt-test-data),
never committed; an empty cache means a download, not a skip.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tarfile
from pathlib import Path

PILLOW_SDIST = "11.0.0"
SAMPLES = {
    "flower.jpg": "Canon PowerShot S40",
    "fujifilm.mpo": "FUJIFILM FinePix REAL 3D W3",
    "frozenpond.mpo": "Nintendo 3DS",
    "xmp_test.jpg": "Canon EOS Rebel T6",
    "ignore_frame_size.mpo": "SAMSUNG NX1000",
    "broken_exif_dpi.jpg": "NIKON D800",
    "iptc.jpg": "Nokia N70-1",
}
DAMAGED = {"ultrahdr.jpg": "Google Pixel 6, cut off after its headers", "truncated_jpeg.jpg": "cut off in its scan"}


def cache_dir() -> Path:
    env = os.environ.get("ICGT_TEST_DATA")
    return Path(env) if env else Path.home() / ".cache" / "icgt-test-data"


def camera_samples() -> dict[str, Path]:
    """{file name: path} of the sample images (SAMPLES and DAMAGED), from the (downloaded if missing) Pillow sdist."""
    names = {**SAMPLES, **DAMAGED}
    root = cache_dir() / f"pillow-{PILLOW_SDIST}-images"
    if all((root / n).is_file() for n in names):
        return {n: root / n for n in names}
    dl = cache_dir() / "sdist"
    dl.mkdir(parents=True, exist_ok=True)
    archive = dl / f"pillow-{PILLOW_SDIST}.tar.gz"
    if not archive.is_file():
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-binary", ":all:", "--no-deps",
               f"pillow=={PILLOW_SDIST}", "-d", str(dl)]  # fmt: skip
        subprocess.run(cmd, check=True, timeout=600)
    root.mkdir(parents=True, exist_ok=True)
    with tarfile.open(archive) as tar:
        for member in tar.getmembers():
            name = member.name.rsplit("/", 1)[-1]
            if name in names and "/Tests/images/" in member.name and member.isfile():
                src = tar.extractfile(member)
                assert src is not None
                (root / name).write_bytes(src.read())
    missing = [n for n in names if not (root / n).is_file()]
    assert not missing, f"not in pillow-{PILLOW_SDIST}'s sdist: {missing}"
    return {n: root / n for n in names}
