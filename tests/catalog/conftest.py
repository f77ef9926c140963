"""Fixtures of the catalogue's tests: synthesised flights (tests/catalog/synth_logs.py), no simulator."""

from __future__ import annotations

import hashlib
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

import synth_logs as sl

from icgt.geotag import FrameRecord


@dataclass
class SynthFlight:
    log: Path
    card: Path
    detections: Path
    frames: list[FrameRecord]
    synth: sl.Synth


def make_flight(folder: Path, s: sl.Synth, *, card: bool = True) -> SynthFlight:
    folder.mkdir(parents=True, exist_ok=True)
    log = folder / "flight.mcap"
    recs = sl.write_log(log, s)
    card_dir = folder / "card"
    if card:
        sl.write_card(card_dir, recs)
    det = sl.write_detections(folder / "detections.json", ["DSC00005.JPG", "DSC00006.JPG"])
    return SynthFlight(log, card_dir, det, recs, s)


@pytest.fixture(scope="module")
def flight_a(tmp_path_factory: pytest.TempPathFactory) -> SynthFlight:
    """40 frames, every 9th without a pose, 2 exposures lost; with a card and a crack seen in two images."""
    return make_flight(tmp_path_factory.mktemp("a"), sl.Synth(no_pose_every=9, lost_exposures=2))


@pytest.fixture(scope="module")
def flight_b(tmp_path_factory: pytest.TempPathFactory) -> SynthFlight:
    """Another device's flight a year later, 200 m away."""
    return make_flight(
        tmp_path_factory.mktemp("b"),
        sl.Synth(seed=5, serial="7654321", recording_id=0x0BADCAFE, start_utc=sl.datetime(2026, 5, 20, 14, 0,
                 tzinfo=sl.UTC), origin=(sl.ORIGIN[0] + 0.0018, sl.ORIGIN[1], sl.ORIGIN[2])),
    )  # fmt: skip


def snapshot(root: Path) -> dict[str, str]:
    """Every visible file of a catalogue (not its lock or staging) with its content hash."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if rel.parts[0] in (".lock", ".staging") or not p.is_file():
            continue
        out[str(rel)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out
