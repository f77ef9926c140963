"""`icgt export` on one simulated flight, every output read back by an independent reader.

One flight (tests/export/export_flight.toml, ~25 s) is flown once for the module. Its camera card
is copied and spoiled the way real cards are: the first image has no EXIF time (nothing to place it
by), a middle one has none either (its neighbours place it), and a stray image from another flight
is added. The export runs through the CLI function; then:

- the originals are byte-for-byte as before;
- every problem is reported per image in problems.csv, and the export completed for the rest;
- EXIF GPS/time read back with exifread (the writer uses Pillow), XMP with ElementTree, and the
  compressed image data of each copy is byte-identical to the original's;
- the GeoJSON passes an RFC 7946 checker written independently (tests/export/geojson_rules.py);
- geo.txt is parsed by ODM's documented rules and its coordinate order checked;
- frames.csv round-trips to the very FrameRecords the ingest reader returns;
- footprints and pixel-to-world against the simulator's truth stay within what the position,
  attitude and LiDAR range errors of each frame imply.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import hashlib
import json
import math
import shutil
import types
import typing
import xml.etree.ElementTree as ET
from dataclasses import dataclass, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import exifread
import numpy as np
import pytest
from PIL import Image

from icgt.demo import fly
from icgt.export.cli import add_export_arguments, cmd_export
from icgt.geodesy import LocalFrame, q_multiply
from icgt.geometry import CameraModel, Plane, Projector, origin_from_frames
from icgt.geotag.bounds import AXIS_95, RADIAL_95
from icgt.geotag.record import FrameRecord
from icgt.ingest import read
from icgt.sim.scenario import load_scenario

from .geojson_rules import check as check_geojson
from .odm_rules import camera_axes_ned, rotation

HERE = Path(__file__).resolve().parent
BASE = np.array([0.5, 0.5, 0.5, 0.5])
PAPER = ["No.", "Filename", "Time", "Distance (m)", "Longitude", "Latitude", "Altitude", "Yaw", "Roll", "Pitch"]
XMP_NS = "urn:icgt:ns:geotag:1.0/"


@dataclass
class Run:
    mcap: Path
    card: Path
    out: Path
    truth: list[dict[str, Any]]
    hashes_before: dict[str, str]
    stdout: str
    exit_code: int
    frames: list[FrameRecord]
    rows: dict[str, dict[str, str]]  # frames.csv rows by file name
    all_rows: list[dict[str, str]]
    header: list[str]


def _hashes(folder: Path) -> dict[str, str]:
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


def _strip_time(path: Path) -> None:
    with Image.open(path) as img:
        img.load()
        exif = img.getexif()
        exif.pop(0x0132, None)
        sub = exif.get_ifd(0x8769)
        for tag in (0x9003, 0x9004, 0x9291, 0x9292):
            sub.pop(tag, None)
        img.save(path, format="JPEG", quality=95, exif=exif)


def _shift_time(src: Path, dst: Path, hours: float) -> None:
    with Image.open(src) as img:
        img.load()
        exif = img.getexif()
        sub = exif.get_ifd(0x8769)
        t = datetime.strptime(sub[0x9003], "%Y:%m:%d %H:%M:%S").timestamp() + hours * 3600
        text = datetime.fromtimestamp(t).strftime("%Y:%m:%d %H:%M:%S")
        sub[0x9003] = sub[0x9004] = exif[0x0132] = text
        img.save(dst, format="JPEG", quality=95, exif=exif)


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    base = tmp_path_factory.mktemp("export_flight")
    flight = fly(load_scenario(HERE / "export_flight.toml"), base / "flight")
    card = base / "card"
    shutil.copytree(flight.card, card)
    images = sorted(card.glob("*.JPG"))
    assert len(images) > 30
    _strip_time(images[0])
    _strip_time(images[5])
    _shift_time(images[10], card / "DSC09999.JPG", hours=2.0)
    hashes = _hashes(card)
    out = base / "out"
    parser = argparse.ArgumentParser()
    add_export_arguments(parser)
    args = parser.parse_args([str(flight.mcap), "--images", str(card), "--out", str(out), "--no-progress"])
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        code = cmd_export(args)
    truth = [json.loads(line) for line in flight.truth_exposures.read_text().splitlines() if line.strip()]
    with (out / "frames.csv").open(newline="", encoding="utf-8") as f:
        reader = csv.reader(f)
        header = next(reader)
        all_rows = [dict(zip(header, r, strict=True)) for r in reader]
    rows = {r["Filename"]: r for r in all_rows if r["Filename"]}
    return Run(flight.mcap, card, out, truth, hashes, buf.getvalue(), code, list(read(flight.mcap).frames()), rows,
               all_rows, header)  # fmt: skip


def _problems(run: Run) -> list[dict[str, str]]:
    with (run.out / "problems.csv").open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_export_completes_and_originals_are_untouched(run: Run) -> None:
    assert run.exit_code == 1  # problems.csv has error rows (an unmatched image, one without an EXIF time)
    assert "exported" in run.stdout and "problems" in run.stdout
    assert _hashes(run.card) == run.hashes_before
    copies = sorted((run.out / "images").glob("*.JPG"))
    assert len(copies) == len(run.rows) >= len(run.hashes_before) - 3


def test_every_input_problem_is_reported_per_image(run: Run) -> None:
    problems = _problems(run)
    by_image: dict[str, list[dict[str, str]]] = {}
    for p in problems:
        by_image.setdefault(p["image"], []).append(p)
    first, fifth = sorted(run.hashes_before)[0], sorted(run.hashes_before)[5]
    assert {(p["severity"], p["code"]) for p in by_image[first]} == {("error", "no_exif_time")}
    assert first not in run.rows
    # (a loaded machine can add a pose_quality warning: the simulated autopilot's messages come late)
    assert {(p["severity"], p["code"]) for p in by_image[fifth]} - {("warning", "pose_quality")} == {
        ("warning", "no_exif_time")
    }
    assert fifth in run.rows  # placed between its timed neighbours, and exported
    assert [(p["severity"], p["code"]) for p in by_image["DSC09999.JPG"]] == [("error", "unmatched_image")]
    missed = [p for p in problems if p["code"] == "frame_feedback_missing"]
    assert len(missed) == 1 and missed[0]["frame_seq"]
    # the frame without an image (and the one whose image had no place) are still in the CSV
    assert len(run.all_rows) == len(run.frames)


def _gps_decimal(tags: dict[str, Any], key: str) -> float:
    d, m, s = (float(x.num) / float(x.den) for x in tags[f"GPS {key}"].values)
    ref = str(tags[f"GPS {key}Ref"].values)
    return (d + m / 60 + s / 3600) * (-1 if ref in "SW" else 1)


def _scan_data(path: Path) -> bytes:
    data = path.read_bytes()
    pos = 2
    while data[pos + 1] != 0xDA:
        pos += 2 + int.from_bytes(data[pos + 2 : pos + 4], "big")
    return data[pos:]


def test_exif_gps_and_time_read_back_with_exifread(run: Run) -> None:
    for name, row in run.rows.items():
        copy = run.out / "images" / name
        with copy.open("rb") as f:
            tags = exifread.process_file(f, details=False)
        assert abs(_gps_decimal(tags, "GPSLatitude") - float(row["Latitude"])) < 1e-9
        assert abs(_gps_decimal(tags, "GPSLongitude") - float(row["Longitude"])) < 1e-9
        alt = tags["GPS GPSAltitude"].values[0]
        assert str(tags["GPS GPSAltitudeRef"].values[0]) == "0"
        assert abs(float(alt.num) / float(alt.den) - float(row["Altitude"])) < 0.0006
        h, m, s = (float(x.num) / float(x.den) for x in tags["GPS GPSTimeStamp"].values)
        day = str(tags["GPS GPSDate"].values)
        stamp = datetime.strptime(day, "%Y:%m:%d").replace(tzinfo=UTC).timestamp() + h * 3600 + m * 60 + s
        want = datetime.strptime(row["Time"], "%Y-%m-%dT%H:%M:%S.%fZ").replace(tzinfo=UTC).timestamp()
        assert abs(stamp - want) < 2e-6
        sd = tags["EXIF SubjectDistance"].values[0]
        assert abs(float(sd.num) / float(sd.den) - float(row["Distance (m)"])) < 0.0006
        d = tags["GPS GPSImgDirection"].values[0]
        assert abs((float(d.num) / float(d.den) - float(row["Yaw"]) + 180) % 360 - 180) < 0.006
        with (run.card / name).open("rb") as f:
            original = exifread.process_file(f, details=False)
        assert str(tags["Image Make"]) == str(original["Image Make"]) == "SONY"
        if "EXIF DateTimeOriginal" in original:
            assert str(tags["EXIF DateTimeOriginal"]) == str(original["EXIF DateTimeOriginal"])
            assert str(tags["EXIF SubSecTimeOriginal"]) == str(original["EXIF SubSecTimeOriginal"])
        assert _scan_data(copy) == _scan_data(run.card / name)  # the pixels are the camera's


def test_xmp_attitude_reads_back(run: Run) -> None:
    for name, row in list(run.rows.items())[:10]:
        data = (run.out / "images" / name).read_bytes()
        start, end = data.index(b"<x:xmpmeta"), data.index(b"</x:xmpmeta>") + len(b"</x:xmpmeta>")
        root = ET.fromstring(data[start:end])
        desc = root.find(".//{http://www.w3.org/1999/02/22-rdf-syntax-ns#}Description")
        assert desc is not None
        attr = {k.split("}")[1]: v for k, v in desc.attrib.items() if k.startswith("{" + XMP_NS)}
        assert float(attr["CameraYawDegree"]) == float(row["Yaw"])
        assert float(attr["CameraPitchDegree"]) == float(row["Pitch"])
        assert float(attr["CameraRollDegree"]) == float(row["Roll"])
        assert float(attr["CameraPitchDegree"]) == pytest.approx(12.0, abs=0.5)  # the gimbal's mount pitch
        assert int(attr["FrameSeq"]) == int(row["frame_seq"])
        assert float(attr["ScaleMmPerPixel"]) == float(row["geo_scale_mm_per_px"])


def test_geojson_is_valid_rfc7946_with_lon_lat_order(run: Run) -> None:
    cams = json.loads((run.out / "cameras.geojson").read_text())
    fps = json.loads((run.out / "footprints.geojson").read_text())
    for obj in (cams, fps):
        errors, _ = check_geojson(obj)
        assert errors == []
    by_seq = {int(r["frame_seq"]): r for r in run.all_rows}
    assert len(cams["features"]) == len(run.frames)
    for f in cams["features"]:
        row = by_seq[f["id"]]
        lon, lat, h = f["geometry"]["coordinates"]
        assert lon == pytest.approx(float(row["Longitude"]), abs=1e-9)
        assert lat == pytest.approx(float(row["Latitude"]), abs=1e-9)
        assert h == pytest.approx(float(row["Altitude"]) + 24.9, abs=1e-3)  # ellipsoidal: MSL + geoid N
    # a pier face is vertical: its outlines have (next to) no area on a map, and say so
    assert len(fps["features"]) >= len(run.rows)
    assert all(f["properties"]["vertical_surface"] for f in fps["features"])
    for f in fps["features"]:
        st = np.array(f["properties"]["outline_map_st_m"])  # on the face: a real quadrilateral
        assert np.ptp(st[:, 0]) > 1.0 and np.ptp(st[:, 1]) > 1.0


def test_geo_txt_follows_odm_rules(run: Run) -> None:
    lines = (run.out / "geo.txt").read_text().strip().split("\n")
    assert lines[0] == "EPSG:4326"
    entries = {}
    for line in lines[1:]:
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        assert len(parts) >= 3
        x, y = float(parts[1]), float(parts[2])
        z = float(parts[3]) if len(parts) >= 4 else None
        angles = [float(p) for p in parts[4:7]] if len(parts) >= 7 else None
        acc = [float(p) for p in parts[7:9]] if len(parts) >= 9 else None
        entries[parts[0]] = (x, y, z, angles, acc)
    assert set(entries) == set(run.rows)
    for name, (x, y, z, angles, acc) in entries.items():
        row = run.rows[name]
        # EPSG:4326 in geo.txt: x is the longitude, y the latitude (the flight is at 127.7 E, 37.9 N)
        assert abs(x - 127.7298) < 0.01 and abs(y - 37.8813) < 0.01
        assert x == pytest.approx(float(row["Longitude"]), abs=2e-9)
        assert y == pytest.approx(float(row["Latitude"]), abs=2e-9)
        assert z == pytest.approx(float(row["Altitude"]), abs=1e-4)
        assert angles is not None and acc is not None
        q = tuple(float(row[k]) for k in ("cam_qw", "cam_qx", "cam_qy", "cam_qz"))
        # ODM's convention (odm_rules): the rotation ODM builds from the three angles is the camera's
        np.testing.assert_allclose(rotation(*angles), camera_axes_ned(q), atol=1e-5)
        # the frame's 95 % bounds as one standard deviation (docs/error-bounds.md), not the receiver's h_acc
        sigma = [float(row["horizontal_error_bound_m"]) / RADIAL_95, float(row["vertical_error_bound_m"]) / AXIS_95]
        assert acc == pytest.approx(sigma, abs=1e-3)
        assert sigma[0] >= float(row["h_acc_m"])  # never more confident than the receiver


def test_opensfm_overrides(run: Run) -> None:
    data = json.loads((run.out / "exif_overrides.json").read_text())
    assert set(data) == set(run.rows)
    for name, entry in data.items():
        row = run.rows[name]
        assert entry["gps"]["latitude"] == float(row["Latitude"])
        assert entry["gps"]["longitude"] == float(row["Longitude"])
        assert entry["gps"]["altitude"] == float(row["Altitude"])
        assert entry["gps"]["dop"] == pytest.approx(float(row["horizontal_error_bound_m"]) / RADIAL_95, rel=1e-9)
        assert entry["capture_time"] == pytest.approx(int(row["mid_utc_us"]) / 1e6, abs=1e-6)


def _parse(value: str, hint: Any) -> Any:
    if value == "":
        return None
    if isinstance(hint, types.UnionType):
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
    kind = typing.get_origin(hint) or hint
    if kind is list:
        return value.split(";")
    if kind is bool:
        return {"true": True, "false": False}[value]
    return kind(value)


def test_csv_round_trip_is_exact(run: Run) -> None:
    assert run.header[: len(PAPER)] == PAPER
    hints = typing.get_type_hints(FrameRecord)
    names = [f.name for f in dataclasses.fields(FrameRecord)]
    assert run.header[len(PAPER) : len(PAPER) + len(names)] == names
    back = []
    for i, row in enumerate(run.all_rows, 1):
        assert row["No."] == str(i)
        fields = {n: _parse(row[n], hints[n]) for n in names}
        fields["flags"] = fields["flags"] or []
        back.append(FrameRecord(**fields))
    assert back == run.frames
    for row in run.all_rows:
        if row["Longitude"]:
            assert row["Longitude"] == row["lon_deg"] and row["Latitude"] == row["lat_deg"]
            assert row["Distance (m)"] == row["range_m"]


def test_footprints_and_pixels_against_truth(run: Run) -> None:
    """Each frame's footprint against the footprint of the true pose on the true plane: the corner errors
    stay within what that frame's own position, attitude and LiDAR range errors imply."""
    sc = load_scenario(HERE / "export_flight.toml")
    recording = read(run.mcap)
    origin = recording.enu_origin
    rec_frame = LocalFrame(*origin) if origin is not None else origin_from_frames(run.frames)
    assert rec_frame is not None
    scen_frame = LocalFrame(sc.origin.lat_deg, sc.origin.lon_deg, sc.origin.alt_m)
    plane = Plane(sc.structure.point_m, sc.structure.normal).transfer(scen_frame, rec_frame)
    n = np.array(plane.normal)
    cam = CameraModel.from_sensor(sc.camera.focal_length_mm, sc.camera.sensor_width_mm,
                                  sc.camera.image_width_px, sc.camera.image_height_px)  # fmt: skip
    ours = Projector(cam, origin=rec_frame, structure=plane)
    exact = Projector(cam, origin=rec_frame, structure=plane, anchor="structure")
    by_start = {int(t["start_device_us"]): t for t in run.truth}
    sigma = sc.sensors.range_noise_cm / 100.0
    uv = np.vstack([cam.border_pixels(0), [[1000.0, 700.0], [4500.0, 3300.0], [3000.0, 2000.0]]])
    errors_cm: list[float] = []
    checked = 0
    for frame in run.frames:
        t = by_start.get(frame.start_device_us)
        if t is None or frame.range_m is None or frame.east_m is None or t["range_m"] is None:
            continue
        c_true = rec_frame.geodetic_to_enu(t["lat_deg"], t["lon_deg"], t["alt_msl_m"])
        q_true = q_multiply(np.array(t["q_camera_ned"]), BASE)
        truth_frame = replace(frame, east_m=float(c_true[0]), north_m=float(c_true[1]), up_m=float(c_true[2]),
                              cam_qw=float(q_true[0]), cam_qx=float(q_true[1]), cam_qy=float(q_true[2]),
                              cam_qz=float(q_true[3]), range_m=float(t["range_m"]))  # fmt: skip
        want = exact.pixel_to_world(truth_frame, uv[:, 0], uv[:, 1]).enu
        got_w = ours.pixel_to_world(frame, uv[:, 0], uv[:, 1])
        got = got_w.enu
        # this frame's own errors
        c_ours = np.array([frame.east_m, frame.north_m, frame.up_m])
        dpos = float(np.linalg.norm(c_ours - c_true))
        q_ours = np.array([frame.cam_qw, frame.cam_qx, frame.cam_qy, frame.cam_qz])
        att = 2.0 * math.acos(min(1.0, abs(float(q_ours @ q_true))))
        sol = ours.solve(frame)
        plane_offset = abs(float((np.array(sol.plane.point) - np.array(plane.point)) @ n))
        assert abs(frame.range_m - t["range_m"]) < 4 * sigma + 0.01  # the LiDAR noise the scenario configures
        d = cam.rays(uv[:, 0], uv[:, 1])
        rays_len = np.linalg.norm(d, axis=1) * float(t["range_m"])
        cos_ray = np.abs((exact.pixel_to_world(truth_frame, uv[:, 0], uv[:, 1]).enu - c_true) @ n) / np.linalg.norm(
            want - c_true, axis=1
        )
        bound = (dpos + plane_offset + rays_len * att) / cos_ray * 1.2 + 1e-3
        err = np.linalg.norm(got - want, axis=1)
        assert np.all(err <= bound), (frame.frame_seq, err, bound)
        errors_cm += list(err * 100)
        # WGS84 output agrees with the ENU point
        assert got_w.lat_deg is not None and got_w.lon_deg is not None
        lat, lon, _ = rec_frame.enu_to_geodetic(got)
        assert np.allclose(got_w.lat_deg, lat, atol=1e-12) and np.allclose(got_w.lon_deg, lon, atol=1e-12)
        # scale at the centre: the truth's over ours differs by the range error and the incidence error only
        true_sol = exact.solve(truth_frame)
        assert sol.scale_mm_per_px == pytest.approx(true_sol.scale_mm_per_px, rel=4 * sigma / 3.0 + 0.01)
        assert sol.incidence_deg == pytest.approx(12.0, abs=1.0)
        checked += 1
    assert checked >= 30
    # typical error: fused position noise (3 cm horizontal) and LiDAR noise (2.5 cm) at 3 m
    assert float(np.median(errors_cm)) < 8.0
