"""Exports from synthetic frames and images (no flight): per-image problems, JPEG edge cases, GeoJSON rings.

Frames are built with exactly known poses; images are small JPEGs written here with Pillow. Every
output is read back with a reader other than the writer (exifread, json + the RFC 7946 checker,
ODM's geo.txt rules, csv).
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import replace
from pathlib import Path

import exifread
import numpy as np
import pytest
from PIL import Image

from icgt.export import ExportError
from icgt.export.cli import export_items, run_export
from icgt.export.common import RECORD_FIELDS, ProblemLog, check_out_dir, prepare_items
from icgt.export.exif_tags import XMP_NS
from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
from icgt.geometry import CameraModel, Projector
from icgt.geotag.record import FrameRecord
from icgt.recorder import topics
from icgt.recording import McapRecorder

from .geojson_rules import check as check_geojson

ORIGIN = (37.8813, 127.7298, 76.0)
BASE = np.array([0.5, 0.5, 0.5, 0.5])
CAM = CameraModel.from_sensor(35.0, 35.6, 6000, 4000)
ALL = ["csv", "geojson", "odm", "opensfm", "jpeg"]


def frame(seq: int, enu: tuple[float, float, float], yaw: float, pitch: float, rng: float | None) -> FrameRecord:
    q_frd = q_from_euler_zyx(0.0, math.radians(pitch), math.radians(yaw))
    q = q_multiply(q_frd, BASE)
    lat, lon, alt = LocalFrame(*ORIGIN).enu_to_geodetic(np.asarray(enu, dtype=float))
    return FrameRecord(
        frame_seq=seq, image_index=seq, camera_id=0, device_flags=16, trigger_device_us=seq * 200_000,
        start_device_us=seq * 200_000 + 48_000, mid_device_us=seq * 200_000 + 48_500, duration_us=1000,
        mid_host_ns=seq * 200_000_000, mid_host_uncertainty_ns=30_000, time_source="pps", flags=[],
        position_source="gps_3d", fix_type=3, pose_gap_before_ms=5.0, pose_gap_after_ms=15.0,
        mid_utc_us=1_795_305_954_000_000 + seq * 200_000, mid_utc_uncertainty_us=1.0,
        lat_deg=float(lat), lon_deg=float(lon), alt_msl_m=float(alt), east_m=enu[0], north_m=enu[1], up_m=enu[2],
        h_acc_m=0.02, v_acc_m=0.03, satellites=20,
        cam_qw=float(q[0]), cam_qx=float(q[1]), cam_qy=float(q[2]), cam_qz=float(q[3]),
        range_m=rng, range_valid=rng is not None,
    )  # fmt: skip


def jpeg(path: Path, *, exif_time: bool = True, xmp: bytes | None = None) -> Path:
    img = Image.new("RGB", (64, 48), (90, 120, 150))
    exif = img.getexif()
    exif[0x010F] = "SONY"
    if exif_time:
        exif.get_ifd(0x8769)[0x9003] = "2026:11:22 00:05:54"
    kw = {"xmp": xmp} if xmp is not None else {}
    img.save(path, format="JPEG", quality=90, exif=exif if exif_time else b"", **kw)
    return path


@pytest.fixture
def spoiled(tmp_path: Path) -> tuple[Path, list[tuple[Path, FrameRecord]]]:
    """Six images, each with a different problem (or none), paired with their frames."""
    card = tmp_path / "card"
    card.mkdir()
    good = frame(1, (0.0, 0.0, 5.0), 0.0, 0.0, 2.5)
    no_fix = replace(frame(2, (0, 0, 5), 0, 0, 2.5), lat_deg=None, lon_deg=None, alt_msl_m=None, east_m=None,
                     north_m=None, up_m=None, flags=["no_fix"], position_source="none", fix_type=1)  # fmt: skip
    zero = replace(frame(3, (0, 0, 5), 0, 0, 2.5), lat_deg=0.0, lon_deg=0.0)
    no_utc = replace(frame(4, (0.5, 0, 5), 0, 0, 2.5), mid_utc_us=None, flags=["no_utc"])
    no_att = replace(frame(5, (1.0, 0, 5), 0, 0, 2.5), cam_qw=None, cam_qx=None, cam_qy=None, cam_qz=None)
    damaged = frame(6, (1.5, 0.0, 5.0), 0.0, 0.0, 2.5)
    xmp = (
        b'<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        b'<rdf:Description rdf:about="" xmlns:tiff="http://ns.adobe.com/tiff/1.0/" tiff:Make="SONY"/>'
        b"</rdf:RDF></x:xmpmeta>"
    )
    pairs = [
        (jpeg(card / "DSC00001.JPG", xmp=xmp), good),
        (jpeg(card / "DSC00002.JPG"), no_fix),
        (jpeg(card / "DSC00003.JPG"), zero),
        (jpeg(card / "DSC00004.JPG", exif_time=False), no_utc),
        (jpeg(card / "DSC00005.JPG"), no_att),
        (card / "DSC00006.JPG", damaged),
    ]
    (card / "DSC00006.JPG").write_bytes(b"\xff\xd8\xff\xe1\x00\x10Exif\x00\x00garbage")
    return card, pairs


def test_per_image_problems_and_the_export_completes(tmp_path: Path, spoiled: tuple[Path, list]) -> None:
    card, pairs = spoiled
    before = {p.name: p.read_bytes() for p in card.iterdir()}
    problems = ProblemLog()
    items = prepare_items(pairs, Projector(CAM, origin=ORIGIN, surface_normal=(0, -1, 0)), problems)
    out = tmp_path / "out"
    check_out_dir(out, card)
    written = export_items(items, out, ALL, problems, geoid_separation_m=None, images_root=card)
    problems.write_csv(out / "problems.csv")
    assert {p.name: p.read_bytes() for p in card.iterdir()} == before
    with (out / "problems.csv").open(newline="") as f:
        got = {(r["image"], r["severity"], r["code"]) for r in csv.DictReader(f)}
    assert ("DSC00002.JPG", "error", "no_fix") in got
    assert ("DSC00003.JPG", "error", "zero_gps") in got
    assert ("DSC00004.JPG", "warning", "no_utc") in got
    assert ("DSC00005.JPG", "warning", "no_attitude") in got
    assert ("DSC00006.JPG", "error", "damaged_image") in got
    assert not any(img == "DSC00001.JPG" for img, _, _ in got)
    assert written["csv rows"] == 6
    assert written["geotagged jpegs"] == 5
    # geo.txt and OpenSfM: only images with a usable position
    geo = (out / "geo.txt").read_text().split("\n")
    assert [line.split()[0] for line in geo[1:] if line] == [
        "DSC00001.JPG",
        "DSC00004.JPG",
        "DSC00005.JPG",
        "DSC00006.JPG",
    ]
    no_att_line = next(line for line in geo if line.startswith("DSC00005.JPG")).split()
    assert no_att_line[4:7] == ["0.0000", "0.0000", "0.0000"]  # ODM: 0 when angles are not known
    overrides = json.loads((out / "exif_overrides.json").read_text())
    assert "capture_time" not in overrides["DSC00004.JPG"] and "gps" in overrides["DSC00004.JPG"]
    assert set(overrides) == {"DSC00001.JPG", "DSC00004.JPG", "DSC00005.JPG", "DSC00006.JPG"}
    # CSV keeps every frame; no position cells for no fix and zero GPS
    with (out / "frames.csv").open(newline="") as f:
        rows = {r["Filename"]: r for r in csv.DictReader(f)}
    assert rows["DSC00002.JPG"]["Latitude"] == "" and rows["DSC00003.JPG"]["Longitude"] == ""
    assert rows["DSC00004.JPG"]["Time"] == "" and rows["DSC00005.JPG"]["Yaw"] == ""

    # EXIF: GPS on the good ones, none on the no-fix copy, GPS on the image that had no EXIF at all
    def tags(name: str) -> dict:
        with (out / "images" / name).open("rb") as f:
            return exifread.process_file(f, details=False)

    assert "GPS GPSLatitude" in tags("DSC00001.JPG")
    assert not any(k.startswith("GPS GPSLat") for k in tags("DSC00002.JPG"))
    t4 = tags("DSC00004.JPG")
    assert "GPS GPSLatitude" in t4 and "GPS GPSTimeStamp" not in t4 and "EXIF DateTimeOriginal" not in t4
    # an XMP packet the camera wrote is kept, ours added
    data = (out / "images" / "DSC00001.JPG").read_bytes()
    assert (b"tiff:Make='SONY'" in data or b'tiff:Make="SONY"' in data) and XMP_NS.encode() in data
    assert data.count(b"http://ns.adobe.com/xap/1.0/\x00") == 1  # one XMP packet, the camera's with ours in it


def test_geojson_rings_follow_the_right_hand_rule(tmp_path: Path) -> None:
    """Under a deck (camera looking up at a horizontal surface) footprints have area on the map:
    their rings must be counterclockwise, whatever the camera's heading."""
    frames = [frame(i + 1, (i * 3.0, 0.0, 10.0), yaw, 90.0 - 1e-9, 4.0) for i, yaw in enumerate([0, 70, 180, 290])]
    frames.append(frame(5, (20.0, 0.0, 30.0), 45.0, -90.0 + 1e-9, 25.0))  # and over the deck, looking down
    problems = ProblemLog()
    items = prepare_items([(tmp_path / f"IMG{i}.JPG", f) for i, f in enumerate(frames)],
                          Projector(CAM, origin=ORIGIN, surface_normal=(0, 0, -1)), problems)  # fmt: skip
    export_items(items, tmp_path, ["geojson"], problems, geoid_separation_m=25.0)
    fps = json.loads((tmp_path / "footprints.geojson").read_text())
    errors, degenerate = check_geojson(fps)
    assert errors == [] and degenerate == []
    assert len(fps["features"]) == 5
    for f in fps["features"]:
        ring = f["geometry"]["coordinates"][0]
        assert len(ring) == 5 and ring[0] == ring[-1] and len(ring[0]) == 3
        assert not f["properties"]["vertical_surface"]


def test_the_geojson_checker_catches_what_it_should() -> None:
    ring = [[127.0, 37.0], [127.001, 37.0], [127.001, 37.001], [127.0, 37.001], [127.0, 37.0]]
    ok = {"type": "FeatureCollection", "features": [
        {"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]}, "properties": {}}]}  # fmt: skip
    assert check_geojson(ok) == ([], [])
    cw = json.loads(json.dumps(ok))
    cw["features"][0]["geometry"]["coordinates"][0].reverse()
    assert "clockwise" in check_geojson(cw)[0][0]
    open_ring = json.loads(json.dumps(ok))
    open_ring["features"][0]["geometry"]["coordinates"][0].pop()
    assert "not closed" in check_geojson(open_ring)[0][0]
    swapped = {"type": "Feature", "geometry": {"type": "Point", "coordinates": [37.0, 127.0]}, "properties": None}
    assert "latitude 127.0 out of range" in check_geojson(swapped)[0][0]


def test_geo_txt_without_accuracy_and_with_bad_names(tmp_path: Path) -> None:
    f1 = replace(frame(1, (0, 0, 5), 10.0, -30.0, 3.0), h_acc_m=None)
    f2 = frame(2, (1, 0, 5), 10.0, -30.0, 3.0)
    problems = ProblemLog()
    items = prepare_items([(tmp_path / "A.JPG", f1), (tmp_path / "B C.JPG", f2)], None, problems)
    export_items(items, tmp_path, ["odm"], problems)
    lines = (tmp_path / "geo.txt").read_text().strip().split("\n")
    assert lines[0] == "EPSG:4326" and len(lines) == 2
    parts = lines[1].split()
    assert len(parts) == 7  # no accuracies: ODM reads them only from lines with 9 fields
    assert [float(p) for p in parts[4:7]] == pytest.approx([10.0, 60.0, 0.0], abs=1e-4)  # ODM: 30 deg down is 60
    assert [(p.image, p.code) for p in problems if p.code == "bad_file_name"] == [("B C.JPG", "bad_file_name")]


def test_out_dir_inside_the_card_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="inside the images folder"):
        check_out_dir(tmp_path / "card" / "export", tmp_path / "card")
    with pytest.raises(ExportError):
        check_out_dir(tmp_path / "card", tmp_path / "card")


def test_run_export_from_a_recording_without_images(tmp_path: Path) -> None:
    path = tmp_path / "log.mcap"
    frames = [frame(i, (0.2 * i, 0.0, 5.0), 0.0, 0.0, 2.5) for i in range(1, 11)]
    frames[3] = replace(frames[3], lat_deg=0.0, lon_deg=0.0)
    with McapRecorder(path, fsync=False) as rec:
        rec.register_dataclass(topics.FRAMES, FrameRecord)
        rec.add_metadata("icgt.calibration", {"focal_length_mm": "35.0", "sensor_width_mm": "35.6",
                                              "image_width_px": "6000", "image_height_px": "4000",
                                              "surface_normal_enu": "(0.0, -1.0, 0.0)"})  # fmt: skip
        for f in frames:
            rec.write(topics.FRAMES, f, 1_700_000_000_000_000_000 + f.mid_host_ns)
    result = run_export(path, tmp_path / "out", formats=["csv", "geojson", "odm"], geoid_separation="auto")
    assert result.written["csv rows"] == 10
    assert result.written["geojson points"] == 9  # the zero-GPS frame has no point
    assert result.written["geo.txt lines"] == 0  # no image names without --images
    assert [p.code for p in result.problems] == ["zero_gps"]
    assert (tmp_path / "out" / "problems.csv").exists()
    cams = json.loads((tmp_path / "out" / "cameras.geojson").read_text())
    assert len(cams["features"][0]["geometry"]["coordinates"]) == 2  # no GPS_RAW_INT: geoid unknown, 2D
    assert check_geojson(cams)[0] == []
    with pytest.raises(ExportError, match="unknown export format 'dxf'"):
        run_export(path, tmp_path / "out2", formats=["dxf"])


@pytest.mark.parametrize("asked", ["shp", "Shapefile", "esri"])
def test_shapefile_is_refused_with_the_reason(asked: str, tmp_path: Path) -> None:
    """No silently truncated Shapefile: the refusal counts the names it would cut and points to GeoPackage."""
    long_names = [n for n in RECORD_FIELDS if len(n) > 10]
    assert len(long_names) > 10  # most FrameRecord names are longer than dBASE allows
    with pytest.raises(ExportError) as exc:
        run_export(tmp_path / "log.mcap", tmp_path / "out", formats=["csv", asked])
    text = str(exc.value)
    assert f"{len(long_names)} of the {len(RECORD_FIELDS)} frame fields" in text
    assert "mid_utc" in text and "gpkg" in text and "Shapefile is not written" in text
    assert not (tmp_path / "out").exists()  # refused before anything is written
