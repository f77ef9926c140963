#!/usr/bin/env python3
"""Benchmark: exporting a one-hour flight against the official mcap reader merely iterating the same file.

    .venv/bin/python benchmarks/export_speed.py [--regenerate] [--repeat 2]

The flight is synthetic but written the way the recorder writes a real one (McapRecorder, the
recorder's topic helpers and schemas, one chunk per second of flight): one hour at 5 fps, i.e.
18 000 FrameRecords on /frames, 360 000 IMU (100 Hz) and 1 800 000 RANGE (500 Hz) raw device
messages, plus the metadata the exporter reads (icgt.calibration, icgt.enu_origin). It is generated
once (a few minutes) and cached under build/bench/.

Timed in the same run, best of --repeat:
(a) the official mcap reader (`mcap.reader.make_reader`) iterating every message of the file, with
    its defaults (log-time order) and without ordering (the cheaper of the two is the baseline);
(b) the full export without JPEGs: the frames read with the ingest reader (`icgt.ingest.read`),
    geometry solved for every frame, frames.csv + cameras/footprints.geojson + geo.txt +
    exif_overrides.json written to a temporary folder.
Target: (b) <= 2 x (a).
"""

from __future__ import annotations

import argparse
import math
import tempfile
import time
from pathlib import Path

import numpy as np

from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
from icgt.geotag.record import FrameRecord
from icgt.protocol.messages import Imu, Range, RangeFlags
from icgt.recorder import topics
from icgt.recording import McapRecorder

ROOT = Path(__file__).resolve().parents[1]
CACHE = ROOT / "build" / "bench" / "export_speed_1h.mcap"
DURATION_S = 3600
FPS = 5
IMU_HZ = 100
RANGE_HZ = 500
ORIGIN = (37.8813, 127.7298, 76.0)
T0_MONO_NS = 1_000_000_000_000
MONO_TO_UTC_NS = 1_795_300_000_000_000_000
DEVICE_OFFSET_US = 3_000_000
_Q_BASE = np.array([0.5, 0.5, 0.5, 0.5])  # camera optical axes -> body FRD (the geotagger's base alignment)


def _pose(t: float) -> tuple[np.ndarray, float]:
    """Camera ENU position and body yaw [rad] at flight time t: vertical passes up and down a pier face."""
    period = 40.0
    k, frac = divmod(t, period)
    up = 1.0 + 11.0 * (0.5 - 0.5 * math.cos(2.0 * math.pi * frac / period))
    east = -20.0 + 1.6 * (k % 25) + 0.05 * math.sin(t / 3.0)
    north = 0.02 * math.sin(t / 5.0)
    return np.array([east, north, up]), 0.02 * math.sin(t / 7.0)


def _frame(seq: int, t: float, frame: LocalFrame) -> FrameRecord:
    pos, yaw = _pose(t)
    q_body = q_from_euler_zyx(0.01 * math.sin(t), 0.01 * math.cos(t), yaw)
    q_cam = q_multiply(q_body, _Q_BASE)
    lat, lon, alt = frame.enu_to_geodetic(pos)
    mid_dev = DEVICE_OFFSET_US + round(t * 1e6)
    rng = 2.5 - pos[1] + 0.01 * math.sin(t * 3.0)
    return FrameRecord(
        frame_seq=seq,
        image_index=seq,
        camera_id=0,
        device_flags=16,
        trigger_device_us=mid_dev - 48_500,
        start_device_us=mid_dev - 500,
        mid_device_us=mid_dev,
        duration_us=1000,
        mid_host_ns=T0_MONO_NS + round(t * 1e9),
        mid_host_uncertainty_ns=20_000,
        time_source="system_time",
        flags=[],
        position_source="gps_3d",
        fix_type=3,
        pose_gap_before_ms=12.0,
        pose_gap_after_ms=8.0,
        mid_utc_us=(MONO_TO_UTC_NS + T0_MONO_NS) // 1000 + round(t * 1e6),
        mid_utc_uncertainty_us=900.0,
        lat_deg=float(lat),
        lon_deg=float(lon),
        alt_msl_m=float(alt),
        east_m=float(pos[0]),
        north_m=float(pos[1]),
        up_m=float(pos[2]),
        h_acc_m=0.7,
        v_acc_m=1.4,
        satellites=15,
        body_qw=float(q_body[0]),
        body_qx=float(q_body[1]),
        body_qy=float(q_body[2]),
        body_qz=float(q_body[3]),
        roll_deg=math.degrees(0.01 * math.sin(t)),
        pitch_deg=math.degrees(0.01 * math.cos(t)),
        yaw_deg=math.degrees(yaw) % 360.0,
        cam_qw=float(q_cam[0]),
        cam_qx=float(q_cam[1]),
        cam_qy=float(q_cam[2]),
        cam_qz=float(q_cam[3]),
        imu_qw=1.0,
        imu_qx=0.0,
        imu_qy=0.0,
        imu_qz=0.0,
        imu_gyro_rad_s=0.01,
        imu_calib_sys=3,
        imu_calib_gyr=3,
        imu_calib_acc=3,
        imu_calib_mag=3,
        imu_age_ms=2.0,
        range_m=rng,
        range_age_ms=1.0,
        range_valid=True,
        scale_mm_per_px=rng * 1000.0 * (35.6 / 6000) / 35.0,
        incidence_deg=0.0,
        blur_px=0.2,
    )


def generate(path: Path) -> None:
    """Write the one-hour recording to path (via a temporary name, so an interrupted run leaves no cache)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".partial")
    tmp.unlink(missing_ok=True)
    frame = LocalFrame(*ORIGIN)
    start = time.perf_counter()
    with McapRecorder(tmp, fsync=False, max_chunk_interval_s=3600.0) as rec:
        rec.register_json(topics.device_topic("IMU"), "icgt.device.IMU", topics.device_schema(Imu))
        rec.register_json(topics.device_topic("RANGE"), "icgt.device.RANGE", topics.device_schema(Range))
        rec.register_dataclass(topics.FRAMES, FrameRecord)
        rec.add_metadata(
            "icgt.calibration",
            {
                "focal_length_mm": "35.0",
                "sensor_width_mm": "35.6",
                "image_width_px": "6000",
                "image_height_px": "4000",
                "surface_normal_enu": "(0.0, -1.0, 0.0)",
            },
        )
        rec.add_metadata(
            "icgt.enu_origin", {"lat_deg": repr(ORIGIN[0]), "lon_deg": repr(ORIGIN[1]), "alt_msl_m": repr(ORIGIN[2])}
        )
        rec.add_metadata("icgt.time_bases", {"monotonic_to_utc_offset_ns": str(MONO_TO_UTC_NS)})
        imu_topic, range_topic = topics.device_topic("IMU"), topics.device_topic("RANGE")
        seq = 0
        frame_seq = 0
        for second in range(DURATION_S):
            events: list[tuple[float, int]] = []  # (t, kind): 0 range, 1 imu, 2 frame
            events += [(second + k / RANGE_HZ, 0) for k in range(RANGE_HZ)]
            events += [(second + k / IMU_HZ + 0.0003, 1) for k in range(IMU_HZ)]
            events += [(second + k / FPS + 0.0007, 2) for k in range(FPS)]
            events.sort()
            for t, kind in events:
                host_ns = T0_MONO_NS + round(t * 1e9) + 400_000
                log_ns = host_ns + MONO_TO_UTC_NS
                dev_us = DEVICE_OFFSET_US + round(t * 1e6)
                if kind == 2:
                    frame_seq += 1
                    rec.write(topics.FRAMES, _frame(frame_seq, t, frame), log_ns)
                    continue
                seq = (seq + 1) & 0xFFFF
                if kind == 0:
                    msg: Imu | Range = Range(
                        acq_start_t_us=dev_us,
                        read_t_us=dev_us + 1200,
                        distance_cm=250 + (dev_us // 7919) % 5,
                        signal_strength=120,
                        flags=int(RangeFlags.VALID),
                    )
                    rec.write(range_topic, topics.device_payload(msg, seq, 0, host_ns), log_ns)
                else:
                    s = math.sin(t)
                    msg = Imu(
                        read_start_t_us=dev_us,
                        read_end_t_us=dev_us + 900,
                        quat_w=1.0,
                        quat_x=0.001 * s,
                        quat_y=-0.001 * s,
                        quat_z=0.0005,
                        gyro_x_rad_s=0.01 * s,
                        gyro_y_rad_s=0.002,
                        gyro_z_rad_s=-0.003,
                        accel_x_m_s2=0.02,
                        accel_y_m_s2=-0.01,
                        accel_z_m_s2=-9.81,
                        lin_accel_x_m_s2=0.02,
                        lin_accel_y_m_s2=-0.01,
                        lin_accel_z_m_s2=0.0,
                        calib_stat=0xFF,
                    )
                    rec.write(imu_topic, topics.device_payload(msg, seq, 0, host_ns), log_ns)
            rec.flush()  # one chunk per second of flight, as the recorder's 1 s chunk timer makes
            if second % 600 == 599:
                print(f"  generated {second + 1} s of flight ({time.perf_counter() - start:.0f} s)", flush=True)
    tmp.rename(path)


def time_official(path: Path, *, log_time_order: bool) -> tuple[float, int]:
    from mcap.reader import make_reader

    start = time.perf_counter()
    n = 0
    with path.open("rb") as f:
        for _ in make_reader(f).iter_messages(log_time_order=log_time_order):
            n += 1
    return time.perf_counter() - start, n


def time_export(path: Path, out_dir: Path) -> tuple[float, dict[str, int]]:
    from icgt.export.cli import camera_from_metadata, export_items, surface_normal_from_metadata
    from icgt.export.common import ProblemLog, prepare_items
    from icgt.geometry import Projector
    from icgt.ingest import read

    start = time.perf_counter()
    recording = read(path)
    frames = list(recording.frames())
    camera = camera_from_metadata(recording.metadata)
    assert camera is not None
    projector = Projector(
        camera, origin=recording.enu_origin, surface_normal=surface_normal_from_metadata(recording.metadata)
    )
    problems = ProblemLog()
    pairs = [(Path(f"DSC{f.image_index:05d}.JPG"), f) for f in frames]
    items = prepare_items(pairs, projector, problems)
    written = export_items(items, out_dir, ["csv", "geojson", "odm", "opensfm"], problems, geoid_separation_m=24.9)
    elapsed = time.perf_counter() - start
    written["problems"] = len(problems)
    return elapsed, written


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--regenerate", action="store_true", help="rewrite the cached one-hour recording")
    parser.add_argument("--repeat", type=int, default=2, help="runs of each measurement (best is kept)")
    parser.add_argument("--file", type=Path, default=CACHE, help="where the recording is cached")
    args = parser.parse_args()
    if args.regenerate or not args.file.exists():
        print(f"generating a one-hour flight into {args.file} (once; a few minutes) ...", flush=True)
        generate(args.file)
    size_mb = args.file.stat().st_size / 1e6
    print(f"recording {args.file} ({size_mb:.0f} MB)")
    ordered, unordered, export = math.inf, math.inf, math.inf
    count = 0
    written: dict[str, int] = {}
    for _ in range(max(1, args.repeat)):
        t, count = time_official(args.file, log_time_order=True)
        ordered = min(ordered, t)
        t, _ = time_official(args.file, log_time_order=False)
        unordered = min(unordered, t)
        with tempfile.TemporaryDirectory() as tmp:
            t, written = time_export(args.file, Path(tmp))
        export = min(export, t)
    baseline = min(ordered, unordered)
    print(f"official mcap reader, iterate all {count} messages (log-time order): {ordered:6.2f} s")
    print(f"official mcap reader, iterate all {count} messages (file order):     {unordered:6.2f} s")
    print(f"icgt export (read /frames + geometry + CSV, GeoJSON, geo.txt, OpenSfM): {export:6.2f} s  {written}")
    ratio = export / baseline
    verdict = "meets" if ratio <= 2.0 else "MISSES"
    print(f"ratio export / fastest official iteration: {ratio:.2f}x  ({verdict} the <= 2x target)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
