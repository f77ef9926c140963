"""Compaction (icgt.catalog.compact): flight folders merged into group files that every reader still reads; a
compacted flight found, left unchanged and replaced; add's own compaction; a kill -9 or a failed check in the
middle leaves the old structure folder; an add while a compaction runs lands."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import geopandas as gpd
import pyarrow.parquet as pq
import pyogrio
import pytest
import shapely
import synth_logs as sl
from conftest import SynthFlight, make_flight, snapshot
from test_catalog_gdal import gdal

from icgt.catalog import CatalogError, compact, store
from icgt.catalog.cli import add_flight
from icgt.catalog.query import query
from icgt.catalog.schema import TABLES
from icgt.catalog.store import Catalog
from icgt.cli import main

ORDER = {
    "flights": "flight",
    "frames": "flight, frame_seq",
    "images": "flight, file",
    "footprints": "flight, frame_seq",
    "defects": "flight, defect_id",
}


def _views(cat: Path) -> dict[str, list[dict[str, Any]]]:
    """Every row of every view, in a fixed order (what a query sees, wherever the files are)."""
    return {t: query(cat, f"SELECT * FROM {t} ORDER BY {ORDER[t]}").to_pylist() for t in TABLES}


def _cli(*args: str) -> int:
    return main(["-q", *args])


@pytest.fixture(scope="module")
def three(flight_a: SynthFlight, flight_b: SynthFlight, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three flights of pier-7 with cards and detections, one of bridge-2, each in its own partition."""
    root = tmp_path_factory.mktemp("compact")
    c = make_flight(root / "c", sl.Synth(n=30, seed=9, serial="5550001", recording_id=0x51, no_pose_every=4))
    d = make_flight(root / "d", sl.Synth(n=12, seed=11, serial="5550002", recording_id=0x52))
    cat = root / "cat"
    for f, structure in ((flight_a, "pier-7"), (flight_b, "pier-7"), (c, "pier-7"), (d, "bridge-2")):
        add_flight(cat, f.log, structure, images=f.card, detections=[f.detections])
    return cat


def _copy(src: Path, dst: Path) -> Path:
    subprocess.run(["cp", "-a", str(src), str(dst)], check=True)
    return dst


def test_compaction_merges_a_structure_and_every_reader_reads_the_group(three: Path, tmp_path: Path) -> None:
    cat = _copy(three, tmp_path / "cat")
    before = _views(cat)
    results = {r.structure: r for r in store.compact(cat)}
    # pier-7's three partitions are one group; bridge-2's single partition is left (a group of one gains nothing)
    assert results["pier-7"].merged == 3 and results["pier-7"].files_before == 15
    assert results["pier-7"].files_after == 5 and results["pier-7"].flights == 3
    assert results["bridge-2"].merged == 0 and results["bridge-2"].files_after == 5
    cats = Catalog(cat)
    assert [p.parent.name for p in cats.groups()] == ["structure=pier-7"]
    assert [p.relative_to(cat).parts[0] for p in cats.partitions()] == ["structure=bridge-2"]
    assert not any((cat / ".staging").iterdir())
    assert _views(cat) == before  # every view's rows unchanged: none lost, none twice
    group = cats.groups()[0]
    for table in TABLES:
        path = group / f"{table}.parquet"
        t = pq.read_table(path)
        flights = t["flight"].to_pylist()
        assert flights == sorted(flights)  # in flight order, each flight's own order kept (the views above)
        geo = json.loads(t.schema.metadata[b"geo"])
        col = geo["columns"]["geometry"]
        assert geo["version"] == "1.1.0" and col["covering"]["bbox"]["xmin"] == ["bbox", "xmin"]
        wkb = [g for g in t["geometry"].to_pylist() if g is not None]
        if wkb:  # the extent over all the group's flights
            assert col["bbox"] == pytest.approx(list(shapely.total_bounds(shapely.from_wkb(wkb))), abs=1e-9)
        assert json.loads(t.schema.metadata[b"icgt.catalog"])["table"] == table
        # geopandas: the CRS and the geometries
        df = gpd.read_parquet(path)
        assert len(df) == t.num_rows and df.crs == "OGC:CRS84"
        assert [g.wkb if g is not None else None for g in df.geometry] == t["geometry"].to_pylist()
        # GDAL (its ADBC driver on DuckDB): the layer as the file declares it
        name, opts = gdal(path)
        info = pyogrio.read_info(name, **opts)
        assert info["features"] == t.num_rows and info["geometry_name"] == "geometry"
        if wkb:
            assert info["total_bounds"] == pytest.approx(tuple(col["bbox"]), abs=1e-9)
    # one flight read from the group (the reader skips the others by the flight column)
    for flight in cats.flights("pier-7"):
        got = cats.read_flight("pier-7", flight, "frames")
        assert got is not None
        want = [r for r in before["frames"] if r["flight"] == flight]
        assert sorted(got.to_pylist(), key=lambda r: r["frame_seq"]) == want
    # compacting again changes nothing
    snap = snapshot(cat)
    assert all(r.merged == 0 for r in store.compact(cat)) and snapshot(cat) == snap


def test_a_compacted_flight_is_unchanged_by_the_same_log_and_replaced_by_a_new_revision(
    three: Path, flight_a: SynthFlight, tmp_path: Path
) -> None:
    cat = _copy(three, tmp_path / "cat")
    store.compact(cat)
    snap = snapshot(cat)
    same = add_flight(cat, flight_a.log, "pier-7", images=flight_a.card, detections=[flight_a.detections])
    assert same.status == "unchanged" and snapshot(cat) == snap
    first = same.revision
    moved = make_flight(tmp_path / "moved", sl.regeotagged(flight_a.synth), card=False)
    res = add_flight(cat, moved.log, "pier-7")
    assert res.status == "replaced" and res.replaced == first
    cats = Catalog(cat)
    # the flight in a partition of its own again, the group rewritten without it; each flight once
    assert res.path == cat / "structure=pier-7" / f"flight={res.flight}"
    assert len(cats.groups()) == 1 and res.flight not in cats.groups()[0].name
    group_flights = pq.read_table(cats.groups()[0] / "flights.parquet")["flight"].to_pylist()
    assert res.flight not in group_flights and len(group_flights) == 2
    flights = query(cat, "SELECT flight, revision, replaced_revisions FROM flights ORDER BY flight").to_pylist()
    assert [r["flight"] for r in flights] == sorted({r["flight"] for r in flights}) and len(flights) == 4
    row = next(r for r in flights if r["flight"] == res.flight)
    assert row["revision"] == res.revision and row["replaced_revisions"] == [first]
    east = query(cat, f"SELECT min(east_m) AS e FROM frames WHERE flight = '{res.flight}'").to_pylist()[0]["e"]
    assert east == pytest.approx(0.3 + min(f.east_m for f in flight_a.frames if f.east_m is not None))
    n = query(cat, f"SELECT count(*) AS n FROM frames WHERE flight = '{res.flight}'").to_pylist()[0]["n"]
    assert n == len(moved.frames)
    # and back into a group, then replaced again: the history grows, the flight still once
    store.compact(cat, "pier-7")
    assert cats.partitions() == [p for p in cats.partitions() if "bridge-2" in str(p)]
    again = add_flight(cat, flight_a.log, "pier-7")
    assert again.status == "replaced"
    row = query(cat, f"SELECT replaced_revisions FROM flights WHERE flight = '{res.flight}'").to_pylist()
    assert row == [{"replaced_revisions": [first, res.revision]}]
    assert not any((cat / ".staging").iterdir())


def test_add_compacts_a_structure_past_compact_after(flight_a: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    logs = [make_flight(tmp_path / f"f{i}", sl.Synth(n=10, seed=i, serial=f"{3000000 + i}", recording_id=i + 1),
                        card=False).log for i in range(5)]  # fmt: skip
    res = [add_flight(cat, log, "pier-7", compact_after=3) for log in logs]
    assert [r.compacted for r in res] == [0, 0, 3, 0, 0]
    assert res[2].path.name.startswith("group-") and res[3].path.name.startswith("flight=")
    cats = Catalog(cat)
    assert len(cats.groups()) == 1 and len(cats.partitions()) == 2
    assert query(cat, "SELECT count(*) AS n FROM frames").to_pylist() == [{"n": 50}]
    assert _cli("catalog", "add", str(logs[4]), "--structure", "pier-7", "--catalog", str(cat)) == 0  # unchanged
    assert _cli("catalog", "compact", "--catalog", str(cat)) == 0
    assert len(cats.groups()) == 1 and cats.partitions() == []
    assert sorted(pq.read_table(cats.groups()[0] / "flights.parquet")["flight"].to_pylist()) == cats.flights("pier-7")
    assert len(cats.flights("pier-7")) == 5


def test_bad_compaction_arguments_are_refused_in_one_line(
    three: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for args, words in (
        (["--catalog", str(tmp_path / "none")], "no such catalogue"),
        (["--catalog", str(three), "--structure", "a/b"], "a structure name is"),
        (["--catalog", str(three), "--structure", "pier-8"], "no structure 'pier-8' (its structures: bridge-2, pier-7"),
    ):
        assert _cli("catalog", "compact", *args) != 0
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and words in err[0], err


def test_a_failed_check_leaves_the_structure_as_it_was(
    three: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The rebuilt folder is checked before the swap: a folder left out (a bug, a full disk) is caught."""
    cat = _copy(three, tmp_path / "cat")
    snap = snapshot(cat)
    real = compact.write_group

    def loses_a_flight(sources: Any, out: Path, exclude: str | None = None) -> Any:
        return real(sources[1:], out, exclude)

    monkeypatch.setattr(compact, "write_group", loses_a_flight)
    with pytest.raises(CatalogError, match=r"the rebuilt structure folder differs .*missing"):
        store.compact(cat, "pier-7")
    assert snapshot(cat) == snap and not any((cat / ".staging").iterdir())


def _process(*args: str) -> subprocess.Popen[str]:
    code = "import sys; from icgt.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.Popen([sys.executable, "-c", code, "-q", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Six flights of 3000 frames in partitions: a compaction long enough to be killed in the middle."""
    root = tmp_path_factory.mktemp("big")
    cat = root / "cat"
    for i in range(6):
        f = make_flight(root / f"f{i}", sl.Synth(n=3000, seed=i, serial=f"{4000000 + i}", recording_id=i + 1,
                                                  no_pose_every=7), card=False)  # fmt: skip
        add_flight(cat, f.log, "pier-7")
    return cat


def test_kill_9_in_the_middle_of_a_compaction_leaves_the_old_folder_or_the_new(big: Path, tmp_path: Path) -> None:
    cat = _copy(big, tmp_path / "cat")
    before_snap, before_views = snapshot(cat), _views(cat)
    staging = cat / ".staging"
    moments = [  # once its work folder exists, once the first group file is written, once four are
        lambda: any(staging.glob("add-*/s0")),
        lambda: any(staging.glob("add-*/s0/group-0/*.parquet")),
        lambda: len(list(staging.glob("add-*/s0/group-0/*.parquet"))) >= 4,
    ]
    killed = 0
    for moment in moments:
        proc = _process("catalog", "compact", "--catalog", str(cat))
        try:
            deadline = time.monotonic() + 120
            while not moment() and proc.poll() is None and time.monotonic() < deadline:
                time.sleep(0.002)
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
                killed += 1
        finally:
            proc.wait()
        if proc.returncode == -signal.SIGKILL:
            assert snapshot(cat) == before_snap, "a killed compaction changed the visible catalogue"
        else:  # it finished first: the whole new folder
            assert proc.returncode == 0 and len(Catalog(cat).groups()) == 1
            break
    assert killed >= 1
    # the next compaction clears what the killed ones left and lands whole, every row once
    store.compact(cat)
    assert not any(staging.iterdir()) and len(Catalog(cat).groups()) == 1 and Catalog(cat).partitions() == []
    assert _views(cat) == before_views


def test_an_add_while_a_compaction_runs_lands_and_nothing_is_lost(big: Path, tmp_path: Path) -> None:
    cat = _copy(big, tmp_path / "cat")
    before = _views(cat)
    new = make_flight(tmp_path / "new", sl.Synth(n=500, seed=99, serial="4999999", recording_id=0x99), card=False)
    procs = [_process("catalog", "compact", "--catalog", str(cat)),
             _process("catalog", "add", str(new.log), "--structure", "pier-7", "--catalog", str(cat))]  # fmt: skip
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    after = _views(cat)
    flights = [r["flight"] for r in after["flights"]]
    assert flights == sorted(set(flights)) and len(flights) == 7
    assert [r for r in after["frames"] if r["flight"] != "4999999-00000099"] == before["frames"]
    assert sum(r["flight"] == "4999999-00000099" for r in after["frames"]) == 500
    assert not any((cat / ".staging").iterdir())
