"""`icgt batch catalog-add` on a 2-worker Dask LocalCluster: one worker killed (SIGKILL) mid-batch, every flight
still done once, the catalogue identical to the one the flights added one after the other make; a failing
flight reported and the others finished."""

from __future__ import annotations

import hashlib
import os
import signal
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import synth_logs as sl
from conftest import make_flight

from icgt.batch import BatchError, Flight, Outcome, resolve, run_batch
from icgt.catalog.cli import add_flight
from icgt.catalog.schema import TABLES
from icgt.catalog.store import Catalog
from icgt.cli import main

N_FLIGHTS = 6


@pytest.fixture(scope="module")
def cluster() -> Iterator[object]:
    from distributed import LocalCluster

    c = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
    try:
        yield c
    finally:
        c.close()


@pytest.fixture(scope="module")
def flights(tmp_path_factory: pytest.TempPathFactory) -> tuple[list[Path], Path]:
    root = tmp_path_factory.mktemp("batch")
    folders = []
    for i in range(N_FLIGHTS):
        make_flight(root / f"f{i}", sl.Synth(n=40, seed=i, serial=f"90000{i:02d}", recording_id=0x100 + i))
        folders.append(root / f"f{i}")
    bad = root / "bad" / "flight.mcap"
    bad.parent.mkdir()
    bad.write_text("not a recording\n")
    return folders, bad.parent


def _contents(cat: Path) -> dict[str, object]:
    """Every partition's files: their bytes' hash, and for flights the row without the time it was added."""
    out: dict[str, object] = {}
    for part in Catalog(cat).partitions():
        for table in TABLES:
            path = part / f"{table}.parquet"
            key = str(path.relative_to(cat))
            if table == "flights":
                row = pq.read_table(path).to_pylist()[0]
                row.pop("added_utc")
                out[key] = row
            else:
                out[key] = hashlib.sha256(path.read_bytes()).hexdigest()
    return out


def test_a_killed_worker_leaves_every_flight_done_once_as_in_a_sequential_run(
    cluster: object, flights: tuple[list[Path], Path], tmp_path: Path
) -> None:
    from distributed import Client

    folders, bad = flights
    seq = tmp_path / "seq"
    logs = [f / "flight.mcap" for f in folders]  # the logs alone: the card's and detections' work is map's
    for log in logs:
        add_flight(seq, log, "pier-7")
    par = tmp_path / "par"
    todo = [resolve(f) for f in [*logs[:3], bad / "flight.mcap", *logs[3:]]]
    result: list[list[Outcome]] = []
    address = cluster.scheduler_address  # type: ignore[attr-defined]
    runner = threading.Thread(
        target=lambda: result.append(
            run_batch(
                "catalog-add", todo, {"catalog": str(par), "structure": "pier-7"}, scheduler=address, progress=False
            )
        )
    )
    with Client(address) as client:
        runner.start()
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and not (par.is_dir() and Catalog(par).partitions()):
            time.sleep(0.01)
        published_at_kill = len(Catalog(par).partitions())
        busy = [w for w, keys in client.processing().items() if keys]
        pids = client.run(os.getpid)
        victim = pids[busy[0]] if busy else next(iter(pids.values()))
        os.kill(victim, signal.SIGKILL)
        runner.join(timeout=300)
    assert not runner.is_alive()
    assert 1 <= published_at_kill < N_FLIGHTS  # the kill came mid-batch
    outcomes = result[0]
    assert [o.flight for o in outcomes] == [f.name for f in todo]
    failed = [o for o in outcomes if not o.ok]
    assert len(failed) == 1 and failed[0].flight == "bad-flight" and "not an MCAP file" in (failed[0].error or "")
    assert all(o.result["status"] in ("added", "unchanged") for o in outcomes if o.ok)
    assert len(Catalog(par).partitions()) == N_FLIGHTS
    assert _contents(par) == _contents(seq)  # each flight once: no partition replaced (empty history), same rows
    assert all(row["replaced_revisions"] == [] for k, row in _contents(par).items() if k.endswith("flights.parquet"))  # type: ignore[index]
    assert not any(p for p in (par / ".staging").iterdir())


def test_the_cli_reports_each_flight_and_fails_when_one_did(
    cluster: object, flights: tuple[list[Path], Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folders, bad = flights
    cat = tmp_path / "cat"
    args = ["batch", "catalog-add", str(folders[0]), str(folders[1] / "flight.mcap"), str(bad / "flight.mcap"),
            "--structure", "pier-7", "--catalog", str(cat), "--scheduler", cluster.scheduler_address]  # type: ignore[attr-defined]  # fmt: skip
    code = main(args)
    out = capsys.readouterr().out.splitlines()
    assert code == 1
    assert out[0].startswith("ok      f0: status added, flight 9000000-00000100")
    assert out[1].startswith("ok      f1-flight: status added")
    assert out[2].startswith("failed  bad-flight: ") and "not an MCAP file" in out[2]
    assert out[3] == "2 of 3 flights done, 1 failed"
    assert main(args[:4] + args[5:]) == 0  # again without the bad one: nothing changes, all ok
    assert "status unchanged" in capsys.readouterr().out


def test_bad_batches_are_refused(tmp_path: Path, flights: tuple[list[Path], Path]) -> None:
    folders, _ = flights
    with pytest.raises(BatchError, match="neither a recording"):
        resolve(tmp_path / "missing")
    (tmp_path / "two").mkdir()
    for n in ("a.mcap", "b.mcap"):
        (tmp_path / "two" / n).write_text("x")
    with pytest.raises(BatchError, match="holds one recording"):
        resolve(tmp_path / "two")
    f = resolve(folders[0])
    assert f == Flight("f0", folders[0] / "flight.mcap", folders[0] / "card", (folders[0] / "detections.json",))
    with pytest.raises(BatchError, match="two flights with one name"):
        run_batch("catalog-add", [f, f], {})
    with pytest.raises(BatchError, match="no batch task"):
        run_batch("nope", [f], {})
