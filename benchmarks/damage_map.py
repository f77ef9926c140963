#!/usr/bin/env python3
"""Benchmark: the damage map against the simulator's truth, next to the paper's per-image method; and
`icgt map` on a one-hour flight's worth of images (time, peak memory).

    .venv/bin/python benchmarks/damage_map.py [--regenerate] [--skip-1h]

(a) Accuracy. The damage-map test flight (tests/mapping/damage_flight.toml: two passes 2 m from a
pier face, five cracks and two spalls) is flown once on the simulator and cached under
build/bench/damage_flight/. The simulated detector (icgt.sim.detector) makes detections from the
truth (true pose, visible part only, 0.3 px noise). Compared with the truth, side by side:
  - `icgt map` (placed on the fitted surface, merged across images, fused);
  - the paper's method: every detection projected on its own image's plane perpendicular to the
    optical axis at the LiDAR distance (eqs 5-7), crack length D * |normalised polyline|, no merging.
Figures: defects reported vs true (count inflation), crack length error and position error p50/p95.
Targets: count exact; length p95 <= 5 % at 2 m standoff; position p95 <= the flight's geotag error
p95 + the LiDAR's range noise (2.5 cm).

(b) Scale. A synthetic one-hour flight (cached under build/bench/damage_1h/): 4 fps for 3600 s
(14 400 frames written with the recorder's McapRecorder and FrameRecord schema), vertical passes
2.5 m from a 40 m face, 600x400 px JPEGs with EXIF times, 400 cracks on the face projected into
every image that sees them. `icgt map` runs as a separate process on it (mosaic at 10 mm/px); its
wall time, CPU time and peak resident memory are printed next to the flight's duration and next to
what holding every decoded image at once would take.
"""

from __future__ import annotations

import argparse
import json
import math
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
CACHE = ROOT / "build" / "bench"
SCENARIO = ROOT / "tests" / "mapping" / "damage_flight.toml"
RANGE_NOISE_M = 0.025


def _flight(regenerate: bool) -> Path:
    from mapping.conftest import fly_healthy

    from icgt.sim.scenario import load_scenario

    out = CACHE / "damage_flight"
    done = out / "done.json"
    if done.is_file() and not regenerate:
        return out
    shutil.rmtree(out, ignore_errors=True)
    print("flying tests/mapping/damage_flight.toml on the simulator (about a minute) ...", flush=True)
    f = fly_healthy(load_scenario(SCENARIO), out)
    done.write_text(json.dumps({"mcap": str(f.mcap.relative_to(out)), "card": str(f.card.relative_to(out))}))
    return out


def accuracy(regenerate: bool) -> bool:
    from mapping.conftest import read_exposures

    from icgt.geometry import Projector
    from icgt.mapping.cli import run_map
    from icgt.mapping.model import CRACK, midpoint
    from icgt.mapping.place import Errors
    from icgt.sim.detector import detect_all, write_polylines
    from icgt.sim.map_truth import MappedItem, compare, geotag_errors_m, load_truth, p50_p95
    from icgt.sim.scenario import load_scenario

    base = _flight(regenerate)
    info = json.loads((base / "done.json").read_text())
    mcap, card = base / info["mcap"], base / info["card"]
    sim = card.parent  # the simulator writes the card into its output folder
    sc = load_scenario(SCENARIO)
    dets = detect_all(sc, read_exposures(sim / "truth_exposures.jsonl"), seed=7)
    write_polylines(base / "detections.json", dets)
    t0 = time.perf_counter()
    res = run_map(mcap, card, [base / "detections.json"], base / "map", calibration=sim / "camera_calibration.toml",
                  errors=Errors(position_m=0.015), mm_per_px=2.0, lookahead_s=1.0)  # fmt: skip
    t_map = time.perf_counter() - t0
    ses = res.session
    truth = load_truth(sim / "truth_defects.json", ses.origin)
    merged = []
    for inst in res.instances:
        mid = midpoint(inst.enu) if inst.kind == CRACK else ses.face.to_enu(
            np.asarray(shapely.Polygon(inst.face).centroid.coords[0]))  # fmt: skip
        merged.append(MappedItem(inst.kind, mid, inst.length_mm, inst.area_mm2))
    paper_proj = Projector(ses.camera, origin=ses.origin)
    paper = []
    for p in res.placed:
        rec = ses.images[p.det.image][1]
        f = ses.camera.width_px / ses.size(p.det.image)[0]
        px = (p.det.points_px + 0.5) * f - 0.5
        if p.det.kind == CRACK:
            c = paper_proj.crack_position(rec, px)
            paper.append(MappedItem(CRACK, c.midpoint_enu, c.length_mm_paper))
        else:
            w = paper_proj.pixel_to_world(rec, px[:, 0], px[:, 1])
            area = shapely.Polygon(w.plane_st).area * 1e6
            paper.append(MappedItem(p.det.kind, w.enu.mean(axis=0), None, area))
    geotag = geotag_errors_m(ses.frames, sim / "truth_exposures.jsonl", sc, ses.origin)
    g95 = float(np.percentile(geotag, 95))
    bound = (g95 + RANGE_NOISE_M) * 1000.0
    n_cracks = sum(1 for t in truth if t.kind == CRACK)
    print(f"\n(a) {len(truth)} true defects ({n_cracks} cracks, {len(truth) - n_cracks} spalls), "
          f"{len(res.session.images)} images, {len(dets)} detections; map took {t_map:.1f} s")  # fmt: skip
    print(f"    geotag error of the flight: p50 {np.percentile(geotag, 50) * 1000:.1f} mm, p95 {g95 * 1000:.1f} mm; "
          f"position target p95 <= {bound:.1f} mm")  # fmt: skip
    print(f"    {'method':<28}{'reported':>9}{'inflation':>10}{'dupl.':>7}{'missed':>7}"
          f"{'length err % p50/p95':>22}{'position mm p50/p95':>21}{'area % p50/p95':>16}")  # fmt: skip
    ok = True
    for name, items in (("icgt map (merged)", merged), ("paper, per image", paper)):
        c = compare(truth, items)
        lp = p50_p95(c.length_err_pct)
        pp = p50_p95(c.position_err_mm)
        ap = p50_p95(c.area_err_pct)
        print(f"    {name:<28}{c.reported:>9}{c.reported / c.truth:>9.1f}x{c.duplicates:>7}{len(c.missed):>7}"
              f"{lp[0]:>12.2f} / {lp[1]:<7.2f}{pp[0]:>11.1f} / {pp[1]:<7.1f}{ap[0]:>7.1f} / {ap[1]:<6.1f}")  # fmt: skip
        if name.startswith("icgt"):
            ok = c.count_exact and lp[1] <= 5.0 and pp[1] <= bound
    print(f"    targets (icgt map): count exact, length p95 <= 5 %, position p95 <= {bound:.1f} mm: "
          f"{'met' if ok else 'NOT MET'}")  # fmt: skip
    return ok


# --- (b) one hour ---------------------------------------------------------------------------

FPS = 4
DURATION_S = 3600
ORIGIN = (37.8813, 127.7298, 76.0)
WALL_NORTH_M = 2.5
T0_MONO_NS = 1_000_000_000_000
MONO_TO_UTC_NS = 1_795_300_000_000_000_000
CAMERA = dict(focal_length_mm=35.0, sensor_width_mm=35.6, width_px=6000, height_px=4000)
IMG = (600, 400)


def _pose(t: float) -> tuple[np.ndarray, float]:
    period = 40.0
    k, frac = divmod(t, period)
    up = 1.0 + 11.0 * (0.5 - 0.5 * math.cos(2.0 * math.pi * frac / period))
    east = -20.0 + 1.6 * (k % 25) + 0.02 * math.sin(t / 3.0)
    return np.array([east, 0.02 * math.sin(t / 5.0), up]), 0.01 * math.sin(t / 7.0)


def _generate_1h(out: Path) -> None:
    from PIL import Image

    from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
    from icgt.geometry import CameraModel
    from icgt.geotag.record import FrameRecord
    from icgt.mapping.pose import world_to_pixel
    from icgt.recorder import topics
    from icgt.recording import McapRecorder
    from icgt.sim.truth import exif_strings

    shutil.rmtree(out, ignore_errors=True)
    card = out / "card"
    card.mkdir(parents=True)
    frame = LocalFrame(*ORIGIN)
    cam = CameraModel.from_sensor(
        CAMERA["focal_length_mm"], CAMERA["sensor_width_mm"], CAMERA["width_px"], CAMERA["height_px"]
    )
    rng = np.random.default_rng(1)
    texture = Image.fromarray(rng.integers(110, 170, size=(IMG[1], IMG[0]), dtype=np.uint8)).convert("RGB")
    # 400 cracks on the face (north = 2.5 m), 0.2-0.8 m long, spread over the scanned area
    starts = np.stack([rng.uniform(-21.0, 20.0, 400), rng.uniform(0.5, 12.0, 400)], axis=1)
    angles = rng.uniform(0, math.pi, 400)
    lengths = rng.uniform(0.2, 0.8, 400)
    u = np.linspace(0.0, 1.0, 8)
    cracks = [
        np.stack([e0 + u * length * math.cos(a), np.full(8, WALL_NORTH_M), z0 + u * length * math.sin(a)], axis=1)
        for (e0, z0), a, length in zip(starts, angles, lengths, strict=True)
    ]
    detections: dict[str, list[dict[str, object]]] = {}
    tmp = out / "flight.partial"
    n_frames = FPS * DURATION_S
    with McapRecorder(tmp, fsync=False, max_chunk_interval_s=3600.0) as rec:
        rec.register_dataclass(topics.FRAMES, FrameRecord)
        rec.add_metadata("icgt.calibration", {"focal_length_mm": "35.0", "sensor_width_mm": "35.6",
                         "image_width_px": "6000", "image_height_px": "4000",
                         "surface_normal_enu": "(0.0, -1.0, 0.0)"})  # fmt: skip
        rec.add_metadata(
            "icgt.enu_origin", {"lat_deg": repr(ORIGIN[0]), "lon_deg": repr(ORIGIN[1]), "alt_msl_m": repr(ORIGIN[2])}
        )
        rec.add_metadata("icgt.time_bases", {"monotonic_to_utc_offset_ns": str(MONO_TO_UTC_NS)})
        for seq in range(1, n_frames + 1):
            t = seq / FPS
            pos, yaw = _pose(t)
            q_body = q_from_euler_zyx(0.0, 0.0, yaw)
            q_cam = q_multiply(q_body, np.array([0.5, 0.5, 0.5, 0.5]))
            lat, lon, alt = frame.enu_to_geodetic(pos)
            mid_dev = 3_000_000 + round(t * 1e6)
            utc_us = (MONO_TO_UTC_NS + T0_MONO_NS) // 1000 + round(t * 1e6)
            r = WALL_NORTH_M - float(pos[1])
            fr = FrameRecord(
                frame_seq=seq, image_index=seq, camera_id=0, device_flags=16, trigger_device_us=mid_dev - 48_500,
                start_device_us=mid_dev - 500, mid_device_us=mid_dev, duration_us=1000,
                mid_host_ns=T0_MONO_NS + round(t * 1e9), mid_host_uncertainty_ns=20_000, time_source="system_time",
                flags=[], position_source="gps_3d", fix_type=6, pose_gap_before_ms=12.0, pose_gap_after_ms=8.0,
                mid_utc_us=utc_us, mid_utc_uncertainty_us=900.0, lat_deg=float(lat), lon_deg=float(lon),
                alt_msl_m=float(alt), east_m=float(pos[0]), north_m=float(pos[1]), up_m=float(pos[2]),
                cam_qw=float(q_cam[0]), cam_qx=float(q_cam[1]), cam_qy=float(q_cam[2]), cam_qz=float(q_cam[3]),
                range_m=r, range_age_ms=1.0, range_valid=True, scale_mm_per_px=r * 1000.0 * (35.6 / 6000) / 35.0,
            )  # fmt: skip
            rec.write(topics.FRAMES, fr, utc_us * 1000 + 400_000)
            name = f"DSC{seq:05d}.JPG"
            img = texture.copy()
            exif = img.getexif()
            text, sub = exif_strings((utc_us - 500) / 1e6, "10ms")
            exif[0x0132] = text
            ifd = exif.get_ifd(0x8769)
            ifd[0x9003] = ifd[0x9004] = text
            ifd[0x9291] = ifd[0x9292] = sub
            img.save(card / name, format="JPEG", quality=85, exif=exif)
            near = [c for c in cracks if abs(c[:, 0].mean() - pos[0]) < 1.6 and abs(c[:, 2].mean() - pos[2]) < 1.2]
            items = []
            for c in near:
                uv = (world_to_pixel(cam, fr, c) + 0.5) / 10.0 - 0.5
                inside = (uv[:, 0] > 0) & (uv[:, 1] > 0) & (uv[:, 0] < IMG[0] - 1) & (uv[:, 1] < IMG[1] - 1)
                if inside.sum() >= 2:
                    items.append({"kind": "crack", "points_px": np.round(uv[inside], 2).tolist(), "width_px": 1.0})
            if items:
                detections[name] = items
            if seq % 3600 == 0:
                print(f"  generated {seq} of {n_frames} frames", flush=True)
            if seq % FPS == 0:
                rec.flush()
    tmp.rename(out / "flight.mcap")
    (out / "detections.json").write_text(json.dumps({"format": "icgt-detections", "images": detections}))
    (out / "done").write_text(f"{len(cracks)} cracks\n")


def one_hour(regenerate: bool) -> None:
    out = CACHE / "damage_1h"
    if regenerate or not (out / "done").is_file():
        print("generating the one-hour flight (a few minutes, cached) ...", flush=True)
        _generate_1h(out)
    shutil.rmtree(out / "map", ignore_errors=True)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "icgt.cli", "map", str(out / "flight.mcap"), "--images", str(out / "card"),
         "--detections", str(out / "detections.json"), "--out", str(out / "map"), "--plane", "0,2.5,0,0,-1,0",
         "--position-sigma-m", "0.01", "--mm-per-px", "10", "--cache-mb", "256"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0, 2):
        raise SystemExit(f"icgt map failed ({proc.returncode}):\n{proc.stderr[-3000:]}")
    summary = json.loads((out / "map" / "map.json").read_text())
    n_img = summary["images_matched"]
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    rss_mb = after.ru_maxrss / 1024.0
    naive_mb = n_img * CAMERA["width_px"] * CAMERA["height_px"] * 3 / 2**20
    print(f"\n(b) one hour: {n_img} images matched, {summary['detections']} detections -> "
          f"{sum(summary['instances'].values())} defects (400 true cracks, some outside the scanned area)")  # fmt: skip
    print(f"    icgt map: wall {wall:.0f} s, CPU {cpu:.0f} s, peak RSS {rss_mb:.0f} MB; mosaic "
          f"{summary['mosaic']['width_px']} x {summary['mosaic']['height_px']} px at 10 mm/px")  # fmt: skip
    print(f"    peers: the flight itself {DURATION_S} s; the decoded 600x400 images all at once "
          f"{n_img * IMG[0] * IMG[1] * 3 / 2**20:.0f} MB, as 24 MP images {naive_mb / 1024:.0f} GB")  # fmt: skip
    print("    " + proc.stdout.strip().replace("\n", "\n    "))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--regenerate", action="store_true", help="fly / generate the cached inputs again")
    ap.add_argument("--skip-1h", action="store_true", help="only (a)")
    args = ap.parse_args()
    ok = accuracy(args.regenerate)
    if not args.skip_1h:
        one_hour(args.regenerate)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
