"""The pose in a geotagged copy and in geo.txt, read back by ODM's and OpenSfM's rules (tests/export/odm_rules.py).

For cameras of three kinds (a plain JPEG, a DJI file with its own drone-dji pose and RTK tags, a
senseFly file with Pix4D Camera:* elements) and attitudes from nadir through oblique and level to
looking up: the rotation ODM builds from what it reads is our camera's rotation, the position is
ours (not the camera's drone-dji:AbsoluteAltitude), the accuracy is ours (doubled by ODM), and the
replaced camera tags are recorded.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from icgt.export.common import ProblemLog, prepare_items
from icgt.export.geotag_writer import write_geotagged_copies
from icgt.export.odm import write_geo_txt
from icgt.export.pose_tags import img_direction, odm_angles
from icgt.geodesy import LocalFrame, q_from_euler_zyx, q_multiply
from icgt.geotag.record import FrameRecord

from .odm_rules import camera_axes_ned, descriptions, geo_txt_angles, odm_read, opensfm_ypr, rotation

ORIGIN = (37.8813, 127.7298, 76.0)
BASE = np.array([0.5, 0.5, 0.5, 0.5])
# (yaw, pitch, roll) of the camera's optical axis [deg], gimbal convention: nadir, oblique, level, up, rolled
ATTITUDES = [(30.0, -90.0, 0.0), (200.0, -45.0, 0.0), (359.996, 0.0, 0.0), (95.0, 12.0, 0.0), (300.0, -30.0, 8.0)]
DJI_XMP = (
    '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    '<rdf:Description rdf:about="" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
    'xmlns:tiff="http://ns.adobe.com/tiff/1.0/" tiff:Make="DJI" '
    'drone-dji:AbsoluteAltitude="+{alt:.3f}" drone-dji:RelativeAltitude="+20.100" '
    'drone-dji:Latitude="{lat:.7f}" drone-dji:Longitude="{lon:.7f}" '
    'drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-12.30" drone-dji:GimbalPitchDegree="-90.00" '
    'drone-dji:FlightRollDegree="+1.20" drone-dji:FlightYawDegree="-12.30" drone-dji:FlightPitchDegree="-3.10" '
    'drone-dji:RtkFlag="50" drone-dji:RtkStdLon="0.011" drone-dji:RtkStdLat="0.012" drone-dji:RtkStdHgt="0.025"/>'
    "</rdf:RDF></x:xmpmeta>"
)
# DJI X3-style packet: the Description is about "DJI Meta Data", and a second one holds Camera Raw settings (crs),
# which ExifTool keeps in a Description of its own when it rewrites the packet.
XPACKET_BEGIN = "<?xpacket begin='\ufeff' id='W5M0MpCehiHzreSzNTczkc9d'?>"  # as cameras write it
XPACKET_END = "<?xpacket end='w'?>"
DJI_X3_XMP = (
    XPACKET_BEGIN
    + '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    '<rdf:Description rdf:about="DJI Meta Data" xmlns:tiff="http://ns.adobe.com/tiff/1.0/" '
    'xmlns:dc="http://purl.org/dc/elements/1.1/" xmlns:drone-dji="http://www.dji.com/drone-dji/1.0/" '
    'tiff:Make="DJI" drone-dji:AbsoluteAltitude="+{alt:.2f}" drone-dji:RelativeAltitude="+20.100" '
    'drone-dji:GimbalRollDegree="+0.00" drone-dji:GimbalYawDegree="-12.30" drone-dji:GimbalPitchDegree="-90.00" '
    'drone-dji:FlightRollDegree="+1.20" drone-dji:FlightYawDegree="-12.30" drone-dji:FlightPitchDegree="-3.10">'
    "<dc:format>image/jpg</dc:format></rdf:Description>"
    '<rdf:Description rdf:about="DJI Meta Data" xmlns:crs="http://ns.adobe.com/camera-raw-settings/1.0/" '
    'crs:Version="7.0" crs:HasSettings="False" crs:HasCrop="False" crs:AlreadyApplied="False"/>'
    "</rdf:RDF></x:xmpmeta>" + " " * 200 + XPACKET_END
)
# A survey camera's packet that repeats a property in one Description (ExifTool: "[Minor] Duplicate XMP property")
DUPLICATE_XMP = (
    XPACKET_BEGIN
    + '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    '<rdf:Description rdf:about="" xmlns:Camera="http://pix4d.com/camera/1.0/">'
    "<Camera:Yaw>10.5</Camera:Yaw><Camera:Pitch>3.0</Camera:Pitch><Camera:Roll>-2.0</Camera:Roll>"
    "<Camera:BandName>RGB</Camera:BandName><Camera:Yaw>10.5</Camera:Yaw></rdf:Description></rdf:RDF></x:xmpmeta>"
    + XPACKET_END
)
SENSEFLY_XMP = (
    '<x:xmpmeta xmlns:x="adobe:ns:meta/"><rdf:RDF xmlns:rdf="http://www.w3.org/1999/02/22-rdf-syntax-ns#">'
    '<rdf:Description rdf:about="" xmlns:Camera="http://pix4d.com/camera/1.0/">'
    "<Camera:Yaw>10.5</Camera:Yaw><Camera:Pitch>3.0</Camera:Pitch><Camera:Roll>-2.0</Camera:Roll>"
    "<Camera:GPSXYAccuracy>5.0</Camera:GPSXYAccuracy></rdf:Description></rdf:RDF></x:xmpmeta>"
)


def frame(seq: int, yaw: float, pitch: float, roll: float) -> FrameRecord:
    q = q_multiply(q_from_euler_zyx(math.radians(roll), math.radians(pitch), math.radians(yaw)), BASE)
    lat, lon, alt = LocalFrame(*ORIGIN).enu_to_geodetic(np.array([seq * 3.0, 1.0, 15.0]))
    return FrameRecord(
        frame_seq=seq, image_index=seq, camera_id=0, device_flags=16, trigger_device_us=seq * 200_000,
        start_device_us=seq * 200_000 + 48_000, mid_device_us=seq * 200_000 + 48_500, duration_us=1000,
        mid_host_ns=seq * 200_000_000, mid_host_uncertainty_ns=30_000, time_source="pps", flags=[],
        position_source="rtk_fixed", fix_type=6, pose_gap_before_ms=5.0, pose_gap_after_ms=15.0,
        mid_utc_us=1_795_305_954_000_000 + seq * 200_000, mid_utc_uncertainty_us=1.0,
        lat_deg=float(lat), lon_deg=float(lon), alt_msl_m=float(alt), east_m=seq * 3.0, north_m=1.0, up_m=15.0,
        h_acc_m=0.02, v_acc_m=0.035, satellites=20,
        cam_qw=float(q[0]), cam_qx=float(q[1]), cam_qy=float(q[2]), cam_qz=float(q[3]),
        range_m=None, range_valid=False,
    )  # fmt: skip


def jpeg(path: Path, make: str, xmp: str | None) -> Path:
    img = Image.new("RGB", (64, 48), (90, 120, 150))
    exif = img.getexif()
    exif[0x010F] = make
    exif[0x0110] = "test"
    kw = {"xmp": xmp.encode()} if xmp is not None else {}
    img.save(path, format="JPEG", quality=90, exif=exif, **kw)
    return path


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, dict[str, FrameRecord], ProblemLog]:
    card, out = tmp_path_factory.mktemp("card"), tmp_path_factory.mktemp("out")
    pairs, frames = [], {}
    seq = 0
    kinds = (("plain", "SONY"), ("dji", "DJI"), ("djix3", "DJI"), ("sensefly", "senseFly"), ("cuav", "CUAV"))
    for kind, make in kinds:
        for att in ATTITUDES:
            seq += 1
            f = frame(seq, *att)
            lat, lon, alt = f.lat_deg or 0.0, f.lon_deg or 0.0, (f.alt_msl_m or 0.0) + 86.0  # the camera's: 86 m off
            xmp = {"plain": None, "dji": DJI_XMP.format(alt=alt, lat=lat, lon=lon), "sensefly": SENSEFLY_XMP,
                   "djix3": DJI_X3_XMP.format(alt=alt), "cuav": DUPLICATE_XMP}[kind]  # fmt: skip
            name = f"{kind.upper()}_{seq:04d}.JPG"
            pairs.append((jpeg(card / name, make, xmp), f))
            frames[name] = f
    (out / "card").symlink_to(card)
    problems = ProblemLog()
    items = prepare_items(pairs, None, problems)
    assert write_geotagged_copies(items, out / "images", problems, images_root=card) == len(pairs)
    write_geo_txt(out / "geo.txt", items, problems)
    return out, frames, problems


def _axes(f: FrameRecord) -> np.ndarray:
    assert f.cam_qw is not None and f.cam_qx is not None and f.cam_qy is not None and f.cam_qz is not None
    return camera_axes_ned((f.cam_qw, f.cam_qx, f.cam_qy, f.cam_qz))


def test_odm_reads_our_rotation_position_and_accuracy(
    exported: tuple[Path, dict[str, FrameRecord], ProblemLog],
) -> None:
    out, frames, _ = exported
    for name, f in frames.items():
        path = out / "images" / name
        with path.open("rb") as fh:
            pose = odm_read(path.read_bytes(), fh)
        assert pose.yaw is not None and pose.pitch is not None and pose.roll is not None, name
        np.testing.assert_allclose(rotation(pose.yaw, pose.pitch, pose.roll), _axes(f), atol=1e-6, err_msg=name)
        assert pose.latitude == pytest.approx(f.lat_deg, abs=1e-9)
        assert pose.longitude == pytest.approx(f.lon_deg, abs=1e-9)
        assert pose.altitude == pytest.approx(f.alt_msl_m, abs=1e-3)  # not the DJI file's own AbsoluteAltitude
        assert pose.xy_stddev == pytest.approx(2 * 0.02) and pose.z_stddev == pytest.approx(2 * 0.035)


def test_opensfm_reads_our_rotation(exported: tuple[Path, dict[str, FrameRecord], ProblemLog]) -> None:
    """Except senseFly files: ODM negates their Camera:Roll, OpenSfM does not (one tag cannot suit both)."""
    out, frames, _ = exported
    for name, f in frames.items():
        ypr = opensfm_ypr((out / "images" / name).read_bytes())
        assert ypr is not None, name
        if name.startswith("SENSEFLY"):
            ypr = (ypr[0], ypr[1], -ypr[2])
        np.testing.assert_allclose(rotation(*ypr), _axes(f), atol=1e-6, err_msg=name)


def test_geo_txt_angles_are_odms(exported: tuple[Path, dict[str, FrameRecord], ProblemLog]) -> None:
    out, frames, _ = exported
    lines = (out / "geo.txt").read_text().strip().split("\n")[1:]
    assert len(lines) == len(frames)
    for line in lines:
        angles = geo_txt_angles(line)
        assert angles is not None
        f = frames[line.split()[0]]
        np.testing.assert_allclose(rotation(*angles), _axes(f), atol=1e-6, err_msg=line)
    nadir = next(line for line in lines if line.startswith("PLAIN_0001"))
    assert geo_txt_angles(nadir) == pytest.approx((30.0, 0.0, 0.0), abs=1e-4)  # ODM: pitch 0 is nadir


def test_the_cameras_own_pose_tags_are_replaced_and_recorded(
    exported: tuple[Path, dict[str, FrameRecord], ProblemLog],
) -> None:
    out, frames, problems = exported
    replaced = {p.image: p.detail for p in problems if p.code == "camera_tags_replaced"}
    dji = [n for n in frames if n.startswith("DJI")]
    assert set(replaced) == set(dji) | {n for n in frames if n.startswith(("SENSEFLY", "CUAV"))}
    for name in dji:
        data = (out / "images" / name).read_bytes()
        (desc,) = descriptions(data)
        assert not {"@drone-dji:FlightYawDegree", "@drone-dji:RtkStdLon", "@Camera:Pitch"} & set(desc)
        assert "XMP-drone-dji:AbsoluteAltitude=" in replaced[name]
        assert name.startswith("DJIX3") or "XMP-drone-dji:RtkStdLon=0.011" in replaced[name]  # X3s have no RTK
        assert desc["@drone-dji:RelativeAltitude"] == "+20.100"  # not a pose tag: kept
        assert "XMP-drone-dji:FlightYawDegree=-12.3" in desc["@icgt:ReplacedTags"]


def test_angle_conventions_on_known_cases() -> None:
    def q(yaw: float, pitch: float, roll: float = 0.0) -> tuple[float, float, float, float]:
        w, x, y, z = q_multiply(q_from_euler_zyx(math.radians(roll), math.radians(pitch), math.radians(yaw)), BASE)
        return float(w), float(x), float(y), float(z)

    assert odm_angles(q(30.0, -90.0)) == pytest.approx((30.0, 0.0, 0.0), abs=1e-6)  # nadir, top of image to 30 deg
    assert odm_angles(q(200.0, -45.0)) == pytest.approx((200.0, 45.0, 0.0), abs=1e-6)
    assert odm_angles(q(95.0, 0.0)) == pytest.approx((95.0, 90.0, 0.0), abs=1e-6)  # level: pitch 90
    assert odm_angles(q(95.0, 12.0)) == pytest.approx((95.0, 102.0, 0.0), abs=1e-6)  # looking up
    assert img_direction(359.996) == 0.0 and img_direction(359.994) == 359.99 and img_direction(-0.5) == 359.5


def test_camera_xmp_defects_are_tolerated_and_said(exported: tuple[Path, dict[str, FrameRecord], ProblemLog]) -> None:
    """A repeated property (a survey camera's) and a Camera Raw block (DJI X3): every file gets its copy, the
    copy's XMP is one Description holding the camera's other properties, and problems.csv says what was done."""
    out, frames, problems = exported
    codes = {(p.image, p.code): p.detail for p in problems}
    for name in frames:
        data = (out / "images" / name).read_bytes()
        (desc,) = descriptions(data)
        if name.startswith("CUAV"):
            assert "Duplicate XMP property" in codes[(name, "xmp_defect_tolerated")]
            assert desc.get("@Camera:BandName", desc.get("Camera:BandName")) == "RGB"  # the camera's own kept
        if name.startswith("DJIX3"):
            assert (name, "xmp_descriptions_merged") in codes
            assert desc["@crs:Version"] == "7.0" and desc.get("@dc:format", desc.get("dc:format")) == "image/jpg"
            assert desc["@rdf:about"] == "DJI Meta Data"
    assert not [p for p in problems if p.severity == "error"]


def _exiftool_view(*paths: Path) -> list[dict[str, Any]]:
    """ExifTool's own reading of each file: every tag by its group (-G1), each warning once (-a, copy numbers)."""
    import exiftool  # PyExifTool

    with exiftool.ExifToolHelper(common_args=["-a", "-G1:4", "-n"]) as et:
        return list(et.execute_json("-validate", "-warning", "-all", *map(str, paths)))


def _warnings(tags: dict[str, Any]) -> set[str]:
    return {str(v) for k, v in tags.items() if k.endswith(":Warning")}


def test_exiftool_reads_every_copy_without_a_new_defect(
    exported: tuple[Path, dict[str, FrameRecord], ProblemLog],
) -> None:
    """ExifTool, the tool users check files with, on the written copies (not our reader): the survey camera's
    repeated property is gone and nothing it warns of in a copy was not already in the camera's file (the
    merged packet keeps its xpacket wrapper); it reads our pose and the camera's other properties back."""
    out, frames, _ = exported
    names = sorted(frames)
    views = _exiftool_view(*(out / "card" / n for n in names), *(out / "images" / n for n in names))
    assert len(views) == 2 * len(names)
    original = dict(zip(names, views[: len(names)], strict=True))
    copy = dict(zip(names, views[len(names) :], strict=True))
    for name in names:
        f, got = frames[name], copy[name]
        assert _warnings(got) <= _warnings(original[name]), (name, _warnings(got) - _warnings(original[name]))
        assert not any("Duplicate XMP" in w for w in _warnings(got)), name
        assert got["Composite:GPSLatitude"] == pytest.approx(f.lat_deg, abs=1e-8)
        assert got["Composite:GPSLongitude"] == pytest.approx(f.lon_deg, abs=1e-8)
        assert got["XMP-icgt:FrameSeq"] == f.frame_seq
        yaw = odm_angles((f.cam_qw or 0.0, f.cam_qx or 0.0, f.cam_qy or 0.0, f.cam_qz or 0.0))[0]
        assert got["XMP-Camera:Yaw"] == pytest.approx(yaw, abs=0.01), name
        if name.startswith("CUAV"):
            assert any("Duplicate XMP property: Camera:Yaw" in w for w in _warnings(original[name]))
            assert got["XMP-Camera:BandName"] == "RGB"
        if name.startswith("DJIX3"):
            assert got["XMP-crs:Version"] == 7.0 and got["XMP-dc:Format"] == "image/jpg"
            assert got["XMP-drone-dji:RelativeAltitude"] == "+20.100"  # the camera's own, kept as written
            assert (out / "images" / name).read_bytes().count(b"<?xpacket end=") == 1
