"""Issue 36 end to end: the recorder died halfway (its log cut at 50 %), the camera kept shooting (the card
holds every image). `icgt recover` keeps the intact chunks, `icgt match` and `icgt export --images` run on
them as a user would: every geotag written belongs to its own exposure (checked against the frame number the
simulator drew into each image's pixels), none to an image whose exposure the cut log lost, and every image
without a geotag is listed in problems.csv."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path
from typing import Any

import pytest
from test_ingest_match import _set_time

from icgt.cli import main
from icgt.demo import Flight
from icgt.ingest.reader import read
from icgt.sim.camera_card import read_frame_number
from icgt.sim.truth import exif_strings


@pytest.mark.parametrize("exif", ["1s", "10ms"])
def test_a_log_cut_in_half_is_recovered_matched_and_exported_without_a_wrong_geotag(
    flight: Flight, truth: list[dict[str, Any]], tmp_path: Path, exif: str
) -> None:
    """With 1 s EXIF times the first half of a steady 5 fps capture does not pin the camera clock against the
    whole card (a shift by a few seconds fits as well): nothing need be tagged, nothing may be wrong. With
    10 ms times the missed triggers do: most of the cut log's images are tagged, each rightly."""
    data = flight.mcap.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) // 2])
    recovered = tmp_path / "recovered.mcap"
    assert main(["recover", str(cut), str(recovered)]) in (0, 1)
    frames = list(read(recovered).frames())
    assert 10 <= len(frames) < len(truth)
    card = tmp_path / "card"
    shutil.copytree(flight.card, card)
    if exif == "10ms":
        first = flight.scenario.camera.first_file_number
        for t in truth:
            _set_time(card / f"DSC{first + t['frame_number'] - 1:05d}.JPG", *exif_strings(t["start_camera_s"], "10ms"))

    match_json = tmp_path / "match.json"
    assert main(["match", "--images", str(card), str(recovered), "--json", str(match_json)]) in (0, 2)
    report = json.loads(match_json.read_text())
    start_by_number = {t["frame_number"]: t["start_device_us"] for t in truth}
    start_by_seq = {f.frame_seq: f.start_device_us for f in frames}
    for p in report["pairs"]:
        number = read_frame_number(card / Path(p["image"]).name)
        assert start_by_seq[p["frame_seq"]] == start_by_number[number], f"{p['image']} paired with the wrong frame"

    out = tmp_path / "out"
    main(["export", str(recovered), "--images", str(card), "--out", str(out), "--no-progress"])
    with (out / "frames.csv").open(newline="", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["Filename"]]
    in_log = {t["frame_number"] for t in truth if t["start_device_us"] in set(start_by_seq.values())}
    for r in rows:
        number = read_frame_number(card / r["Filename"])
        assert number in in_log, f"{r['Filename']} geotagged though its exposure is not in the recovered log"
        assert int(r["start_device_us"]) == start_by_number[number], f"{r['Filename']} has another exposure's geotag"
    geotagged = {r["Filename"] for r in rows}
    if exif == "10ms":  # the cut log's images are tagged
        assert len(geotagged) >= 0.8 * len(in_log), (len(geotagged), len(in_log), report["notes"])
    with (out / "problems.csv").open(newline="", encoding="utf-8") as f:
        listed = {Path(r["image"]).name for r in csv.DictReader(f) if r["image"]}
    untagged = {p.name for p in card.glob("*.JPG")} - geotagged
    assert untagged <= listed, sorted(untagged - listed)[:5]
