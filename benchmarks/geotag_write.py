#!/usr/bin/env python3
"""Benchmark: geotagged copies of 236 full-size camera JPEGs, icgt's writer against ExifTool writing the same tags.

    .venv/bin/python benchmarks/geotag_write.py [--count 236] [--repeat 1]

The card: 236 copies of one full-size (6000 x 4000, about 24 MP) camera JPEG, generated once
under build/bench/geotag_card/: its pixels made here, its EXIF block the Canon PowerShot S40's
from Pillow's sdist (maker notes, IFD1 thumbnail; tests/export/camera_samples.py downloads it).

Timed in the same run (best of --repeat), both writing to a fresh folder on the same disk:
(a) the peer: one ``exiftool`` process (``-@`` argument file, one ``-execute`` per image) writing
    exactly the tags icgt writes (the same command lines, from `icgt.export.exif_tags.write_args`)
    into copies, and nothing else: no reading of the originals, no check of the copies;
(b) icgt's `write_geotagged_copies`: the originals read (batched), checked whole, the copies
    written, read back, compared and renamed into place.
Target: (b) no slower than (a).
"""

from __future__ import annotations

import argparse
import math
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

from icgt.export.common import ProblemLog, prepare_items
from icgt.export.exif_tags import ICGT_TAGS, intended_tags, write_args
from icgt.export.exiftool_session import config_text
from icgt.export.geotag_writer import write_geotagged_copies
from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
from icgt.geotag.record import FrameRecord

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "export"))
from camera_samples import camera_samples  # noqa: E402

CACHE = ROOT / "build" / "bench" / "geotag_card"
ORIGIN = (37.8813, 127.7298, 76.0)


def full_size_jpeg(path: Path) -> None:
    """6000 x 4000 with texture a camera would record (gradients and noise: about 10 MB at quality 92)."""
    rng = np.random.default_rng(7)
    y, x = np.mgrid[0:4000, 0:6000]
    base = (np.sin(x / 170.0) * 60 + np.cos(y / 90.0) * 50 + 128)[..., None] + np.array([0.0, 10.0, -10.0])
    pixels = np.clip(base + rng.normal(0, 14, (4000, 6000, 3)), 0, 255).astype(np.uint8)
    exif = Image.open(camera_samples()["flower.jpg"]).info["exif"]  # raw APP1 payload, maker notes included
    Image.fromarray(pixels).save(path, format="JPEG", quality=92, exif=exif)


def card(count: int) -> list[Path]:
    CACHE.mkdir(parents=True, exist_ok=True)
    master = CACHE / "master.jpg"
    if not master.exists():
        full_size_jpeg(master)
    paths = [CACHE / f"IMG_{i:04d}.JPG" for i in range(1, count + 1)]
    for p in paths:
        if not p.exists():
            shutil.copyfile(master, p)
    return paths


def frame(seq: int) -> FrameRecord:
    q = q_multiply(q_from_euler_zyx(0.0, math.radians(-60.0), math.radians(10.0 + seq)), np.array([0.5] * 4))
    lat, lon, alt = LocalFrame(*ORIGIN).enu_to_geodetic(np.array([seq * 0.8, 2.0, 18.0]))
    return FrameRecord(
        frame_seq=seq, image_index=seq, camera_id=0, device_flags=16, trigger_device_us=seq * 200_000,
        start_device_us=seq * 200_000 + 48_000, mid_device_us=seq * 200_000 + 48_500, duration_us=1000,
        mid_host_ns=seq * 200_000_000, mid_host_uncertainty_ns=30_000, time_source="pps", flags=[],
        position_source="gps_3d", fix_type=3, pose_gap_before_ms=5.0, pose_gap_after_ms=15.0,
        mid_utc_us=1_795_305_954_000_000 + seq * 200_000, mid_utc_uncertainty_us=1.0,
        lat_deg=float(lat), lon_deg=float(lon), alt_msl_m=float(alt), east_m=seq * 0.8, north_m=2.0, up_m=18.0,
        h_acc_m=0.02, v_acc_m=0.03, satellites=20,
        cam_qw=float(q[0]), cam_qx=float(q[1]), cam_qy=float(q[2]), cam_qz=float(q[3]), range_m=4.2, range_valid=True,
    )  # fmt: skip


def run_peer(items: list, before: dict, out: Path, cfg: Path) -> float:
    lines: list[str] = []
    for item in items:
        tags = intended_tags(item, before)
        lines += ["-q", *write_args(item.image, out / item.image.name, tags), "-execute"]
    argfile = out / "args.txt"
    argfile.write_text("\n".join(lines) + "\n", encoding="utf-8")
    t0 = time.perf_counter()
    subprocess.run(["exiftool", "-config", str(cfg), "-q", "-q", "-@", str(argfile)], check=True)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=236)
    ap.add_argument("--repeat", type=int, default=1)
    args = ap.parse_args()
    paths = card(args.count)
    size_mb = sum(p.stat().st_size for p in paths) / 1e6
    problems = ProblemLog()
    items = prepare_items([(p, frame(i)) for i, p in enumerate(paths, 1)], None, problems)
    before = {"IFD0:Make": "Canon"}
    best_peer = best_ours = math.inf
    with tempfile.TemporaryDirectory(dir=CACHE.parent) as tmp:
        cfg = Path(tmp) / "icgt.config"
        cfg.write_text(config_text(ICGT_TAGS), encoding="utf-8")
        for r in range(args.repeat):
            peer_out, ours_out = Path(tmp) / f"peer{r}", Path(tmp) / f"ours{r}"
            peer_out.mkdir()
            best_peer = min(best_peer, run_peer(items, before, peer_out, cfg))
            shutil.rmtree(peer_out)
            problems = ProblemLog()
            t0 = time.perf_counter()
            n = write_geotagged_copies(items, ours_out, problems)
            best_ours = min(best_ours, time.perf_counter() - t0)
            if n != len(items):
                print(f"icgt wrote {n} of {len(items)} copies: {[p.detail for p in problems][:3]}")
                return 1
            shutil.rmtree(ours_out)
    n = len(items)
    print(f"card: {n} JPEGs, 6000x4000, {size_mb / n:.1f} MB each, Canon S40 EXIF with maker notes and thumbnail")
    print(
        f"(a) exiftool, one process, same tags, no read-back: {best_peer:7.2f} s  "
        f"({1000 * best_peer / n:6.1f} ms/image)"
    )
    print(
        f"(b) icgt export, read + write + read-back check:   {best_ours:7.2f} s  ({1000 * best_ours / n:6.1f} ms/image)"
    )
    print(f"ratio (b)/(a): {best_ours / best_peer:.2f}  (target <= 1.00)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
