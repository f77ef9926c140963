"""`icgt catalog add` and `icgt catalog query`: the command-line side of the catalogue (icgt.catalog)."""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

from icgt.catalog import CatalogError

FORMATS = ("table", "csv", "parquet", "json")


def default_catalog() -> Path:
    """$ICGT_CATALOG, else ./catalog."""
    return Path(os.environ.get("ICGT_CATALOG", "catalog"))


def add_flight(
    root: Path,
    log: Path,
    structure: str,
    *,
    images: Path | None = None,
    detections: list[Path] | None = None,
    wait_s: float | None = None,
    compact_after: int | None = None,
) -> Any:
    """Add one flight to the catalogue at `root` (created if missing or empty); a catalogue this call created is
    removed again when the add fails, so a failed add leaves the folder as it was."""
    from icgt.catalog.files import check_structure
    from icgt.catalog.store import COMPACT_AFTER, DEFAULT_WAIT_S, Catalog

    check_structure(structure)
    existed = root.exists()
    try:
        cat = Catalog(root, create=True)
        return cat.add(log, structure, images=images, detections=detections or [],
                       wait_s=DEFAULT_WAIT_S if wait_s is None else wait_s,
                       compact_after=COMPACT_AFTER if compact_after is None else compact_after)  # fmt: skip
    except BaseException:
        if not existed and root.is_dir():
            _remove_if_still_empty(root)
        raise


def _remove_if_still_empty(root: Path) -> None:
    """Remove the catalogue a failed add created, unless another add (an `icgt batch` of flights into a new
    catalogue) has put anything into it since: checked under its write lock, which adds take to start their work
    folder and to publish, so none is doing either meanwhile."""
    from icgt.catalog.store import LOCK, MARKER, STAGING, Catalog

    try:
        cat = Catalog(root)
        with cat.locked(wait_s=0.0):
            staging = root / STAGING
            if {p.name for p in root.iterdir()} <= {MARKER, LOCK, STAGING} and not (
                staging.is_dir() and any(staging.iterdir())
            ):
                shutil.rmtree(root, ignore_errors=True)
    except CatalogError:  # another add holds the lock (its catalogue now: left alone), or no marker was written
        with contextlib.suppress(OSError):
            root.rmdir()  # only if empty


def cmd_add(args: argparse.Namespace) -> int:
    result = add_flight(
        args.catalog, args.log, args.structure, images=args.images, detections=args.detections, wait_s=args.wait_s
    )
    if result.status == "unchanged":
        print(f"{args.log}: already in {args.catalog} as {result.structure}/{result.flight} "
              f"(revision {result.revision}): nothing changed")  # fmt: skip
    else:
        rows = ", ".join(f"{n} {k}" for k, n in result.rows.items())
        how = f"replaced revision {result.replaced}" if result.replaced else "added"
        print(f"{args.log}: {how} -> {result.path} (revision {result.revision}; {rows})")
        if result.compacted:
            print(f"{args.catalog}: {result.compacted} folders of {result.structure} compacted into {result.path.name}")
    return 0


def cmd_compact(args: argparse.Namespace) -> int:
    from icgt.catalog.store import compact

    for r in compact(args.catalog, args.structure, target_bytes=int(args.target_mb * 1024 * 1024), wait_s=args.wait_s):
        if r.merged:
            print(f"{r.structure}: {r.merged} folders merged into groups; {r.flights} flights, "
                  f"{r.files_before} files -> {r.files_after}")  # fmt: skip
        else:
            print(f"{r.structure}: nothing to compact ({r.flights} flights, {r.files_after} files)")
    return 0


def cmd_query(args: argparse.Namespace) -> int:
    from icgt.catalog.query import format_table, query

    table = query(args.catalog, args.sql)
    fmt = args.format
    if fmt in ("parquet",) and args.out is None:
        raise CatalogError("--format parquet needs --out FILE")
    if fmt == "table":
        text = format_table(table, max_rows=args.max_rows) + "\n"
    elif fmt == "csv":
        text = _csv(table)
    elif fmt == "json":
        text = json.dumps(_json_rows(table), indent=1, default=str) + "\n"
    else:
        import pyarrow.parquet as pq

        try:
            pq.write_table(table, args.out)
        except OSError as exc:
            raise CatalogError(f"cannot write {args.out}: {exc.strerror or exc}") from None
        print(f"{table.num_rows} rows written to {args.out}")
        return 0
    if args.out is None:
        sys.stdout.write(text)
    else:
        try:
            Path(args.out).write_text(text, encoding="utf-8")
        except OSError as exc:
            raise CatalogError(f"cannot write {args.out}: {exc.strerror or exc}") from None
        print(f"{table.num_rows} rows written to {args.out}")
    return 0


def _csv(table: Any) -> str:
    import io

    import pyarrow as pa
    import pyarrow.csv as pacsv

    cols = []
    for name in table.column_names:
        col = table[name]
        if pa.types.is_binary(col.type) or pa.types.is_nested(col.type):
            cols.append(pa.array([_plain(v) for v in col.to_pylist()], type=pa.string()))
        else:
            cols.append(col)
    buf = io.BytesIO()
    pacsv.write_csv(pa.table(cols, names=table.column_names), buf)
    return buf.getvalue().decode()


def _plain(v: Any) -> Any:
    if v is None:
        return None
    if isinstance(v, bytes):
        import shapely

        return shapely.from_wkb(v).wkt
    return json.dumps(v, default=str)


def _json_rows(table: Any) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = table.to_pylist()
    for r in rows:
        for k, v in r.items():
            if isinstance(v, bytes):
                import shapely

                r[k] = shapely.from_wkb(v).wkt
    return rows


def add_catalog_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="catalog_command", required=True, metavar="{add,query,compact}")
    add = sub.add_parser("add", help="add a flight (log, card, detections) to the catalogue")
    add.add_argument("log", type=Path, help="the recording (.mcap)")
    add.add_argument("--structure", required=True, help="the structure inspected (a partition name)")
    add.add_argument("--images", type=Path, help="folder of the camera card's JPEGs")
    add.add_argument("--detections", type=Path, nargs="+", default=[], help="detector output for the damage map")
    add.add_argument("--catalog", type=Path, default=default_catalog(), help="the catalogue folder ($ICGT_CATALOG)")
    add.add_argument("--wait-s", type=float, default=None, help="wait this long for another add's lock [s] (60)")
    add.set_defaults(func=cmd_add)
    q = sub.add_parser("query", help="run SQL (DuckDB, spatial) over the whole catalogue")
    q.add_argument("sql", help="the query; views: flights, frames, images, footprints, defects")
    q.add_argument("--catalog", type=Path, default=default_catalog(), help="the catalogue folder ($ICGT_CATALOG)")
    q.add_argument("--format", choices=FORMATS, default="table", help="table (default), csv, parquet or json")
    q.add_argument("--out", type=Path, help="write to this file instead of the terminal")
    q.add_argument("--max-rows", type=int, default=50, help="rows printed in table format (50)")
    q.set_defaults(func=cmd_query)
    c = sub.add_parser("compact", help="merge each structure's per-flight files into a few larger ones")
    c.add_argument("--catalog", type=Path, default=default_catalog(), help="the catalogue folder ($ICGT_CATALOG)")
    c.add_argument("--structure", help="only this structure (default: every one)")
    c.add_argument("--target-mb", type=float, default=256.0, help="a group's size to aim at [MiB] (256)")
    c.add_argument("--wait-s", type=float, default=None, help="wait this long for an add's lock [s] (60)")
    c.set_defaults(func=cmd_compact)
