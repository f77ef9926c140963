"""Match the camera card's JPEGs to the recorded exposures: `icgt match --images DIR LOG`.

The public face of the matcher; the work is done in `icgt.ingest.matching`: `exif` (the card and its
EXIF times), `clock` (candidate offsets, offset and drift fit), `align` (the alignment for one clock
model), `search` (settling, refining and scanning offsets), `rules` (shutter-lag swaps, untimed
images), `report` (the MatchResult), `core` (the pipeline), `reuse` (a match remembered for `icgt
export`), `cli` (the command).

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

Scaling: banded dynamic programming around the fitted clock (linear in the card, time and memory).
Under one clock model image i may only pair with the few exposures inside its window, and since both
sequences are ordered, row r of the alignment (r images placed) only differs from plain sums of skip
costs on [least frame any image from r - 1 on may take, one past the greatest any image up to r may
take]. The DP keeps each row on that band only (`icgt.ingest.matching.align`); values outside follow
exactly from prefix sums of the frames' skip costs, and every minimum the ambiguity test takes lies
inside. So a segment costs a few cells per image instead of images x exposures, which is what made
the old matcher quadratic: with 1 s EXIF times and windows widened for the not yet known drift, a
steady 5 fps pass chains every second to the next and most of the card was one segment (5.4 GB at
8 000 images). The results are exactly those of the full table (tests/ingest: a hypothesis test
compares the two), so every guarantee above is kept. The offset searches around it stay as they
were but cost less: a scanned offset is first costed by forward passes alone, stopped as soon as it
exceeds the margin (or, when settling, the least cost found so far), and only a rival within the
margin is solved in full; one-image segments are solved in closed form, small segments remembered
across offsets, windows found by vectorised searches, an image whose only exposure within the margin
is the optimum's paired without the general bookkeeping, the clock fitted on arrays. Chosen over
cutting the card at bursts and gaps, which alone does not bound a segment (the chaining above), and
over a streaming alignment, which cannot give the cost of the best alignment *without* each pair (the
backward pass) that the ambiguity test rests on. Measured by benchmarks/match_scaling.py against reading the EXIF alone.

Limits: two unexplained events that cancel within one EXIF second (an image lost from the card
and an extra shot) are indistinguishable from none; the default tolerance (20 ms beyond the
resolution, plus the recording's own timing bound) trades missed ambiguity against guessing.
"""

from __future__ import annotations

from icgt.ingest.matching.cli import cmd_match
from icgt.ingest.matching.core import match_images, match_times
from icgt.ingest.matching.exif import list_images, parse_exif_time, read_image_time
from icgt.ingest.matching.results import (
    AMBIGUITY_MARGIN,
    FRAME_AMBIGUOUS,
    FRAME_FEEDBACK_MISSING,
    FRAME_NO_IMAGE,
    IMAGE_EXTRA,
    IMAGE_NO_EXPOSURE,
    IMAGE_NO_TIME_UNPLACED,
    IMAGE_UNREADABLE,
    LIKELY_SKIP_COST,
    SKIP_COST,
    Ambiguous,
    ImageTime,
    MatchError,
    MatchResult,
    Pair,
    UnmatchedFrame,
    UnmatchedImage,
)

__all__ = [
    "AMBIGUITY_MARGIN",
    "FRAME_AMBIGUOUS",
    "FRAME_FEEDBACK_MISSING",
    "FRAME_NO_IMAGE",
    "IMAGE_EXTRA",
    "IMAGE_NO_EXPOSURE",
    "IMAGE_NO_TIME_UNPLACED",
    "IMAGE_UNREADABLE",
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
    "parse_exif_time",
    "read_image_time",
]
