"""The tags of a geotagged copy: EXIF GPS, the XMP pose tags photogrammetry tools read, ours; and the check of a copy.

Written with ExifTool (`icgt.export.exiftool_session`, which says why ExifTool), which changes
nothing else in the file: maker notes, thumbnails, previews, MPF, tag types and the existing XMP
stay as the camera wrote them, and the compressed image data is copied byte for byte.

EXIF GPS tags (EXIF 2.32, GPS IFD; the camera's own GPS IFD is replaced whole): GPSVersionID
2.3.0.0; GPSLatitudeRef/GPSLatitude and GPSLongitudeRef/GPSLongitude [deg, WGS84; ExifTool writes
degrees, minutes and seconds as rationals good to about 1e-11 deg]; GPSAltitudeRef (0 above, 1
below sea level) and GPSAltitude [m, MSL]; GPSTimeStamp (UTC, to the microsecond) and GPSDateStamp
of mid-exposure; GPSSatellites; GPSStatus "A"; GPSMeasureMode "3" or "2"; GPSMapDatum "WGS-84";
GPSDifferential (1 for RTK); GPSHPositioningError [m] (the GPS horizontal accuracy);
GPSImgDirectionRef "T" and GPSImgDirection [deg, 0-359.99] (the camera's heading). In the EXIF
IFD: SubjectDistance [m] (the LiDAR range). The camera's DateTimeOriginal is left as it is.

XMP (one rdf:Description, properties as attributes; `icgt.export.pose_tags` has the rules and the
conventions): Camera:Yaw/Pitch/Roll and Camera:GPSXYAccuracy/GPSZAccuracy for ODM, OpenSfM, Pix4D
and Metashape, drone-dji:Gimbal*Degree on DJI/Hasselblad files; and namespace ``icgt``
(`XMP_NS`): CameraYawDegree, CameraPitchDegree, CameraRollDegree (gimbal convention, see
`icgt.geometry.camera_angles_deg`), CameraQuaternionNED ("w x y z", camera x right, y down, z
forward -> NED), VehicleYawDegree/PitchDegree/RollDegree, the record's time, position, range,
scale, incidence, sources and flags, and ReplacedTags (the camera's tags this copy replaced).

Every copy is read back (`check_copy`): each tag written must read back as the value meant, else
the copy is removed and the image gets a problem row.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from icgt.export.common import ExportItem, position_sigma_m, utc_iso
from icgt.export.exiftool_session import NS_ICGT, XMP_LAYOUT
from icgt.export.pose_tags import CONFLICTING, img_direction, odm_angles, xmp_pose_values
from icgt.export.xmp_packet import xmp_span

XMP_NS = NS_ICGT

ICGT_TAGS = (
    "FrameSeq", "ImageIndex", "MidExposureUTC", "MidExposureUTCUncertaintyMicroseconds", "TimeSource",
    "PositionSource", "FixType", "LatitudeDegrees", "LongitudeDegrees", "AltitudeMSLMeters",
    "HorizontalAccuracyMeters", "VerticalAccuracyMeters", "EastMeters", "NorthMeters", "UpMeters",
    "VehicleYawDegree", "VehiclePitchDegree", "VehicleRollDegree", "LidarRangeMeters", "BlurPixels", "Flags",
    "CameraYawDegree", "CameraPitchDegree", "CameraRollDegree", "CameraQuaternionNED", "ScaleMmPerPixel",
    "IncidenceDegree", "SurfaceModel", "ReplacedTags",
)  # fmt: skip
"""Every property of the icgt XMP namespace (declared to ExifTool by its config)."""

READ_TAGS = ("-EXIF:Make", "-XMP-tiff:Make", "-GPS:all", "-XMP-exif:all", "-XMP-drone-dji:all", "-XMP-Camera:all",
             "-XMP-icgt:all",
             "-ExifIFD:SubjectDistance", "-Composite:GPSLatitude", "-Composite:GPSLongitude",
             "-File:FileType", "-ExifTool:Warning", "-ExifTool:Error")  # fmt: skip
"""What is read of each original (before) and of each copy (after), in one batched command."""


def gps_values(item: ExportItem) -> dict[str, Any]:
    """EXIF GPS tags (ExifTool names, numeric values) of an item with a usable position."""
    rec = item.frame
    assert rec.lat_deg is not None and rec.lon_deg is not None and rec.alt_msl_m is not None
    tags: dict[str, Any] = {
        "GPS:GPSVersionID": "2 3 0 0",
        "GPS:GPSLatitudeRef": "N" if rec.lat_deg >= 0 else "S",
        "GPS:GPSLatitude": abs(rec.lat_deg),
        "GPS:GPSLongitudeRef": "E" if rec.lon_deg >= 0 else "W",
        "GPS:GPSLongitude": abs(rec.lon_deg),
        "GPS:GPSAltitudeRef": 0 if rec.alt_msl_m >= 0 else 1,
        "GPS:GPSAltitude": round(abs(rec.alt_msl_m), 4),
        "GPS:GPSStatus": "A",
        "GPS:GPSMeasureMode": 3 if rec.fix_type >= 3 else 2,
        "GPS:GPSMapDatum": "WGS-84",
        "GPS:GPSDifferential": 1 if rec.position_source.startswith("rtk") else 0,
    }
    if rec.satellites is not None:
        tags["GPS:GPSSatellites"] = str(rec.satellites)
    h_sigma, _ = position_sigma_m(rec)
    if h_sigma is not None and math.isfinite(h_sigma):
        tags["GPS:GPSHPositioningError"] = round(h_sigma, 4)
    if item.angles is not None:
        tags["GPS:GPSImgDirectionRef"] = "T"
        tags["GPS:GPSImgDirection"] = img_direction(item.angles[0])
    if rec.mid_utc_us is not None:
        dt = datetime.fromtimestamp(rec.mid_utc_us // 1_000_000, tz=UTC)
        tags["GPS:GPSTimeStamp"] = f"{dt.hour:02d}:{dt.minute:02d}:{dt.second:02d}.{rec.mid_utc_us % 1_000_000:06d}"
        tags["GPS:GPSDateStamp"] = dt.strftime("%Y:%m:%d")
    return tags


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


def item_odm_angles(item: ExportItem) -> tuple[float, float, float] | None:
    """The camera's (yaw, pitch, roll) in ODM's convention (icgt.export.pose_tags), None without an attitude."""
    r = item.frame
    if r.cam_qw is None or r.cam_qx is None or r.cam_qy is None or r.cam_qz is None:
        return None
    return odm_angles((r.cam_qw, r.cam_qx, r.cam_qy, r.cam_qz))


def intended_tags(item: ExportItem, before: Mapping[str, Any], *, sidecar: bool = False) -> dict[str, Any]:
    """Every tag (ExifTool family-1 name) the copy of `item` must carry, given the original's tags `before`."""
    rec = item.frame
    make = before.get("IFD0:Make") or before.get("XMP-tiff:Make")
    tags: dict[str, Any] = {}
    if item.position_ok:
        gps = gps_values(item)
        if sidecar:  # XMP has no GPS IFD: exif:GPS* of the XMP exif schema, signed decimal degrees
            lat, lon = rec.lat_deg, rec.lon_deg
            tags["XMP-exif:GPSLatitude"] = lat
            tags["XMP-exif:GPSLongitude"] = lon
            for k in ("GPSAltitudeRef", "GPSAltitude", "GPSImgDirectionRef", "GPSImgDirection", "GPSMapDatum",
                      "GPSMeasureMode", "GPSStatus", "GPSDifferential", "GPSHPositioningError", "GPSSatellites",
                      "GPSVersionID"):  # fmt: skip
                if f"GPS:{k}" in gps:
                    tags[f"XMP-exif:{k}"] = gps[f"GPS:{k}"]
            if rec.mid_utc_us is not None:
                tags["XMP-exif:GPSDateTime"] = utc_iso(rec.mid_utc_us)
        else:
            tags.update(gps)
    if rec.range_valid and rec.range_m is not None and math.isfinite(rec.range_m) and not sidecar:
        tags["ExifIFD:SubjectDistance"] = round(rec.range_m, 3)
    h_acc, v_acc = position_sigma_m(rec) if item.position_ok else (None, None)
    tags.update(xmp_pose_values(item_odm_angles(item), str(make) if make else None, h_acc, v_acc))
    tags.update({f"XMP-icgt:{k}": v for k, v in xmp_properties(item).items()})
    replaced = replaced_tags(before, tags)
    if replaced:
        tags["XMP-icgt:ReplacedTags"] = replaced
    return tags


def replaced_tags(before: Mapping[str, Any], new: Mapping[str, Any]) -> str:
    """'name=value; ...' of the camera's GPS and pose tags that the copy replaces or removes."""
    parts = []
    for key, value in before.items():
        ours = (key.startswith("GPS:") and key != "GPS:GPSVersionID") or key in CONFLICTING
        if ours and new.get(key) != value:
            parts.append(f"{key}={value}")
    return "; ".join(parts)


def write_args(
    src: Path, dst: Path, tags: Mapping[str, Any], *, sidecar: bool = False, rewrap_xmp: bool = False
) -> list[str]:
    """The ExifTool command that writes `tags` into a copy of src at dst (a new file).

    `rewrap_xmp`: the camera's XMP packet has no ``x:xmpmeta`` element (ExifTool keeps a packet's
    shape): rebuild the packet from its own properties so that it gets one, as ODM and OpenSfM
    find XMP by it.
    """
    args = ["-n", *XMP_LAYOUT]
    if rewrap_xmp:
        args += ["-XMP:all=", "-tagsFromFile", "@", "-XMP:all", *[f"--{t}" for t in CONFLICTING]]
    args += ["-XMP-icgt:all="]
    if not sidecar:
        args += ["-GPS:all="]
        args += [f"-{t}=" for t in CONFLICTING if t not in tags]
    args += [f"-{k}={v}" for k, v in tags.items()]
    if sidecar:
        return [*args, str(dst)]  # ExifTool creates a new XMP file from these tags alone
    return [*args, "-o", str(dst), str(src)]


def xmp_lacks_wrapper(data: bytes) -> bool:
    """The JPEG's XMP packet (APP1) has no x:xmpmeta element (a bare rdf:RDF, x:xapmeta is fine for ExifTool)."""
    where = xmp_span(data)
    if where is None:
        return False
    packet = data[where[0] : where[1]]
    return b"<x:xmpmeta" not in packet and b"<x:xapmeta" not in packet


def _seconds(hms: Any) -> float:
    h, m, s = str(hms).split(":")
    return int(h) * 3600 + int(m) * 60 + float(s)


def _same(key: str, want: Any, got: Any) -> bool:
    """Equal as written: rationals to 1e-9 deg (0.1 mm) for latitude/longitude, 1e-6 elsewhere, times to 1 us."""
    if key.endswith("GPSTimeStamp"):
        try:
            return abs(_seconds(want) - _seconds(got)) < 1.5e-6
        except ValueError:
            return False
    if isinstance(want, float | int) and not isinstance(want, bool):
        try:
            g = float(got)
        except (TypeError, ValueError):
            return False
        tol = 1e-9 if key.endswith(("Latitude", "Longitude")) else max(1e-6, 1e-9 * abs(float(want)))
        return abs(g - float(want)) <= tol
    if isinstance(got, float | int) and not isinstance(got, bool):
        try:
            return abs(float(want) - float(got)) <= 1e-9 * max(1.0, abs(float(got)))
        except (TypeError, ValueError):
            return False
    return str(want).strip() == str(got).strip()


def check_copy(want: Mapping[str, Any], got: Mapping[str, Any]) -> list[str]:
    """What differs between the tags meant and those read back from the copy ([] when all are there)."""
    diffs = []
    for key, value in want.items():
        if key == "XMP-exif:GPSDateTime":
            continue  # ExifTool normalises the date-time's spelling; the GPS time is checked in EXIF
        if key not in got:
            diffs.append(f"{key} missing")
        elif not _same(key, value, got[key]):
            diffs.append(f"{key} is {got[key]!r}, meant {value!r}")
    for key in CONFLICTING:
        if key in got and key not in want:
            diffs.append(f"{key} still there")
    return diffs
