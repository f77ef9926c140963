"""Synthesised flights for the catalogue's tests and benchmark: frame records written with the project's MCAP
writer (McapRecorder), the recorder's metadata, and optionally a camera card of small JPEGs whose EXIF times
match the exposures, and polyline detections for the damage map.

The flight: a camera 2 m south of a vertical face (the plane north = 10 m in the log's ENU frame), looking
north, moving east along two rows, its LiDAR ranging the face; frames 0.4-0.6 s apart (irregular, so the
card's clock offset is decidable).
"""

from __future__ import annotations

import json
import random
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path

from PIL import Image

from icgt.geodesy import LocalFrame
from icgt.geotag import FrameRecord
from icgt.recording import McapRecorder, layout

ORIGIN = (37.5665, 126.9780, 30.0)
FACE_NORTH_M = 10.0
CAMERA_OFFSET_S = 3600.0 + 0.37  # the camera's clock: an hour (its zone) and 0.37 s ahead of UTC


@dataclass(frozen=True)
class Synth:
    n: int = 40
    seed: int = 1
    serial: str = "1234567"
    recording_id: int = 0x00C0FFEE
    start_utc: datetime = datetime(2025, 6, 3, 9, 30, tzinfo=UTC)
    shift_east_m: float = 0.0
    """Moves every position east (a re-geotagged copy of one flight differs so)."""
    shift_up_m: float = 0.0
    """Moves every position up (another flight line, or a GPS bias)."""
    row_spacing_m: float = 0.8
    calibration_px: tuple[int, int] = (640, 480)
    no_pose_every: int = 0
    """Every k-th frame has no position (flag no_pose); 0: none."""
    lost_exposures: int = 0
    origin: tuple[float, float, float] = ORIGIN


def frames(s: Synth) -> list[FrameRecord]:
    rng = random.Random(s.seed)
    lf = LocalFrame(*s.origin)
    out = []
    t = 0.0
    base_us = round(s.start_utc.timestamp() * 1e6)
    for k in range(1, s.n + 1):
        t += rng.uniform(0.4, 0.6)
        row, col = divmod(k - 1, max(1, s.n // 2))
        east = 0.25 * col + s.shift_east_m
        north = FACE_NORTH_M - 2.0 + rng.gauss(0.0, 0.01)
        up = 3.0 + s.row_spacing_m * row + s.shift_up_m
        no_pose = s.no_pose_every > 0 and k % s.no_pose_every == 0
        lat, lon, alt = (float(v) for v in lf.enu_to_geodetic([east, north, up]))
        mid_us = round(t * 1e6)
        pose = {} if no_pose else {
            "lat_deg": lat, "lon_deg": lon, "alt_msl_m": alt, "east_m": east, "north_m": north, "up_m": up,
            "h_acc_m": 0.02, "v_acc_m": 0.03, "satellites": 18,
            "body_qw": 1.0, "body_qx": 0.0, "body_qy": 0.0, "body_qz": 0.0, "roll_deg": 0.0, "pitch_deg": 0.0,
            "yaw_deg": 0.0, "cam_qw": 0.5, "cam_qx": 0.5, "cam_qy": 0.5, "cam_qz": 0.5,
            "horizontal_error_bound_m": 0.05, "vertical_error_bound_m": 0.06, "position_error_bound_m": 0.078,
            "attitude_error_bound_deg": 0.5,
        }  # fmt: skip
        rng_m = FACE_NORTH_M - north
        out.append(
            FrameRecord(
                frame_seq=k, image_index=k, camera_id=0, device_flags=0,
                trigger_device_us=1_000_000 + mid_us - 40_000, start_device_us=1_000_000 + mid_us - 500,
                mid_device_us=1_000_000 + mid_us, duration_us=1000, mid_host_ns=5_000_000_000 + mid_us * 1000,
                mid_host_uncertainty_ns=300_000, time_source="pps", flags=["no_pose"] if no_pose else [],
                position_source="none" if no_pose else "rtk_fixed", fix_type=6,
                pose_gap_before_ms=math_inf() if no_pose else 10.0, pose_gap_after_ms=math_inf() if no_pose else 10.0,
                mid_utc_us=base_us + mid_us, mid_utc_uncertainty_us=20.0,
                range_m=None if no_pose else rng_m, range_age_ms=None if no_pose else 2.0,
                range_valid=not no_pose, range_source="none" if no_pose else "samples",
                scale_mm_per_px=None if no_pose else 0.42 + 0.001 * (k % 50), incidence_deg=None if no_pose else 1.5,
                blur_px=0.3, imu_source="none", autopilot_clock="timesync", autopilot_clock_uncertainty_us=150.0,
                **pose,
            )
        )  # fmt: skip
    return out


def math_inf() -> float:
    return float("inf")


def write_log(path: Path, s: Synth, records: list[FrameRecord] | None = None) -> list[FrameRecord]:
    """The flight as an ICGT log (the recorder's metadata, /frames, one autopilot HEARTBEAT); its frames."""
    recs = frames(s) if records is None else records
    rec = McapRecorder(path, fsync=False)
    rec.add_metadata(layout.META_FLIGHT, {"kind": "recording", "recording_id": f"0x{s.recording_id:08X}",
                                          "file": path.name})  # fmt: skip
    rec.add_metadata(layout.META_DEVICE, {"firmware_version": "0.9.0", "board": "teensy41",
                                          "serial_number": s.serial, "protocol_version": "2"})  # fmt: skip
    rec.add_metadata(layout.META_CONFIG, {"source": "synth", "config": f"[camera]\nmodel = 'synth'\n# {s.serial}\n",
                                          "host_software": "icgt synth"})  # fmt: skip
    rec.add_metadata(layout.META_ENU_ORIGIN, {"lat_deg": repr(s.origin[0]), "lon_deg": repr(s.origin[1]),
                                              "alt_msl_m": repr(s.origin[2])})  # fmt: skip
    rec.add_metadata(layout.META_CALIBRATION, {"focal_length_mm": "8.8", "sensor_width_mm": "13.2",
                                               "image_width_px": str(s.calibration_px[0]),
                                               "image_height_px": str(s.calibration_px[1]),
                                               "surface_normal_enu": "[0.0, -1.0, 0.0]"})  # fmt: skip
    rec.add_metadata(layout.META_DEVICE_LINK, {"lost_exposures": str(s.lost_exposures), "resend_recovered": "0"})
    rec.register_dataclass(layout.FRAMES, FrameRecord)
    base_ns = round(s.start_utc.timestamp() * 1e9)
    rec.register_json(layout.mavlink_topic("HEARTBEAT"), "mavlink.HEARTBEAT", {"type": "object"})
    rec.write(layout.mavlink_topic("HEARTBEAT"), {"type": 2, "autopilot": 12, "base_mode": 0}, base_ns)
    for r in recs:
        assert r.mid_utc_us is not None
        rec.write(layout.FRAMES, r, r.mid_utc_us * 1000)
    rec.close()
    return recs


def write_card(
    card: Path, recs: list[FrameRecord], *, clock_shift_s: float = 0.0, size: tuple[int, int] = (64, 48)
) -> list[Path]:
    """One JPEG per frame (64x48 by default: the 640x480 calibration scaled down): the camera's EXIF time (10 ms)
    of its exposure start."""
    card.mkdir(parents=True, exist_ok=True)
    out = []
    for k, r in enumerate(recs, start=1):
        assert r.mid_utc_us is not None
        t = (r.mid_utc_us - r.duration_us / 2) / 1e6 + CAMERA_OFFSET_S + clock_shift_s
        dt = datetime.fromtimestamp(t, UTC)
        img = Image.new("RGB", size, (k % 256, 90, 90))  # the calibration's 4:3
        exif = img.getexif()
        exif[0x010F] = "SYNTH"
        exif[0x0132] = dt.strftime("%Y:%m:%d %H:%M:%S")
        ifd = exif.get_ifd(0x8769)
        ifd[0x9003] = dt.strftime("%Y:%m:%d %H:%M:%S")
        ifd[0x9291] = f"{dt.microsecond // 10_000:02d}"
        p = card / f"DSC{k:05d}.JPG"
        img.save(p, format="JPEG", quality=80, exif=exif)
        out.append(p)
    return out


def write_detections(path: Path, names: list[str]) -> Path:
    """icgt-detections polylines: one horizontal crack across the middle of each named image."""
    images = {n: [{"kind": "crack", "points_px": [[20.0, 24.0], [44.0, 25.0]], "width_px": 0.5, "score": 0.9}]
              for n in names}  # fmt: skip
    path.write_text(json.dumps({"format": "icgt-detections", "images": images}))
    return path


def regeotagged(s: Synth) -> Synth:
    """The same flight (device, recording id) with positions moved 0.3 m east: what a PPK re-geotag brings."""
    return replace(s, shift_east_m=s.shift_east_m + 0.3)
