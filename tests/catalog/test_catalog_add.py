"""`icgt catalog add`: round trip against icgt.read, idempotence, replacement with history, bad inputs."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import synth_logs as sl
from conftest import SynthFlight, make_flight, snapshot
from mcap.reader import make_reader

import icgt
from icgt.catalog import CatalogError
from icgt.catalog.cli import add_flight
from icgt.catalog.schema import SCHEMA_VERSION, TABLES
from icgt.catalog.store import Catalog
from icgt.cli import main
from icgt.geotag import FrameRecord

FIELDS = [f.name for f in dataclasses.fields(FrameRecord)]


def _frames_back(path: Path) -> list[FrameRecord]:
    rows = pq.read_table(path, columns=FIELDS).to_pylist()
    return [FrameRecord(**r) for r in rows]


def test_every_frame_field_round_trips_equal_to_icgt_read(flight_a: SynthFlight, tmp_path: Path) -> None:
    res = add_flight(tmp_path / "cat", flight_a.log, "pier-7")
    assert res.status == "added" and res.rows["frames"] == 40
    back = _frames_back(res.path / "frames.parquet")
    read = list(icgt.read(flight_a.log).frames())
    assert len(back) == len(read) == 40
    for b, r in zip(back, read, strict=True):
        for name in FIELDS:
            vb, vr = getattr(b, name), getattr(r, name)
            assert type(vb) is type(vr) and (vb == vr or (isinstance(vr, float) and math.isnan(vr))), (name, vb, vr)
    no_pose = [b for b in back if "no_pose" in b.flags]
    assert len(no_pose) == 4 and all(b.lat_deg is None and b.pose_gap_before_ms == math.inf for b in no_pose)


def test_files_carry_the_schema_version_units_and_geoparquet_metadata(flight_a: SynthFlight, tmp_path: Path) -> None:
    res = add_flight(tmp_path / "cat", flight_a.log, "pier-7", images=flight_a.card)
    for table in TABLES:
        f = pq.ParquetFile(res.path / f"{table}.parquet")
        meta = f.schema_arrow.metadata
        assert json.loads(meta[b"icgt.catalog"])["schema_version"] == SCHEMA_VERSION
        geo = json.loads(meta[b"geo"])
        assert geo["version"] == "1.1.0" and geo["primary_column"] == "geometry"
        col = geo["columns"]["geometry"]
        assert col["encoding"] == "WKB" and col["crs"]["id"] == {"authority": "OGC", "code": "CRS84"}
        assert col["covering"]["bbox"]["xmin"] == ["bbox", "xmin"]
    frames = pq.read_table(res.path / "frames.parquet")
    assert frames.schema.field("range_m").metadata[b"unit"] == b"m"
    assert frames.schema.field("mid_host_uncertainty_ns").metadata[b"unit"] == b"ns"
    bbox = json.loads(frames.schema.metadata[b"geo"])["columns"]["geometry"]["bbox"]
    lons = [f.lon_deg for f in flight_a.frames if f.lon_deg is not None]
    assert bbox[0] == min(lons) and bbox[2] == max(lons)
    flights = pq.read_table(res.path / "flights.parquet").to_pylist()[0]
    assert flights["frames"] == 40 and flights["frames_without_pose"] == 4 and flights["lost_exposures"] == 2
    assert flights["images"] == 40 and flights["images_paired"] == 40 and flights["footprints"] == 36
    assert flights["device_serial"] == "1234567" and flights["recording_id"] == "0x00C0FFEE"
    assert flights["autopilot"] == "MAV_AUTOPILOT_PX4" and flights["year"] == 2025


def test_the_same_log_twice_changes_nothing(flight_a: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    first = add_flight(cat, flight_a.log, "pier-7", images=flight_a.card)
    before = snapshot(cat)
    mtimes = {p: p.stat().st_mtime_ns for p in cat.rglob("*.parquet")}
    again = add_flight(cat, flight_a.log, "pier-7", images=flight_a.card)
    assert again.status == "unchanged" and again.revision == first.revision
    assert snapshot(cat) == before
    assert {p: p.stat().st_mtime_ns for p in cat.rglob("*.parquet")} == mtimes


def test_a_regeotagged_log_replaces_its_partition_and_keeps_the_old_id(flight_a: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    first = add_flight(cat, flight_a.log, "pier-7")
    moved = make_flight(tmp_path / "moved", sl.regeotagged(flight_a.synth), card=False)
    second = add_flight(cat, moved.log, "pier-7")
    assert second.status == "replaced" and second.flight == first.flight and second.replaced == first.revision
    assert len(Catalog(cat).partitions()) == 1
    row = pq.read_table(second.path / "flights.parquet").to_pylist()[0]
    assert row["revision"] == second.revision and row["replaced_revisions"] == [first.revision]
    east = [f.east_m for f in _frames_back(second.path / "frames.parquet") if f.east_m is not None]
    assert east[0] == pytest.approx(0.3)
    third = add_flight(cat, flight_a.log, "pier-7")  # back to the first revision: both earlier ones in the history
    row = pq.read_table(third.path / "flights.parquet").to_pylist()[0]
    assert third.status == "replaced" and row["replaced_revisions"] == [first.revision, second.revision]
    assert not any((cat / ".staging").iterdir())


def test_card_and_detections_give_images_footprints_and_defects(flight_a: SynthFlight, tmp_path: Path) -> None:
    res = add_flight(tmp_path / "cat", flight_a.log, "pier-7", images=flight_a.card, detections=[flight_a.detections])
    images = pq.read_table(res.path / "images.parquet").to_pylist()
    assert len(images) == 40 and sum(r["verdict"] == "paired" for r in images) == 40
    paired = {r["file"]: r["frame_seq"] for r in images if r["verdict"] == "paired"}
    assert paired["DSC00005.JPG"] == 5
    assert all(len(r["sha256"]) == 64 for r in images)
    fps = pq.read_table(res.path / "footprints.parquet").to_pylist()
    assert len(fps) == 36 and all(r["geometry"] and r["geometry_face"] and r["area_m2"] > 0 for r in fps)
    defects = pq.read_table(res.path / "defects.parquet").to_pylist()
    assert len(defects) == 1 and defects[0]["kind"] == "crack" and defects[0]["length_mm"] > 0
    assert sorted(defects[0]["images"]) == ["DSC00005.JPG", "DSC00006.JPG"]
    assert res.rows["defects"] == 1


# --- bad input: one line, exit != 0, the catalogue as it was ------------------------------------------


def _cli(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str]:
    code = main(args)
    err = capsys.readouterr().err.strip().splitlines()
    err = [line for line in err if " INFO " not in line]  # log lines are not the error
    assert len(err) == 1, err
    return code, err[0]


@pytest.fixture
def populated(flight_a: SynthFlight, tmp_path: Path) -> Path:
    cat = tmp_path / "cat"
    add_flight(cat, flight_a.log, "pier-7", images=flight_a.card)
    return cat


def test_bad_inputs_are_refused_in_one_line_and_leave_the_catalogue_as_it_was(
    flight_a: SynthFlight, populated: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    before = snapshot(populated)
    text = tmp_path / "notes.mcap"
    text.write_text("not a recording\n")
    damaged = tmp_path / "damaged.mcap"
    data = bytearray(flight_a.log.read_bytes())
    with flight_a.log.open("rb") as f:
        chunk = max(make_reader(f).get_summary().chunk_indexes, key=lambda c: c.chunk_length)
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2  # inside the frames' compressed chunk
    data[mid : mid + 64] = bytes(64)
    damaged.write_bytes(bytes(data))
    other = make_flight(tmp_path / "other", sl.Synth(seed=7, recording_id=0x77))
    cases = [
        ([str(text)], r"not an MCAP file"),
        ([str(damaged)], r"damaged recording"),
        ([str(flight_a.log), "--images", str(other.card)], r"card of another flight"),
        ([str(tmp_path / "missing.mcap")], r"no such file"),
    ]
    for extra, pattern in cases:
        code, line = _cli(["catalog", "add", *extra, "--structure", "pier-7", "--catalog", str(populated)], capsys)
        assert code != 0 and line.startswith("icgt: ") and __import__("re").search(pattern, line), (extra, line)
        assert snapshot(populated) == before, extra
    for name in ("../escape", "a/b", ".hidden", "x=y", ""):
        code, line = _cli(["catalog", "add", str(flight_a.log), "--structure", name, "--catalog", str(populated)],
                          capsys)  # fmt: skip
        assert code != 0 and "structure name" in line, line
        assert snapshot(populated) == before
    assert not (tmp_path / "escape").exists()


def test_a_folder_that_is_not_a_catalogue_is_refused(
    flight_a: SynthFlight, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "photos"
    folder.mkdir()
    (folder / "holiday.jpg").write_bytes(b"x")
    code, line = _cli(["catalog", "add", str(flight_a.log), "--structure", "p", "--catalog", str(folder)], capsys)
    assert code != 0 and "not an icgt catalogue" in line
    assert sorted(p.name for p in folder.iterdir()) == ["holiday.jpg"]
    # a catalogue that did not exist and whose first add fails is not left behind
    missing = tmp_path / "new-cat"
    code, line = _cli(["catalog", "add", str(tmp_path / "nope.mcap"), "--structure", "p", "--catalog", str(missing)],
                      capsys)  # fmt: skip
    assert code != 0 and not missing.exists()


def test_a_catalogue_of_another_version_is_refused_naming_both(
    flight_a: SynthFlight, populated: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from icgt.catalog.query import query

    marker = populated / "icgt-catalog.json"
    good = marker.read_text()
    marker.write_text(json.dumps({"format": "icgt-catalog", "schema_version": 99}))
    with pytest.raises(CatalogError, match=rf"schema version 99, this icgt writes version {SCHEMA_VERSION}"):
        add_flight(populated, flight_a.log, "pier-7")
    code, line = _cli(["catalog", "query", "SELECT 1", "--catalog", str(populated)], capsys)
    assert code != 0 and "version 99" in line and f"version {SCHEMA_VERSION}" in line
    marker.write_text(good)
    # one partition written by another version: the query is refused naming the file and both versions
    path = next(populated.rglob("flights.parquet"))
    table = pq.read_table(path)
    meta = dict(table.schema.metadata)
    meta[b"icgt.catalog"] = json.dumps({"schema_version": 7, "table": "flights"}).encode()
    pq.write_table(table.replace_schema_metadata(meta), path)
    with pytest.raises(CatalogError, match=rf"{path.name}: written with catalogue schema version 7"):
        query(populated, "SELECT count(*) FROM frames")
