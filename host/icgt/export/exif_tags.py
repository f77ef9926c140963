"""Geotagged copies of the camera's JPEGs: EXIF GPS and an XMP packet, written without re-encoding.

The EXIF block is rebuilt with Pillow (``PIL.Image.Exif``: the camera's own tags are kept and a GPS
IFD is added) and the XMP packet with the standard library's ElementTree; both are then spliced
into the copy's APP1 segments, and every other byte of the JPEG (the compressed image above all) is
copied unchanged, so the pixels the crack detector sees are the camera's. The originals are only
ever opened for reading; a copy is written next to its final name and renamed into place.

EXIF GPS tags written (EXIF 2.32, GPS IFD): GPSVersionID 2.3.0.0; GPSLatitudeRef/GPSLatitude and
GPSLongitudeRef/GPSLongitude (degrees, minutes, seconds as rationals, seconds to 1e-6); GPSAltitudeRef
(0 above, 1 below sea level) and GPSAltitude [m, MSL, to the mm]; GPSTimeStamp (UTC hours, minutes,
seconds to the microsecond) and GPSDateStamp ("YYYY:MM:DD") of mid-exposure; GPSSatellites;
GPSStatus "A"; GPSMeasureMode "3" or "2"; GPSMapDatum "WGS-84"; GPSDifferential (1 for RTK);
GPSHPositioningError [m] (the GPS horizontal accuracy); GPSImgDirectionRef "T" and GPSImgDirection
[deg] (the camera's heading). In the EXIF IFD: SubjectDistance [m] (the LiDAR range). The
camera's DateTimeOriginal is left as the camera wrote it.

EXIF has no tags for a camera's attitude, so it goes into XMP, namespace ``icgt`` (`XMP_NS`):
CameraYawDegree, CameraPitchDegree, CameraRollDegree (gimbal convention, see
`icgt.geometry.camera_angles_deg`), CameraQuaternionNED ("w x y z", camera x right, y down, z
forward -> NED), VehicleYawDegree/PitchDegree/RollDegree, and the record's time, position, range,
scale, incidence, sources and flags. An XMP packet already in the image is kept, with ours added as
one more rdf:Description.
"""

from __future__ import annotations

import contextlib
import io
import math
import os
import shutil
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from PIL import Image
from PIL.TiffImagePlugin import IFDRational
from tqdm import tqdm

from icgt.export import ExportError
from icgt.export.common import ExportItem, ProblemLog, utc_iso

EXIF_HEADER = b"Exif\x00\x00"
XMP_HEADER = b"http://ns.adobe.com/xap/1.0/\x00"
XMP_NS = "urn:icgt:ns:geotag:1.0/"
_NS_X = "adobe:ns:meta/"
_NS_RDF = "http://www.w3.org/1999/02/22-rdf-syntax-ns#"
_APP1 = 0xE1
_APP0 = 0xE0
_MAX_SEGMENT = 65533  # payload bytes of one marker segment (its 16-bit length counts itself)

IFD_EXIF = 0x8769
IFD_GPS = 0x8825
TAG_SUBJECT_DISTANCE = 0x9206
GPS = {
    "GPSVersionID": 0x00,
    "GPSLatitudeRef": 0x01,
    "GPSLatitude": 0x02,
    "GPSLongitudeRef": 0x03,
    "GPSLongitude": 0x04,
    "GPSAltitudeRef": 0x05,
    "GPSAltitude": 0x06,
    "GPSTimeStamp": 0x07,
    "GPSSatellites": 0x08,
    "GPSStatus": 0x09,
    "GPSMeasureMode": 0x0A,
    "GPSImgDirectionRef": 0x10,
    "GPSImgDirection": 0x11,
    "GPSMapDatum": 0x12,
    "GPSDateStamp": 0x1D,
    "GPSDifferential": 0x1E,
    "GPSHPositioningError": 0x1F,
}


# --- JPEG segments --------------------------------------------------------------------------


def split_jpeg(data: bytes) -> tuple[list[tuple[int, bytes]], bytes]:
    """(marker segments before the image data as (marker, payload), the rest from SOS on, verbatim)."""
    if data[:2] != b"\xff\xd8":
        raise ExportError("not a JPEG file (no SOI marker)")
    pos = 2
    segments: list[tuple[int, bytes]] = []
    while True:
        if pos + 2 > len(data) or data[pos] != 0xFF:
            raise ExportError(f"damaged JPEG: no marker at byte {pos}")
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker in (0xDA, 0xD9):  # start of scan / end of image: the rest is copied as it is
            return segments, data[pos:]
        if pos + 4 > len(data):
            raise ExportError(f"damaged JPEG: segment header cut off at byte {pos}")
        length = int.from_bytes(data[pos + 2 : pos + 4], "big")
        if length < 2 or pos + 2 + length > len(data):
            raise ExportError(f"damaged JPEG: segment {marker:#04x} at byte {pos} runs past the end")
        segments.append((marker, data[pos + 4 : pos + 2 + length]))
        pos += 2 + length


def join_jpeg(segments: Sequence[tuple[int, bytes]], rest: bytes) -> bytes:
    out = bytearray(b"\xff\xd8")
    for marker, payload in segments:
        if len(payload) > _MAX_SEGMENT:
            raise ExportError(f"a {marker:#04x} segment of {len(payload)} bytes does not fit a JPEG segment")
        out += bytes((0xFF, marker)) + (len(payload) + 2).to_bytes(2, "big") + payload
    out += rest
    return bytes(out)


# --- EXIF -----------------------------------------------------------------------------------


def _dms(value_deg: float) -> tuple[IFDRational, IFDRational, IFDRational]:
    """|value| as degrees, minutes, seconds rationals (seconds to 1e-6, carried exactly)."""
    micro = round(abs(value_deg) * 3600.0 * 1e6)
    deg, rem = divmod(micro, 3600 * 1_000_000)
    minutes, sec_micro = divmod(rem, 60 * 1_000_000)
    return IFDRational(deg, 1), IFDRational(minutes, 1), IFDRational(sec_micro, 1_000_000)


def _ratio(value: float, denominator: int = 1000) -> IFDRational:
    return IFDRational(round(value * denominator), denominator)


def gps_tags(item: ExportItem) -> dict[int, Any]:
    """The GPS IFD of an item with a usable position (module docstring)."""
    rec = item.frame
    assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
    tags: dict[int, Any] = {
        GPS["GPSVersionID"]: b"\x02\x03\x00\x00",
        GPS["GPSLatitudeRef"]: "N" if rec.lat_deg >= 0 else "S",
        GPS["GPSLatitude"]: _dms(rec.lat_deg),
        GPS["GPSLongitudeRef"]: "E" if rec.lon_deg >= 0 else "W",
        GPS["GPSLongitude"]: _dms(rec.lon_deg),
        GPS["GPSAltitudeRef"]: b"\x00" if rec.alt_msl_m >= 0 else b"\x01",
        GPS["GPSAltitude"]: _ratio(abs(rec.alt_msl_m)),
        GPS["GPSStatus"]: "A",
        GPS["GPSMeasureMode"]: "3" if rec.fix_type >= 3 else "2",
        GPS["GPSMapDatum"]: "WGS-84",
        GPS["GPSDifferential"]: 1 if rec.position_source.startswith("rtk") else 0,
    }
    if rec.satellites is not None:
        tags[GPS["GPSSatellites"]] = str(rec.satellites)
    if rec.h_acc_m is not None and math.isfinite(rec.h_acc_m):
        tags[GPS["GPSHPositioningError"]] = _ratio(rec.h_acc_m)
    if item.angles is not None:
        tags[GPS["GPSImgDirectionRef"]] = "T"
        tags[GPS["GPSImgDirection"]] = _ratio(item.angles[0] % 360.0, 100)
    if rec.mid_utc_us is not None:
        dt = datetime.fromtimestamp(rec.mid_utc_us // 1_000_000, tz=UTC)
        micro = dt.second * 1_000_000 + rec.mid_utc_us % 1_000_000
        tags[GPS["GPSTimeStamp"]] = (IFDRational(dt.hour, 1), IFDRational(dt.minute, 1), IFDRational(micro, 1_000_000))
        tags[GPS["GPSDateStamp"]] = dt.strftime("%Y:%m:%d")
    return tags


def exif_payload(existing: bytes | None, item: ExportItem) -> bytes:
    """The new EXIF APP1 payload: the camera's tags kept, the GPS IFD replaced, SubjectDistance set."""
    exif = Image.Exif()
    if existing is not None:
        try:
            exif.load(existing)
        except Exception as exc:  # Pillow raises many kinds on damaged EXIF
            raise ExportError(f"cannot read the image's EXIF ({type(exc).__name__}: {exc})") from exc
    gps = exif.get_ifd(IFD_GPS)
    gps.clear()
    if item.position_ok:
        gps.update(gps_tags(item))
    rec = item.frame
    if rec.range_valid and rec.range_m is not None and math.isfinite(rec.range_m):
        exif.get_ifd(IFD_EXIF)[TAG_SUBJECT_DISTANCE] = _ratio(rec.range_m)
    data = exif.tobytes()
    return data if data.startswith(EXIF_HEADER) else EXIF_HEADER + data


# --- XMP ------------------------------------------------------------------------------------


def _fmt(value: Any) -> str | None:
    if value is None:
        return None
    if isinstance(value, bool):
        return "True" if value else "False"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else None
    if isinstance(value, list | tuple):
        return " ".join(str(v) for v in value)
    return str(value)


def xmp_properties(item: ExportItem) -> dict[str, str]:
    """The icgt XMP properties of an item (names in XMP's UpperCamelCase)."""
    rec = item.frame
    props: dict[str, Any] = {
        "FrameSeq": rec.frame_seq,
        "ImageIndex": rec.image_index,
        "MidExposureUTC": utc_iso(rec.mid_utc_us) or None,
        "MidExposureUTCUncertaintyMicroseconds": rec.mid_utc_uncertainty_us,
        "TimeSource": rec.time_source,
        "PositionSource": rec.position_source,
        "FixType": rec.fix_type,
        "LatitudeDegrees": rec.lat_deg if item.position_ok else None,
        "LongitudeDegrees": rec.lon_deg if item.position_ok else None,
        "AltitudeMSLMeters": rec.alt_msl_m if item.position_ok else None,
        "HorizontalAccuracyMeters": rec.h_acc_m,
        "VerticalAccuracyMeters": rec.v_acc_m,
        "EastMeters": rec.east_m,
        "NorthMeters": rec.north_m,
        "UpMeters": rec.up_m,
        "VehicleYawDegree": rec.yaw_deg,
        "VehiclePitchDegree": rec.pitch_deg,
        "VehicleRollDegree": rec.roll_deg,
        "LidarRangeMeters": rec.range_m if rec.range_valid else None,
        "BlurPixels": rec.blur_px,
        "Flags": list(rec.flags) or None,
    }
    if item.angles is not None:
        props["CameraYawDegree"], props["CameraPitchDegree"], props["CameraRollDegree"] = item.angles
        props["CameraQuaternionNED"] = [rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz]
    s = item.solution
    if s is not None:
        props["ScaleMmPerPixel"] = s.scale_mm_per_px
        props["IncidenceDegree"] = s.incidence_deg
        props["SurfaceModel"] = s.surface.value
    out: dict[str, str] = {}
    for k, v in props.items():
        text = _fmt(v)
        if text is not None:
            out[k] = text
    return out


def xmp_payload(existing: bytes | None, props: Mapping[str, str]) -> bytes:
    """An XMP APP1 payload: the existing packet (if readable) with our rdf:Description replacing any older one."""
    ET.register_namespace("x", _NS_X)
    ET.register_namespace("rdf", _NS_RDF)
    ET.register_namespace("icgt", XMP_NS)
    root: ET.Element | None = None
    if existing is not None:
        body = existing[len(XMP_HEADER) :].decode("utf-8", "replace")
        start, end = body.find("<x:xmpmeta"), body.rfind("</x:xmpmeta>")
        if 0 <= start < end:
            xml_text = body[start : end + len("</x:xmpmeta>")]
            with contextlib.suppress(ET.ParseError):
                # keep the packet's own prefixes (tiff:, exif:, drone-dji: ...) when it is written back
                for _, (prefix, uri) in ET.iterparse(io.StringIO(xml_text), events=("start-ns",)):
                    with contextlib.suppress(ValueError):
                        ET.register_namespace(prefix, uri)
                root = ET.fromstring(xml_text)
    if root is None:
        root = ET.Element(f"{{{_NS_X}}}xmpmeta")
    rdf = root.find(f"{{{_NS_RDF}}}RDF")
    if rdf is None:
        rdf = ET.SubElement(root, f"{{{_NS_RDF}}}RDF")
    for d in rdf.findall(f"{{{_NS_RDF}}}Description"):
        if any(k.startswith(f"{{{XMP_NS}}}") for k in d.attrib):
            rdf.remove(d)
    attrs = {f"{{{_NS_RDF}}}about": ""} | {f"{{{XMP_NS}}}{k}": v for k, v in props.items()}
    ET.SubElement(rdf, f"{{{_NS_RDF}}}Description", attrs)
    xml = ET.tostring(root, encoding="unicode")
    packet = f'<?xpacket begin="\ufeff" id="W5M0MpCehiHzreSzNTczkc9d"?>{xml}<?xpacket end="w"?>'
    return XMP_HEADER + packet.encode("utf-8")


# --- one image, all images ------------------------------------------------------------------


def geotag_jpeg(src: Path, dst: Path, item: ExportItem) -> None:
    """Write a geotagged copy of src to dst (never src itself); raises ExportError."""
    try:
        if dst.resolve() == src.resolve():
            raise ExportError(f"{dst}: refusing to overwrite the original")
    except OSError:
        pass
    try:
        data = src.read_bytes()
    except OSError as exc:
        raise ExportError(f"cannot read {src}: {exc.strerror or exc}") from exc
    segments, rest = split_jpeg(data)
    old_exif = next((p for m, p in segments if m == _APP1 and p.startswith(EXIF_HEADER)), None)
    old_xmp = next((p for m, p in segments if m == _APP1 and p.startswith(XMP_HEADER)), None)
    new_exif = exif_payload(old_exif, item)
    new_xmp = xmp_payload(old_xmp, xmp_properties(item))
    kept = [(m, p) for m, p in segments if not (m == _APP1 and (p.startswith(EXIF_HEADER) or p.startswith(XMP_HEADER)))]
    # EXIF where it was (or after APP0/SOI), XMP right after it
    at = next((i for i, (m, p) in enumerate(segments) if m == _APP1 and p.startswith(EXIF_HEADER)), None)
    if at is None:
        at = 1 if kept and kept[0][0] == _APP0 else 0
    else:
        at = sum(1 for m, p in segments[:at] if not (m == _APP1 and p.startswith(XMP_HEADER)))
    out = join_jpeg([*kept[:at], (_APP1, new_exif), (_APP1, new_xmp), *kept[at:]], rest)
    tmp = dst.with_name(f".{dst.name}.tmp")
    try:
        tmp.write_bytes(out)
        shutil.copystat(src, tmp)
        os.replace(tmp, dst)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise ExportError(f"cannot write {dst}: {exc.strerror or exc}") from exc


def write_geotagged_copies(
    items: Sequence[ExportItem],
    out_dir: Path,
    problems: ProblemLog,
    *,
    progress: bool = False,
    images_root: Path | None = None,
) -> int:
    """Geotagged copies of every item's image into out_dir; returns how many were written.

    Copies keep their path below `images_root` (DCIM/100MSDCF/...), else their file name. An image
    that cannot be copied (damaged, unreadable) is reported and skipped; an image without a usable
    position is still copied (XMP only, no GPS tags; prepare_items reported why).
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExportError(f"cannot create {out_dir}: {exc.strerror or exc}") from exc
    written = 0
    for item in tqdm([i for i in items if i.image is not None], desc="jpeg", unit="image", disable=not progress):
        assert item.image is not None
        dst = out_dir / item.image.name
        if images_root is not None and item.image.is_relative_to(images_root):
            dst = out_dir / item.image.relative_to(images_root)
        try:
            dst.parent.mkdir(parents=True, exist_ok=True)
            geotag_jpeg(item.image, dst, item)
            written += 1
        except OSError as exc:
            problems.add(item.name, item.frame.frame_seq, "error", "jpeg_write_failed", str(exc), "jpeg")
        except ExportError as exc:
            problems.add(item.name, item.frame.frame_seq, "error", "jpeg_write_failed", str(exc), "jpeg")
    return written
