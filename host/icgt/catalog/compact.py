"""Compaction: a structure's small per-flight files merged into a few larger GeoParquet files.

    DIR/structure=NAME/flight=ID/TABLE.parquet     one flight, as `add` wrote it
    DIR/structure=NAME/group-GID/TABLE.parquet     several flights, in flight order; GID is a content id of its
                                                   flights' revisions (no `=` in the name: readers that infer
                                                   hive partitions from the path, DuckDB's and GDAL's, would
                                                   add a column `group`)

A query pays about 0.4 ms for every Parquet file it opens, so a catalogue of one file per flight per table
answers slower the more flights it holds; a group file holds many flights at the cost of one file. Every
file is still a whole GeoParquet 1.1 file (the declared schema, WKB geometry with its PROJJSON CRS, the bbox
covering column, the `geo` extent over its flights, the schema version), so GDAL, geopandas and DuckDB read
a group's file as they read a flight's, and a flight is read from it by its `flight` column (the row groups'
statistics let readers skip the others).

A flight lives in exactly one folder of its structure, a `flight=` or a `group-` one. Compaction and the
replacement of a flight that is in a group change several folders of a structure at once, so they build
the structure's new folder whole in .staging (the folders that stay as hard links of their files, the new
groups written, fsynced and read back), check that it holds every flight of the old one exactly once with
the same revision and row counts (or the one replaced flight's new revision), and swap it with the old one
in one step (store.Catalog._swap: renameat2 RENAME_EXCHANGE, or a journal the next add completes). All of
it holds the catalogue's write lock; a kill -9 at any moment leaves the old structure folder or the new
one, and the next add removes what the killed one left in .staging.

`add` compacts a structure itself once it holds `store.COMPACT_AFTER` flights outside groups (the call that
did so says so in its result); `icgt catalog compact` does it on demand.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from icgt.catalog import CatalogError
from icgt.catalog.files import fsync_dir, read_table
from icgt.catalog.schema import SCHEMA_VERSION, SCHEMAS, TABLES, file_metadata, table_version

if TYPE_CHECKING:
    from icgt.catalog.store import Catalog

ROW_GROUP_ROWS = 65536
"""Rows per row group of a group's file: its flights in order, so a flight is in one or two row groups (the
`flight` column's statistics say which), and the footer stays small (a row group per flight would cost a
query about 0.1 ms per row group, more than the files it replaces: measured in docs/catalog.md)."""
TARGET_BYTES = 256 * 1024 * 1024
"""A group grows to about this size (all its tables); a group of half of it or more is left as it is."""

Counts = dict[str, Counter[str]]
"""Rows per flight per table."""


@dataclass(frozen=True)
class CompactResult:
    structure: str
    flights: int
    """flights in the structure (each still there once)."""
    merged: int
    """folders (flight= and group-) merged into new groups; 0: nothing to do."""
    groups: tuple[Path, ...]
    """the structure's group folders after compaction."""
    files_before: int
    files_after: int


def unit_flights(unit: Path) -> dict[str, str]:
    """The flights of a folder (a flight's or a group's) and their revisions, from its flights file."""
    t = read_table(unit / "flights.parquet").select(["flight", "revision"])
    return dict(zip(t["flight"].to_pylist(), t["revision"].to_pylist(), strict=True))


def index(units: Iterable[Path]) -> dict[str, tuple[str, Path]]:
    """Flight -> (revision, folder) over the folders of one structure; CatalogError for a flight found twice."""
    out: dict[str, tuple[str, Path]] = {}
    for unit in units:
        for flight, revision in unit_flights(unit).items():
            if flight in out:
                raise CatalogError(f"flight {flight} is in both {out[flight][1]} and {unit}")
            out[flight] = (revision, unit)
    return out


def structure_units(cat: Catalog, structure: str) -> list[Path]:
    folder = cat.root / f"structure={structure}"
    return structure_units_of(folder) if folder.is_dir() else []


def _counts(units: Iterable[Path], exclude: str | None = None) -> Counts:
    counts: Counts = {t: Counter() for t in TABLES}
    for unit in units:
        for table in TABLES:
            col = pq.read_table(unit / f"{table}.parquet", columns=["flight"])["flight"]
            counts[table].update(f for f in col.to_pylist() if f != exclude)
    return counts


def write_group(sources: Sequence[Path], out: Path, exclude: str | None = None) -> Counts:
    """Merge the folders `sources` (without flight `exclude`) into the group folder `out`: per table one file,
    its rows in flight order (each flight's own order kept), row groups of `ROW_GROUP_ROWS`, the `geo` extent
    over them; fsynced, read back and checked (rows per flight)."""
    out.mkdir()
    expected = _counts(sources, exclude)
    for table in TABLES:
        parts = [read_table(src / f"{table}.parquet") for src in sources]
        merged = pa.concat_tables([p.replace_schema_metadata(None) for p in parts])
        if exclude is not None:
            merged = merged.filter(pc.not_equal(merged["flight"], exclude))
        bbox = _extent(merged)
        merged = merged.take(pc.sort_indices(merged, [("flight", "ascending")]))  # stable: a flight's own order
        schema = SCHEMAS[table].with_metadata(file_metadata(table, bbox))
        path = out / f"{table}.parquet"
        try:
            pq.write_table(pa.Table.from_arrays(merged.columns, schema=schema), path, compression="zstd",
                           row_group_size=ROW_GROUP_ROWS)  # fmt: skip
            with path.open("rb") as f:
                os.fsync(f.fileno())
        except OSError as exc:
            raise CatalogError(f"cannot write {path}: {exc.strerror or exc}") from None
        back = read_table(path)
        got = Counter(back["flight"].to_pylist())
        if back.schema.names != SCHEMAS[table].names or got != expected[table]:
            raise CatalogError(f"{path} does not read back as written")
    fsync_dir(out)
    return expected


def _extent(table: pa.Table) -> list[float] | None:
    """The extent of a table's `geometry` column from its bbox covering column (None: no geometry)."""
    box = table["bbox"]
    lo = [pc.min(pc.struct_field(box, k)).as_py() for k in ("xmin", "ymin")]
    hi = [pc.max(pc.struct_field(box, k)).as_py() for k in ("xmax", "ymax")]
    values = lo + hi
    return None if any(v is None for v in values) else [float(v) for v in values]


def group_name(flights: dict[str, str]) -> str:
    digest = hashlib.sha256("\n".join(f"{f} {r}" for f, r in sorted(flights.items())).encode()).hexdigest()
    return f"group-{digest[:16]}"


def _link_unit(unit: Path, dest: Path) -> None:
    """`unit`'s files in `dest` as hard links (copies where the filesystem has none)."""
    dest.mkdir()
    for f in sorted(unit.iterdir()):
        try:
            os.link(f, dest / f.name)
        except OSError:
            shutil.copy2(f, dest / f.name)
    fsync_dir(dest)


def rebuild(
    cat: Catalog,
    structure: str,
    work: Path,
    *,
    merge: Sequence[Sequence[Path]] = (),
    replace: tuple[str, Path] | None = None,
) -> Path:
    """The structure's new folder built in `work` and swapped in (see the module's doc). merge: lists of
    folders, each merged into one new group; replace: (flight, its new flight folder): the flight taken out of
    the group holding it (rewritten without it) and put in its own folder. Holds no lock itself: the caller
    holds the catalogue's."""
    final = cat.root / f"structure={structure}"
    units = structure_units(cat, structure)
    before = index(units)
    expected = {f: r for f, (r, _) in before.items()}
    merged_units = {u for group in merge for u in group}
    rewrite: Path | None = None
    if replace is not None:
        flight, new_part = replace
        rewrite = before[flight][1]
        if rewrite in merged_units:
            raise CatalogError(f"{rewrite}: replaced and merged at once")
        expected.update(unit_flights(new_part))
    want = _counts(units, exclude=replace[0] if replace else None)
    if replace is not None:
        for table, c in _counts([replace[1]]).items():
            want[table].update(c)
    new = work / "structure"
    new.mkdir()
    for unit in units:
        if unit not in merged_units and unit != rewrite:
            _link_unit(unit, new / unit.name)
    for i, group in enumerate(merge):
        staged = work / f"group-{i}"
        write_group(group, staged)
        os.rename(staged, new / group_name({f: r for f, (r, _) in index(group).items()}))
    if replace is not None and rewrite is not None:
        flight, new_part = replace
        rest = {f: r for f, r in unit_flights(rewrite).items() if f != flight}
        if rest:
            staged = work / "rewritten"
            write_group([rewrite], staged, exclude=flight)
            os.rename(staged, new / group_name(rest))
        os.rename(new_part, new / f"flight={flight}")
    got = {f: r for f, (r, _) in index(structure_units_of(new)).items()}
    if got != expected:
        lost, extra = sorted(set(expected) - set(got)), sorted(set(got) - set(expected))
        raise CatalogError(f"{final}: the rebuilt structure folder differs (missing {lost}, unexpected {extra}); "
                           "nothing changed")  # fmt: skip
    if _counts(structure_units_of(new)) != want:
        raise CatalogError(f"{final}: the rebuilt structure folder's rows differ from the old one's; nothing changed")
    fsync_dir(new)
    if final.exists():
        cat._swap(final, new, work)
    else:
        os.rename(new, final)
    fsync_dir(cat.root)
    return final


def structure_units_of(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_dir() and p.name.startswith(("flight=", "group-")))


def _size(unit: Path) -> int:
    return sum(f.stat().st_size for f in unit.iterdir())


def plan(units: Sequence[Path], target_bytes: int = TARGET_BYTES) -> list[list[Path]]:
    """The groups to write: the flight folders and the groups under half the target, in name order, packed
    into groups of about `target_bytes`; a group of one folder is no group (nothing is gained)."""
    small = [u for u in units if u.name.startswith("flight=") or _size(u) < target_bytes // 2]
    small = [u for u in small if _version(u) == SCHEMA_VERSION]  # another version's folder is left as it is
    groups: list[list[Path]] = [[]]
    size = 0
    for unit in small:
        s = _size(unit)
        if groups[-1] and size + s > target_bytes:
            groups.append([])
            size = 0
        groups[-1].append(unit)
        size += s
    return [g for g in groups if len(g) >= 2]


def _version(unit: Path) -> int:
    path = unit / "flights.parquet"
    return table_version(pq.read_metadata(path).metadata, str(path))


def compact_structure(cat: Catalog, structure: str, work: Path, target_bytes: int = TARGET_BYTES) -> CompactResult:
    """Compact one structure (the caller holds the catalogue's lock; `work` is a fresh folder of .staging)."""
    units = structure_units(cat, structure)
    groups = plan(units, target_bytes)
    files_before = sum(len(list(u.glob("*.parquet"))) for u in units)
    if groups:
        rebuild(cat, structure, work, merge=groups)
    after = structure_units(cat, structure)
    return CompactResult(
        structure, len(index(after)), sum(len(g) for g in groups),
        tuple(u for u in after if u.name.startswith("group-")), files_before,
        sum(len(list(u.glob("*.parquet"))) for u in after),
    )  # fmt: skip
