"""The rows of one flight, from the project's own readers (nothing here re-derives what they compute).

- frames: `icgt.read(log).frames()`, every FrameRecord field as recorded;
- flights: the report's reader (`icgt.report.summary.gather`: duration, outages, losses, the device's
  counters) plus the recording's metadata and content hashes;
- images: the matcher (`icgt.ingest.match.match_images`) over the card, each file hashed;
- footprints: the damage map's face (`icgt.mapping.surface.find_face`, the plane fitted to the LiDAR
  returns) and the export's projector (`icgt.geometry.Projector`, anchored at each frame's range);
- defects: `icgt map`'s pipeline (`icgt.mapping.cli.run_map`, its GeoJSON features) when detections
  are given, in the same face frame as the footprints.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from icgt.catalog import CatalogError
from icgt.catalog.schema import SCHEMA_VERSION, SCHEMAS, file_metadata, frame_fields
from icgt.geotag.record import POOR_POSE_FLAGS, FrameFlag, FrameRecord
from icgt.recording import layout
from icgt.recording.identity import file_sha256, flight_id

log = logging.getLogger(__name__)

_HASH_CHUNK = 1 << 20


@dataclass(frozen=True)
class FlightTables:
    """One flight ready to be written: its id, its content revision and one Arrow table per catalogue table."""

    structure: str
    flight: str
    revision: str
    tables: dict[str, pa.Table]


def sha256_file(path: Path) -> str:
    try:
        return file_sha256(path)
    except OSError as exc:
        raise CatalogError(f"cannot read {path}: {exc.strerror or exc}") from None


def _card_files(card: Path) -> list[Path]:
    from icgt.ingest.match import list_images

    return list(list_images(card))


def _card_hash(card: Path, files: Sequence[Path], hashes: dict[Path, str]) -> str:
    h = hashlib.sha256()
    for p in files:
        h.update(str(p.relative_to(card)).encode() + b"\0" + hashes[p].encode() + b"\n")
    return h.hexdigest()


def _files_hash(paths: Sequence[Path]) -> str:
    h = hashlib.sha256()
    for p in sorted(paths):
        files = sorted(q for q in p.rglob("*") if q.is_file()) if p.is_dir() else [p]
        for q in files:
            h.update(q.name.encode() + b"\0" + sha256_file(q).encode() + b"\n")
    return h.hexdigest()


def _wkb(geoms: Sequence[Any]) -> tuple[list[bytes | None], list[dict[str, float] | None]]:
    import shapely

    wkb: list[bytes | None] = []
    boxes: list[dict[str, float] | None] = []
    for g in geoms:
        if g is None or g.is_empty:
            wkb.append(None)
            boxes.append(None)
            continue
        wkb.append(shapely.to_wkb(g, output_dimension=2))
        x0, y0, x1, y1 = g.bounds
        boxes.append({"xmin": x0, "ymin": y0, "xmax": x1, "ymax": y1})
    return wkb, boxes


def _extent(boxes: Sequence[dict[str, float] | None]) -> list[float] | None:
    got = [b for b in boxes if b is not None]
    if not got:
        return None
    return [
        min(b["xmin"] for b in got),
        min(b["ymin"] for b in got),
        max(b["xmax"] for b in got),
        max(b["ymax"] for b in got),
    ]


def _table(name: str, columns: dict[str, list[Any]], n: int) -> pa.Table:
    schema = SCHEMAS[name]
    arrays = []
    for field in schema:
        values = columns.get(field.name)
        if values is None:
            values = [None] * n
        arrays.append(pa.array(values, type=field.type))
    table = pa.Table.from_arrays(arrays, schema=schema)
    return table.replace_schema_metadata(file_metadata(name, _extent(columns.get("bbox", []))))


def _utc(us: int | None) -> datetime | None:
    return None if us is None else datetime.fromtimestamp(us / 1e6, UTC)


def _frames_table(structure: str, flight: str, frames: Sequence[FrameRecord]) -> pa.Table:
    import shapely

    n = len(frames)
    cols: dict[str, list[Any]] = {"structure": [structure] * n, "flight": [flight] * n}
    for f in frame_fields():
        values = [getattr(r, f.name) for r in frames]
        if pa.types.is_floating(f.type):
            # JSON has no NaN: the recorder leaves a non-finite optional value out (None); required gaps are inf
            values = [None if v is None else float(v) for v in values]
        cols[f.name] = values
    cols["mid_utc"] = [_utc(r.mid_utc_us) for r in frames]
    points = [
        shapely.Point(r.lon_deg, r.lat_deg) if r.lat_deg is not None and r.lon_deg is not None else None for r in frames
    ]
    cols["geometry"], cols["bbox"] = _wkb(points)
    return _table("frames", cols, n)


@dataclass
class _Images:
    table: pa.Table
    paired: dict[int, str]
    count: int
    n_paired: int


def _images_table(structure: str, flight: str, frames: Sequence[FrameRecord], ident: Identity) -> _Images:
    import shapely

    from icgt.ingest.match import match_images

    assert ident.card is not None
    card, files, hashes = ident.card, ident.card_files, ident.card_hashes
    result = match_images(frames, card)
    if frames and not result.pairs:
        why = "; ".join(result.notes[:2]) or "no image's time fits an exposure"
        raise CatalogError(f"--images {card}: a card of another flight? none of its {len(files)} images pairs with "
                           f"the log's {len(frames)} frames ({why})")  # fmt: skip
    rows: dict[Path, dict[str, Any]] = {}
    for p in result.pairs:
        rows[p.image] = {"verdict": "paired", "frame": p.frame, "residual_s": p.residual_s}
    for a in result.ambiguous:
        rows[a.image] = {"verdict": "ambiguous", "reason": "ambiguous", "detail": a.why,
                         "candidates": [c.frame_seq for c in a.candidates]}  # fmt: skip
    for u in result.unmatched_images:
        rows[u.image] = {"verdict": "unmatched", "reason": u.reason, "detail": u.detail}
    cols: dict[str, list[Any]] = {k: [] for k in SCHEMAS["images"].names}
    geoms = []
    for path in files:
        row = rows.get(path, {"verdict": "unmatched", "reason": "not_considered", "detail": "not read by the matcher"})
        frame: FrameRecord | None = row.get("frame")
        cols["structure"].append(structure)
        cols["flight"].append(flight)
        cols["file"].append(str(path.relative_to(card)))
        cols["sha256"].append(hashes[path])
        cols["bytes"].append(path.stat().st_size)
        cols["verdict"].append(row["verdict"])
        cols["reason"].append(row.get("reason"))
        cols["detail"].append(row.get("detail"))
        cols["frame_seq"].append(frame.frame_seq if frame is not None else None)
        cols["candidates"].append(row.get("candidates"))
        cols["residual_s"].append(row.get("residual_s"))
        has_pos = frame is not None and frame.lat_deg is not None and frame.lon_deg is not None
        geoms.append(shapely.Point(frame.lon_deg, frame.lat_deg) if has_pos and frame is not None else None)
    cols["geometry"], cols["bbox"] = _wkb(geoms)
    paired = {p.frame.frame_seq: str(p.image.relative_to(card)) for p in result.pairs}
    return _Images(_table("images", cols, len(files)), paired, len(files), len(result.pairs))


@dataclass
class _Face:
    face: Any
    origin: Any
    projector: Any


def _locate(recording: Any, frames: Sequence[FrameRecord]) -> _Face | None:
    """The damage map's face and projector for this flight (icgt.mapping.cli.open_session's choice without a
    card), or None when the log cannot place anything on a surface (no calibration, no LiDAR returns)."""
    from icgt.export.cli import camera_from_metadata, surface_normal_from_metadata
    from icgt.geodesy import LocalFrame
    from icgt.geometry import GeometryError, Projector, origin_from_frames
    from icgt.mapping import MappingError
    from icgt.mapping.surface import find_face

    camera = camera_from_metadata(recording.metadata)
    if camera is None or not frames:
        return None
    enu = recording.enu_origin
    origin = LocalFrame(*enu) if enu is not None else origin_from_frames(frames)
    if origin is None:
        return None
    trusted = [f for f in frames if not any(flag.value in f.flags for flag in POOR_POSE_FLAGS)]
    try:
        face = find_face(camera, trusted, plane=None, normal=surface_normal_from_metadata(recording.metadata))
        projector = Projector(camera, origin=origin, structure=face.plane, anchor="range")
    except (MappingError, GeometryError) as exc:
        log.info("%s: no footprints: %s", recording.path, exc)
        return None
    return _Face(face, origin, projector)


def _footprints_table(
    structure: str, flight: str, frames: Sequence[FrameRecord], where: _Face | None, paired: dict[int, str]
) -> pa.Table:
    import shapely

    from icgt.geometry import GeometryError

    cols: dict[str, list[Any]] = {k: [] for k in SCHEMAS["footprints"].names}
    wgs, face_geoms = [], []
    if where is not None:
        for rec, sol in zip(frames, where.projector.solve_many(list(frames)), strict=True):
            if isinstance(sol, GeometryError) or sol.footprint is None:
                continue
            fp = sol.footprint
            st = where.face.to_face(fp.enu)
            if fp.lat_deg is None or fp.lon_deg is None or not np.isfinite(st).all():
                continue
            ring = np.stack([fp.lon_deg, fp.lat_deg], axis=1)
            if not np.isfinite(ring).all():
                continue
            wgs.append(shapely.Polygon(ring))
            face_geoms.append(shapely.Polygon(st))
            cols["structure"].append(structure)
            cols["flight"].append(flight)
            cols["frame_seq"].append(rec.frame_seq)
            cols["image"].append(paired.get(rec.frame_seq))
            cols["surface"].append(str(sol.surface.value))
            cols["area_m2"].append(sol.footprint_area_m2)
            cols["scale_mm_per_px"].append(sol.scale_mm_per_px)
            cols["incidence_deg"].append(sol.incidence_deg)
            cols["horizontal_error_bound_m"].append(rec.horizontal_error_bound_m)
            cols["attitude_error_bound_deg"].append(rec.attitude_error_bound_deg)
    cols["geometry"], cols["bbox"] = _wkb(wgs)
    cols["geometry_face"], _ = _wkb(face_geoms)
    return _table("footprints", cols, len(wgs))


def _defects_table(structure: str, flight: str, wgs84: dict[str, Any], face: dict[str, Any]) -> pa.Table:
    from shapely.geometry import shape

    cols: dict[str, list[Any]] = {k: [] for k in SCHEMAS["defects"].names}
    by_id = {f["id"]: f for f in face["features"]}
    geoms, face_geoms = [], []
    for feat in wgs84["features"]:
        p = feat["properties"]
        geoms.append(shape(feat["geometry"]))
        face_geoms.append(shape(by_id[feat["id"]]["geometry"]))
        cols["structure"].append(structure)
        cols["flight"].append(flight)
        cols["defect_id"].append(str(p["id"]))
        cols["kind"].append(p["kind"])
        cols["categories"].append(list(p["categories"]))
        for k in ("length_mm", "width_mm", "area_mm2", "position_sigma_mm", "length_sigma_mm", "mid_alt_msl_m",
                  "mid_face_s_m", "mid_face_t_m"):  # fmt: skip
            cols[k].append(None if p.get(k) is None else float(p[k]))
        cols["truncated"].append(bool(p["truncated"]))
        cols["images"].append(list(p["images"]))
        cols["n_detections"].append(int(p["n_detections"]))
    cols["geometry"], cols["bbox"] = _wkb(geoms)
    cols["geometry_face"], _ = _wkb(face_geoms)
    return _table("defects", cols, len(geoms))


def _heartbeat(recording: Any) -> tuple[str | None, str | None]:
    """(MAV_AUTOPILOT name, MAV_TYPE name) of the autopilot's first HEARTBEAT in the log."""
    topic = layout.mavlink_topic("HEARTBEAT")
    if topic not in recording.topics():
        return None, None
    from pymavlink.dialects.v20 import common as mav

    for _, msg in recording.messages(topic):
        ap, typ = msg.get("autopilot"), msg.get("type")
        if ap == mav.MAV_AUTOPILOT_INVALID:
            continue  # a ground station or companion component

        def name(enum: str, v: Any) -> str | None:
            entry = mav.enums[enum].get(v) if isinstance(v, int) else None
            return entry.name if entry is not None else (None if v is None else str(v))

        return name("MAV_AUTOPILOT", ap), name("MAV_TYPE", typ)
    return None, None


def _flights_table(
    structure: str,
    flight: str,
    revision: str,
    data: Any,
    recording: Any,
    log_path: Path,
    log_sha: str,
    extra: dict[str, Any],
) -> pa.Table:
    import shapely

    from icgt.version import __version__

    frames: list[FrameRecord] = data.frames
    md: dict[str, dict[str, str]] = data.metadata
    device = md.get(layout.META_DEVICE, {})
    fl = md.get(layout.META_FLIGHT, {})
    config = md.get(layout.META_CONFIG, {})
    link = md.get(layout.META_DEVICE_LINK, {})
    utc = [r.mid_utc_us for r in frames if r.mid_utc_us is not None]
    start = _utc(min(utc)) if utc else None
    autopilot, vehicle = _heartbeat(recording)

    def flagged(*flags: FrameFlag) -> int:
        return sum(1 for r in frames if any(f.value in r.flags for f in flags))

    def as_int(v: str | None) -> int:
        try:
            return int(v) if v is not None else 0
        except ValueError:
            return 0

    pts = [(r.lon_deg, r.lat_deg) for r in frames if r.lat_deg is not None and r.lon_deg is not None]
    hull = shapely.MultiPoint(pts).convex_hull if pts else None
    row: dict[str, Any] = {
        "structure": structure,
        "flight": flight,
        "revision": revision,
        "replaced_revisions": [],
        "schema_version": SCHEMA_VERSION,
        "icgt_version": __version__,
        "added_utc": datetime.now(UTC),
        "log_file": log_path.name,
        "log_sha256": log_sha,
        "log_bytes": log_path.stat().st_size,
        "recording_id": fl.get("recording_id"),
        "flight_kind": fl.get("kind", "recording"),
        "device_board": device.get("board"),
        "device_serial": device.get("serial_number"),
        "firmware_version": device.get("firmware_version"),
        "autopilot": autopilot,
        "vehicle_type": vehicle,
        "host_software": config.get("host_software"),
        "config_sha256": hashlib.sha256(config["config"].encode()).hexdigest() if "config" in config else None,
        "start_utc": start,
        "end_utc": _utc(max(utc)) if utc else None,
        "year": start.year if start is not None else None,
        "duration_s": data.duration_s,
        "frames": len(frames),
        "frames_with_position": sum(1 for r in frames if r.lat_deg is not None),
        "frames_without_pose": flagged(FrameFlag.NO_POSE, FrameFlag.TELEMETRY_EXPIRED),
        "frames_untrusted_pose": flagged(*POOR_POSE_FLAGS),
        "frames_feedback_missing": flagged(FrameFlag.FEEDBACK_MISSING),
        "lost_exposures": as_int(link.get("lost_exposures")),
        "lost_exposures_unknown_at_end": data.unreachable_at_end is not None,
        "device_messages_missing": sum(x.count for x in data.losses if x.kind == "sequence_gap"),
        "corrupt_frames": sum(x.count for x in data.losses if x.kind == "frames_rejected"),
        "link_outages": len(data.outages),
        "outage_s": float(sum(o.end_s - o.start_s for o in data.outages)),
        **extra,
    }
    geom = [hull]
    wkb, boxes = _wkb(geom)
    row["geometry"], row["bbox"] = wkb[0], boxes[0]
    cols = {k: [v] for k, v in row.items()}
    return _table("flights", cols, 1)


@dataclass(frozen=True)
class Identity:
    """Which flight a log is and which content it brings, known before anything is computed from it."""

    flight: str
    revision: str
    log_sha256: str
    card: Path | None
    card_files: tuple[Path, ...]
    card_hashes: dict[Path, str]
    card_sha256: str | None
    detections_sha256: str | None


def safe_id(text: str) -> str:
    """`text` if it can name a folder as it is (letters, digits, ._-), else a hash of it."""
    if re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}", text):
        return text
    return "id-" + hashlib.sha256(text.encode()).hexdigest()[:24]


def identify(log_path: Path, *, images: Path | None, detections: Sequence[Path]) -> Identity:
    """The flight id (from the log's metadata) and the content revision (hashes of the log, card, detections)."""
    from icgt.ingest import read

    if detections and images is None:
        raise CatalogError("--detections needs --images (the card the detector saw)")
    for d in detections:
        if not d.exists():
            raise CatalogError(f"--detections {d}: no such file or folder")
    recording = read(log_path)  # not a file, not an MCAP, unfinished: IngestError naming the file
    log_sha = sha256_file(log_path)
    flight, _rid, _kind = flight_id(recording.metadata, log_sha)
    content = hashlib.sha256(f"schema {SCHEMA_VERSION}\nlog {log_sha}\n".encode())
    files: list[Path] = []
    hashes: dict[Path, str] = {}
    card_sha = det_sha = None
    if images is not None:
        if not images.is_dir():
            raise CatalogError(f"--images {images}: not a folder")
        files = _card_files(images)
        if not files:
            raise CatalogError(f"--images {images}: no JPEG images on the card")
        hashes = {p: sha256_file(p) for p in files}
        card_sha = _card_hash(images, files, hashes)
        content.update(f"card {card_sha}\n".encode())
    if detections:
        det_sha = _files_hash(list(detections))
        content.update(f"detections {det_sha}\n".encode())
    return Identity(safe_id(flight), content.hexdigest()[:32], log_sha, images, tuple(files), hashes, card_sha, det_sha)


def collect(
    log_path: Path,
    structure: str,
    ident: Identity,
    *,
    detections: Sequence[Path],
    work_dir: Path,
) -> FlightTables:
    """Every table of one flight (`ident` from `identify`). `work_dir`: scratch space for the damage map's files
    (inside the catalogue's staging folder, so nothing is left elsewhere)."""
    from icgt.ingest import read
    from icgt.report.summary import gather

    recording = read(log_path)
    data = gather(recording)  # reads every record: a damaged chunk anywhere surfaces here as an IngestError
    frames: list[FrameRecord] = data.frames
    flight = ident.flight
    extra: dict[str, Any] = {
        "images": None,
        "images_paired": None,
        "defects": None,
        "card_sha256": ident.card_sha256,
        "detections_sha256": ident.detections_sha256,
    }
    tables: dict[str, pa.Table] = {"frames": _frames_table(structure, flight, frames)}
    paired: dict[int, str] = {}
    if ident.card is not None:
        im = _images_table(structure, flight, frames, ident)
        tables["images"] = im.table
        paired = im.paired
        extra.update(images=im.count, images_paired=im.n_paired)
    else:
        tables["images"] = _table("images", {}, 0)
    where: _Face | None
    if detections:
        from icgt.mapping.cli import run_map
        from icgt.mapping.geojson import features_face, features_wgs84

        assert ident.card is not None
        result = run_map(log_path, ident.card, list(detections), work_dir / "map", mm_per_px=None)
        ses = result.session
        where = _Face(ses.face, ses.origin, ses.projector)
        tables["defects"] = _defects_table(
            structure,
            flight,
            features_wgs84(result.instances, ses.origin, ses.geoid_separation_m),
            features_face(result.instances, ses.face, ses.origin),
        )
        extra["defects"] = len(result.instances)
    else:
        where = _locate(recording, frames)
        tables["defects"] = _table("defects", {}, 0)
    tables["footprints"] = _footprints_table(structure, flight, frames, where, paired)
    extra["footprints"] = tables["footprints"].num_rows
    if where is not None:
        from icgt.mapping.geojson import face_frame_json

        extra["face_frame"] = json.dumps(face_frame_json(where.face, where.origin))
    tables["flights"] = _flights_table(
        structure, flight, ident.revision, data, recording, log_path, ident.log_sha256, extra
    )
    return FlightTables(structure, flight, ident.revision, tables)
