"""The catalogue's declared schema: five tables, their columns with units, and the GeoParquet 1.1 metadata.

Every file carries, in its Parquet key-value metadata:

- ``geo``: GeoParquet 1.1 (https://geoparquet.org/releases/v1.1.0/): geometry columns as WKB, the WGS84
  one (``geometry``, [lon, lat] degrees) with its CRS as PROJJSON (OGC:CRS84) and a ``bbox`` covering
  column (struct xmin/ymin/xmax/ymax); the structure-face one (``geometry_face``, (s, t) metres in the
  flight's face frame, `icgt.mapping`) with ``crs: null`` (an engineering frame with no EPSG code; the
  frame itself is in the flight's ``face_frame`` column, origin and axes in WGS84 and ENU).
- ``icgt.catalog``: ``{"schema_version": N, "table": NAME, "icgt_version": ...}``.

Every column has field metadata ``description`` and, where it has one, ``unit``. The frames table holds
every `FrameRecord` field under its own name and type (flags as a list of FrameFlag values, a missing
optional value as null), so a frame read back equals `icgt.read`'s.

Versions: `SCHEMA_VERSION` is written into every file and the catalogue's marker. A catalogue of an
older version that this one can still read is listed in `READABLE_VERSIONS`; any other is refused with
both versions named (`check_version`).
"""

from __future__ import annotations

import dataclasses
import functools
import json
import types
import typing
from collections.abc import Mapping, Sequence
from typing import Any

import pyarrow as pa

from icgt.field_doc import Doc
from icgt.geotag.record import FrameRecord

SCHEMA_VERSION = 1
"""The catalogue's schema version: bumped whenever a table's columns change meaning or type."""
READABLE_VERSIONS = frozenset({1})
"""Schema versions this version reads (a newer catalogue, or an older one without a converter, is refused)."""

META_KEY = b"icgt.catalog"
GEO_KEY = b"geo"
TABLES = ("flights", "frames", "images", "footprints", "defects")

_BBOX = pa.struct(
    [
        pa.field("xmin", pa.float64()),
        pa.field("ymin", pa.float64()),
        pa.field("xmax", pa.float64()),
        pa.field("ymax", pa.float64()),
    ]
)


def _f(name: str, typ: pa.DataType, description: str, unit: str | None = None, nullable: bool = True) -> pa.Field:
    meta = {"description": description}
    if unit:
        meta["unit"] = unit
    return pa.field(name, typ, nullable=nullable, metadata=meta)


_UTC_US = pa.timestamp("us", tz="UTC")

_KEYS = [
    _f("structure", pa.string(), "the structure's name (--structure), the first partition key", nullable=False),
    _f(
        "flight", pa.string(), "the flight's id: device serial and recording id (the second partition key)", None, False
    ),
]
_GEOMETRY = _f("geometry", pa.binary(), "WKB, WGS84 longitude/latitude (OGC:CRS84)", "deg")
_GEOMETRY_FACE = _f(
    "geometry_face", pa.binary(), "WKB on the structure face: (s along the face, t up) from the face origin", "m"
)
_BBOX_FIELD = _f("bbox", _BBOX, "bounding box of geometry (GeoParquet 1.1 covering column)", "deg")


def _frame_type(hint: Any) -> tuple[pa.DataType, bool]:
    optional = False
    if isinstance(hint, types.UnionType):
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        optional = len(args) < len(typing.get_args(hint))
        hint = args[0]
    base = typing.get_origin(hint) or hint
    arrow = {int: pa.int64(), float: pa.float64(), bool: pa.bool_(), str: pa.string(), list: pa.list_(pa.string())}
    if base not in arrow:
        raise TypeError(f"FrameRecord field of type {hint!r} has no catalogue column type")
    return arrow[base], optional


@functools.cache
def frame_fields() -> tuple[pa.Field, ...]:
    """One column per FrameRecord field, in its order, with the field's description and unit."""
    hints = typing.get_type_hints(FrameRecord, include_extras=True)
    out = []
    for f in dataclasses.fields(FrameRecord):
        hint = hints[f.name]
        doc = next((m for m in getattr(hint, "__metadata__", ()) if isinstance(m, Doc)), None)
        typ, _optional = _frame_type(typing.get_args(hint)[0] if doc is not None else hint)
        out.append(_f(f.name, typ, doc.description if doc else f.name, doc.unit if doc else None))
    return tuple(out)


FLIGHTS = pa.schema(
    [
        *_KEYS,
        _f(
            "revision",
            pa.string(),
            "content id of this partition: SHA-256 over the log, card and detections",
            None,
            False,
        ),
        _f(
            "replaced_revisions", pa.list_(pa.string()), "revisions of this flight replaced by later adds, oldest first"
        ),
        _f("schema_version", pa.int32(), "catalogue schema version of this partition", None, False),
        _f("icgt_version", pa.string(), "icgt version that wrote the partition"),
        _f("added_utc", _UTC_US, "when this revision was added", "us"),
        _f("log_file", pa.string(), "file name of the recording"),
        _f("log_sha256", pa.string(), "SHA-256 of the recording's bytes"),
        _f("log_bytes", pa.int64(), "size of the recording", "B"),
        _f("card_sha256", pa.string(), "SHA-256 over the card's image names and contents (null without --images)"),
        _f("detections_sha256", pa.string(), "SHA-256 over the detection files (null without --detections)"),
        _f("recording_id", pa.string(), "the recording id the recorder named to the device (metadata icgt.flight)"),
        _f("flight_kind", pa.string(), "recording, or recovered (icgt recover-device)"),
        _f("device_board", pa.string(), "the device's board (metadata icgt.device)"),
        _f("device_serial", pa.string(), "the device's USB serial number"),
        _f("firmware_version", pa.string(), "the device's firmware version"),
        _f("autopilot", pa.string(), "the autopilot (MAV_AUTOPILOT of its first HEARTBEAT)"),
        _f("vehicle_type", pa.string(), "the vehicle (MAV_TYPE of the autopilot's first HEARTBEAT)"),
        _f("host_software", pa.string(), "the recorder's software (metadata icgt.config)"),
        _f("config_sha256", pa.string(), "SHA-256 of the recorder's configuration text (metadata icgt.config)"),
        _f("start_utc", _UTC_US, "mid-exposure of the first frame with a UTC time", "us"),
        _f("end_utc", _UTC_US, "mid-exposure of the last frame with a UTC time", "us"),
        _f("year", pa.int32(), "UTC year of start_utc"),
        _f("duration_s", pa.float64(), "first to last message of the recording, host clock", "s"),
        _f("frames", pa.int64(), "frame records"),
        _f("frames_with_position", pa.int64(), "frames with a WGS84 position"),
        _f("frames_without_pose", pa.int64(), "frames flagged no_pose or telemetry_expired"),
        _f("frames_untrusted_pose", pa.int64(), "frames with any POOR_POSE_FLAGS flag"),
        _f("frames_feedback_missing", pa.int64(), "triggers the camera did not confirm"),
        _f(
            "lost_exposures",
            pa.int64(),
            "exposures the device could no longer resend (icgt.device_link lost_exposures)",
        ),
        _f(
            "lost_exposures_unknown_at_end", pa.bool_(), "the recording ended with the device unreachable and capturing"
        ),
        _f("device_messages_missing", pa.int64(), "device messages missing from the sequence (sequence_gap events)"),
        _f("corrupt_frames", pa.int64(), "corrupt device frames skipped (frames_rejected events)"),
        _f("link_outages", pa.int64(), "device and MAVLink outages"),
        _f("outage_s", pa.float64(), "outages in all", "s"),
        _f("images", pa.int64(), "JPEG images on the card (null without --images)"),
        _f("images_paired", pa.int64(), "images paired with a frame"),
        _f("defects", pa.int64(), "merged damage-map defects (null without --detections)"),
        _f("footprints", pa.int64(), "frames with a footprint on the face"),
        _f("face_frame", pa.string(), "JSON: the structure face frame of this flight (icgt.mapping face_frame_json)"),
        _GEOMETRY,
        _BBOX_FIELD,
    ],
)

FRAMES = pa.schema(
    [
        *_KEYS,
        *frame_fields(),
        _f("mid_utc", _UTC_US, "mid_utc_us as a timestamp", "us"),
        _GEOMETRY,
        _BBOX_FIELD,
    ]
)

IMAGES = pa.schema(
    [
        *_KEYS,
        _f("file", pa.string(), "path of the image on the card, relative to --images", None, False),
        _f("sha256", pa.string(), "SHA-256 of the image file"),
        _f("bytes", pa.int64(), "size of the image file", "B"),
        _f("verdict", pa.string(), "paired, ambiguous or unmatched (icgt.ingest.match)", None, False),
        _f("reason", pa.string(), "why not paired (the matcher's reason code)"),
        _f("detail", pa.string(), "the matcher's explanation"),
        _f("frame_seq", pa.int64(), "the frame it is paired with"),
        _f("candidates", pa.list_(pa.int64()), "frame_seq of the exposures an ambiguous image could be"),
        _f("residual_s", pa.float64(), "EXIF time minus the clock model's time of the exposure", "s"),
        _GEOMETRY,
        _BBOX_FIELD,
    ]
)

FOOTPRINTS = pa.schema(
    [
        *_KEYS,
        _f("frame_seq", pa.int64(), "the frame", None, False),
        _f("image", pa.string(), "the card image paired with the frame (with --images)"),
        _f("surface", pa.string(), "the surface the image was projected on (icgt.geometry SurfaceSource)"),
        _f("area_m2", pa.float64(), "footprint area on the surface", "m^2"),
        _f("scale_mm_per_px", pa.float64(), "ground sample distance at the image centre", "mm/px"),
        _f("incidence_deg", pa.float64(), "angle between the optical axis and the surface normal", "deg"),
        _f("horizontal_error_bound_m", pa.float64(), "the frame's 95 % horizontal position bound", "m"),
        _f("attitude_error_bound_deg", pa.float64(), "the frame's 95 % attitude bound", "deg"),
        _GEOMETRY,
        _GEOMETRY_FACE,
        _BBOX_FIELD,
    ]
)

DEFECTS = pa.schema(
    [
        *_KEYS,
        _f("defect_id", pa.string(), "the damage map's instance id", None, False),
        _f("kind", pa.string(), "crack, or an area defect kind (icgt.mapping.model)", None, False),
        _f("categories", pa.list_(pa.string()), "detector classes of its detections"),
        _f("length_mm", pa.float64(), "crack length along the centreline", "mm"),
        _f("width_mm", pa.float64(), "crack width", "mm"),
        _f("area_mm2", pa.float64(), "area of an area defect", "mm^2"),
        _f("position_sigma_mm", pa.float64(), "1-sigma position uncertainty", "mm"),
        _f("length_sigma_mm", pa.float64(), "1-sigma length uncertainty", "mm"),
        _f("truncated", pa.bool_(), "the defect runs out of every image it was seen in"),
        _f("images", pa.list_(pa.string()), "the images it was seen in"),
        _f("n_detections", pa.int64(), "detections merged into it"),
        _f("mid_alt_msl_m", pa.float64(), "height of its midpoint above mean sea level", "m"),
        _f("mid_face_s_m", pa.float64(), "its midpoint along the face", "m"),
        _f("mid_face_t_m", pa.float64(), "its midpoint up the face", "m"),
        _GEOMETRY,
        _GEOMETRY_FACE,
        _BBOX_FIELD,
    ]
)

SCHEMAS: dict[str, pa.Schema] = {
    "flights": FLIGHTS,
    "frames": FRAMES,
    "images": IMAGES,
    "footprints": FOOTPRINTS,
    "defects": DEFECTS,
}
GEOMETRY_TYPES: dict[str, list[str]] = {
    "flights": ["Polygon", "Point", "LineString"],
    "frames": ["Point"],
    "images": ["Point"],
    "footprints": ["Polygon"],
    "defects": ["LineString", "Polygon"],
}


@functools.cache
def crs84_projjson() -> dict[str, Any]:
    """OGC:CRS84 (WGS84, longitude first) as PROJJSON, from PROJ's database (pyproj)."""
    import pyproj

    out: dict[str, Any] = pyproj.CRS.from_user_input("OGC:CRS84").to_json_dict()
    return out


def geo_metadata(table: str, bbox: Sequence[float] | None) -> dict[str, Any]:
    """The GeoParquet 1.1 `geo` metadata of a table's file; bbox: the extent of its `geometry` column."""
    columns: dict[str, Any] = {
        "geometry": {
            "encoding": "WKB",
            "geometry_types": GEOMETRY_TYPES[table],
            "crs": crs84_projjson(),
            "edges": "planar",
            "covering": {
                "bbox": {
                    "xmin": ["bbox", "xmin"],
                    "ymin": ["bbox", "ymin"],
                    "xmax": ["bbox", "xmax"],
                    "ymax": ["bbox", "ymax"],
                }
            },
        }
    }
    if bbox is not None:
        columns["geometry"]["bbox"] = [float(v) for v in bbox]
    if "geometry_face" in SCHEMAS[table].names:
        columns["geometry_face"] = {"encoding": "WKB", "geometry_types": GEOMETRY_TYPES[table], "crs": None}
    return {"version": "1.1.0", "primary_column": "geometry", "columns": columns}


def file_metadata(table: str, bbox: Sequence[float] | None) -> dict[bytes, bytes]:
    from icgt.version import __version__

    return {
        GEO_KEY: json.dumps(geo_metadata(table, bbox)).encode(),
        META_KEY: json.dumps({"schema_version": SCHEMA_VERSION, "table": table, "icgt_version": __version__}).encode(),
    }


def check_version(found: object, where: str) -> int:
    """The schema version `found` (from a file or the marker) if readable; CatalogError naming both otherwise."""
    from icgt.catalog import CatalogError

    if not isinstance(found, int) or found not in READABLE_VERSIONS:
        readable = ", ".join(str(v) for v in sorted(READABLE_VERSIONS))
        newer = isinstance(found, int) and found > SCHEMA_VERSION
        raise CatalogError(
            f"{where}: written with catalogue schema version {found}, this icgt writes version {SCHEMA_VERSION} "
            f"and reads {readable}: " + ("upgrade icgt to read it" if newer else "add its flights again")
        )
    return found


def table_version(meta: Mapping[bytes, bytes] | None, where: str) -> int:
    """The schema version in a file's key-value metadata (check_version applied)."""
    from icgt.catalog import CatalogError

    raw = (meta or {}).get(META_KEY)
    if raw is None:
        raise CatalogError(f"{where}: not a catalogue file (no {META_KEY.decode()} metadata)")
    try:
        version = json.loads(raw)["schema_version"]
    except (ValueError, KeyError, TypeError):
        raise CatalogError(f"{where}: its {META_KEY.decode()} metadata is unreadable") from None
    return check_version(version, where)
