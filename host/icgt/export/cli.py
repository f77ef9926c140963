"""`icgt export LOG --images DIR --out DIR`: match the card's JPEGs to the log and write every export.

    icgt export flight.mcap --images card/DCIM --out export/
                [--formats csv,gpkg,geojson,kml,odm,opensfm,jpeg,ros2,ppk,mcap]
                [--calibration camera.toml] [--plane E,N,U,nE,nN,nU] [--anchor range|structure]
                [--geoid-separation auto|none|METRES] [--no-progress]

Writes into --out: frames.csv, icgt.gpkg (GeoPackage: cameras, footprints, footprints on the face),
cameras.geojson, footprints.geojson, icgt.kml (absolute MSL heights), geo.txt, exif_overrides.json,
images/ (geotagged copies; the originals are only read), with ``fgb`` the same layers as FlatGeobuf
(cameras.fgb, footprints.fgb, footprints_face.fgb), with ``ros2`` the ROS 2 bag ros2/ (not by
default: it holds every sensor sample), with ``ppk`` the exposure events in GPS time for PPK tools
(events_gpst.csv, Timestamp.MRK: `icgt.export.ppk_events`), with ``mcap`` foxglove.mcap (the
log with every paired image on the timeline: `icgt.export.foxglove_mcap`) and problems.csv (one row per input problem:
no fix, zero GPS, no UTC, an image without EXIF time or without an exposure, an exposure without an
image, a damaged image, a camera GPS far from the log, HEIC files, RAW files without their JPEG;
hidden and macOS AppleDouble ``._*`` files are skipped and listed as info rows). One bad image never
stops the export. RAW files next to a paired JPEG of the same name get an XMP sidecar (NAME.xmp in
images/, beside the JPEG's copy) with the same geotag: put it next to the RAW file.

Exit status: 0 when everything was exported and problems.csv has no error or warning row (info rows
only); 1 when it has errors or warnings (the export is still written: read problems.csv), and 1
with a message on standard error when no export could be made at all (no frames, unreadable log,
output folder unusable, exiftool missing).
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import logging
import sys
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from icgt.errors import IcgtError
from icgt.export import ExportError
from icgt.recording import layout

if TYPE_CHECKING:  # the heavy modules load when a command runs, not when the parser is built
    from icgt.export.card import CardScan
    from icgt.export.common import ExportItem, ProblemLog
    from icgt.geometry import CameraModel, Plane
    from icgt.geotag.record import FrameRecord

log = logging.getLogger(__name__)

FORMATS = ("csv", "gpkg", "geojson", "kml", "odm", "opensfm", "jpeg", "ros2", "ppk", "fgb", "mcap")
DEFAULT_FORMATS = ("csv", "gpkg", "geojson", "kml", "odm", "opensfm", "jpeg")
CSV_FILE = "frames.csv"
PROBLEMS_FILE = "problems.csv"
IMAGES_DIR = "images"


@dataclass
class ExportResult:
    out_dir: Path
    written: dict[str, int]
    problems: ProblemLog
    items: list[ExportItem] = field(default_factory=list)

    def describe(self) -> str:
        parts = [f"{k} {v}" for k, v in self.written.items()]
        return (
            f"exported {len(self.items)} frames to {self.out_dir}: {', '.join(parts)}; "
            f"{len(self.problems)} problems ({self.problems.summary()}) -> {self.out_dir / PROBLEMS_FILE}"
        )


def export_items(
    items: Sequence[ExportItem],
    out_dir: Path,
    formats: Iterable[str],
    problems: ProblemLog,
    *,
    geoid_separation_m: float | None = None,
    progress: bool = False,
    images_root: Path | None = None,
    raws: Sequence[Path] = (),
) -> dict[str, int]:
    """Write the requested formats for prepared items; returns what each wrote (rows, features, images)."""
    from icgt.export.csv_export import write_csv
    from icgt.export.geojson_export import write_geojson
    from icgt.export.geotag_writer import write_geotagged_copies
    from icgt.export.odm import GEO_TXT, write_geo_txt
    from icgt.export.opensfm import EXIF_OVERRIDES, write_exif_overrides

    wanted = list(formats)
    written: dict[str, int] = {}
    if "csv" in wanted:
        written["csv rows"] = write_csv(out_dir / CSV_FILE, items, progress=progress)
    if "geojson" in wanted:
        points, polygons = write_geojson(out_dir, items, geoid_separation_m=geoid_separation_m, progress=progress)
        written["geojson points"] = points
        written["geojson footprints"] = polygons
    if "gpkg" in wanted:
        from icgt.export.gis import GPKG_FILE, write_gpkg

        for layer, n in write_gpkg(out_dir / GPKG_FILE, items).items():
            written[f"gpkg {layer}"] = n
    if "kml" in wanted:
        from icgt.export.gis import KML_FILE, write_kml

        for layer, n in write_kml(out_dir / KML_FILE, items).items():
            written[f"kml {layer}"] = n
    if "fgb" in wanted:
        from icgt.export.gis import write_fgb

        for layer, n in write_fgb(out_dir, items).items():
            written[f"fgb {layer}"] = n
    if "odm" in wanted:
        written["geo.txt lines"] = write_geo_txt(out_dir / GEO_TXT, items, problems, progress=progress)
    if "opensfm" in wanted:
        written["exif_overrides entries"] = write_exif_overrides(out_dir / EXIF_OVERRIDES, items)
    if "jpeg" in wanted:
        written["geotagged jpegs"] = write_geotagged_copies(
            items, out_dir / IMAGES_DIR, problems, progress=progress, images_root=images_root, raws=raws
        )
    return written


# --- inputs from the recording ----------------------------------------------------------------


def camera_from_metadata(metadata: Mapping[str, Mapping[str, str]]) -> CameraModel | None:
    """The recorder's camera ([camera] of its config, metadata icgt.calibration) as an ideal CameraModel."""
    from icgt.geometry import CameraModel, GeometryError

    cal = metadata.get("icgt.calibration")
    if not cal:
        return None
    try:
        return CameraModel.from_sensor(
            float(ast.literal_eval(cal["focal_length_mm"])),
            float(ast.literal_eval(cal["sensor_width_mm"])),
            int(ast.literal_eval(cal["image_width_px"])),
            int(ast.literal_eval(cal["image_height_px"])),
            source="recording metadata icgt.calibration",
        )
    except (KeyError, ValueError, SyntaxError, TypeError, GeometryError):
        return None


def surface_normal_from_metadata(metadata: Mapping[str, Mapping[str, str]]) -> tuple[float, float, float] | None:
    value = metadata.get("icgt.calibration", {}).get("surface_normal_enu")
    if not value:
        return None
    try:
        n = ast.literal_eval(value)
    except (ValueError, SyntaxError):
        return None
    if isinstance(n, list | tuple) and len(n) == 3 and all(isinstance(c, int | float) for c in n):
        return (float(n[0]), float(n[1]), float(n[2]))
    return None


def geoid_separation_from_log(recording: Any) -> float | None:
    """GPS_RAW_INT alt_ellipsoid - alt [m] of the first message that has both (MAVLink 2 extension)."""
    try:
        messages = recording.messages(layout.mavlink_topic("GPS_RAW_INT"))
        try:
            for _, msg in messages:
                alt, alt_ell = msg.get("alt"), msg.get("alt_ellipsoid")
                if isinstance(alt, int) and isinstance(alt_ell, int) and alt_ell != 0 and msg.get("fix_type", 0) >= 3:
                    return (alt_ell - alt) / 1000.0
        finally:
            close = getattr(messages, "close", None)
            if close is not None:
                close()
    except IcgtError as exc:
        log.warning("cannot read the geoid separation from the log: %s", exc)
    return None


def report_card(scan: CardScan, paired: set[Path], problems: ProblemLog) -> None:
    """Rows for what the card holds besides paired JPEGs: hidden files, HEIC, other images, RAW without a JPEG."""
    from icgt.export.card import raw_siblings

    for p in scan.hidden:
        problems.add(
            p.name, None, "info", "hidden_file_skipped", f"{p}: hidden or macOS AppleDouble file, not an image"
        )
    for p in scan.heic:
        problems.add(p.name, None, "error", "heic_not_supported",
                     f"{p}: HEIC/HEIF images are not read (convert them to JPEG first)", "all")  # fmt: skip
    for p in scan.unsupported:
        problems.add(p.name, None, "warning", "image_not_supported",
                     f"{p}: {p.suffix} images are not read (only JPEG): not paired, no copy", "all")  # fmt: skip
    with_jpeg = {r for j in paired for r in raw_siblings(j, scan.raw)}
    for p in scan.raw:
        if p not in with_jpeg:
            problems.add(p.name, None, "warning", "raw_without_jpeg",
                         f"{p}: no paired JPEG of this name in its folder: no sidecar", "xmp-sidecar")  # fmt: skip


def match_pairs(
    frames: list[FrameRecord], images_dir: Path, problems: ProblemLog, *, progress: bool = False
) -> list[tuple[Path | None, FrameRecord, float | None]]:
    """Match the card's images to the frames (icgt.ingest.match); every leftover is reported per image."""
    from tqdm import tqdm

    from icgt.ingest.matching.reuse import match_images_reusing

    bar = tqdm(desc="match (EXIF times)", unit="image", disable=not progress)

    def tick(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    try:
        result, _reused = match_images_reusing(frames, images_dir, progress=tick)  # icgt match's, if made
    finally:
        bar.close()
    pairs: list[tuple[Path | None, FrameRecord, float | None]] = [
        (p.image, p.frame, p.residual_s) for p in result.pairs
    ]
    for p in result.pairs:
        if p.residual_s is None:
            detail = "the image has no EXIF time: paired by its place on the card between two timed neighbours"
            problems.add(p.image.name, p.frame.frame_seq, "warning", "no_exif_time", detail)
    for u in result.unmatched_images:
        code = {"no_exif_time": "no_exif_time", "unreadable": "unreadable_image"}.get(u.reason, "unmatched_image")
        problems.add(u.image.name, None, "error", code, f"not matched to an exposure ({u.reason}): {u.detail}", "all")
    for a in result.ambiguous:
        code = "no_exif_time" if a.why.startswith("no EXIF time") else "ambiguous_match"
        seqs = ", ".join(str(f.frame_seq) for f in a.candidates) or "none named"
        problems.add(a.image.name, None, "error", code, f"not paired: {a.why} (candidate frames: {seqs})", "all")
    for uf in result.unmatched_frames:
        severity = "info" if uf.reason == "feedback_missing" else "warning"
        problems.add("", uf.frame.frame_seq, severity, f"frame_{uf.reason}", uf.detail, "jpeg,geo.txt,opensfm")
    names: dict[str, int] = {}
    for image, _, _ in pairs:
        if image is not None:
            names[image.name] = names.get(image.name, 0) + 1
    for name, n in sorted(names.items()):
        if n > 1:
            problems.add(
                name,
                None,
                "warning",
                "duplicate_file_name",
                f"{n} matched images share this file name (subfolders): geo.txt and OpenSfM keep the first",
            )
    for note in result.notes:
        log.info("matching: %s", note)
    # every frame goes into the CSV and GeoJSON, with its image or without one
    paired = {id(f) for _, f, _ in pairs}
    pairs += [(None, f, None) for f in frames if id(f) not in paired]
    pairs.sort(key=lambda p: p[1].frame_seq)
    return pairs


def parse_plane(text: str) -> Plane:
    from icgt.geometry import Plane

    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        values = []
    if len(values) != 6:
        raise ExportError(f"--plane wants E,N,U,nE,nN,nU (six numbers, ENU metres and a normal), got {text!r}")
    return Plane((values[0], values[1], values[2]), (values[3], values[4], values[5]))


def parse_geoid(text: str) -> float | str | None:
    if text == "auto":
        return "auto"
    if text == "none":
        return None
    try:
        return float(text)
    except ValueError:
        raise ExportError(f"--geoid-separation wants auto, none or metres, got {text!r}") from None


def run_export(
    log_path: Path,
    out_dir: Path,
    *,
    images: Path | None = None,
    formats: Sequence[str] = DEFAULT_FORMATS,
    calibration: Path | None = None,
    plane: Plane | None = None,
    anchor: str = "range",
    geoid_separation: float | str | None = "auto",
    progress: bool = False,
) -> ExportResult:
    """The whole export (the CLI without argparse). Raises IcgtError only for problems with the whole run;
    an `out_dir` it created for a run refused that way is removed again if nothing was written to it."""
    created = not out_dir.exists()
    try:
        return _run_export(
            log_path, out_dir, images=images, formats=formats, calibration=calibration, plane=plane, anchor=anchor,
            geoid_separation=geoid_separation, progress=progress,
        )  # fmt: skip
    except IcgtError:
        if created:
            with contextlib.suppress(OSError):  # not empty, or not ours to remove: left as it is
                out_dir.rmdir()
        raise


def _run_export(
    log_path: Path,
    out_dir: Path,
    *,
    images: Path | None,
    formats: Sequence[str],
    calibration: Path | None,
    plane: Plane | None,
    anchor: str,
    geoid_separation: float | str | None,
    progress: bool,
) -> ExportResult:
    from tqdm import tqdm

    from icgt.export.common import ProblemLog, check_out_dir, prepare_items
    from icgt.geometry import Projector, load_calibration
    from icgt.ingest import read

    unknown = [f for f in formats if f not in FORMATS]
    from icgt.export.gis import SHAPEFILE_NAMES, shapefile_refusal

    if shapefile := next((f for f in unknown if f.lower() in SHAPEFILE_NAMES), None):
        raise ExportError(shapefile_refusal(shapefile))
    if unknown:
        raise ExportError(f"unknown export format {unknown[0]!r}: choose from {', '.join(FORMATS)}")
    if images is not None and not images.is_dir():
        raise ExportError(f"--images {images}: not a folder")
    check_out_dir(out_dir, images)
    recording = read(log_path)
    problems = ProblemLog()
    if getattr(recording, "note", None):
        log.warning("%s", recording.note)
    total = recording.topics().get(layout.FRAMES)
    frames = list(tqdm(recording.frames(), desc="frames", unit="frame", total=total, disable=not progress))
    ros2_only = set(formats) <= {"ros2"}  # the bag needs neither frames nor a camera model
    camera_free = set(formats) <= {"ros2", "ppk", "mcap"}  # nor do the PPK events and the enriched log
    if not frames and not ros2_only:
        raise ExportError(f"{log_path}: the recording has no frames (/frames is empty)")
    metadata = recording.metadata
    camera = load_calibration(calibration) if calibration is not None else camera_from_metadata(metadata)
    if camera is None and not camera_free:
        raise ExportError(f"{log_path}: no camera calibration in the recording: give --calibration FILE")
    normal = plane.normal if plane is not None else surface_normal_from_metadata(metadata)
    projector = (
        Projector(
            camera,
            origin=recording.enu_origin,
            structure=plane,
            surface_normal=normal,
            anchor="structure" if anchor == "structure" else "range",
        )
        if camera is not None
        else None
    )
    geoid = geoid_separation_from_log(recording) if geoid_separation == "auto" else geoid_separation
    assert geoid is None or isinstance(geoid, float)
    pairs: list[tuple[Path | None, FrameRecord, float | None]]
    raws: list[Path] = []
    if images is not None:
        from icgt.export.card import scan_card

        scan = scan_card(images)
        pairs = match_pairs(frames, images, problems, progress=progress)
        report_card(scan, {p[0] for p in pairs if p[0] is not None}, problems)
        raws = scan.raw
    else:
        pairs = [(None, f, None) for f in frames]
    items = prepare_items(pairs, projector, problems)
    wanted = [f for f in formats if f != "jpeg" or images is not None]
    written = export_items(
        items, out_dir, wanted, problems, geoid_separation_m=geoid, progress=progress, images_root=images, raws=raws
    )
    if "ros2" in wanted:
        from icgt.export.ros2 import write_ros2_bag

        bag = write_ros2_bag(recording, out_dir)
        written["ros2 messages"] = bag.total
    if "mcap" in wanted:
        from icgt.export.foxglove_mcap import paired_images, write_foxglove_mcap
        from icgt.ingest.recompute import recording_sync_config

        if images is None:
            log.warning("mcap export without --images: the enriched log has no camera images")
        sync = recording_sync_config(recording)
        fox = write_foxglove_mcap(
            log_path,
            out_dir,
            paired_images(pairs),
            sync.geotag,
            recording=recording,
            vehicle_system=sync.autopilot_system,
        )
        written["foxglove.mcap messages"] = fox["copied"]
        written["foxglove.mcap images"] = fox["images"]
    if "ppk" in wanted:
        from icgt.export.ppk_events import export_ppk

        written.update(export_ppk(recording, frames, out_dir, problems, geoid_separation_m=geoid))
    problems.write_csv(out_dir / PROBLEMS_FILE)
    return ExportResult(out_dir, written, problems, items)


def cmd_export(args: argparse.Namespace) -> int:
    """Entry point of `icgt export` (see the module docstring for the arguments)."""
    formats = [f.strip() for f in str(args.formats).split(",") if f.strip()]
    result = run_export(
        Path(args.log),
        Path(args.out),
        images=Path(args.images) if args.images is not None else None,
        formats=formats,
        calibration=Path(args.calibration) if args.calibration is not None else None,
        plane=parse_plane(args.plane) if args.plane else None,
        anchor=args.anchor,
        geoid_separation=parse_geoid(args.geoid_separation),
        progress=not args.no_progress,
    )
    log_problems(result.problems)
    print(result.describe(), file=sys.stdout)
    return exit_status(result.problems, strict=bool(getattr(args, "strict", False)))


WARNINGS_SAID_PER_CODE = 5
"""Warnings of one code said on stderr (every one is in problems.csv): a loaded flight flags many frames alike."""


def log_problems(problems: ProblemLog) -> None:
    """Every error, and the first `WARNINGS_SAID_PER_CODE` warnings of each code, on stderr (problems.csv has all)."""
    said: dict[str, int] = {}
    for p in problems:
        if p.severity == "warning":
            said[p.code] = said.get(p.code, 0) + 1
            if said[p.code] > WARNINGS_SAID_PER_CODE:
                continue
        elif p.severity != "error":
            continue
        where = f"{p.image or ''}{f' (frame {p.frame_seq})' if p.frame_seq else ''}"
        log.warning("%s: %s: %s: %s", p.severity, where, p.code, p.detail)
    for code, n in said.items():
        if n > WARNINGS_SAID_PER_CODE:
            log.warning("warning: %d more %s rows in problems.csv", n - WARNINGS_SAID_PER_CODE, code)


def exit_status(problems: ProblemLog, *, strict: bool = False) -> int:
    """0: exported, problems.csv holds no error (warnings and info rows are said there and on stderr);
    1: problems.csv has errors; with `strict`, warnings count as errors too."""
    failing = ("error", "warning") if strict else ("error",)
    return 1 if any(p.severity in failing for p in problems) else 0


def add_export_arguments(parser: argparse.ArgumentParser) -> None:
    """The arguments of `icgt export` (for a subparser)."""
    parser.add_argument("log", type=Path, help="the recording (.mcap)")
    parser.add_argument("--images", type=Path, help="folder of the camera card's JPEGs (only read)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (not the images folder)")
    parser.add_argument(
        "--formats",
        default=",".join(DEFAULT_FORMATS),
        help=f"comma-separated subset of {','.join(FORMATS)} (default {','.join(DEFAULT_FORMATS)})",
    )
    parser.add_argument("--calibration", type=Path, help="camera calibration (.toml, OpenCV .yaml/.json)")
    parser.add_argument("--plane", help="structure plane E,N,U,nE,nN,nU in the recording's ENU frame [m]")
    parser.add_argument(
        "--anchor",
        choices=("range", "structure"),
        default="range",
        help="place the surface through the LiDAR return (default) or use --plane as given",
    )
    parser.add_argument(
        "--geoid-separation",
        default="auto",
        help="geoid height N [m] for GeoJSON ellipsoidal heights: auto (from GPS_RAW_INT), none, or metres",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")
    parser.add_argument(
        "--strict", action="store_true", help="exit 1 on warnings too (default: only on errors in problems.csv)"
    )
