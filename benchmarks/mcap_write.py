#!/usr/bin/env python3
"""Benchmark: MCAP recording throughput and size, ICGT recorder against plain mcap-protobuf-support, same run.

    .venv/bin/python benchmarks/mcap_write.py [--seconds 60] [--compression zstd|lz4|none|all]

The mix is one second of a capture, repeated (709 messages): 5 frame records, 5 foxglove.LocationFix,
5 foxglove.PoseInFrame, 100 IMU and 500 range samples from the device, 84 raw MAVLink messages and
10 clock estimates (JSON). The recorder closes a chunk (and fsyncs) after every simulated second, as its
1-second timer does during a flight, so the size and CPU include per-second chunking. The peer is
mcap-protobuf-support's Writer putting the same number of LocationFix messages into 1 MiB chunks
with no time-based closing; the recorder writing those same LocationFix messages is printed too.
Files go to a temporary directory on the disk of the current directory (fsync is real).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.writer import CompressionType
from mcap_protobuf.writer import Writer as ProtobufWriter

from icgt.recording import Doc, McapRecorder
from icgt.recording.writer import Compression


@dataclass(frozen=True)
class ImuSample:
    """BNO055 sample as streamed by the device."""

    read_start_t_us: Annotated[int, Doc("read start, device clock", unit="us")]
    read_end_t_us: Annotated[int, Doc("read end, device clock", unit="us")]
    quat: Annotated[tuple[float, float, float, float], Doc("orientation quaternion w, x, y, z")]
    gyro_rad_s: Annotated[tuple[float, float, float], Doc("angular rate x, y, z", unit="rad/s")]
    accel_m_s2: Annotated[tuple[float, float, float], Doc("acceleration x, y, z", unit="m/s^2")]
    calib_stat: Annotated[int, Doc("BNO055 CALIB_STAT register")]
    seq: Annotated[int, Doc("protocol sequence number")]


@dataclass(frozen=True)
class RangeSample:
    """LiDAR-Lite distance sample as streamed by the device."""

    acq_start_t_us: Annotated[int, Doc("acquisition start, device clock", unit="us")]
    read_t_us: Annotated[int, Doc("read time, device clock", unit="us")]
    distance_m: Annotated[float, Doc("distance", unit="m")]
    signal_strength: Annotated[int, Doc("signal strength, 0-255")]
    valid: Annotated[bool, Doc("measurement valid")]
    seq: Annotated[int, Doc("protocol sequence number")]


@dataclass(frozen=True)
class RawMavlink:
    """One MAVLink message exactly as received."""

    host_rx_ns: Annotated[int, Doc("host receive time since the Unix epoch", unit="ns")]
    msgid: Annotated[int, Doc("MAVLink message id")]
    name: Annotated[str, Doc("MAVLink message name")]
    raw: Annotated[bytes, Doc("the message bytes on the wire")]


@dataclass(frozen=True)
class ClockEstimate:
    """Device-to-host clock mapping."""

    offset_ns: Annotated[int, Doc("host minus device time", unit="ns")]
    drift_ppm: Annotated[float, Doc("device clock drift", unit="ppm")]
    sigma_ns: Annotated[float, Doc("1-sigma uncertainty", unit="ns")]


@dataclass(frozen=True)
class FrameRecord:
    """A geotagged exposure (a stand-in of the frame record's size and shape)."""

    frame_seq: Annotated[int, Doc("frame sequence number")]
    image_index: Annotated[int, Doc("image index on the card")]
    camera_id: Annotated[str, Doc("camera id")]
    mid_exposure_device_us: Annotated[int, Doc("mid-exposure, device clock", unit="us")]
    mid_exposure_host_ns: Annotated[int, Doc("mid-exposure, host clock", unit="ns")]
    mid_exposure_utc_ns: Annotated[int, Doc("mid-exposure, UTC", unit="ns")]
    exposure_s: Annotated[float, Doc("exposure duration", unit="s")]
    time_sigma_ns: Annotated[float, Doc("timestamp uncertainty", unit="ns")]
    lat_deg: Annotated[float, Doc("latitude WGS84", unit="deg")]
    lon_deg: Annotated[float, Doc("longitude WGS84", unit="deg")]
    alt_m: Annotated[float, Doc("altitude above the ellipsoid", unit="m")]
    enu_m: Annotated[tuple[float, float, float], Doc("position east, north, up", unit="m")]
    attitude_quat: Annotated[tuple[float, float, float, float], Doc("attitude w, x, y, z")]
    pose_source: Annotated[str, Doc("RTK, 3D_FIX, FUSED, VIO or NONE")]
    pose_gap_ms: Annotated[float, Doc("gap to the nearest pose samples", unit="ms")]
    range_m: Annotated[float, Doc("LiDAR range at exposure", unit="m")]
    range_age_ms: Annotated[float, Doc("age of the range sample", unit="ms")]
    scale_mm_px: Annotated[float, Doc("ground sample distance", unit="mm/px")]
    incidence_deg: Annotated[float, Doc("incidence angle", unit="deg")]
    flags: Annotated[list[str], Doc("quality flags")]


Item = tuple[str, Any, int]


def second_of_capture(s: int) -> Iterator[Item]:
    """The messages of simulated second `s`: (topic, message, log_time_ns)."""
    base_ns = 1_700_000_000_000_000_000 + s * 1_000_000_000
    for k in range(500):
        t_ns = base_ns + k * 2_000_000
        t_us = 10_000_000 + s * 1_000_000 + k * 2000
        yield "/device/range", RangeSample(t_us, t_us + 1800, 5.12 + (k % 7) * 0.01, 80, True, k), t_ns
        if k % 5 == 0:
            imu = ImuSample(t_us, t_us + 950, (0.99, 0.01, 0.02, 0.1), (0.01, -0.02, 0.003), (0.1, 0.2, 9.81), 255, k)
            yield "/device/imu", imu, t_ns
        if k % 100 == 0:
            frame = FrameRecord(
                s * 5 + k // 100, s * 5 + k // 100, "cam0", t_us, t_ns, t_ns, 0.002, 12_000.0, 47.3769 + k * 1e-7,
                8.5417, 512.3, (10.0 + k * 0.01, 20.0, 30.0), (0.99, 0.01, 0.02, 0.1), "RTK", 4.2, 5.12, 1.3, 0.71,
                12.5, [],
            )  # fmt: skip
            yield "/frames", frame, t_ns
            fix = LocationFix(latitude=47.3769 + k * 1e-7, longitude=8.5417, altitude=512.3, frame_id="gps")
            fix.timestamp.FromNanoseconds(t_ns)
            yield "/frames/location", fix, t_ns
            pose = PoseInFrame(frame_id="enu")
            pose.timestamp.FromNanoseconds(t_ns)
            pose.pose.position.x, pose.pose.orientation.w = 10.0 + k * 0.01, 1.0
            yield "/frames/pose", pose, t_ns
        if k % 50 == 0:
            yield "/clock/device", ClockEstimate(1_234_567 + k, 3.2, 20.0), t_ns
        if k % 6 == 0 and k < 540:
            raw = bytes((k + i) & 0xFF for i in range(40))
            yield "/mavlink/raw", RawMavlink(t_ns, 30, "ATTITUDE", raw), t_ns


Mix = Callable[[int], Iterator[Item]]


def run_recorder(path: Path, seconds: int, compression: Compression, mix: Mix) -> tuple[int, float]:
    """Writes `seconds` simulated seconds; returns (messages, CPU seconds)."""
    messages = 0
    cpu = time.process_time()
    with McapRecorder(path, compression=compression) as recorder:
        for s in range(seconds):
            for topic, message, t_ns in mix(s):
                recorder.write(topic, message, t_ns)
                messages += 1
            recorder.flush()  # the 1-second chunk boundary (and its fsync) of a real flight
    return messages, time.process_time() - cpu


def location_fixes(count: int, start: int = 0) -> Iterator[Item]:
    for i in range(start, start + count):
        t_ns = 1_700_000_000_000_000_000 + i * 10_000_000
        fix = LocationFix(latitude=47.3769 + i * 1e-7, longitude=8.5417, altitude=512.3, frame_id="gps")
        fix.timestamp.FromNanoseconds(t_ns)
        yield "/frames/location", fix, t_ns


def run_peer(path: Path, count: int) -> float:
    cpu = time.process_time()
    with path.open("wb") as f, ProtobufWriter(f, compression=CompressionType.ZSTD) as writer:
        for topic, message, t_ns in location_fixes(count):
            writer.write_message(topic, message, log_time=t_ns, publish_time=t_ns)
    return time.process_time() - cpu


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=int, default=60, help="simulated seconds of capture (709 messages each)")
    parser.add_argument("--compression", default="all", choices=["zstd", "lz4", "none", "all"])
    args = parser.parse_args()
    kinds: list[Compression] = ["zstd", "lz4", "none"] if args.compression == "all" else [args.compression]
    with tempfile.TemporaryDirectory(dir=".") as tmp:
        out = Path(tmp)
        print(f"{'what':58} {'msg/s':>9} {'B/msg':>7} {'CPU us/msg':>10}")
        total = 0
        for kind in kinds:
            t0 = time.perf_counter()
            total, cpu = run_recorder(out / f"mix-{kind}.mcap", args.seconds, kind, second_of_capture)
            wall = time.perf_counter() - t0
            size = os.path.getsize(out / f"mix-{kind}.mcap")
            label = f"icgt recorder, realistic mix, 1 s chunks, {kind}"
            print(f"{label:58} {total / wall:9.0f} {size / total:7.1f} {cpu / total * 1e6:10.1f}")
        fixes = total
        t0 = time.perf_counter()
        cpu = run_peer(out / "peer.mcap", fixes)
        wall = time.perf_counter() - t0
        size = os.path.getsize(out / "peer.mcap")
        label = "peer: mcap-protobuf-support, LocationFix, 1 MiB chunks, zstd"
        print(f"{label:58} {fixes / wall:9.0f} {size / fixes:7.1f} {cpu / fixes * 1e6:10.1f}")

        def fix_seconds(s: int) -> Iterator[Item]:
            per_second = max(1, fixes // args.seconds)
            yield from location_fixes(per_second, start=s * per_second)

        t0 = time.perf_counter()
        n, cpu = run_recorder(out / "fixes.mcap", args.seconds, "zstd", fix_seconds)
        wall = time.perf_counter() - t0
        size = os.path.getsize(out / "fixes.mcap")
        label = "icgt recorder, same LocationFix, 1 s chunks, zstd"
        print(f"{label:58} {n / wall:9.0f} {size / n:7.1f} {cpu / n * 1e6:10.1f}")


if __name__ == "__main__":
    main()
