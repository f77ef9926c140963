"""`icgt map` and `icgt tiles`: the command-line side of the damage map (icgt.mapping)."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from PIL import Image

from icgt.export.cli import (
    camera_from_metadata,
    geoid_separation_from_log,
    match_pairs,
    parse_plane,
    surface_normal_from_metadata,
)
from icgt.export.common import ProblemLog, check_out_dir
from icgt.geodesy import LocalFrame
from icgt.geometry import (
    CameraModel,
    FrameSolution,
    GeometryError,
    Plane,
    Projector,
    load_calibration,
    origin_from_frames,
)
from icgt.geotag.record import POOR_POSE_FLAGS, FrameRecord
from icgt.mapping import MappingError
from icgt.mapping.consensus import Consensus, View
from icgt.mapping.detections import read_detections
from icgt.mapping.geojson import face_frame_json, features_face, features_wgs84, write_json
from icgt.mapping.merge import build_instances
from icgt.mapping.model import Detection, Instance, Placed
from icgt.mapping.mosaic import MosaicImage, MosaicInfo, build_mosaic
from icgt.mapping.place import Errors, place
from icgt.mapping.surface import Face, find_face
from icgt.mapping.tiles import TileRef, cut, load_index, stems

log = logging.getLogger(__name__)

UNTRUSTED_POSE = POOR_POSE_FLAGS
"""Frames flagged so are not used for placing detections or the mosaic (unless asked: trust_flagged)."""


@dataclass
class Session:
    """A log, its card and the surface: what both commands need."""

    camera: CameraModel
    origin: LocalFrame
    face: Face
    projector: Projector
    frames: list[FrameRecord]
    images: dict[str, tuple[Path, FrameRecord]]
    """Matched card images by file name."""
    solutions: dict[int, FrameSolution]
    problems: ProblemLog
    geoid_separation_m: float | None
    sizes: dict[str, tuple[int, int]] = field(default_factory=dict)

    def size(self, name: str) -> tuple[int, int]:
        if name not in self.sizes:
            hit = self.images.get(name)
            if hit is None:
                raise MappingError(f"{name}: not an image of the card matched to the recording")
            try:
                with Image.open(hit[0]) as im:
                    self.sizes[name] = im.size
            except OSError as exc:
                raise MappingError(f"{hit[0]}: cannot read: {exc}") from exc
        return self.sizes[name]


def open_session(
    log_path: Path,
    images_dir: Path,
    *,
    calibration: Path | None,
    plane: Plane | None,
    anchor: str,
    geoid: float | str | None = "auto",
    trust_flagged: bool = False,
    lookahead_s: float | None = None,
) -> Session:
    from icgt.ingest import read

    if not images_dir.is_dir():
        raise MappingError(f"--images {images_dir}: not a folder")
    recording = read(log_path)
    if lookahead_s is None:
        frames = list(recording.frames())
    else:
        # geotag again offline with the pose and clock samples that came after each exposure too
        # (the recorder, live, had to extrapolate when they were late: frames flagged stale_pose)
        from icgt.ingest.recompute import recompute

        redone = recompute(recording, lookahead_s=lookahead_s)
        for note in redone.notes:
            log.info("recompute: %s", note)
        frames = sorted(redone.frames, key=lambda f: f.frame_seq)
    if not frames:
        raise MappingError(f"{log_path}: the recording has no frames")
    camera = load_calibration(calibration) if calibration is not None else camera_from_metadata(recording.metadata)
    if camera is None:
        raise MappingError(f"{log_path}: no camera calibration in the recording: give --calibration FILE")
    enu = recording.enu_origin
    origin = LocalFrame(*enu) if enu is not None else origin_from_frames(frames)
    if origin is None:
        raise MappingError(f"{log_path}: no frame has both a WGS84 and an ENU position: the map cannot be placed")
    trusted = [f for f in frames if trust_flagged or not any(flag.value in f.flags for flag in UNTRUSTED_POSE)]
    face = find_face(camera, trusted, plane=plane, normal=surface_normal_from_metadata(recording.metadata))
    if anchor not in ("range", "structure"):
        raise MappingError(f"--anchor must be range or structure, not {anchor!r}")
    projector = Projector(
        camera, origin=origin, structure=face.plane, anchor="range" if anchor == "range" else "structure"
    )
    problems = ProblemLog()
    pairs = match_pairs(frames, images_dir, problems)
    images: dict[str, tuple[Path, FrameRecord]] = {}
    for path, rec, _ in pairs:
        if path is not None and path.name not in images:
            images[path.name] = (path, rec)
    sols: dict[int, FrameSolution] = {}
    recs = [rec for _, rec in images.values()]
    for rec, sol in zip(recs, projector.solve_many(recs), strict=True):
        bad = [f.value for f in UNTRUSTED_POSE if f.value in rec.flags]
        if bad and not trust_flagged:
            why = f"pose flagged {', '.join(bad)} (gaps {rec.pose_gap_before_ms:.0f} / {rec.pose_gap_after_ms:.0f} ms)"
            problems.add(
                "", rec.frame_seq, "error", "untrusted_pose", f"{why}: not used (--trust-flagged-poses)", "map"
            )
        elif isinstance(sol, GeometryError):
            problems.add("", rec.frame_seq, "warning", "no_geometry", str(sol), "map")
        else:
            sols[rec.frame_seq] = sol
    g = geoid_separation_from_log(recording) if geoid == "auto" else geoid
    return Session(camera, origin, face, projector, frames, images, sols, problems, g if isinstance(g, float) else None)


# --- icgt map -------------------------------------------------------------------------------


@dataclass
class MapResult:
    out_dir: Path
    detections: list[Detection]
    placed: list[Placed]
    instances: list[Instance]
    unplaced: list[tuple[Detection, str]]
    mosaic: MosaicInfo | None
    session: Session


def _from_tiles(dets: list[Detection], index: dict[str, TileRef]) -> list[Detection]:
    out = []
    for d in dets:
        t = index.get(d.image)
        if t is None:
            out.append(d)
        else:
            out.append(
                dataclasses.replace(d, image=t.image, points_px=d.points_px + np.array([t.x0, t.y0], dtype=np.float64))
            )
    return out


def run_map(
    log_path: Path,
    images_dir: Path,
    detections: Sequence[Path],
    out_dir: Path,
    *,
    calibration: Path | None = None,
    plane: Plane | None = None,
    anchor: str = "range",
    classes: Sequence[str] | None = None,
    tiles: Path | None = None,
    errors: Errors = Errors(),  # noqa: B008 (frozen)
    mm_per_px: float | None = 2.0,
    extent: tuple[float, float, float, float] | None = None,
    min_tolerance_mm: float = 10.0,
    cache_mb: float = 512.0,
    trust_flagged: bool = False,
    mosaic_format: str = "png",
    lookahead_s: float | None = None,
    consensus: Consensus = Consensus(),  # noqa: B008 (frozen)
) -> MapResult:
    if mosaic_format not in ("png", "tif"):
        raise MappingError(f"mosaic format must be png or tif, not {mosaic_format!r}")
    check_out_dir(out_dir, images_dir)
    ses = open_session(
        log_path, images_dir, calibration=calibration, plane=plane, anchor=anchor, trust_flagged=trust_flagged,
        lookahead_s=lookahead_s,
    )  # fmt: skip
    index = load_index(tiles) if tiles is not None else {}
    stem_map = {p.stem: name for name, (p, _) in ses.images.items()} | stems(index)

    def size(name: str) -> tuple[int, int]:
        t = index.get(name)
        return (t.width, t.height) if t is not None else ses.size(name)

    dets: list[Detection] = []
    for path in detections:
        dets += _from_tiles(read_detections(path, size, stem_map, classes), index)
    placed: list[Placed] = []
    unplaced: list[tuple[Detection, str]] = []
    for d in dets:
        hit = ses.images.get(d.image)
        if hit is None:
            unplaced.append((d, "the image is not on the card or not matched to an exposure"))
            continue
        sol = ses.solutions.get(hit[1].frame_seq)
        if sol is None:
            unplaced.append((d, "the image's frame has no trusted pose or no surface (problems.csv)"))
            continue
        try:
            p = place(d, hit[1], sol, ses.size(d.image), ses.projector, ses.face, errors)
        except MappingError as exc:
            unplaced.append((d, str(exc)))
            continue
        p.index = len(placed)
        placed.append(p)
    for d, why in unplaced:
        ses.problems.add(d.image, None, "error", "detection_unplaced", f"{d.source}: {why}", "map")
    instances = build_instances(
        placed, ses.face, errors.position_m * 1000.0, min_tolerance_mm=min_tolerance_mm, views=views(ses),
        consensus=consensus,
    )  # fmt: skip
    write_json(out_dir / "defects.geojson", features_wgs84(instances, ses.origin, ses.geoid_separation_m))
    write_json(out_dir / "defects_face.geojson", features_face(instances, ses.face, ses.origin))
    _write_detections_csv(out_dir / "detections.csv", dets, placed, unplaced, instances)
    mosaic = None
    if mm_per_px is not None:
        mosaic = build_mosaic(
            out_dir / f"mosaic.{mosaic_format}", mosaic_images(ses), ses.camera, ses.face, mm_per_px, instances,
            extent=extent, cache_mb=cache_mb,
        )  # fmt: skip
    ses.problems.write_csv(out_dir / "problems.csv")
    summary: dict[str, Any] = {
        "face_frame": face_frame_json(ses.face, ses.origin),
        "images_matched": len(ses.images),
        "detections": len(dets),
        "detections_placed": len(placed),
        "detections_unplaced": len(unplaced),
        "instances": {k: sum(1 for i in instances if i.kind == k) for k in sorted({i.kind for i in instances})},
        "confirmed": {
            k: sum(1 for i in instances if i.kind == k and i.status == "confirmed")
            for k in sorted({i.kind for i in instances})
        },
        "consensus": {**dataclasses.asdict(consensus), "threshold": round(consensus.threshold, 4)},
        "errors_1sigma": dataclasses.asdict(errors),
        "mosaic": None if mosaic is None else {
            "file": mosaic.path.name, "width_px": mosaic.width_px, "height_px": mosaic.height_px,
            "mm_per_px": mosaic.mm_per_px, "extent_face_m": mosaic.extent,
            "world_file": "mosaic.pgw" if mosaic_format == "png" else None,
            "images_used": mosaic.images_used, "covered_fraction": round(mosaic.covered_fraction, 4),
        },
    }  # fmt: skip
    write_json(out_dir / "map.json", summary)
    return MapResult(out_dir, dets, placed, instances, unplaced, mosaic, ses)


def views(ses: Session) -> list[View]:
    """Every image with a trusted pose and its footprint on the face (for the consensus)."""
    out = []
    for name, (_, rec) in ses.images.items():
        sol = ses.solutions.get(rec.frame_seq)
        if sol is None or sol.footprint is None:
            continue
        ring = shapely.Polygon(ses.face.to_face(sol.footprint.enu))
        out.append(View(name, ring if ring.is_valid else shapely.make_valid(ring)))
    return out


def mosaic_images(ses: Session) -> list[MosaicImage]:
    out = []
    for name, (path, rec) in ses.images.items():
        sol = ses.solutions.get(rec.frame_seq)
        if sol is None or sol.footprint is None:
            continue
        st = ses.face.to_face(sol.footprint.enu)
        w, h = ses.size(name)
        bbox = (float(st[:, 0].min()), float(st[:, 1].min()), float(st[:, 0].max()), float(st[:, 1].max()))
        out.append(MosaicImage(path, rec, (w, h), bbox, sol.scale_mm_per_px * ses.camera.width_px / w))
    return out


def _write_detections_csv(
    path: Path,
    dets: Sequence[Detection],
    placed: Sequence[Placed],
    unplaced: Sequence[tuple[Detection, str]],
    instances: Sequence[Instance],
) -> None:
    """Every detection read, placed or not: its instance, or why it was not placed."""
    owner = {id(m): inst.id for inst in instances for m in inst.members}
    by_det = {id(p.det): p for p in placed}
    why = {id(d): w for d, w in unplaced}
    cols = ["source", "image", "kind", "category", "score", "frame_seq", "instance", "length_mm", "width_mm",
            "area_mm2", "position_sigma_mm", "truncated", "not_placed_because"]  # fmt: skip
    try:
        with path.open("w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow(cols)
            for d in dets:
                p = by_det.get(id(d))
                w.writerow([
                    d.source, d.image, d.kind, d.category, "" if d.score is None else d.score,
                    "" if p is None else p.frame_seq, "" if p is None else owner.get(id(p), ""),
                    fmt(p.length_mm if p else None), fmt(p.width_mm if p else None), fmt(p.area_mm2 if p else None),
                    fmt(p.sigma_pos_mm if p else None), "" if p is None else int(p.truncated), why.get(id(d), ""),
                ])  # fmt: skip
    except OSError as exc:
        raise MappingError(f"cannot write {path}: {exc.strerror or exc}") from exc


def fmt(x: float | None) -> str:
    return "" if x is None else f"{x:.2f}"


def _extent(text: str | None) -> tuple[float, float, float, float] | None:
    if not text:
        return None
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 4 or v[2] <= v[0] or v[3] <= v[1] or not all(math.isfinite(x) for x in v):
        raise MappingError(f"--extent wants s0,t0,s1,t1 in face metres with s1 > s0 and t1 > t0, got {text!r}")
    return (v[0], v[1], v[2], v[3])


def cmd_map(args: argparse.Namespace) -> int:
    result = run_map(
        Path(args.log), Path(args.images), [Path(d) for d in args.detections], Path(args.out),
        calibration=args.calibration, plane=parse_plane(args.plane) if args.plane else None, anchor=args.anchor,
        classes=[c.strip() for c in args.classes.split(",")] if args.classes else None, tiles=args.tiles,
        errors=Errors(args.position_sigma_m, args.attitude_sigma_deg, args.range_sigma_m),
        mm_per_px=None if args.no_mosaic else args.mm_per_px, extent=_extent(args.extent),
        min_tolerance_mm=args.min_tolerance_mm, cache_mb=args.cache_mb, trust_flagged=args.trust_flagged_poses,
        mosaic_format=args.mosaic_format, lookahead_s=args.recompute_lookahead_s,
        consensus=Consensus(recall=args.detector_recall, lookalike_rate=args.lookalike_rate),
    )  # fmt: skip
    kinds = ", ".join(f"{n} {k}" for k, n in sorted(_count(result.instances).items())) or "none"
    doubtful = sum(i.status != "confirmed" for i in result.instances)
    print(
        f"{len(result.detections)} detections in {len(result.session.images)} images -> {len(result.instances)} "
        f"defects ({kinds}; {doubtful} doubtful: seen by too few of the images that could see them); "
        f"{len(result.unplaced)} detections not placed (problems.csv)"
    )
    if result.mosaic is not None:
        m = result.mosaic
        print(f"mosaic {m.width_px} x {m.height_px} px at {m.mm_per_px} mm/px from {m.images_used} images: {m.path}")
    print(f"written to {result.out_dir}: defects.geojson, defects_face.geojson, detections.csv, map.json")
    return 0 if not result.unplaced else 2


def _count(instances: Sequence[Instance]) -> dict[str, int]:
    out: dict[str, int] = {}
    for i in instances:
        out[i.kind] = out.get(i.kind, 0) + 1
    return out


# --- icgt tiles -----------------------------------------------------------------------------


def run_tiles(
    log_path: Path, images_dir: Path, out_dir: Path, *, size: int = 512, overlap: int = 0,
    calibration: Path | None = None, plane: Plane | None = None, anchor: str = "range",
    lookahead_s: float | None = None,
) -> list[dict[str, Any]]:  # fmt: skip
    check_out_dir(out_dir, images_dir)
    ses = open_session(
        log_path, images_dir, calibration=calibration, plane=plane, anchor=anchor, lookahead_s=lookahead_s
    )
    rows: list[dict[str, Any]] = []
    for name, (path, rec) in sorted(ses.images.items()):
        w, _h = ses.size(name)
        f = ses.camera.width_px / w
        for t in cut(path, out_dir, size, overlap):
            t["frame_seq"] = rec.frame_seq
            t["corners_face_m"] = t["corners_wgs84"] = None
            if rec.frame_seq in ses.solutions:
                x0, y0, x1, y1 = t["x0"] - 0.5, t["y0"] - 0.5, t["x0"] + t["width"] - 0.5, t["y0"] + t["height"] - 0.5
                u = (np.array([x0, x1, x1, x0]) + 0.5) * f - 0.5
                v = (np.array([y0, y0, y1, y1]) + 0.5) * f - 0.5
                wp = ses.projector.pixel_to_world(rec, u, v)
                if np.isfinite(wp.enu).all():
                    t["corners_face_m"] = np.round(ses.face.to_face(wp.enu), 5).tolist()
                    if wp.lat_deg is not None and wp.lon_deg is not None:
                        t["corners_wgs84"] = [
                            [round(float(a), 9), round(float(b), 9)]
                            for a, b in zip(wp.lon_deg, wp.lat_deg, strict=True)
                        ]
            rows.append(t)
    index = {"format": "icgt-tiles", "tile_size_px": size, "overlap_px": overlap,
             "face_frame": face_frame_json(ses.face, ses.origin), "tiles": rows}  # fmt: skip
    write_json(out_dir / "tiles.json", index)
    ses.problems.write_csv(out_dir / "problems.csv")
    return rows


def cmd_tiles(args: argparse.Namespace) -> int:
    rows = run_tiles(
        Path(args.log), Path(args.images), Path(args.out), size=args.size, overlap=args.overlap,
        calibration=args.calibration, plane=parse_plane(args.plane) if args.plane else None, anchor=args.anchor,
        lookahead_s=args.recompute_lookahead_s,
    )  # fmt: skip
    print(f"{len(rows)} tiles of {args.size} px written to {args.out} (tiles.json maps them back)")
    return 0
