"""Atomic adds: kill -9 in the middle leaves the old partition or the whole new one; two adds at once."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest
import synth_logs as sl
from conftest import SynthFlight, make_flight, snapshot

from icgt.catalog.cli import add_flight
from icgt.catalog.schema import TABLES
from icgt.catalog.store import Catalog


def _add_process(log: Path, cat: Path, *extra: str) -> subprocess.Popen[str]:
    code = "import sys; from icgt.cli import main; sys.exit(main(sys.argv[1:]))"
    args = [
        sys.executable,
        "-c",
        code,
        "-q",
        "catalog",
        "add",
        str(log),
        "--structure",
        "pier-7",
        "--catalog",
        str(cat),
    ]
    return subprocess.Popen([*args, *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(cond: object, timeout_s: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if cond():  # type: ignore[operator]
            return True
        time.sleep(0.002)
    return False


def _staged_files(cat: Path) -> list[Path]:
    return list((cat / ".staging").glob("add-*/partition/*.parquet"))


def test_kill_9_in_the_middle_of_an_add_leaves_no_partial_partition(flight_a: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    first = add_flight(cat, flight_a.log, "pier-7")
    before = snapshot(cat)
    big = make_flight(tmp_path / "big", sl.Synth(n=6000, no_pose_every=9, shift_east_m=0.3), card=False)
    # kill at three moments: while it reads the log, once the first staged file exists, once three do
    moments = [
        lambda: (cat / ".staging").is_dir() and any((cat / ".staging").glob("add-*")),
        lambda: len(_staged_files(cat)) >= 1,
        lambda: len(_staged_files(cat)) >= 3,
    ]
    killed = 0
    for moment in moments:
        proc = _add_process(big.log, cat)
        try:
            reached = _wait_for(lambda p=proc, m=moment: m() or p.poll() is not None)  # type: ignore[misc]
            assert reached
            if proc.poll() is None:
                os.kill(proc.pid, signal.SIGKILL)
                killed += 1
        finally:
            proc.wait()
        after = snapshot(cat)
        if proc.returncode == -signal.SIGKILL:
            assert after == before, "a killed add changed the visible catalogue"
        else:  # it finished before the kill: the whole new partition, nothing of the old
            assert proc.returncode == 0 and after != before
            break
    assert killed >= 1
    # the next add clears what the killed ones left and lands whole
    res = add_flight(cat, big.log, "pier-7")
    assert res.status == "replaced" and res.replaced == first.revision
    assert not any((cat / ".staging").iterdir())
    assert [len(pq.read_table(res.path / f"{t}.parquet")) for t in ("flights", "frames")] == [1, 6000]
    assert sorted(p.name for p in res.path.iterdir()) == sorted(f"{t}.parquet" for t in TABLES)


def test_two_adds_at_once_both_land(flight_a: SynthFlight, flight_b: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    Catalog(cat, create=True)
    procs = [_add_process(flight_a.log, cat), _add_process(flight_b.log, cat)]
    outs = [p.communicate(timeout=120) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    flights = sorted(pq.read_table(p / "flights.parquet")["flight"][0].as_py() for p in Catalog(cat).partitions())
    assert flights == ["1234567-00c0ffee", "7654321-0badcafe"]


def test_an_add_that_cannot_get_the_lock_is_refused_clearly(flight_a: SynthFlight, tmp_path: Path) -> None:
    cat = tmp_path / "cat"
    add_flight(cat, flight_b_log := flight_a.log, "pier-7")
    before = snapshot(cat)
    moved = make_flight(tmp_path / "moved", sl.regeotagged(flight_a.synth), card=False)
    with Catalog(cat).locked():
        proc = _add_process(moved.log, cat, "--wait-s", "0.2")
        out, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("icgt: ") and "another add is writing this catalogue" in lines[0]
    assert f"pid {os.getpid()}" in lines[0]
    assert snapshot(cat) == before
    assert add_flight(cat, flight_b_log, "pier-7").status == "unchanged"


def test_an_add_in_progress_keeps_its_work_folder_while_another_add_publishes(
    flight_a: SynthFlight, flight_b: SynthFlight, tmp_path: Path
) -> None:
    """Adds compute outside the lock: another add's recovery of .staging leaves a live add's folder alone and
    removes only the folders of adds that died (their owner lock released)."""
    import fcntl

    cat = tmp_path / "cat"
    c = Catalog(cat, create=True)
    dead = cat / ".staging" / "add-dead"
    dead.mkdir(parents=True)
    (dead / ".owner").write_text("")  # nobody holds its lock: a killed add's leftovers
    with c.work_dir(5.0) as live:
        (live / "partial.parquet").write_bytes(b"x")
        fd = os.open(live / ".owner", os.O_RDWR)
        try:  # the live add holds its owner lock
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                held = False
            except OSError:
                held = True
        finally:
            os.close(fd)
        assert held
        assert add_flight(cat, flight_b.log, "pier-7").status == "added"
        assert (live / "partial.parquet").is_file() and not dead.exists()
    assert not live.exists()
    assert add_flight(cat, flight_a.log, "pier-7").status == "added"
    assert len(Catalog(cat).partitions()) == 2 and not any((cat / ".staging").iterdir())


def test_adds_that_create_one_catalogue_at_once_all_find_it(tmp_path: Path) -> None:
    """The first tasks of an `icgt batch` into a new catalogue create it together: each must end with the one
    marker, none refused (the marker used to be written through one shared temporary name, so one creator's
    rename could find the other's file gone)."""
    import threading

    n = 8
    for k in range(40):
        root = tmp_path / f"cat{k}"
        barrier = threading.Barrier(n)
        errors: list[BaseException] = []

        def create(
            root: Path = root, barrier: threading.Barrier = barrier, errors: list[BaseException] = errors
        ) -> None:
            barrier.wait()
            try:
                Catalog(root, create=True)
            except BaseException as exc:
                errors.append(exc)

        threads = [threading.Thread(target=create) for _ in range(n)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
        assert errors == [], (k, errors)
        assert sorted(p.name for p in root.iterdir()) == ["icgt-catalog.json"], k


def test_a_failed_add_leaves_a_catalogue_another_add_filled_meanwhile(
    flight_a: SynthFlight, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A failed add removes the catalogue it created, but not once another add (a batch's other flight) has
    published into it: the partition that landed meanwhile stays."""
    from icgt.catalog import CatalogError
    from icgt.catalog import store as store_mod

    cat = tmp_path / "cat"
    real_add = store_mod.Catalog.add
    calls: list[str] = []

    def add(self: Catalog, log: Path, structure: str, **kw: object) -> object:
        calls.append(structure)
        if structure == "bad":  # while this add works, the other one lands; then this one fails
            real_add(Catalog(cat), flight_a.log, "pier-7", images=None, detections=[])  # type: ignore[arg-type]
            raise CatalogError("this flight is bad")
        return real_add(self, log, structure, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(store_mod.Catalog, "add", add)
    with pytest.raises(CatalogError, match="this flight is bad"):
        add_flight(cat, flight_a.log, "bad")
    assert calls == ["bad"]
    assert [p.relative_to(cat).as_posix() for p in Catalog(cat).partitions()] == [
        "structure=pier-7/flight=1234567-00c0ffee"
    ]
    # and alone, a failed add into a new catalogue still leaves no folder behind
    monkeypatch.setattr(store_mod.Catalog, "add", lambda *a, **k: (_ for _ in ()).throw(CatalogError("bad")))
    with pytest.raises(CatalogError):
        add_flight(tmp_path / "new", flight_a.log, "pier-7")
    assert not (tmp_path / "new").exists()
