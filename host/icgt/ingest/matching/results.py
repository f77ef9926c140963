"""What a match produces: pairs, leftovers on both sides with their reasons, the camera clock found.

Also the costs the alignment weighs evidence with, and the reasons as they appear in the JSON report."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError
from icgt.geotag.record import FrameRecord

SKIP_COST = 10.0
"""Cost of one unexplained event: an image with no exposure, or a confirmed exposure with no image."""
LIKELY_SKIP_COST = 2.0
"""Cost of an event the recording cannot rule out: an unconfirmed trigger (no hot-shoe feedback) without
an image, or an extra image when the device does not see exposures (then manual shots go unrecorded).
Two of them cost less than AMBIGUITY_MARGIN: an alignment explaining the card with them is a real alternative."""
AMBIGUITY_MARGIN = 5.0
"""An alternative alignment costing less than this more than the optimum makes an image ambiguous."""

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
    undecided_exposures: int = 0
    """Exposures of the log the card's images could explain under an offset that is not decided (the best
    offset's overlap when rivals explain the card as well; 0 when the clock is decided): another session of
    the card then cannot claim those exposures as its own (`sessions.match_sessions`). Not in the report."""

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
