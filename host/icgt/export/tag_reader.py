"""The few tags the geotag writer needs of a JPEG, read in-process (exifread and the XMP packet), by ExifTool's names.

Before writing, the writer needs each original's make, GPS and XMP pose tags; after writing, every
tag it wrote, to compare. ExifTool reads them too, but at tens of milliseconds of Perl per file,
about a third of a write; exifread and ElementTree read the same few tags in about a millisecond,
and being other readers than the writer they make the check of each copy independent of it.
Values come out as ExifTool's ``-n -G1`` JSON gives them (``GPS:GPSLatitude`` unsigned decimal
degrees, ``Composite:GPSLatitude`` signed, XMP properties by namespace as ``XMP-Camera:Yaw``), so
the writer handles both alike; a file these readers cannot parse returns None and is read with
ExifTool instead.
"""

from __future__ import annotations

import logging
import math
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

from icgt.export.exiftool_session import NS_CAMERA, NS_ICGT
from icgt.export.xmp_packet import xmp_span

_RDF = "{http://www.w3.org/1999/02/22-rdf-syntax-ns#}"
GROUPS = {
    NS_CAMERA: "XMP-Camera",
    NS_ICGT: "XMP-icgt",
    "http://www.dji.com/drone-dji/1.0/": "XMP-drone-dji",
    "http://ns.adobe.com/exif/1.0/": "XMP-exif",
    "http://ns.adobe.com/tiff/1.0/": "XMP-tiff",
}
_GPS_NAMES = {"GPSDate": "GPSDateStamp", "Tag 0x001F": "GPSHPositioningError"}  # exifread's name -> ExifTool's


def _number(v: Any) -> float:
    num, den = getattr(v, "num", v), getattr(v, "den", 1)
    return float(num) / float(den)


def _gps_value(name: str, values: Any) -> Any:
    vals = values if isinstance(values, list) else [values]
    if name in ("GPSLatitude", "GPSLongitude", "GPSDestLatitude", "GPSDestLongitude") and len(vals) == 3:
        d, m, s = (_number(v) for v in vals)
        return d + m / 60.0 + s / 3600.0
    if name == "GPSTimeStamp" and len(vals) == 3:
        h, m, s = (_number(v) for v in vals)
        return f"{int(h):02d}:{int(m):02d}:{s!r}"
    if name == "GPSVersionID":
        return " ".join(str(int(v)) for v in vals)
    if isinstance(values, str):
        return values.strip()
    if len(vals) == 1:
        v = vals[0]
        return _number(v) if hasattr(v, "den") else v
    return " ".join(str(v) for v in vals)


def _xmp_value(text: str) -> Any:
    t = text.strip()
    try:
        f = float(t)
    except ValueError:
        return t
    return f if math.isfinite(f) and t.lower() not in ("nan", "inf", "infinity") else t


def _xmp_packet(data: bytes) -> bytes | None:
    where = xmp_span(data)
    return None if where is None else data[where[0] : where[1]]


def _xmp_tags(packet: bytes) -> dict[str, Any]:
    # the packet is one XML document: xpacket processing instructions around the root element
    root = ET.fromstring(packet.decode("utf-8").strip("\x00 \t\r\n"))
    out: dict[str, Any] = {}
    for desc in root.iter(f"{_RDF}Description"):
        items = list(desc.attrib.items())
        items += [(child.tag, child.text or "") for child in desc if len(child) == 0]
        for key, value in items:
            if not key.startswith("{"):
                continue
            uri, local = key[1:].split("}", 1)
            group = GROUPS.get(uri)
            if group is not None:
                out[f"{group}:{local}"] = _xmp_value(value)
    return out


def read_tags(path: Path) -> dict[str, Any] | None:
    """Make, GPS, SubjectDistance and the XMP tags of our namespaces of a JPEG; None if it cannot be parsed here."""
    import exifread

    logging.getLogger("exifread").setLevel(logging.ERROR)
    try:
        from io import BytesIO

        from icgt.export.card import jpeg_header

        data = jpeg_header(path)

        tags = exifread.process_file(BytesIO(data), details=False)
        out: dict[str, Any] = {}
        for key, tag in tags.items():
            if key == "Image Make":
                out["IFD0:Make"] = str(tag.values).strip()
            elif key == "EXIF SubjectDistance":
                out["ExifIFD:SubjectDistance"] = _number(tag.values[0])
            elif key.startswith("GPS "):
                name = _GPS_NAMES.get(key[4:], key[4:])
                if not name.startswith("Tag 0x"):  # a GPS tag exifread does not know: not one we write
                    out[f"GPS:{name}"] = _gps_value(name, tag.values)
        if "GPS:GPSLatitude" in out and "GPS:GPSLongitude" in out:
            lat, lon = out["GPS:GPSLatitude"], out["GPS:GPSLongitude"]
            if isinstance(lat, float) and isinstance(lon, float):
                s_lat = -1.0 if str(out.get("GPS:GPSLatitudeRef", "N")).upper().startswith("S") else 1.0
                s_lon = -1.0 if str(out.get("GPS:GPSLongitudeRef", "E")).upper().startswith("W") else 1.0
                out["Composite:GPSLatitude"] = s_lat * lat
                out["Composite:GPSLongitude"] = s_lon * lon
        packet = _xmp_packet(data)
        if packet is not None:
            out.update(_xmp_tags(packet))
        return out
    except Exception:  # exifread and the XML parser fail in many ways on odd files: ExifTool reads those
        return None
