"""What a real card holds besides clean JPEGs: AppleDouble and hidden files, RAW+JPEG pairs, HEIC,
a camera's own GPS far from the log; and the export's exit status."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest
from PIL import Image

from icgt.export.card import jpeg_damage, jpeg_file_damage, scan_card
from icgt.export.cli import exit_status, report_card
from icgt.export.common import ProblemLog, prepare_items
from icgt.export.geotag_writer import write_geotagged_copies
from icgt.ingest.match import list_images

from .test_pose_tags_odm import frame


def jpeg(path: Path, make: str = "SONY") -> Path:
    img = Image.new("RGB", (64, 48), (90, 120, 150))
    exif = img.getexif()
    exif[0x010F] = make
    exif.get_ifd(0x8769)[0x9003] = "2026:11:22 00:05:54"
    img.save(path, format="JPEG", quality=90, exif=exif)
    return path


@pytest.fixture
def card(tmp_path: Path) -> Path:
    root = tmp_path / "DCIM"
    (root / "100MSDCF").mkdir(parents=True)
    (root / ".Trashes").mkdir()
    jpeg(root / "100MSDCF" / "DSC00001.JPG")
    jpeg(root / "100MSDCF" / "DSC00002.JPG")
    # AppleDouble resource fork: not a JPEG at all, but named like one
    (root / "100MSDCF" / "._DSC00001.JPG").write_bytes(b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        ")
    jpeg(root / ".Trashes" / "DSC00099.JPG")
    Image.new("RGB", (32, 24)).save(root / "100MSDCF" / "DSC00001.ARW", format="TIFF")  # stands in for a RAW
    Image.new("RGB", (32, 24)).save(root / "100MSDCF" / "DSC00077.NEF", format="TIFF")
    (root / "100MSDCF" / "IMG_0001.HEIC").write_bytes(b"\x00\x00\x00\x18ftypheic")
    Image.new("RGB", (32, 24)).save(root / "100MSDCF" / "DSC00003.PNG", format="PNG")
    (root / "100MSDCF" / "C0001.MP4").write_bytes(b"\x00\x00\x00\x18ftypmp42")  # a video: not an image
    return root


def test_hidden_files_are_not_images_and_are_listed(card: Path) -> None:
    assert [p.name for p in list_images(card)] == ["DSC00001.JPG", "DSC00002.JPG"]
    scan = scan_card(card)
    assert sorted(p.name for p in scan.hidden) == ["._DSC00001.JPG", "DSC00099.JPG"]
    problems = ProblemLog()
    report_card(scan, {card / "100MSDCF" / "DSC00001.JPG", card / "100MSDCF" / "DSC00002.JPG"}, problems)
    rows = {(p.image, p.severity, p.code) for p in problems}
    assert rows == {
        ("._DSC00001.JPG", "info", "hidden_file_skipped"),
        ("DSC00099.JPG", "info", "hidden_file_skipped"),
        ("IMG_0001.HEIC", "error", "heic_not_supported"),
        ("DSC00077.NEF", "warning", "raw_without_jpeg"),
        ("DSC00003.PNG", "warning", "image_not_supported"),
    }
    assert exit_status(problems) == 1
    infos = ProblemLog()
    report_card(scan_card(card / ".Trashes"), set(), infos)
    assert exit_status(infos) == 0 and exit_status(ProblemLog()) == 0
    # warnings alone: exit 0 (they are in problems.csv and on stderr), 1 with --strict
    warnings = ProblemLog()
    warnings.add("DSC00003.PNG", None, "warning", "image_not_supported", "png")
    assert exit_status(warnings) == 0 and exit_status(warnings, strict=True) == 1


def test_raw_files_get_an_xmp_sidecar_with_the_same_geotag(card: Path, tmp_path: Path) -> None:
    src = card / "100MSDCF" / "DSC00001.JPG"
    problems = ProblemLog()
    items = prepare_items([(src, frame(1, 40.0, -80.0, 0.0))], None, problems)
    out = tmp_path / "out"
    n = write_geotagged_copies(items, out, problems, images_root=card, raws=scan_card(card).raw)
    assert n == 1 and [p for p in problems if p.severity == "error"] == []
    sidecar = out / "100MSDCF" / "DSC00001.xmp"
    cmd = ["exiftool", "-j", "-n", "-G1", str(sidecar), str(out / "100MSDCF" / "DSC00001.JPG")]
    side, copy = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
    f = items[0].frame
    assert side["XMP-exif:GPSLatitude"] == pytest.approx(f.lat_deg, abs=1e-9)
    assert side["XMP-exif:GPSLongitude"] == pytest.approx(f.lon_deg, abs=1e-9)
    assert side["XMP-exif:GPSAltitude"] == pytest.approx(f.alt_msl_m, abs=1e-3)
    assert side["XMP-exif:GPSLatitude"] == pytest.approx(copy["GPS:GPSLatitude"], abs=1e-9)
    for tag in ("XMP-Camera:Yaw", "XMP-Camera:Pitch", "XMP-Camera:Roll", "XMP-icgt:FrameSeq"):
        assert side[tag] == copy[tag]


def test_a_camera_gps_far_from_the_log_is_a_warning(tmp_path: Path) -> None:
    src = jpeg(tmp_path / "IMG_0001.JPG")
    subprocess.run(["exiftool", "-q", "-overwrite_original", "-GPSLatitude=1.5", "-GPSLatitudeRef=S",
                    "-GPSLongitude=36.8", "-GPSLongitudeRef=E", str(src)], check=True)  # fmt: skip
    problems = ProblemLog()
    items = prepare_items([(src, frame(1, 40.0, -80.0, 0.0))], None, problems)
    assert write_geotagged_copies(items, tmp_path / "out", problems) == 1
    (far,) = [p for p in problems if p.code == "camera_gps_far"]
    assert far.severity == "warning" and "km from the log" in far.detail
    assert float(far.detail.split(" is ")[1].split(" km")[0]) > 8000
    (rep,) = [p for p in problems if p.code == "camera_tags_replaced"]
    assert "GPS:GPSLatitude=1.5" in rep.detail


def test_jpeg_damage_finds_cut_off_and_broken_files(tmp_path: Path) -> None:
    data = jpeg(tmp_path / "a.jpg").read_bytes()
    assert jpeg_damage(data) is None
    assert "cut off" in (jpeg_damage(data[: len(data) - 40]) or "")
    assert "cut off" in (jpeg_damage(data[:30]) or "")
    assert "not a JPEG" in (jpeg_damage(b"\x00\x05\x16\x07Mac OS X") or "")
    for cut, expect in ((len(data), None), (len(data) - 40, "cut off"), (30, "cut off"), (2, "cut off")):
        (tmp_path / "b.jpg").write_bytes(data[:cut])
        got = jpeg_file_damage(tmp_path / "b.jpg")
        assert (got is None) if expect is None else (expect in (got or "")), (cut, got)


@pytest.mark.parametrize(
    "packet",
    [
        '<x:xapmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
        '<rdf:Description rdf:about="" xmlns:dc="http://purl.org/dc/elements/1.1/" xmlns:t="http://ns.adobe.com/tiff/1.0/"'
        ' t:Make="SONY"><dc:creator><rdf:Seq><rdf:li>pilot</rdf:li></rdf:Seq></dc:creator></rdf:Description>'
        "</rdf:RDF></x:xapmeta>",
        '<rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#"><rdf:Description rdf:about=""'
        ' xmlns:dc="http://purl.org/dc/elements/1.1/" xmlns:t="http://ns.adobe.com/tiff/1.0/" t:Make="SONY">'
        "<dc:creator><rdf:Seq><rdf:li>pilot</rdf:li></rdf:Seq></dc:creator></rdf:Description></rdf:RDF>",
    ],
    ids=["xapmeta-root", "bare-rdf-root"],
)
def test_existing_xmp_with_another_root_spelling_is_kept(tmp_path: Path, packet: str) -> None:
    src = tmp_path / "DSC00001.JPG"
    img = Image.new("RGB", (64, 48), (90, 120, 150))
    exif = img.getexif()
    exif[0x010F] = "SONY"
    img.save(src, format="JPEG", quality=90, exif=exif, xmp=packet.encode())
    problems = ProblemLog()
    items = prepare_items([(src, frame(1, 40.0, -80.0, 0.0))], None, problems)
    assert write_geotagged_copies(items, tmp_path / "out", problems) == 1
    cmd = ["exiftool", "-j", "-G1", "-XMP:all", str(src), str(tmp_path / "out" / src.name)]
    before, after = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)
    assert before["XMP-dc:Creator"] == after["XMP-dc:Creator"] == "pilot"
    assert before["XMP-tiff:Make"] == after["XMP-tiff:Make"] == "SONY"
    data = (tmp_path / "out" / src.name).read_bytes()
    assert data.count(b"<x:xmpmeta") == 1  # one packet, with the root ODM and OpenSfM look for
    assert ("xmp_rewrapped" in {p.code for p in problems}) == packet.startswith("<rdf")


def test_the_in_process_reader_agrees_with_exiftool_and_the_check_can_fail(tmp_path: Path) -> None:
    from icgt.export.exif_tags import check_copy, intended_tags
    from icgt.export.tag_reader import read_tags

    src = jpeg(tmp_path / "DSC00001.JPG", make="DJI")
    problems = ProblemLog()
    items = prepare_items([(src, frame(1, 40.0, -80.0, 3.0))], None, problems)
    assert write_geotagged_copies(items, tmp_path / "out", problems) == 1
    copy = tmp_path / "out" / src.name
    ours = read_tags(copy)
    assert ours is not None
    cmd = [
        "exiftool",
        "-j",
        "-n",
        "-G1",
        "-a",
        "-GPS:all",
        "-XMP:all",
        "-EXIF:Make",
        "-Composite:GPSLatitude",
        str(copy),
    ]
    theirs = json.loads(subprocess.run(cmd, capture_output=True, text=True, check=True).stdout)[0]
    want = intended_tags(items[0], {"IFD0:Make": "DJI"})
    assert check_copy(want, ours) == []
    # ExifTool shows date-like XMP text in its own date spelling: that one is compared in our reader only
    assert check_copy({k: v for k, v in want.items() if k != "XMP-icgt:MidExposureUTC"}, theirs) == []
    assert len(want) > 30 and "XMP-drone-dji:GimbalPitchDegree" in ours
    wrong = dict(ours, **{"GPS:GPSLatitude": ours["GPS:GPSLatitude"] + 1e-7})
    del wrong["XMP-Camera:Yaw"]
    assert len(check_copy(want, wrong)) == 2
