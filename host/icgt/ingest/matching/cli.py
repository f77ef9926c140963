"""`icgt match --images DIR LOG`: the command line (summary, every undecided image, the JSON report)."""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from tqdm import tqdm

from icgt.ingest.matching.results import MatchError
from icgt.ingest.matching.reuse import match_images_reusing


def cmd_match(args: argparse.Namespace) -> int:
    """`icgt match --images DIR LOG [--json OUT] [--camera-id N] [--tolerance S] [--no-progress]`.

    Prints the summary, every ambiguous and unmatched image; exit status 0 when every image is
    decided (paired or explained), 2 when some are ambiguous and need a look. The result is kept
    (icgt.ingest.matching.reuse) for `icgt export` of the same log and card, which then does not match again."""
    from icgt.ingest.reader import read

    log_path: Path = args.log
    images: Path = args.images
    rec = read(log_path)
    frames = list(rec.frames())
    if not frames:
        raise MatchError(f"{log_path}: the recording has no frames")
    tolerance = getattr(args, "tolerance", None)
    quiet = bool(getattr(args, "no_progress", False))
    reading = tqdm(desc="match: EXIF times", unit="image", disable=quiet)
    aligning = tqdm(desc="match: alignment", unit="step", disable=quiet)
    try:
        result, kept = match_images_reusing(
            frames,
            images,
            camera_id=getattr(args, "camera_id", None),
            time_tolerance_s=0.02 if tolerance is None else float(tolerance),
            progress=_ticker(reading),
            align_progress=_ticker(aligning),
            reuse=False,
            keep=True,
        )
    finally:
        reading.close()
        aligning.close()
    print(result.summary())
    for a in result.ambiguous:
        seqs = ", ".join(str(f.frame_seq) for f in a.candidates) or "none named"
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
    if kept is not None:
        print(f"kept for icgt export: {kept}", file=sys.stderr)
    return 2 if result.ambiguous else 0


def _ticker(bar: tqdm[Any]) -> Callable[[int, int], None]:
    def tick(done: int, total: int) -> None:
        bar.total = total
        bar.update(done - bar.n)

    return tick
