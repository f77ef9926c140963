"""Live == replay: recomputing a recorded flight with its own settings gives back every frame exactly.

Used by every test that flies a whole flight (e2e, ingest, export), so the check runs on flights with
USB unplugs, autopilot outages, GPS denial, PPS and missed triggers, at no extra flying time.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from icgt.ingest.reader import read
from icgt.ingest.recompute import recompute


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def assert_replay_reproduces_every_frame(mcap: Path) -> int:
    """Every /frames record equals its recomputation field for field; returns the number of frames."""
    recorded = list(read(mcap).frames())
    result = recompute(mcap)
    replayed = {f.frame_seq: f for f in result.frames}
    assert len(recorded) > 0
    assert result.counts["frames_emitted_as_recorded"] == result.counts["frames_in_log"] == len(recorded)
    assert result.counts["frames_emitted_at_end"] == 0
    differences: dict[int, list[str]] = {}
    for a in recorded:
        b = replayed.get(a.frame_seq)
        assert b is not None, f"frame {a.frame_seq} not recomputed"
        diff = [
            f"{f.name}: {getattr(a, f.name)!r} != {getattr(b, f.name)!r}"
            for f in dataclasses.fields(a)
            if not _same(getattr(a, f.name), getattr(b, f.name))
        ]
        if diff:
            differences[a.frame_seq] = diff
    assert not differences, (
        f"{len(differences)} of {len(recorded)} frames differ: {dict(list(differences.items())[:3])}"
    )
    return len(recorded)
