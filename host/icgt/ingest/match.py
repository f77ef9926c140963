"""Match the camera card's JPEGs to the recorded exposures: `icgt match --images DIR LOG`.

Evidence, strongest first:

1. Order. The camera numbers its files in shooting order, and exposures happen in time order, so
   the pairing is a monotone alignment of two sequences (a camera never swaps two shots).
2. Time. EXIF DateTimeOriginal (+ SubSecTimeOriginal) is the camera's own clock, in local time
   of an unknown zone, truncated to its resolution (1 s without SubSec, 10 ms with two digits):
   the true camera time of image i lies in [c_i, c_i + r_i). The camera clock is modelled against
   the recording's clock (exposure start on the host clock, which the recorder maps to UTC) as
   ``camera = t * (1 + drift) + offset``; the zone goes into the offset.
3. What the device saw. A frame flagged feedback_missing (the camera did not confirm the
   trigger) is expected to have no image; any other frame, including an unsolicited one (a
   manual shot), is expected to have exactly one.

Method. Candidate offsets come from voting (each EXIF image against each exposure) and scoring
by how many images and exposures find a partner within the time window. Each is settled (a scan
of nearby offsets for the cheapest alignment), then refined: align, fit offset and drift to the
confident pairs (the (offset, drift) farthest inside every pair's EXIF interval, which the seconds'
boundaries pin far better than least squares on the interval centres), align again. The
alignment is dynamic programming over the order of both sequences: skipping an image (an extra
shot) or an expected exposure (a frame without an image) costs `SKIP_COST` (`LIKELY_SKIP_COST`
where the recording cannot rule it out: no hot-shoe feedback), a pair inside its padded EXIF window
costs nothing and is impossible outside it, a feedback_missing frame is skipped for free and never
paired. The problem splits into independent segments wherever the windows do not overlap.

No silent guesses. (1) For every image the cost of the best alignment that does *not* pair it as
the optimum does is computed (forward and backward passes); within `AMBIGUITY_MARGIN` of the
optimum the image is ambiguous: reported with the exposures it could be, not paired. So with 1 s
EXIF times a second holding one image too many (or one too few without a feedback_missing flag)
makes that second's images ambiguous instead of a guess. (2) The offset is only as certain as the
card makes it: with a steady trigger interval, an offset one interval (or a fraction of the EXIF
resolution) away explains the card almost as well, the ends and irregular shots deciding. Offsets
around the fit are scanned (each grid cell widened so nothing between grid points is missed, with
a lower bound on the cost to skip hopeless ones); any pair that a solution within the margin makes
differently is not made. (3) An image without EXIF time is paired by order only when both its
neighbours on the card are paired by time and exactly one exposure lies between theirs.

Limits: two unexplained events that cancel within one EXIF second (an image lost from the card
and an extra shot) are indistinguishable from none; the default tolerance (20 ms beyond the
resolution, plus the recording's own timing bound) trades missed ambiguity against guessing.
"""

from __future__ import annotations

import argparse
import bisect
import calendar
import itertools
import json
import logging
import math
import operator
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np

from icgt.errors import IcgtError
from icgt.geotag.record import FrameFlag, FrameRecord

__all__ = [
    "AMBIGUITY_MARGIN",
    "LIKELY_SKIP_COST",
    "SKIP_COST",
    "Ambiguous",
    "ImageTime",
    "MatchError",
    "MatchResult",
    "Pair",
    "UnmatchedFrame",
    "UnmatchedImage",
    "cmd_match",
    "list_images",
    "match_images",
    "match_times",
    "read_image_time",
]

SKIP_COST = 10.0
"""Cost of one unexplained event: an image with no exposure, or a confirmed exposure with no image."""
LIKELY_SKIP_COST = 2.0
"""Cost of an event the recording cannot rule out: an unconfirmed trigger (no hot-shoe feedback) without
an image, or an extra image when the device does not see exposures (then manual shots go unrecorded).
Two of them cost less than AMBIGUITY_MARGIN: an alignment explaining the card with them is a real alternative."""
AMBIGUITY_MARGIN = 5.0
"""An alternative alignment costing less than this more than the optimum makes an image ambiguous."""
_MAX_SEGMENT_CELLS = 4_000_000
_FIRST_PASS_WIDEN_MAX_S = 0.05
_MAX_SCAN_S = 3.0
_DRIFT_REPORT_PPM = 20.0
_SWAP_MARGIN_US = 10_000.0
_JPEG_SUFFIXES = (".jpg", ".jpeg")
_IFD_EXIF = 0x8769
_TAG_DATETIME_ORIGINAL = 0x9003
_TAG_SUBSEC_ORIGINAL = 0x9291

# Reasons (JSON values)
FRAME_FEEDBACK_MISSING = "feedback_missing"  # the camera did not confirm the trigger: no image expected
FRAME_NO_IMAGE = "no_image"  # a confirmed exposure no image on the card belongs to
FRAME_AMBIGUOUS = "ambiguous"  # a candidate of an ambiguous image
IMAGE_NO_EXPOSURE = "no_exposure"  # no recorded exposure near its EXIF time (shot while not recording?)
IMAGE_EXTRA = "extra"  # exposures near its time all belong to other images
IMAGE_UNREADABLE = "unreadable"
IMAGE_NO_TIME_UNPLACED = "no_exif_time"  # no EXIF time and nothing to place it by (no exposure left)


class MatchError(IcgtError):
    """The images or frames cannot be matched at all (no images, no frames, several cameras...)."""


# ----------------------------------------------------------------------------- results
@dataclass(frozen=True)
class ImageTime:
    """An image's EXIF capture time on the camera clock [s, local time read as if UTC], None if absent."""

    path: Path
    time_s: float | None
    resolution_s: float | None  # 1.0 without SubSecTimeOriginal, 10**-digits with it
    problem: str | None = None  # why the file could not be read


@dataclass(frozen=True)
class Pair:
    image: Path
    frame: FrameRecord
    residual_s: float | None
    """Predicted camera time of the exposure start minus the middle of the EXIF interval; None: placed by order."""


@dataclass(frozen=True)
class UnmatchedImage:
    image: Path
    reason: str
    detail: str


@dataclass(frozen=True)
class UnmatchedFrame:
    frame: FrameRecord
    reason: str
    detail: str


@dataclass(frozen=True)
class Ambiguous:
    image: Path
    candidates: tuple[FrameRecord, ...]
    why: str


@dataclass
class MatchResult:
    """Pairs, leftovers on both sides, ambiguities and the camera clock found."""

    pairs: list[Pair] = field(default_factory=list)
    unmatched_images: list[UnmatchedImage] = field(default_factory=list)
    unmatched_frames: list[UnmatchedFrame] = field(default_factory=list)
    ambiguous: list[Ambiguous] = field(default_factory=list)
    camera_offset_s: float | None = None
    """Camera clock minus UTC at the first paired exposure [s] (time zone included); None without UTC."""
    camera_drift_ppm: float | None = None
    """How fast the camera clock runs against the recording's clock [ppm]; None when the card does not
    tell (a short flight, 1 s EXIF times): the offset alone explains it."""
    resolution_s: float | None = None
    """Coarsest EXIF time resolution seen (1.0: whole seconds)."""
    notes: list[str] = field(default_factory=list)

    def to_json(self) -> dict[str, Any]:
        def frame_ref(f: FrameRecord) -> dict[str, Any]:
            return {"frame_seq": f.frame_seq, "image_index": f.image_index, "flags": list(f.flags)}

        return {
            "camera_offset_s": self.camera_offset_s,
            "camera_drift_ppm": self.camera_drift_ppm,
            "resolution_s": self.resolution_s,
            "pairs": [{"image": str(p.image), **frame_ref(p.frame), "residual_s": p.residual_s} for p in self.pairs],
            "unmatched_images": [
                {"image": str(u.image), "reason": u.reason, "detail": u.detail} for u in self.unmatched_images
            ],
            "unmatched_frames": [
                {**frame_ref(u.frame), "reason": u.reason, "detail": u.detail} for u in self.unmatched_frames
            ],
            "ambiguous": [
                {"image": str(a.image), "candidates": [frame_ref(f) for f in a.candidates], "why": a.why}
                for a in self.ambiguous
            ],
            "notes": list(self.notes),
        }

    def summary(self) -> str:
        reasons: dict[str, int] = {}
        for u in self.unmatched_frames:
            reasons[u.reason] = reasons.get(u.reason, 0) + 1
        img_reasons: dict[str, int] = {}
        for ui in self.unmatched_images:
            img_reasons[ui.reason] = img_reasons.get(ui.reason, 0) + 1
        offset = "unknown" if self.camera_offset_s is None else f"{self.camera_offset_s:+.3f} s"
        drift = "unknown" if self.camera_drift_ppm is None else f"{self.camera_drift_ppm:+.1f} ppm"
        res = "none" if self.resolution_s is None else f"{self.resolution_s:g} s"
        lines = [
            f"{len(self.pairs)} images paired with exposures",
            f"{len(self.ambiguous)} images ambiguous (not paired: check them)",
            f"{len(self.unmatched_images)} images without an exposure {img_reasons or ''}".rstrip(),
            f"{len(self.unmatched_frames)} exposures without an image {reasons or ''}".rstrip(),
            f"camera clock: {offset} from UTC, drift {drift}, EXIF resolution {res}",
        ]
        return "\n".join(lines + self.notes)


# ----------------------------------------------------------------------------- EXIF
_EXIF_DT = re.compile(r"^\s*(\d{4}):(\d{2}):(\d{2})[ T](\d{2}):(\d{2}):(\d{2})")


def parse_exif_time(text: str | None, subsec: str | None) -> tuple[float, float] | None:
    """(seconds [local time read as UTC], resolution [s]) of DateTimeOriginal + SubSecTimeOriginal."""
    if not text:
        return None
    m = _EXIF_DT.match(text)
    if m is None:
        return None
    y, mo, d, h, mi, s = (int(g) for g in m.groups())
    try:
        whole = calendar.timegm(datetime(y, mo, d, h, mi, s).timetuple())
    except ValueError:
        return None  # "0000:00:00 00:00:00" and other placeholders
    digits = re.sub(r"\D", "", subsec or "")
    if not digits:
        return float(whole), 1.0
    return whole + int(digits) / 10 ** len(digits), 10.0 ** -len(digits)


def _exif_tags(path: Path) -> tuple[str | None, str | None]:
    """(DateTimeOriginal, SubSecTimeOriginal) as text; exifread if installed, else Pillow."""
    try:
        import exifread
    except ImportError:  # pragma: no cover - exifread is the documented reader, Pillow a fallback
        from PIL import Image

        with Image.open(path) as img:
            ifd = img.getexif().get_ifd(_IFD_EXIF)
            dto, sub = ifd.get(_TAG_DATETIME_ORIGINAL), ifd.get(_TAG_SUBSEC_ORIGINAL)
        return (str(dto) if dto is not None else None), (str(sub) if sub is not None else None)
    logging.getLogger("exifread").setLevel(logging.ERROR)  # it logs every file without EXIF
    with path.open("rb") as f:
        tags = exifread.process_file(f, details=False)
    dto, sub = tags.get("EXIF DateTimeOriginal"), tags.get("EXIF SubSecTimeOriginal")
    return (str(dto) if dto is not None else None), (str(sub) if sub is not None else None)


def read_image_time(path: Path) -> ImageTime:
    """The EXIF capture time of one image (no exception for a file without EXIF or a damaged one)."""
    try:
        dto, sub = _exif_tags(path)
    except OSError as exc:
        return ImageTime(path, None, None, f"cannot read: {exc.strerror or exc}")
    except Exception as exc:  # EXIF readers raise assorted errors on damaged files
        return ImageTime(path, None, None, f"EXIF unreadable: {exc}")
    parsed = parse_exif_time(dto, sub)
    if parsed is None:
        return ImageTime(path, None, None)
    return ImageTime(path, parsed[0], parsed[1])


def _natural_key(path: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", str(path))]


def list_images(directory: Path) -> list[Path]:
    """The JPEGs in a folder and its subfolders (DCIM/100MSDCF, 101MSDCF, ...) in the camera's numbering order.

    Hidden files and folders are not images: macOS writes an AppleDouble file ``._NAME.JPG`` next to
    every file it touches on a FAT card, and keeps ``.Trashes`` and ``.Spotlight-V100`` there.
    """
    if not directory.is_dir():
        raise MatchError(f"{directory}: not a folder")
    paths = [
        p
        for p in directory.rglob("*")
        if p.is_file()
        and p.suffix.lower() in _JPEG_SUFFIXES
        and not any(part.startswith(".") for part in p.relative_to(directory).parts)
    ]
    return sorted(paths, key=_natural_key)


# ----------------------------------------------------------------------------- alignment
@dataclass
class _Frames:
    recs: list[FrameRecord]  # sorted by exposure start
    x: np.ndarray[Any, np.dtype[np.float64]]  # exposure start on the recording's clock, s from the first
    tol: np.ndarray[Any, np.dtype[np.float64]]
    eligible: np.ndarray[Any, np.dtype[np.bool_]]  # may have an image (not feedback_missing)
    skip: list[float]  # cost of the frame having no image
    image_skip: float  # cost of an image having no frame
    x0_ns: int
    cache: dict[tuple[Any, ...], _Outcome] = field(default_factory=dict)  # solved segments


@dataclass
class _Model:
    offset: float  # camera time minus x at x = 0 [s]
    drift: float  # dimensionless
    drift_known: bool = False  # the pairs pin the drift to within _DRIFT_REPORT_PPM

    def predict(self, x: np.ndarray[Any, np.dtype[np.float64]] | float) -> Any:
        return x * (1.0 + self.drift) + self.offset


@dataclass
class _Outcome:
    cost: float
    pairs: dict[int, int]  # image -> frame (confident)
    ambiguous: dict[int, tuple[list[int], str]]  # image -> (candidate frames, why)
    extra: dict[int, str]  # image -> reason (IMAGE_NO_EXPOSURE / IMAGE_EXTRA / ...)
    frame_ambiguous: set[int]


def _frames_from(records: Sequence[FrameRecord], base_tolerance_s: float) -> _Frames:
    starts = [f.mid_host_ns - (f.mid_device_us - f.start_device_us) * 1000 for f in records]
    order = sorted(range(len(records)), key=lambda k: (starts[k], records[k].frame_seq))
    recs = [records[k] for k in order]
    x0 = starts[order[0]] if order else 0
    x = np.array([(starts[k] - x0) * 1e-9 for k in order], dtype=np.float64)
    tol = np.array([base_tolerance_s + max(0, f.mid_host_uncertainty_ns) * 1e-9 for f in recs], dtype=np.float64)
    eligible = np.array([FrameFlag.FEEDBACK_MISSING.value not in f.flags for f in recs], dtype=bool)
    unconfirmed = [FrameFlag.NO_FEEDBACK.value in f.flags for f in recs]
    skip = [0.0 if not e else LIKELY_SKIP_COST if u else SKIP_COST for e, u in zip(eligible, unconfirmed, strict=True)]
    # Without feedback the device does not see manual shots: extra images are then to be expected.
    blind = sum(unconfirmed[k] and bool(eligible[k]) for k in range(len(recs))) * 2 > max(1, int(eligible.sum()))
    return _Frames(recs, x, tol, eligible, skip, LIKELY_SKIP_COST if blind else SKIP_COST, x0)


def _windows(
    times: list[ImageTime], fr: _Frames, model: _Model, widen: float
) -> tuple[list[dict[int, float]], list[tuple[int, int] | None]]:
    """Per image: candidate frames with pair costs (EXIF images), and the frame range each image may use."""
    p = model.predict(fr.x)
    tol = fr.tol + widen
    tmax = float(tol.max()) if len(tol) else 0.0
    cands: list[dict[int, float]] = []
    ranges: list[tuple[int, int] | None] = []
    for it in times:
        c: dict[int, float] = {}
        if it.time_s is not None and it.resolution_s is not None:
            lo_t, hi_t = it.time_s, it.time_s + it.resolution_s
            a = int(np.searchsorted(p, lo_t - tmax, side="left"))
            b = int(np.searchsorted(p, hi_t + tmax, side="right"))
            for j in range(a, b):
                if not fr.eligible[j]:
                    continue
                dist = max(0.0, lo_t - float(p[j]), float(p[j]) - hi_t)
                tj = float(tol[j])
                if dist <= tj:
                    c[j] = 0.0  # inside the padded window: timing noise carries no evidence
        cands.append(c)
        ranges.append((min(c), max(c)) if c else None)
    # Images without a time may take any exposure between their timed neighbours' windows.
    n = len(times)
    timed = [i for i in range(n) if times[i].time_s is not None and ranges[i] is not None]
    m = len(fr.recs)
    for i in range(n):
        if times[i].time_s is not None:
            continue
        k = bisect.bisect_left(timed, i)
        before = ranges[timed[k - 1]] if k > 0 else None
        after = ranges[timed[k]] if k < len(timed) else None
        lo = before[0] if before is not None else 0
        hi = after[1] if after is not None else m - 1
        ranges[i] = (lo, hi) if bool(fr.eligible[lo : hi + 1].any()) else None
    return cands, ranges


def _solve(times: list[ImageTime], fr: _Frames, model: _Model, widen: float) -> _Outcome:
    cands, ranges = _windows(times, fr, model, widen)
    n, m = len(times), len(fr.recs)
    skip_fr = fr.skip
    out = _Outcome(0.0, {}, {}, {}, set())
    # Ranges made monotone (a camera numbers in time order); segments where ranges overlap.
    segs: list[tuple[list[int], int, int]] = []
    run_lo = 0
    for i in range(n):
        r = ranges[i]
        if r is None:
            continue
        lo, hi = max(r[0], run_lo), r[1]
        if lo > hi:
            ranges[i] = None
            out.extra[i] = IMAGE_EXTRA
            continue
        ranges[i] = (lo, hi)
        run_lo = lo
        if segs and lo <= segs[-1][2]:
            segs[-1][0].append(i)
            segs[-1] = (segs[-1][0], segs[-1][1], max(segs[-1][2], hi))
        else:
            segs.append(([i], lo, hi))
    in_seg = [False] * m
    for imgs, lo, hi in segs:
        for j in range(lo, hi + 1):
            in_seg[j] = True
        # The same images seeing the same exposures give the same answer (offset scans repeat most segments).
        key = (lo, hi, *((i, tuple(cands[i]) if times[i].time_s is not None else ranges[i]) for i in imgs))
        part = fr.cache.get(key)
        if part is None:
            part = _Outcome(0.0, {}, {}, {}, set())
            _solve_segment(times, fr, cands, ranges, imgs, lo, hi, skip_fr, part)
            fr.cache[key] = part
        out.cost += part.cost
        out.pairs.update(part.pairs)
        out.ambiguous.update(part.ambiguous)
        out.extra.update(part.extra)
        out.frame_ambiguous.update(part.frame_ambiguous)
    for i in range(n):
        if ranges[i] is None and i not in out.extra:
            out.extra[i] = IMAGE_NO_EXPOSURE if times[i].time_s is not None else IMAGE_NO_TIME_UNPLACED
            out.cost += fr.image_skip
        elif i in out.extra and ranges[i] is None:
            out.cost += fr.image_skip
    out.cost += sum(skip_fr[j] for j in range(m) if not in_seg[j])
    return out


def _solve_segment(
    times: list[ImageTime],
    fr: _Frames,
    cands: list[dict[int, float]],
    ranges: list[tuple[int, int] | None],
    imgs: list[int],
    lo: int,
    hi: int,
    skip_fr: list[float],
    out: _Outcome,
) -> None:
    p, q = len(imgs), hi - lo + 1
    if p * q > _MAX_SEGMENT_CELLS:
        # Only long runs of images without EXIF time make segments this large: leave them out.
        untimed = [i for i in imgs if times[i].time_s is None]
        for i in untimed:
            out.ambiguous[i] = ([], "no EXIF time, in a run of such images too long to place by order")
        imgs = [i for i in imgs if times[i].time_s is not None]
        p = len(imgs)
    inf = math.inf
    si = fr.image_skip
    sf = skip_fr[lo : hi + 1]
    pair: list[dict[int, float]] = []
    for i in imgs:
        if times[i].time_s is not None:
            pair.append({j - lo: c for j, c in cands[i].items() if lo <= j <= hi})
        else:
            r = ranges[i]
            r0, r1 = (max(lo, r[0]), min(hi, r[1])) if r is not None else (lo, hi)
            pair.append({j - lo: 0.0 for j in range(r0, r1 + 1) if fr.eligible[j]})
    # forward: f[a][b] = best cost of images[:a] with frames[:b]. Per row: skip the image or pair it
    # (both from the row above), then the frame skips sweep left to right.
    f: list[list[float]] = [[inf] * (q + 1)]
    f[0][0] = 0.0
    for b in range(1, q + 1):
        f[0][b] = f[0][b - 1] + sf[b - 1]
    for a in range(1, p + 1):
        prev = f[a - 1]
        row = [v + si for v in prev]
        for bb, c in pair[a - 1].items():
            w = prev[bb] + c
            if w < row[bb + 1]:
                row[bb + 1] = w
        last = row[0]
        for b in range(1, q + 1):
            w = last + sf[b - 1]
            if w < row[b]:
                row[b] = w
            last = row[b]
        f.append(row)
    # backward: g[a][b] = best cost of images[a:] with frames[b:]
    g: list[list[float]] = [[inf] * (q + 1) for _ in range(p + 1)]
    g[p][q] = 0.0
    for b in range(q - 1, -1, -1):
        g[p][b] = g[p][b + 1] + sf[b]
    for a in range(p - 1, -1, -1):
        nxt = g[a + 1]
        row = [v + si for v in nxt]
        for bb, c in pair[a].items():
            w = nxt[bb + 1] + c
            if w < row[bb]:
                row[bb] = w
        last = row[q]
        for b in range(q - 1, -1, -1):
            w = last + sf[b]
            if w < row[b]:
                row[b] = w
            last = row[b]
        g[a] = row
    opt = f[p][q]
    out.cost += opt
    # the optimal path (ties: pair first)
    chosen: dict[int, int] = {}
    a, b = p, q
    while a > 0 or b > 0:
        pc = pair[a - 1].get(b - 1) if a > 0 and b > 0 else None
        if pc is not None and abs(f[a - 1][b - 1] + pc - f[a][b]) < 1e-9:
            chosen[a - 1] = b - 1
            a, b = a - 1, b - 1
        elif b > 0 and abs(f[a][b - 1] + sf[b - 1] - f[a][b]) < 1e-9:
            b -= 1
        else:
            a -= 1
    limit = opt + AMBIGUITY_MARGIN
    for a in range(p):
        i = imgs[a]
        with_pair = {bb: f[a][bb] + c + g[a + 1][bb + 1] for bb, c in pair[a].items()}
        with_skip = min(map(operator.add, f[a], g[a + 1])) + si
        mine = chosen.get(a)
        alts = [v for bb, v in with_pair.items() if bb != mine]
        if mine is not None:
            alts.append(with_skip)
        alt = min(alts, default=inf)
        near = sorted(bb + lo for bb, v in with_pair.items() if v <= limit)
        if alt > limit:
            if mine is not None:
                out.pairs[i] = mine + lo
            else:
                out.extra[i] = IMAGE_EXTRA
            continue
        if mine is None and not near:
            out.extra[i] = IMAGE_EXTRA
            continue
        if times[i].time_s is None:
            why = "no EXIF time and the order does not single out one exposure"
        elif with_skip <= limit:
            why = "its EXIF time fits these exposures and the counts do not say which image is the extra one"
        else:
            why = "its EXIF time fits several exposures and the order does not decide"
        out.ambiguous[i] = (near, why)
        out.frame_ambiguous.update(near)


def _fit(times: list[ImageTime], fr: _Frames, pairs: dict[int, int], prior: _Model, max_drift_ppm: float) -> _Model:
    """Offset and drift from the confident timed pairs: weighted least squares, drift with a weak prior."""
    rows = [(float(fr.x[j]), times[i]) for i, j in pairs.items() if times[i].time_s is not None]
    if not rows:
        return prior
    x = np.array([r[0] for r in rows])
    ref = float(rows[0][1].time_s or 0.0)  # camera times are ~1e9 s: work relative to one of them
    c = np.array([r[1].time_s for r in rows], dtype=np.float64) - ref
    res = np.array([r[1].resolution_s for r in rows], dtype=np.float64)
    y = c + res / 2.0 - x  # camera minus recording time: o + d x
    w = 1.0 / (res**2 / 12.0 + 1e-6)
    sd = max_drift_ppm * 1e-6 / 2.0
    # minimise sum w (y - o - d x)^2 + (d / sd)^2
    sw, sx, sxx = w.sum(), (w * x).sum(), (w * x * x).sum() + 1.0 / sd**2
    sy, sxy = (w * y).sum(), (w * x * y).sum()
    det = sw * sxx - sx * sx
    if det <= 0:
        return prior
    o = (sxx * sy - sx * sxy) / det
    d = (sw * sxy - sx * sy) / det
    d = float(np.clip(d, -max_drift_ppm * 1e-6, max_drift_ppm * 1e-6))
    # Better: the (offset, drift) farthest inside every pair's EXIF interval (widened by the timing
    # tolerance). For a drift d the offsets allowed form [max(lo - x(1+d)), min(hi - x(1+d))], whose width
    # is concave in d: maximise it (ties broken towards no drift, which a short flight cannot tell from
    # a small one), then take the middle. Truncated EXIF times pin the clock far better
    # through the seconds' boundaries than least squares on their centres does.
    tol = np.array([fr.tol[j] for i, j in pairs.items() if times[i].time_s is not None], dtype=np.float64)
    lo_b, hi_b = c - tol - x, c + res + tol - x
    span = float(x.max() - x.min()) if len(x) else 0.0

    def bounds(dd: float) -> tuple[float, float]:
        return float((lo_b - dd * x).max()), float((hi_b - dd * x).min())

    def width(dd: float, penalty: float) -> float:
        a, b = bounds(dd)
        return b - a - penalty * abs(dd) * span

    lim = max_drift_ppm * 1e-6
    d_best = 0.0
    for penalty in (0.01,):  # breaks ties towards no drift where the width is flat
        a_d, b_d = -lim, lim
        for _ in range(100):
            m1, m2 = a_d + (b_d - a_d) / 3.0, b_d - (b_d - a_d) / 3.0
            if width(m1, penalty) < width(m2, penalty):
                a_d = m1
            else:
                b_d = m2
        d_best = (a_d + b_d) / 2.0
        o_lo, o_hi = bounds(d_best)
        if o_lo <= o_hi:
            # Known if drifts _DRIFT_REPORT_PPM away narrow the allowed offsets by more than a millisecond.
            top = width(d_best, 0.0)
            step = _DRIFT_REPORT_PPM * 1e-6
            known = width(d_best - step, 0.0) < top - 1e-3 and width(d_best + step, 0.0) < top - 1e-3
            return _Model((o_lo + o_hi) / 2.0 + ref, d_best, known)
    return _Model(float(o) + ref, d)


def _offset_candidates(times: list[ImageTime], fr: _Frames, widen: float, keep: int = 3) -> list[_Model]:
    """A few distinct camera offsets (drift 0) under which most images and exposures find a partner."""
    timed = [t for t in times if t.time_s is not None and t.resolution_s is not None]
    xe = fr.x[fr.eligible]
    if not timed or len(xe) == 0:
        return []
    c = np.array([t.time_s for t in timed], dtype=np.float64)
    r = np.array([t.resolution_s for t in timed], dtype=np.float64)
    tol = float(np.median(fr.tol)) + widen
    c_sorted = np.sort(c)
    r_max = float(r.max())

    def score(o: float, slack: float = 0.0) -> int:
        t = tol + slack
        lo = np.searchsorted(xe, c - o - t, side="left")
        hi = np.searchsorted(xe, c + r - o + t, side="right")
        images = int(np.count_nonzero(hi > lo))
        pe = xe + o
        a = np.searchsorted(c_sorted, pe - r_max - t, side="left")
        b = np.searchsorted(c_sorted, pe + t, side="right")
        return images + int(np.count_nonzero(b > a))

    step = max(1, len(timed) // 40)
    sample = np.arange(0, len(timed), step)[:40]
    votes = (c[sample, None] + r[sample, None] / 2.0 - xe[None, :]).ravel()
    coarse_q = max(1.0, r_max)
    bins, counts = np.unique(np.floor(votes / coarse_q), return_counts=True)
    top = bins[np.argsort(-counts, kind="stable")[:200]]
    coarse = sorted(((score(float((k + 0.5) * coarse_q), coarse_q / 2), float(k)) for k in top), reverse=True)
    best_bins = [k for _, k in coarse[:3]]
    fine = np.unique(np.round(votes[np.isin(np.floor(votes / coarse_q), best_bins)], 3))
    scored = sorted(((score(float(o)), float(o)) for o in fine), key=lambda t: (-t[0], t[1]))
    if not scored:
        return []
    # Among the best, keep the middle of each run of equal scores, and distinct ones only.
    best = scored[0][0]
    out: list[float] = []
    sep = 2.0 * tol + float(r.min())
    for s, o in scored:
        if s < best - max(4, best // 20):
            break
        group = [oo for ss, oo in scored if ss == s and abs(oo - o) <= r_max + 2 * tol]
        centre = (min(group) + max(group)) / 2.0
        if all(abs(centre - k) > sep for k in out):
            out.append(centre)
        if len(out) >= keep:
            break
    return [_Model(o, 0.0) for o in out]


def match_times(
    frames: Sequence[FrameRecord],
    times: Sequence[ImageTime],
    *,
    camera_id: int | None = None,
    time_tolerance_s: float = 0.02,
    max_drift_ppm: float = 100.0,
) -> MatchResult:
    """Pair images (in card order, with their EXIF times) with frames; see the module docstring.

    `time_tolerance_s`: how far a camera's time stamp may be from the exposure start beyond its
    resolution (latency, the recording's own timing error is added per frame). `max_drift_ppm`:
    the largest camera clock rate error believed.
    """
    result = MatchResult()
    ids = sorted({f.camera_id for f in frames})
    if camera_id is None and len(ids) > 1:
        raise MatchError(f"the log has frames of cameras {ids}: say which camera's card this is (camera_id)")
    recs = [f for f in frames if camera_id is None or f.camera_id == camera_id]
    images = list(times)
    if not images:
        raise MatchError("no images to match")
    res = [t.resolution_s for t in images if t.resolution_s is not None]
    result.resolution_s = max(res) if res else None
    if not recs:
        result.unmatched_images = [UnmatchedImage(t.path, IMAGE_NO_EXPOSURE, "the log has no frames") for t in images]
        return result
    fr = _frames_from(recs, time_tolerance_s)
    span = float(fr.x[-1] - fr.x[0]) if len(fr.x) else 0.0
    # The drift's worst effect before it is estimated, capped: on a long flight the first pass pairs
    # the part near where the offset fits best, and the drift fitted there extends it to the rest.
    widen = min(max_drift_ppm * 1e-6 * span, _FIRST_PASS_WIDEN_MAX_S)
    candidates = _offset_candidates(images, fr, widen)
    if not candidates:
        result.notes.append("no image has an EXIF time: images can only be placed by order")
        candidates = [_Model(0.0, 0.0)]
    solutions: list[tuple[float, _Model, _Outcome]] = []
    for start in candidates:
        # Where in its neighbourhood does the offset fit best (with steady triggers a candidate can be
        # a fraction of an interval off, which shifts pairs near the seconds' boundaries)? Then the drift.
        settled = _settle(images, fr, start, time_tolerance_s)
        model, outcome = _refine(images, fr, settled, widen, max_drift_ppm)
        solutions.append((outcome.cost, model, outcome))
    solutions.sort(key=lambda s: s[0])
    cost, model, outcome = solutions[0]
    # The offset is only known as well as the card pins it: with steady triggers an offset a few
    # intervals away, or a fraction of the EXIF resolution away, can explain the card about as well
    # (then only the ends or irregular shots decide). Scan the offsets around the fit; a cheaper
    # solution replaces it, and every pair not made the same way by all solutions within
    # AMBIGUITY_MARGIN of the best is not made.
    scan: list[tuple[float, _Model, _Outcome]] = []
    for _ in range(3):
        step, reach = _grid(fr, images, time_tolerance_s, coarse=False)
        scan = [(c, m, o) for c, m, o, _k in _scan(images, fr, model, cost, step, reach)]
        cheaper = [t for t in scan if t[0] < cost - 1e-9]
        if not cheaper:
            break
        start = min(cheaper, key=lambda t: t[0])[1]
        better_model, better = _refine(images, fr, start, 0.0, max_drift_ppm)
        if better.cost >= cost - 1e-9:
            break
        model, outcome, cost = better_model, better, better.cost
    else:
        step, reach = _grid(fr, images, time_tolerance_s, coarse=False)
        scan = [(c, m, o) for c, m, o, _k in _scan(images, fr, model, cost, step, reach)]
    near: list[tuple[float, _Model, _Outcome]] = []
    for t in solutions[1:] + scan:
        if t[0] <= cost + AMBIGUITY_MARGIN and t[2].pairs != outcome.pairs and all(t[2] is not u[2] for u in near):
            near.append(t)
    for _other_cost, other_model, other in near:
        differ = [i for i in outcome.pairs if other.pairs.get(i) != outcome.pairs[i]]
        for i in differ:
            cands = {outcome.pairs[i]}
            if i in other.pairs:
                cands.add(other.pairs[i])
            if i in other.ambiguous:
                cands.update(other.ambiguous[i][0])
            outcome.ambiguous[i] = (
                sorted(cands),
                f"the camera clock is not pinned down: an offset {other_model.offset - model.offset:+.3f} s from "
                "the best fit explains the card about as well and pairs this image otherwise",
            )
            outcome.frame_ambiguous.update(cands)
            del outcome.pairs[i]
        if differ:
            note = "the camera clock offset is ambiguous: the pairs that depend on it are not made"
            if note not in result.notes:
                result.notes.append(note)
    _swap_rule(images, fr, model, outcome)
    _untimed_rule(images, fr, outcome)
    _report(images, fr, model, outcome, result)
    return result


def _refine(
    images: list[ImageTime], fr: _Frames, start: _Model, widen: float, max_drift_ppm: float
) -> tuple[_Model, _Outcome]:
    """Align with widened windows (the drift is unknown), fit, and close the windows to the tolerance."""
    model = start
    for w in (widen, widen, widen / 2.0, 0.0) if widen > 0 else (0.0, 0.0):
        outcome = _solve(images, fr, model, w)
        model = _fit(images, fr, outcome.pairs, model, max_drift_ppm)
    return model, _solve(images, fr, model, 0.0)


def _grid(fr: _Frames, images: list[ImageTime], tolerance_s: float, *, coarse: bool) -> tuple[float, float]:
    """(step, reach) of an offset scan [s]: fine for the ambiguity scan, coarser to settle a candidate."""
    xe = fr.x[fr.eligible]
    res = [t.resolution_s for t in images if t.resolution_s is not None]
    dt = float(np.median(np.diff(xe))) if len(xe) >= 2 else 0.0
    r_max = max(res) if res else 0.0
    if coarse:
        return max(0.004, tolerance_s / 2.0, r_max / 20.0), min(_MAX_SCAN_S, r_max / 2.0 + dt)
    return max(0.004, tolerance_s / 2.0), min(_MAX_SCAN_S, r_max / 2.0 + 2.0 * dt + 2.0 * tolerance_s)


def _settle(images: list[ImageTime], fr: _Frames, start: _Model, tolerance_s: float) -> _Model:
    """The middle of the run of scanned offsets around `start` that cost least."""
    step, reach = _grid(fr, images, tolerance_s, coarse=True)
    base = _solve(images, fr, start, 0.0)
    found = _scan(images, fr, start, base.cost, step, reach, centre=True)
    if not found:
        return start
    least = min(c for c, _m, _o, _k in found)
    ks = {k for c, _m, _o, k in found if c <= least + 1e-9}
    best_k = min(ks, key=abs)
    lo = hi = best_k
    while lo - 1 in ks:
        lo -= 1
    while hi + 1 in ks:
        hi += 1
    return _Model(start.offset + (lo + hi) / 2.0 * step, start.drift)


def _scan(
    images: list[ImageTime],
    fr: _Frames,
    model: _Model,
    best: float,
    step: float,
    reach: float,
    *,
    centre: bool = False,
) -> list[tuple[float, _Model, _Outcome, int]]:
    """Solutions at offsets around `model` (a grid) that may cost at most `best` + AMBIGUITY_MARGIN.

    Each offset is solved with its windows widened by half the grid step, so an alignment that fits
    anywhere between two grid offsets is seen (the scan errs towards ambiguity).
    """
    xe = fr.x[fr.eligible]
    if len(xe) < 2 or all(t.time_s is None for t in images):
        return []
    timed = [i for i, t in enumerate(images) if t.time_s is not None and t.resolution_s is not None]
    c = np.array([images[i].time_s for i in timed], dtype=np.float64)
    r = np.array([images[i].resolution_s for i in timed], dtype=np.float64)
    order = np.argsort(c, kind="stable")
    c_sorted, r_sorted = c[order], r[order]
    skip_e = np.array(fr.skip, dtype=np.float64)[fr.eligible]
    min_skip = float(skip_e[skip_e > 0].min()) if bool((skip_e > 0).any()) else 0.0
    t_pad = float(fr.tol.max()) + step / 2.0
    untimed = float(len(images) - len(timed))
    seen: dict[int, tuple[float, _Model, _Outcome, int] | None] = {}
    out: list[tuple[float, _Model, _Outcome, int]] = []
    for k in range(-math.floor(reach / step), math.floor(reach / step) + 1):
        if k == 0 and not centre:
            continue
        m = _Model(model.offset + k * step, model.drift)
        pe = np.asarray(m.predict(xe), dtype=np.float64)
        lo = np.searchsorted(pe, c - t_pad, side="left")
        hi = np.searchsorted(pe, c + r + t_pad, side="right")
        signature = hash(lo.tobytes() + hi.tobytes())
        if signature in seen:  # every image sees the same exposures as at an offset already tried
            if seen[signature] is not None:
                c0, _m0, o0, _k0 = seen[signature]  # type: ignore[misc]
                out.append((c0, m, o0, k))
            continue
        seen[signature] = None
        # A lower bound on the cost: images with fewer exposures in reach than images of the same
        # EXIF time, exposures in reach of no image, exposures deep inside one window outnumbering its images.
        bound = 0.0
        uniq, first, counts = np.unique(c, return_index=True, return_counts=True)
        avail = hi[first] - lo[first]
        bound += float(np.clip(counts - avail, 0, None).sum()) * fr.image_skip
        k_idx = np.searchsorted(c_sorted, pe + t_pad, side="right") - 1
        covered = (k_idx >= 0) & (pe <= c_sorted[np.clip(k_idx, 0, None)] + r_sorted[np.clip(k_idx, 0, None)] + t_pad)
        uncovered = float(np.count_nonzero(~covered & (skip_e > 0)))
        core_lo = np.searchsorted(pe, uniq + t_pad, side="left")
        core_hi = np.searchsorted(pe, uniq + r[first] - t_pad, side="left")
        excess = float(np.clip((core_hi - core_lo) - counts, 0, None).sum())
        # (an image without EXIF time may take any of those exposures)
        bound += max(0.0, uncovered + excess - untimed) * min_skip
        if bound > best + AMBIGUITY_MARGIN:
            continue
        alt = _solve(images, fr, m, step / 2.0)
        if alt.cost <= best + AMBIGUITY_MARGIN:
            out.append((alt.cost, m, alt, k))
            seen[signature] = out[-1]
    return out


def _swap_rule(times: list[ImageTime], fr: _Frames, model: _Model, out: _Outcome) -> None:
    """A manual shot during a trigger's shutter lag: the card may number the two either way.

    A camera numbers its files in the order it takes the shots, but a shot fired by hand while a
    triggered one waits out its shutter lag can be exposed first (and its flash-sync edge taken for
    the trigger's). If an unsolicited exposure starts between a neighbouring trigger and the end of
    that trigger's usual lag, and the EXIF times allow both orders, both images are ambiguous."""
    lags = [
        r.start_device_us - r.trigger_device_us
        for r in fr.recs
        if r.trigger_device_us > 0 and FrameFlag.NO_FEEDBACK.value not in r.flags
    ]
    if not lags:
        return
    lag_us = float(np.median(lags)) + _SWAP_MARGIN_US
    p = model.predict(fr.x)
    frame_image = {j: i for i, j in out.pairs.items()}

    def fits(i: int, j: int) -> bool:
        t = times[i]
        if t.time_s is None or t.resolution_s is None:
            return True
        tol = float(fr.tol[j])
        return t.time_s - tol <= float(p[j]) <= t.time_s + t.resolution_s + tol

    eligible = [j for j in range(len(fr.recs)) if fr.eligible[j]]
    for j, k in itertools.pairwise(eligible):
        a, b = fr.recs[j], fr.recs[k]
        unsolicited = [x for x in (a, b) if FrameFlag.UNSOLICITED.value in x.flags]
        triggered = [x for x in (a, b) if x.trigger_device_us > 0]
        if len(unsolicited) != 1 or len(triggered) != 1:
            continue
        u, t = unsolicited[0], triggered[0]
        if not t.trigger_device_us - _SWAP_MARGIN_US <= u.start_device_us <= t.trigger_device_us + lag_us:
            continue
        ij, ik = frame_image.get(j), frame_image.get(k)
        if ij is None or ik is None or ij not in out.pairs or ik not in out.pairs:
            continue
        if not (fits(ij, k) and fits(ik, j)):
            continue
        why = "a manual shot during a trigger's shutter lag: the card may number the two either way"
        for i in (ij, ik):
            out.ambiguous[i] = ([j, k], why)
            del out.pairs[i]
        out.frame_ambiguous.update((j, k))


def _untimed_rule(times: list[ImageTime], fr: _Frames, out: _Outcome) -> None:
    """An image without EXIF time keeps its pair only between two time-confident neighbours, one exposure apart."""
    n = len(times)
    for i in range(n):
        if times[i].time_s is not None or i not in out.pairs:
            continue
        prev_ok = i > 0 and times[i - 1].time_s is not None and (i - 1) in out.pairs
        next_ok = i + 1 < n and times[i + 1].time_s is not None and (i + 1) in out.pairs
        if prev_ok and next_ok:
            between = [j for j in range(out.pairs[i - 1] + 1, out.pairs[i + 1]) if fr.eligible[j]]
            if len(between) == 1 and between[0] == out.pairs[i]:
                continue
            why = f"no EXIF time and {len(between)} exposures lie between its neighbours' exposures"
        else:
            between = [out.pairs[i]]
            why = "no EXIF time and its neighbours on the card are not both paired by time"
        out.ambiguous[i] = (between, why)
        out.frame_ambiguous.update(between)
        del out.pairs[i]


def _report(times: list[ImageTime], fr: _Frames, model: _Model, out: _Outcome, result: MatchResult) -> None:
    p = model.predict(fr.x)
    used: set[int] = set()
    for i in sorted(out.pairs):
        j = out.pairs[i]
        t = times[i]
        residual = None
        if t.time_s is not None and t.resolution_s is not None:
            residual = float(p[j]) - (t.time_s + t.resolution_s / 2.0)
        result.pairs.append(Pair(t.path, fr.recs[j], residual))
        used.add(j)
    for i in sorted(out.ambiguous):
        cands, why = out.ambiguous[i]
        result.ambiguous.append(Ambiguous(times[i].path, tuple(fr.recs[j] for j in cands if j not in used), why))
    for i in sorted(out.extra):
        t = times[i]
        reason = out.extra[i]
        if t.problem is not None:
            result.unmatched_images.append(UnmatchedImage(t.path, IMAGE_UNREADABLE, t.problem))
        elif reason == IMAGE_NO_EXPOSURE:
            result.unmatched_images.append(
                UnmatchedImage(t.path, reason, "no recorded exposure near its EXIF time (shot while not recording?)")
            )
        elif reason == IMAGE_NO_TIME_UNPLACED:
            result.unmatched_images.append(UnmatchedImage(t.path, reason, "no EXIF time and no exposure left for it"))
        else:
            result.unmatched_images.append(
                UnmatchedImage(t.path, reason, "the exposures near its time belong to other images (an extra shot?)")
            )
    timed = [float(t.time_s) for t in times if t.time_s is not None]
    first_t, last_t = (min(timed), max(timed) + 1.0) if timed else (-math.inf, math.inf)
    for j, rec in enumerate(fr.recs):
        if j in used:
            continue
        if not fr.eligible[j]:
            result.unmatched_frames.append(
                UnmatchedFrame(
                    rec, FRAME_FEEDBACK_MISSING, "the camera did not confirm this trigger: no image expected"
                )
            )
        elif j in out.frame_ambiguous:
            result.unmatched_frames.append(UnmatchedFrame(rec, FRAME_AMBIGUOUS, "a candidate of an ambiguous image"))
        elif not first_t - 1.0 <= float(p[j]) <= last_t + 1.0:
            result.unmatched_frames.append(
                UnmatchedFrame(rec, FRAME_NO_IMAGE, "outside the time span of the card's images")
            )
        else:
            result.unmatched_frames.append(
                UnmatchedFrame(rec, FRAME_NO_IMAGE, "a confirmed exposure without an image on the card")
            )
    result.camera_drift_ppm = model.drift * 1e6 if model.drift_known else None
    utc = [
        (float(p[j]) - (r.mid_utc_us - (r.mid_device_us - r.start_device_us)) * 1e-6)
        for j, r in ((out.pairs[i], fr.recs[out.pairs[i]]) for i in sorted(out.pairs))
        if r.mid_utc_us is not None
    ]
    result.camera_offset_s = utc[0] if utc else None


def match_images(
    frames: Sequence[FrameRecord],
    images: Sequence[Path] | Path,
    *,
    camera_id: int | None = None,
    time_tolerance_s: float = 0.02,
    max_drift_ppm: float = 100.0,
    progress: Callable[[int, int], None] | None = None,
) -> MatchResult:
    """Pair the camera card's images with the recorded frames.

    `images`: a folder (its JPEGs, subfolders included, in the camera's numbering order) or paths in
    card order. See `match_times` for the other arguments.
    """
    paths = list_images(images) if isinstance(images, Path) else [Path(p) for p in images]
    if not paths:
        raise MatchError(f"no JPEG images in {images}")
    times = []
    for k, path in enumerate(paths):
        times.append(read_image_time(path))
        if progress is not None:
            progress(k + 1, len(paths))
    result = match_times(
        frames, times, camera_id=camera_id, time_tolerance_s=time_tolerance_s, max_drift_ppm=max_drift_ppm
    )
    untimed = sum(1 for t in times if t.time_s is None)
    if untimed:
        result.notes.append(f"{untimed} images without EXIF DateTimeOriginal")
    return result


# ----------------------------------------------------------------------------- command line
def cmd_match(args: argparse.Namespace) -> int:
    """`icgt match --images DIR LOG [--json OUT] [--camera-id N] [--tolerance S]`.

    Prints the summary, every ambiguous and unmatched image; exit status 0 when every image is
    decided (paired or explained), 2 when some are ambiguous and need a look."""
    from icgt.ingest.reader import read

    log_path: Path = args.log
    images: Path = args.images
    rec = read(log_path)
    frames = list(rec.frames())
    if not frames:
        raise MatchError(f"{log_path}: the recording has no frames")
    tolerance = getattr(args, "tolerance", None)
    result = match_images(
        frames,
        images,
        camera_id=getattr(args, "camera_id", None),
        time_tolerance_s=0.02 if tolerance is None else float(tolerance),
    )
    print(result.summary())
    for a in result.ambiguous:
        seqs = ", ".join(str(f.frame_seq) for f in a.candidates) or "none left"
        print(f"  ambiguous {a.image.name}: frames {seqs}: {a.why}")
    for u in result.unmatched_images:
        print(f"  image {u.image.name}: {u.reason}: {u.detail}")
    out: Path | None = getattr(args, "json", None)
    if out is not None:
        try:
            out.write_text(json.dumps(result.to_json(), indent=2) + "\n")
        except OSError as exc:
            raise MatchError(f"cannot write {out}: {exc.strerror or exc}") from None
        print(f"written {out}", file=sys.stderr)
    return 2 if result.ambiguous else 0
