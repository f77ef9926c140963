"""Geotagged copies of the card's images (and XMP sidecars of its RAW files), each read back and checked.

For every paired image: the original is checked whole (`icgt.export.card.jpeg_damage`), its
tags are read (make, GPS, the camera's own pose tags; `icgt.export.tag_reader`), the copy is
written next to its final name by ExifTool (`icgt.export.exif_tags` has the tags,
`icgt.export.pose_tags` the pose rules), read back, compared with what was meant, and only then
renamed into place. Each image that fails any step is a problem row (error, the copy is not left
behind); the originals are only ever read.

Problem rows written here: ``damaged_image`` (cut off or broken JPEG), ``jpeg_write_failed``
(ExifTool refused or failed, its message quoted), ``jpeg_readback_mismatch`` (a tag did not read
back as meant), ``camera_gps_far`` (warning: the camera's own GPS is more than `FAR_GPS_M` from
the log's position; the log's is written), ``camera_tags_replaced`` (info: which of the camera's
GPS and pose tags the copy replaced, also in the copy's ``icgt:ReplacedTags``), and for RAW files
``xmp_sidecar_failed``.
"""

from __future__ import annotations

import math
import os
import shutil
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tqdm import tqdm

from icgt.export import ExportError
from icgt.export.card import JPEG_SUFFIXES, jpeg_file_damage, jpeg_header, raw_siblings
from icgt.export.common import ExportItem, ProblemLog
from icgt.export.exif_tags import ICGT_TAGS, READ_TAGS, check_copy, intended_tags, write_args, xmp_lacks_wrapper
from icgt.export.exiftool_session import ExifToolSession
from icgt.export.tag_reader import read_tags
from icgt.export.xmp_packet import merge_descriptions_in_jpeg

FAR_GPS_M = 100.0
"""A camera GPS further than this from the log's position is reported (GPS errors are metres, not 100 m)."""
_BATCH = 64  # files per batched read


@dataclass
class _Pending:
    item: ExportItem
    src: Path
    dst: Path
    tmp: Path
    tags: dict[str, Any]
    sidecar: bool
    warnings: str = ""  # what ExifTool warned of while writing (quoted if the copy does not read back right)


def _ground_distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Great-circle distance on a 6371 km sphere [m] (a plausibility check, not geodesy)."""
    p1, p2 = math.radians(lat1), math.radians(lat2)
    dp, dl = p2 - p1, math.radians(lon2 - lon1)
    a = math.sin(dp / 2) ** 2 + math.cos(p1) * math.cos(p2) * math.sin(dl / 2) ** 2
    return 2 * 6_371_000.0 * math.asin(min(1.0, math.sqrt(a)))


def _read_all(et: ExifToolSession, files: Sequence[Path]) -> dict[Path, dict[str, Any]]:
    """JPEGs in-process (icgt.export.tag_reader); RAW files, sidecars and what it cannot parse with ExifTool."""
    out: dict[Path, dict[str, Any]] = {}
    rest: list[Path] = []
    for f in files:
        tags = read_tags(f) if f.suffix.lower() in JPEG_SUFFIXES else None
        if tags is None:
            rest.append(f)
        else:
            out[f] = tags
    for i in range(0, len(rest), _BATCH):
        out.update(et.read_json(rest[i : i + _BATCH], READ_TAGS))
    return out


def _tmp_name(dst: Path) -> Path:
    return dst.with_name(f".{dst.stem}.icgt-tmp{dst.suffix}")


def _destination(src: Path, out_dir: Path, images_root: Path | None) -> Path:
    if images_root is not None and src.is_relative_to(images_root):
        return out_dir / src.relative_to(images_root)
    return out_dir / src.name


def _check_camera_gps(item: ExportItem, before: dict[str, Any], problems: ProblemLog) -> None:
    lat, lon = before.get("Composite:GPSLatitude"), before.get("Composite:GPSLongitude")
    rec = item.frame
    if not item.position_ok or not isinstance(lat, int | float) or not isinstance(lon, int | float):
        return
    assert rec.lat_deg is not None and rec.lon_deg is not None
    if abs(lat) < 1e-7 and abs(lon) < 1e-7:
        return  # a camera without a fix writes 0, 0
    d = _ground_distance_m(float(lat), float(lon), rec.lat_deg, rec.lon_deg)
    if d > FAR_GPS_M:
        problems.add(
            item.name,
            rec.frame_seq,
            "warning",
            "camera_gps_far",
            f"the camera's own GPS ({lat:.6f}, {lon:.6f}) is {d / 1000.0:.3f} km from the log's position "
            f"({rec.lat_deg:.6f}, {rec.lon_deg:.6f}): the log's is written; check the pairing or the camera's GPS",
        )


def write_geotagged_copies(
    items: Sequence[ExportItem],
    out_dir: Path,
    problems: ProblemLog,
    *,
    progress: bool = False,
    images_root: Path | None = None,
    raws: Sequence[Path] = (),
    workers: int | None = None,
) -> int:
    """Geotagged copies of every item's image into out_dir, XMP sidecars for their RAW files; returns the copies made.

    Copies keep their path below `images_root` (DCIM/100MSDCF/...), else their file name; a
    sidecar is named after its RAW file with the suffix .xmp. An image without a usable position
    is still copied (XMP only, no GPS tags; prepare_items reported why). `workers`: ExifTool
    processes run side by side (default: one per CPU core).
    """
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ExportError(f"cannot create {out_dir}: {exc.strerror or exc}") from exc
    todo = [i for i in items if i.image is not None]
    if not todo:
        return 0
    # ExifTool is one Perl process per session, single-threaded: one session per core, each on
    # its own share of the images (the threads only wait on their process); rows merged in order
    workers = max(1, min(workers if workers is not None else (os.cpu_count() or 1), len(todo), 8))
    shares = [todo[k::workers] for k in range(workers)]
    bar = tqdm(total=len(todo), desc="jpeg", unit="image", disable=not progress)
    logs = [ProblemLog() for _ in shares]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        futures = [
            pool.submit(_run_share, share, out_dir, images_root, list(raws), log, bar)
            for share, log in zip(shares, logs, strict=True)
        ]
        written = sum(f.result() for f in futures)
    bar.close()
    rows = [r for log in logs for r in log.problems]
    order = {id(item): k for k, item in enumerate(todo)}
    seqs = {item.frame.frame_seq: order[id(item)] for item in todo}
    rows.sort(key=lambda r: seqs.get(r.frame_seq, len(todo)) if r.frame_seq is not None else len(todo))
    problems.problems.extend(rows)
    return written


def _run_share(
    share: list[ExportItem], out_dir: Path, images_root: Path | None, raws: list[Path], problems: ProblemLog, bar: Any
) -> int:
    with ExifToolSession(ICGT_TAGS) as et:
        sources: list[Path] = []
        for item in share:
            assert item.image is not None
            sources.append(item.image)
            sources += raw_siblings(item.image, raws)
        before = _read_all(et, sources)
        pending: list[_Pending] = []
        try:
            for item in share:
                assert item.image is not None
                src = item.image
                pending += _write_one(et, item, src, _destination(src, out_dir, images_root), before, problems)
                for raw in raw_siblings(src, raws):
                    dst = _destination(raw, out_dir, images_root).with_suffix(".xmp")
                    pending += _write_one(et, item, raw, dst, before, problems, sidecar=True)
                bar.update(1)
            after = _read_all(et, [p.tmp for p in pending])
        except BaseException:  # ExifTool died, Ctrl-C: no half-checked copies left behind
            for p in pending:
                p.tmp.unlink(missing_ok=True)
            raise
    return sum(_finish(p, after.get(p.tmp, {}), problems) for p in pending)


def _write_one(
    et: ExifToolSession,
    item: ExportItem,
    src: Path,
    dst: Path,
    before: dict[Path, dict[str, Any]],
    problems: ProblemLog,
    *,
    sidecar: bool = False,
) -> list[_Pending]:
    code = "xmp_sidecar_failed" if sidecar else "jpeg_write_failed"
    seq = item.frame.frame_seq
    name = src.name
    try:
        if dst.resolve() == src.resolve():
            problems.add(name, seq, "error", code, f"{dst}: refusing to overwrite the original", "jpeg")
            return []
    except OSError:
        pass
    b = before.get(src, {})
    rewrap = False
    if not sidecar:
        try:
            damage = jpeg_file_damage(src)
            head = jpeg_header(src)
        except OSError as exc:
            problems.add(name, seq, "error", code, f"cannot read {src}: {exc.strerror or exc}", "jpeg")
            return []
        if damage is not None:
            problems.add(name, seq, "error", "damaged_image", f"{damage}: no geotagged copy", "jpeg")
            return []
        _check_camera_gps(item, b, problems)
        rewrap = xmp_lacks_wrapper(head)
        if rewrap:
            problems.add(name, seq, "info", "xmp_rewrapped", "the camera's XMP packet had no x:xmpmeta element "
                         "(ODM and OpenSfM look for it): rewritten with one, its properties kept")  # fmt: skip
    tags = intended_tags(item, b, sidecar=sidecar)
    tmp = _tmp_name(dst)
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
        tmp.unlink(missing_ok=True)
    except OSError as exc:
        problems.add(name, seq, "error", code, f"cannot write {dst}: {exc.strerror or exc}", "jpeg")
        return []
    args = write_args(src, tmp, tags, sidecar=sidecar, rewrap_xmp=rewrap)
    status, _, err = et.run(args)
    minor = _minor_defects(err)
    if minor:
        # ExifTool leaves the whole XMP packet unwritten when the camera's has a minor defect (a property
        # repeated in one rdf:Description, Descriptions of different rdf:about): written again with -m,
        # which drops the repetition and keeps every property, and the defect is said.
        tmp.unlink(missing_ok=True)
        status, _, err2 = et.run(["-m", *args])
        err = "; ".join(x for x in (err.strip(), err2.strip()) if x)
        problems.add(name, seq, "info", "xmp_defect_tolerated", "the camera's XMP has a minor defect ExifTool "
                     f"would not write over ({'; '.join(minor)}): written with it tolerated")  # fmt: skip
    if status != 0 or not tmp.exists():
        tmp.unlink(missing_ok=True)
        why = " ".join(err.split()) or f"exiftool exit status {status}"
        problems.add(name, seq, "error", code, f"exiftool could not write the copy: {why}", "jpeg")
        return []
    if not sidecar:
        try:
            merge = merge_descriptions_in_jpeg(tmp)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            problems.add(name, seq, "error", code, f"cannot rewrite {tmp}: {exc.strerror or exc}", "jpeg")
            return []
        if merge.merged:
            problems.add(name, seq, "info", "xmp_descriptions_merged", f"ExifTool wrote {merge.merged} "
                         "rdf:Description elements (it keeps Camera Raw settings apart): merged into one, so that "
                         "ODM applies its per-make pitch and accuracy rules once")  # fmt: skip
        elif merge.refused:
            problems.add(name, seq, "warning", "xmp_descriptions_kept", f"the copy's XMP keeps several "
                         f"rdf:Description elements ({merge.refused}): ODM may apply its per-make rules more "
                         "than once (geo.txt carries the pose as meant)")  # fmt: skip
    return [_Pending(item, src, dst, tmp, tags, sidecar, " ".join(err.split()))]


def _minor_defects(stderr: str) -> list[str]:
    """ExifTool's '[Minor]' warnings and errors (file name stripped): defects -m lets it write over."""
    out = []
    for line in stderr.splitlines():
        if "[minor]" in line.lower():
            text = line.split(":", 1)[1].strip() if ":" in line else line.strip()
            out.append(text.rsplit(" - ", 1)[0])
    return out


def _finish(p: _Pending, got: dict[str, Any], problems: ProblemLog) -> int:
    seq = p.item.frame.frame_seq
    diffs = check_copy(p.tags, got)
    if diffs:
        p.tmp.unlink(missing_ok=True)
        code = "xmp_sidecar_failed" if p.sidecar else "jpeg_readback_mismatch"
        detail = "the written copy does not read back as meant: " + "; ".join(diffs[:5])
        if p.warnings:
            detail += f" (exiftool said: {p.warnings})"
        problems.add(p.src.name, seq, "error", code, detail, "jpeg")
        return 0
    try:
        if not p.sidecar:
            shutil.copystat(p.src, p.tmp)
        os.replace(p.tmp, p.dst)
    except OSError as exc:
        p.tmp.unlink(missing_ok=True)
        problems.add(p.src.name, seq, "error", "jpeg_write_failed", f"cannot write {p.dst}: {exc.strerror or exc}")
        return 0
    replaced = p.tags.get("XMP-icgt:ReplacedTags")
    if replaced:
        problems.add(p.src.name, seq, "info", "camera_tags_replaced", f"replaced or removed: {replaced}")
    return 0 if p.sidecar else 1
