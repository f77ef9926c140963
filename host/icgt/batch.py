"""`icgt batch {export,map,catalog-add} FLIGHTS...`: the per-flight work of many flights on Dask distributed.

    icgt batch catalog-add flights/*/ --structure pier-7 --catalog catalog
    icgt batch export flights/*/ --out exports [--scheduler tcp://10.0.0.5:8786]

A FLIGHT is a recording (.mcap), or a folder holding one recording, optionally its camera card (a folder
named `card` or `images`) and detector output (files `detections*.json`). Each flight is one task; the tasks
run on a LocalCluster of the machine's cores (one worker process per core, one thread each), or on the
cluster whose scheduler is at `--scheduler` with the same code (its workers need icgt installed and the
flights' paths visible).

Every task is idempotent: `catalog-add` by content (the catalogue's own rule: the same flight twice
changes nothing), `export` and `map` by writing the same files into the flight's own output folder. A task
whose worker dies is run again on another worker (the scheduler's rule: up to
`distributed.scheduler.allowed-failures` times). A flight that fails is reported with its error (one line)
and the others finish; the exit status is 1 when any failed.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError

KINDS = ("export", "map", "catalog-add")


class BatchError(IcgtError):
    """A batch refused as a whole (no flights, a flight argument that is neither a log nor a flight folder, a
    scheduler that cannot be reached)."""


@dataclass(frozen=True)
class Flight:
    name: str
    log: Path
    images: Path | None = None
    detections: tuple[Path, ...] = ()


@dataclass(frozen=True)
class Outcome:
    flight: str
    ok: bool
    result: dict[str, Any] = field(default_factory=dict)
    error: str | None = None
    seconds: float = 0.0


def resolve(arg: Path) -> Flight:
    """A FLIGHT argument as its log, card and detections (see the module's doc)."""
    if arg.is_file() or arg.suffix == ".mcap":
        return Flight(arg.stem if arg.parent == Path() else f"{arg.parent.name}-{arg.stem}", arg)
    if not arg.is_dir():
        raise BatchError(f"{arg}: neither a recording (.mcap) nor a flight folder")
    logs = sorted(arg.glob("*.mcap"))
    if len(logs) != 1:
        raise BatchError(f"{arg}: a flight folder holds one recording (.mcap), this one {len(logs)}")
    card = next((arg / n for n in ("card", "images") if (arg / n).is_dir()), None)
    dets = tuple(sorted(arg.glob("detections*.json")))
    return Flight(arg.resolve().name, logs[0], card, dets)


def run_one(kind: str, flight: Flight, params: dict[str, Any]) -> Outcome:
    """One flight's task (runs on a worker). Errors of the flight are its outcome, not the task's."""
    start = time.perf_counter()
    try:
        result = _work(kind, flight, params)
    except IcgtError as exc:
        return Outcome(flight.name, False, {}, str(exc).splitlines()[0], time.perf_counter() - start)
    except OSError as exc:
        return Outcome(flight.name, False, {}, f"{exc.filename or flight.log}: {exc.strerror or exc}",
                       time.perf_counter() - start)  # fmt: skip
    return Outcome(flight.name, True, result, None, time.perf_counter() - start)


def _work(kind: str, flight: Flight, params: dict[str, Any]) -> dict[str, Any]:
    if kind == "catalog-add":
        from icgt.catalog.cli import add_flight

        r = add_flight(Path(params["catalog"]), flight.log, params["structure"], images=flight.images,
                       detections=list(flight.detections))  # fmt: skip
        return {"status": r.status, "flight": r.flight, "revision": r.revision, "path": str(r.path)}
    out = Path(params["out"]) / flight.name
    if kind == "export":
        from icgt.export.cli import run_export

        e = run_export(flight.log, out, images=flight.images)
        return {"out": str(out), "summary": e.describe().splitlines()[0] if e.describe() else ""}
    if kind == "map":
        from icgt.mapping.cli import run_map

        if flight.images is None or not flight.detections:
            raise BatchError(f"{flight.name}: map needs the flight's card and detections (card/, detections*.json)")
        m = run_map(flight.log, flight.images, list(flight.detections), out, mm_per_px=params.get("mm_per_px"))
        return {"out": str(out), "defects": len(m.instances)}
    raise BatchError(f"no batch task {kind!r}; tasks: {', '.join(KINDS)}")


def _key(kind: str, flight: Flight) -> str:
    digest = hashlib.sha256(f"{kind}\0{flight.log.resolve()}".encode()).hexdigest()[:16]
    return f"icgt-{kind}-{digest}"


def run_batch(
    kind: str,
    flights: list[Flight],
    params: dict[str, Any],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: bool | None = None,
) -> list[Outcome]:
    """Every flight's task on Dask distributed; the outcomes in the flights' order. progress: distributed's
    text progress bar (default: when the output is a terminal)."""
    import importlib
    import logging

    dist: Any = importlib.import_module("distributed")  # partly typed: used as Any

    if kind not in KINDS:
        raise BatchError(f"no batch task {kind!r}; tasks: {', '.join(KINDS)}")
    if not flights:
        raise BatchError("no flights given")
    names = [f.name for f in flights]
    if len(set(names)) != len(names):
        raise BatchError(f"two flights with one name: {sorted({n for n in names if names.count(n) > 1})}")
    cluster: Any = None
    for noisy in ("distributed", "tornado", "bokeh"):
        logging.getLogger(noisy).setLevel(logging.ERROR)
    try:
        if scheduler is None:
            n = workers or os.cpu_count() or 1
            # Without the worker's statistical profiler (it samples the task thread's stack every 10 ms for the
            # dashboard, which a LocalCluster here does not serve): measured with it, two workers on two idle
            # cores ran 1.48-1.55x one worker; without it 1.98 (benchmarks/batch_dask.py, docs/catalog.md).
            # The nanny hands the worker processes this configuration.
            dask_config: Any = importlib.import_module("dask.config")
            with dask_config.set({"distributed.worker.profile.enabled": False}):
                cluster = dist.LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None)
            client = dist.Client(cluster)
        else:
            client = dist.Client(scheduler, timeout="20s")
    except OSError as exc:
        raise BatchError(f"cannot reach the Dask scheduler {scheduler or '(local)'}: {exc}") from None
    try:
        futures = [client.submit(run_one, kind, f, params, key=_key(kind, f), pure=False) for f in flights]
        if progress if progress is not None else sys.stdout.isatty():
            importlib.import_module("distributed.diagnostics.progressbar").progress(futures, notebook=False)
            print()
        dist.wait(futures)
        out = []
        for f, fut in zip(flights, futures, strict=True):
            err = fut.exception()
            if err is None:
                out.append(fut.result())
            else:  # not the flight's error: the task's (a worker killed more often than allowed, a bug)
                out.append(
                    Outcome(f.name, False, {}, f"{type(err).__name__}: {str(err).splitlines()[0] if str(err) else ''}")
                )
        return out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def cmd_batch(args: argparse.Namespace) -> int:
    flights = [resolve(Path(a)) for a in args.flights]
    params: dict[str, Any] = {}
    if args.kind == "catalog-add":
        from icgt.catalog.files import check_structure

        if args.structure is None:
            raise BatchError("catalog-add needs --structure NAME")
        params = {"catalog": str(args.catalog), "structure": check_structure(args.structure)}
    else:
        if args.out is None:
            raise BatchError(f"{args.kind} needs --out DIR (a folder per flight inside it)")
        params = {"out": str(args.out)}
    outcomes = run_batch(args.kind, flights, params, scheduler=args.scheduler, workers=args.workers,
                         progress=False if args.no_progress else None)  # fmt: skip
    failed = 0
    for o in outcomes:
        if o.ok:
            detail = ", ".join(f"{k} {v}" for k, v in o.result.items() if k in ("status", "flight", "defects", "out"))
            print(f"ok      {o.flight}: {detail} ({o.seconds:.1f} s)")
        else:
            failed += 1
            print(f"failed  {o.flight}: {o.error}")
    print(f"{len(outcomes) - failed} of {len(outcomes)} flights done" + (f", {failed} failed" if failed else ""))
    return 1 if failed else 0


def add_batch_arguments(p: argparse.ArgumentParser) -> None:
    from icgt.catalog.cli import default_catalog

    p.add_argument("kind", choices=KINDS, help="the per-flight work")
    p.add_argument("flights", nargs="+", help="recordings (.mcap) or flight folders (log, card/, detections*.json)")
    p.add_argument("--scheduler", help="a running Dask scheduler's address (default: a LocalCluster of this machine)")
    p.add_argument("--workers", type=int, help="LocalCluster worker processes (default: the machine's cores)")
    p.add_argument("--structure", help="catalog-add: the structure the flights inspected")
    p.add_argument("--catalog", type=Path, default=default_catalog(), help="catalog-add: the catalogue folder")
    p.add_argument("--out", type=Path, help="export, map: the output folder (one folder per flight inside it)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (there is one on a terminal)")
    p.set_defaults(func=cmd_batch)
