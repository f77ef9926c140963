"""How OpenDroneMap and OpenSfM read a photo's pose, written down from their readers (not from icgt.export).

ODM, opendm/photo.py (ODM_Photo.parse_exif_values, compute_opk), and opendm/types.py (geo.txt):

1. XMP: the bytes from the first ``<x:xmpmeta`` to the first ``</x:xmpmeta`` are parsed with
   xmltodict, which keeps the literal prefixes; ``x:xmpmeta`` -> ``rdf:RDF`` -> ``rdf:Description``
   (one or a list). Attributes are keys ``@prefix:Name``, child elements ``prefix:Name``. Each
   Description is read in turn; a later one overwrites what an earlier one set.
2. Position: EXIF GPSLatitude/Longitude/Altitude (Ref respected), then ``@drone-dji:Longitude``,
   ``@drone-dji:Latitude``, ``@drone-dji:AbsoluteAltitude`` replace them when present.
3. Accuracy: ``@drone-dji:RtkStdLon``/``RtkStdLat`` (max of the two) and ``RtkStdHgt`` if
   RtkStdLon is present, else ``@Camera:GPSXYAccuracy`` / ``GPSXYAccuracy`` and
   ``@Camera:GPSZAccuracy`` / ``GPSZAccuracy``; both are then doubled.
4. Angles: yaw from the first of ``@drone-dji:FlightYawDegree``, ``@Camera:Yaw``, ``Camera:Yaw``;
   pitch from ``@drone-dji:GimbalPitchDegree``, ``@Camera:Pitch``, ``Camera:Pitch``; roll from
   ``@drone-dji:GimbalRollDegree``, ``@Camera:Roll``, ``Camera:Roll``. If all three are known:
   EXIF Make dji or hasselblad (any case): pitch += 90; senseFly: roll = -roll.
5. geo.txt: ``name x y [z [yaw pitch roll [horizontal vertical accuracy]]]``; angles only with at
   least 7 fields; they replace the photo's angles as they are (no per-make correction).
6. Rotation (compute_opk): Cnb = Rz(yaw) Ry(pitch) Rx(roll) with the standard right-handed
   rotation matrices in NED, times Cbb = [[0,1,0],[1,0,0],[0,0,-1]]; Cnb Cbb takes the
   photogrammetric camera axes (x right, y up in the image, z out of the back) to NED.

OpenSfM's own reader (opensfm/exif.py, EXIF.extract_opk) reads only the first rdf:Description's
attributes: ``@Camera:Yaw``/``Pitch``/``Roll`` as they are if all three are there, else
``@drone-dji:GimbalYawDegree``/``GimbalPitchDegree``/``GimbalRollDegree`` with pitch + 90; no
per-make rule; the same rotation (rule 6).
"""

from __future__ import annotations

import math
import xml.parsers.expat
from dataclasses import dataclass, field
from typing import Any

import exifread
import numpy as np


def descriptions(data: bytes) -> list[dict[str, str]]:
    """The rdf:Description dicts of the first XMP packet, keys as xmltodict gives them (rule 1)."""
    start, end = data.find(b"<x:xmpmeta"), data.find(b"</x:xmpmeta")
    if not 0 <= start < end:
        return []
    out: list[dict[str, str]] = []
    stack: list[str] = []
    text: list[str] = []
    current: dict[str, str] | None = None

    def start_el(name: str, attrs: dict[str, str]) -> None:
        nonlocal current
        stack.append(name)
        text.clear()
        if name == "rdf:Description" and stack[:-1] == ["x:xmpmeta", "rdf:RDF"]:
            current = {f"@{k}": v for k, v in attrs.items()}
            out.append(current)

    def end_el(name: str) -> None:
        nonlocal current
        if current is not None and len(stack) == 4 and stack[2] == "rdf:Description":
            current[name] = "".join(text).strip()
        if name == "rdf:Description" and len(stack) == 3:
            current = None
        stack.pop()
        text.clear()

    p = xml.parsers.expat.ParserCreate()  # no namespace processing: literal prefixes, as xmltodict
    p.StartElementHandler = start_el
    p.EndElementHandler = end_el
    p.CharacterDataHandler = text.append
    p.Parse(data[start : end + 12].decode("utf-8"), True)
    return out


@dataclass
class OdmPose:
    make: str = ""
    latitude: float | None = None
    longitude: float | None = None
    altitude: float | None = None
    yaw: float | None = None
    pitch: float | None = None
    roll: float | None = None
    xy_stddev: float | None = None
    z_stddev: float | None = None
    xmp: list[dict[str, str]] = field(default_factory=list)


def _first(tags: dict[str, str], names: list[str]) -> float | None:
    for n in names:
        if n in tags:
            return float(tags[n])
    return None


def _dms(tag: Any, ref: Any) -> float:
    d, m, s = (float(v.num) / float(v.den) for v in tag.values)
    return (d + m / 60 + s / 3600) * (-1 if str(ref.values)[0] in "SWsw" else 1)


def odm_read(data: bytes, path_for_exif: Any) -> OdmPose:
    """The pose ODM takes from an image (rules 1-4); `path_for_exif` an open binary file of it."""
    tags = exifread.process_file(path_for_exif, details=False)
    pose = OdmPose(make=str(tags["Image Make"].values).strip() if "Image Make" in tags else "")
    if "GPS GPSAltitude" in tags:
        a = tags["GPS GPSAltitude"].values[0]
        pose.altitude = float(a.num) / float(a.den)
        if "GPS GPSAltitudeRef" in tags and int(tags["GPS GPSAltitudeRef"].values[0]) > 0:
            pose.altitude *= -1
    if "GPS GPSLatitude" in tags:
        pose.latitude = _dms(tags["GPS GPSLatitude"], tags["GPS GPSLatitudeRef"])
        pose.longitude = _dms(tags["GPS GPSLongitude"], tags["GPS GPSLongitudeRef"])
    pose.xmp = descriptions(data)
    for x in pose.xmp:
        for attr, name in (("longitude", "@drone-dji:Longitude"), ("latitude", "@drone-dji:Latitude"),
                           ("altitude", "@drone-dji:AbsoluteAltitude")):  # fmt: skip
            if name in x:
                setattr(pose, attr, float(x[name]))
        if "@drone-dji:RtkStdLon" in x:
            pose.xy_stddev = max(float(x["@drone-dji:RtkStdLon"]), float(x["@drone-dji:RtkStdLat"]))
            if "@drone-dji:RtkStdHgt" in x:
                pose.z_stddev = float(x["@drone-dji:RtkStdHgt"])
        else:
            v = _first(x, ["@Camera:GPSXYAccuracy", "GPSXYAccuracy"])
            pose.xy_stddev = v if v is not None else pose.xy_stddev
            v = _first(x, ["@Camera:GPSZAccuracy", "GPSZAccuracy"])
            pose.z_stddev = v if v is not None else pose.z_stddev
        if pose.xy_stddev is not None:
            pose.xy_stddev *= 2.0
        if pose.z_stddev is not None:
            pose.z_stddev *= 2.0
        for attr, names in (("yaw", ["@drone-dji:FlightYawDegree", "@Camera:Yaw", "Camera:Yaw"]),
                            ("pitch", ["@drone-dji:GimbalPitchDegree", "@Camera:Pitch", "Camera:Pitch"]),
                            ("roll", ["@drone-dji:GimbalRollDegree", "@Camera:Roll", "Camera:Roll"])):  # fmt: skip
            v = _first(x, names)
            if v is not None:
                setattr(pose, attr, v)
        if pose.yaw is not None and pose.pitch is not None and pose.roll is not None:
            if pose.make.lower() in ("dji", "hasselblad"):
                pose.pitch = 90 + pose.pitch
            if pose.make.lower() == "sensefly":
                pose.roll *= -1
    return pose


def opensfm_ypr(data: bytes) -> tuple[float, float, float] | None:
    """OpenSfM's (yaw, pitch, roll) from the first rdf:Description's attributes (pitch in ODM's convention)."""
    xmp = descriptions(data)
    if not xmp:
        return None
    x = xmp[0]
    if all(f"@Camera:{a}" in x for a in ("Yaw", "Pitch", "Roll")):
        return float(x["@Camera:Yaw"]), float(x["@Camera:Pitch"]), float(x["@Camera:Roll"])
    if all(f"@drone-dji:Gimbal{a}Degree" in x for a in ("Yaw", "Pitch", "Roll")):
        return (float(x["@drone-dji:GimbalYawDegree"]), float(x["@drone-dji:GimbalPitchDegree"]) + 90.0,
                float(x["@drone-dji:GimbalRollDegree"]))  # fmt: skip
    return None


def rotation(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """Rule 6: photogrammetric camera axes -> NED."""
    y, p, r = (math.radians(a) for a in (yaw, pitch, roll))
    cy, sy, cp, sp, cr, sr = math.cos(y), math.sin(y), math.cos(p), math.sin(p), math.cos(r), math.sin(r)
    cnb = np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                    [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                    [-sp, cp * sr, cp * cr]])  # fmt: skip
    cbb = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1]])
    return np.asarray(cnb @ cbb)


def camera_axes_ned(q: tuple[float, float, float, float]) -> np.ndarray:
    """Photogrammetric camera axes -> NED of an icgt camera quaternion (camera x right, y down, z forward -> NED)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])  # fmt: skip
    return np.asarray(r @ np.diag([1.0, -1.0, -1.0]))


def geo_txt_angles(line: str) -> tuple[float, float, float] | None:
    """Rule 5."""
    parts = line.split()
    return (float(parts[4]), float(parts[5]), float(parts[6])) if len(parts) >= 7 else None
