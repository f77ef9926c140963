"""The matcher's working state: the exposures and the card as arrays, the camera clock model, an outcome."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.ingest.matching.results import LIKELY_SKIP_COST, SKIP_COST, ImageTime

FloatArray = np.ndarray[Any, np.dtype[np.float64]]
IntArray = np.ndarray[Any, np.dtype[np.int64]]
BoolArray = np.ndarray[Any, np.dtype[np.bool_]]


@dataclass
class Outcome:
    """One alignment: its cost and what it decides per image (indices into the card and the frames)."""

    cost: float
    pairs: dict[int, int]  # image -> frame (confident)
    ambiguous: dict[int, tuple[list[int], str]]  # image -> (candidate frames, why)
    extra: dict[int, str]  # image -> reason (IMAGE_NO_EXPOSURE / IMAGE_EXTRA / ...)
    frame_ambiguous: set[int]


@dataclass
class Frames:
    """The exposures of one camera in time order, with what the alignment needs of each."""

    recs: list[FrameRecord]  # sorted by exposure start
    x: FloatArray  # exposure start on the recording's clock, s from the first
    tol: FloatArray  # how far the camera's time stamp may be outside its EXIF interval [s]
    eligible: BoolArray  # may have an image (not feedback_missing)
    skip: list[float]  # cost of the frame having no image
    image_skip: float  # cost of an image having no frame
    x0_ns: int
    skip_prefix: FloatArray = field(default_factory=lambda: np.zeros(1))  # skip_prefix[j] = sum(skip[:j])
    eligible_prefix: IntArray = field(default_factory=lambda: np.zeros(1, dtype=np.int64))
    cache: dict[tuple[Any, ...], Outcome] = field(default_factory=dict)  # solved small segments
    cost_cache: dict[tuple[Any, ...], float] = field(default_factory=dict)  # their costs alone
    last_segments: tuple[tuple[float, float, float], Any] | None = None  # align.segments' last answer


@dataclass
class Card:
    """The card's images in card order, their EXIF intervals as arrays (NaN: no time)."""

    times: list[ImageTime]
    c: FloatArray  # interval start (the EXIF time) [s]
    r: FloatArray  # interval length (the resolution) [s]
    timed: IntArray  # indices of images with a time, in card order
    has: list[bool]  # has[i]: image i has an EXIF time
    untimed_prefix: list[int]  # untimed_prefix[i]: images without a time before image i

    @classmethod
    def of(cls, times: Sequence[ImageTime]) -> Card:
        ts = list(times)
        c = np.array([t.time_s if t.time_s is not None else np.nan for t in ts], dtype=np.float64)
        r = np.array([t.resolution_s if t.resolution_s is not None else np.nan for t in ts], dtype=np.float64)
        timed = np.flatnonzero(~(np.isnan(c) | np.isnan(r))).astype(np.int64)
        has = [t.time_s is not None for t in ts]
        untimed = np.concatenate([[0], np.cumsum(~np.array(has, dtype=bool))]).astype(np.int64)
        return cls(ts, c, r, timed, has, untimed.tolist())

    def __len__(self) -> int:
        return len(self.times)

    def has_time(self, i: int) -> bool:
        return self.has[i]


class Ranges:
    """Per image the frame range (first, last) it may pair within, None where it has none; held as
    arrays (-1: none) and read per image, with the images without one listed (ascending)."""

    def __init__(self, lo: IntArray, hi: IntArray) -> None:
        self._lo: list[int] = lo.tolist()
        self._hi: list[int] = hi.tolist()
        self.missing: list[int] = np.flatnonzero(lo < 0).tolist()

    def __getitem__(self, i: int) -> tuple[int, int] | None:
        a = self._lo[i]
        return None if a < 0 else (a, self._hi[i])


@dataclass
class Model:
    offset: float  # camera time minus x at x = 0 [s]
    drift: float  # dimensionless
    drift_known: bool = False  # the pairs pin the drift to within DRIFT_REPORT_PPM

    def predict(self, x: FloatArray | float) -> Any:
        return x * (1.0 + self.drift) + self.offset


def frames_from(records: Sequence[FrameRecord], base_tolerance_s: float) -> Frames:
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
    fr = Frames(recs, x, tol, eligible, skip, LIKELY_SKIP_COST if blind else SKIP_COST, x0)
    fr.skip_prefix = np.concatenate([[0.0], np.cumsum(np.array(skip, dtype=np.float64))])
    fr.eligible_prefix = np.concatenate([[0], np.cumsum(eligible.astype(np.int64))])
    return fr
