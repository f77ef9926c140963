"""The catalogue folder: its marker, its lock, staging and the atomic publication of a flight's partition.

    DIR/icgt-catalog.json                          the marker: format and schema version
    DIR/.lock                                      held (flock) by the add writing; its pid inside
    DIR/.staging/add-*/                            adds in progress, each flock'd by its add (a killed one's
                                                   leftovers are removed by the next add)
    DIR/structure=NAME/flight=ID/TABLE.parquet     the partitions, TABLE in flights frames images footprints defects
    DIR/structure=NAME/group-GID/TABLE.parquet     several flights' partitions compacted into one (compact.py)

A flight's tables are computed outside the lock (adds of several flights run in parallel); then, holding
the lock, its partition is written whole into DIR/.staging, read back, and renamed into place: one rename, so a
reader (or a kill -9) sees the flight's old partition or its new one, never part of one. A partition
replaced by a new revision of its flight is swapped in one step where the filesystem can (Linux
renameat2 RENAME_EXCHANGE); elsewhere the old one is moved aside and the new one in, with a journal in
.staging that the next add completes if it was interrupted between the two. Two adds at once: the
second waits for the lock (`wait_s`), then is refused naming the holder. A flight in a group (compact.py)
is replaced by rebuilding its structure's folder: the group rewritten without it, its new partition beside.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
import fcntl
import json
import logging
import os
import shutil
import time
import uuid
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from icgt.catalog import CatalogError
from icgt.catalog.collect import FlightTables, collect, identify
from icgt.catalog.compact import TARGET_BYTES, CompactResult, compact_structure, rebuild
from icgt.catalog.files import check_structure, fsync_dir, read_table
from icgt.catalog.schema import SCHEMA_VERSION, SCHEMAS, TABLES, check_version

log = logging.getLogger(__name__)

MARKER = "icgt-catalog.json"
FORMAT = "icgt-catalog"
LOCK = ".lock"
STAGING = ".staging"
OWNER = ".owner"
DEFAULT_CATALOG = Path("catalog")
DEFAULT_WAIT_S = 60.0
"""How long an add waits for another add holding the catalogue's lock before it is refused [s]."""
COMPACT_AFTER = 32
"""An add compacts its structure once this many of its flights are in partitions of their own (compact.py)."""


def partition(root: Path, structure: str, flight: str) -> Path:
    return root / f"structure={structure}" / f"flight={flight}"


@dataclass(frozen=True)
class AddResult:
    structure: str
    flight: str
    revision: str
    status: str
    """added, replaced (a new revision of a flight already there) or unchanged (the same content)."""
    replaced: str | None
    rows: dict[str, int]
    path: Path
    """the folder holding the flight: its partition, or the group the add compacted it into."""
    compacted: int = 0
    """folders this add compacted into groups (compact.py; 0: none)."""


class Catalog:
    """A catalogue folder (created by the first add into an empty or missing folder)."""

    def __init__(self, root: Path, *, create: bool = False) -> None:
        self.root = root
        marker = root / MARKER
        if not root.exists():
            if not create:
                raise CatalogError(f"{root}: no such catalogue")
            try:
                root.mkdir(parents=True, exist_ok=True)  # another add may be creating it at the same time
            except OSError as exc:
                raise CatalogError(f"cannot create the catalogue {root}: {exc.strerror or exc}") from None
        if not root.is_dir():
            raise CatalogError(f"{root}: not a folder, so not a catalogue")
        if not marker.exists():
            if not create:
                raise CatalogError(
                    f"{root}: not an icgt catalogue (no {MARKER}; a new catalogue needs an empty or missing folder)"
                )
            self._create(root, marker)
        self.version = self._read_marker(marker)

    @staticmethod
    def _create(root: Path, marker: Path) -> None:
        """Write the marker into an empty folder. Adds that create one catalogue at the same time (`icgt batch`'s
        first tasks) take turns on a flock of the folder itself, so one writes the marker and the others find
        it; a marker's temporary file left by a killed creator does not make the folder someone else's."""
        try:
            fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
        except OSError as exc:
            raise CatalogError(f"cannot create the catalogue {root}: {exc.strerror or exc}") from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            if marker.exists():
                return
            tmp = marker.with_name(marker.name + ".tmp")
            if any(p != tmp for p in root.iterdir()):
                raise CatalogError(
                    f"{root}: not an icgt catalogue (no {MARKER}; a new catalogue needs an empty or missing folder)"
                )
            tmp.write_text(json.dumps({"format": FORMAT, "schema_version": SCHEMA_VERSION}, indent=1) + "\n")
            os.replace(tmp, marker)
        except OSError as exc:
            raise CatalogError(f"cannot create the catalogue {root}: {exc.strerror or exc}") from None
        finally:
            os.close(fd)  # releases the flock

    @staticmethod
    def _read_marker(marker: Path) -> int:
        try:
            data = json.loads(marker.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise CatalogError(f"{marker}: unreadable catalogue marker ({exc})") from None
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise CatalogError(f"{marker}: not an icgt catalogue marker (format {FORMAT!r} expected)")
        return check_version(data.get("schema_version"), str(marker.parent))

    # --- reading -------------------------------------------------------------------------------------
    def partitions(self) -> list[Path]:
        """The folders of one flight each (`structure=*/flight=*`)."""
        return sorted(p for p in self.root.glob("structure=*/flight=*") if p.is_dir())

    def groups(self) -> list[Path]:
        """The folders of compacted flights (`structure=*/group-*`, compact.py)."""
        return sorted(p for p in self.root.glob("structure=*/group-*") if p.is_dir())

    def units(self) -> list[Path]:
        """Every folder holding flights: partitions and groups."""
        return sorted(self.partitions() + self.groups())

    def files(self, table: str) -> list[Path]:
        if table not in TABLES:
            raise CatalogError(f"no table {table!r}; tables: {', '.join(TABLES)}")
        return [p / f"{table}.parquet" for p in self.units() if (p / f"{table}.parquet").is_file()]

    def locate(self, structure: str, flight: str) -> Path | None:
        """The folder holding the flight (its partition, or the group it was compacted into), None if none."""
        own = partition(self.root, structure, flight)
        if (own / "flights.parquet").is_file():
            return own
        for group in sorted((self.root / f"structure={structure}").glob("group-*")):
            path = group / "flights.parquet"
            if path.is_file() and flight in read_table(path, columns=["flight"])["flight"].to_pylist():
                return group
        return None

    def flights(self, structure: str) -> list[str]:
        """The flight ids of a structure, sorted."""
        out: list[str] = []
        folder = self.root / f"structure={structure}"
        for unit in sorted(p for p in folder.glob("*") if p.name.startswith(("flight=", "group-"))):
            if (unit / "flights.parquet").is_file():
                out += read_table(unit / "flights.parquet", columns=["flight"])["flight"].to_pylist()
        return sorted(out)

    def read_flight(self, structure: str, flight: str, table: str) -> pa.Table | None:
        """One flight's rows of a table (from its partition or its group), None if the flight is not there."""
        if table not in TABLES:
            raise CatalogError(f"no table {table!r}; tables: {', '.join(TABLES)}")
        unit = self.locate(structure, flight)
        if unit is None:
            return None
        return read_table(unit / f"{table}.parquet", filters=[("flight", "=", flight)])

    def flight_row(self, structure: str, flight: str) -> dict[str, object] | None:
        t = self.read_flight(structure, flight, "flights")
        rows = [] if t is None else t.to_pylist()
        return rows[0] if rows else None

    # --- writing -------------------------------------------------------------------------------------
    @contextmanager
    def locked(self, wait_s: float = DEFAULT_WAIT_S) -> Iterator[None]:
        """Hold the catalogue's write lock (flock: released by the kernel when the holder dies, even by kill -9)."""
        path = self.root / LOCK
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            deadline = time.monotonic() + wait_s
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except OSError as exc:
                    if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):
                        raise CatalogError(f"cannot lock {path}: {exc.strerror}") from None
                    if time.monotonic() >= deadline:
                        holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
                        raise CatalogError(
                            f"{self.root}: another add is writing this catalogue ({holder}); waited {wait_s:g} s, "
                            "nothing written: try again when it has finished"
                        ) from None
                    time.sleep(0.05)
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()} since {time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())}".encode(), 0)
            self._recover()
            yield
        finally:
            os.close(fd)  # releases the lock

    def _staging(self) -> Path:
        d = self.root / STAGING
        d.mkdir(exist_ok=True)
        return d

    def _recover(self) -> None:
        """Complete an interrupted replacement (its journal) and remove what killed adds left in .staging."""
        staging = self._staging()
        for journal in sorted(staging.glob("replace-*.json")):
            try:
                j = json.loads(journal.read_text())
                final, new, old = Path(j["final"]), Path(j["new"]), Path(j["old"])
            except (OSError, ValueError, KeyError):
                journal.unlink(missing_ok=True)
                continue
            if not final.exists() and new.exists():
                os.rename(new, final)
                log.info("completed the interrupted replacement of %s", final)
            elif not final.exists() and old.exists():
                os.rename(old, final)
            journal.unlink()
        for leftover in staging.iterdir():
            if leftover.is_dir():
                if _alive(leftover / OWNER):
                    continue  # another add working on its flight, outside the lock
                shutil.rmtree(leftover, ignore_errors=True)
            else:
                leftover.unlink(missing_ok=True)

    def add(
        self,
        log_path: Path,
        structure: str,
        *,
        images: Path | None = None,
        detections: Sequence[Path] = (),
        wait_s: float = DEFAULT_WAIT_S,
        compact_after: int = COMPACT_AFTER,
    ) -> AddResult:
        """Add one flight (see the module's doc); the catalogue is unchanged by any error. Once the structure
        holds `compact_after` partitions (0: never), they are compacted into groups (compact.py)."""
        check_structure(structure)
        ident = identify(log_path, images=images, detections=detections)
        final = partition(self.root, structure, ident.flight)
        old = self.flight_row(structure, ident.flight)
        if old is not None and old.get("revision") == ident.revision:
            return AddResult(structure, ident.flight, ident.revision, "unchanged", None, {}, final)
        # the work (reading the log, the matcher, the damage map) runs outside the lock, so adds of several
        # flights run in parallel; only the publication is one at a time
        with self.work_dir(wait_s) as work:
            tables = collect(log_path, structure, ident, detections=detections, work_dir=work)
            with self.locked(wait_s):
                old = self.flight_row(structure, ident.flight)  # another add may have published it meanwhile
                if old is not None and old.get("revision") == ident.revision:
                    return AddResult(structure, ident.flight, ident.revision, "unchanged", None, {}, final)
                if old is not None:
                    history = [*list(old.get("replaced_revisions") or []), str(old["revision"])]  # type: ignore[call-overload]
                    tables = _with_history(tables, history)
                part = work / "partition"
                part.mkdir()
                rows = write_partition(part, tables)
                final.parent.mkdir(parents=True, exist_ok=True)
                if old is None:
                    os.rename(part, final)
                elif (final / "flights.parquet").is_file():
                    self._swap(final, part, work)
                else:  # compacted into a group: the structure's folder rebuilt, the group without it
                    rebuild(self, structure, work, replace=(ident.flight, part))
                fsync_dir(final.parent)
                merged = 0
                if compact_after > 0 and len(list(final.parent.glob("flight=*"))) >= compact_after:
                    (work / "compact").mkdir()
                    merged = compact_structure(self, structure, work / "compact").merged
                    final = self.locate(structure, ident.flight) or final
        return AddResult(
            structure, ident.flight, ident.revision, "added" if old is None else "replaced",
            None if old is None else str(old["revision"]), rows, final, merged,
        )  # fmt: skip

    @contextmanager
    def work_dir(self, wait_s: float) -> Iterator[Path]:
        """A private folder in .staging, flock'd by this add while it lives (so a concurrent add's recovery
        leaves it alone, and removes it once a kill -9 has released the lock); removed at the end. Made under
        the catalogue's lock, as recoveries run, so none sees it before its owner file is locked."""
        with self.locked(wait_s):
            work = self._staging() / f"add-{uuid.uuid4().hex}"
            work.mkdir()
            fd = os.open(work / OWNER, os.O_RDWR | os.O_CREAT, 0o644)
            fcntl.flock(fd, fcntl.LOCK_EX)
        try:
            yield work
        finally:
            shutil.rmtree(work, ignore_errors=True)
            os.close(fd)

    def _swap(self, final: Path, new: Path, work: Path) -> None:
        if _exchange(new, final):
            return  # `new` now holds the old partition, removed with `work`
        old = work / "replaced"
        journal = self._staging() / f"replace-{uuid.uuid4().hex}.json"
        journal.write_text(json.dumps({"final": str(final), "new": str(new), "old": str(old)}))
        fsync_dir(journal.parent)
        os.rename(final, old)
        os.rename(new, final)
        journal.unlink()


def _with_history(t: FlightTables, history: list[str]) -> FlightTables:
    flights = t.tables["flights"]
    idx = flights.schema.get_field_index("replaced_revisions")
    col = pa.array([history], type=flights.schema.field(idx).type)
    tables = dict(t.tables)
    tables["flights"] = flights.set_column(idx, flights.schema.field(idx), col)
    return FlightTables(t.structure, t.flight, t.revision, tables)


def write_partition(folder: Path, tables: FlightTables) -> dict[str, int]:
    """Write every table of the flight into `folder`, fsynced, and read each back (rows and schema)."""
    rows: dict[str, int] = {}
    for name in TABLES:
        table = tables.tables[name]
        path = folder / f"{name}.parquet"
        try:
            pq.write_table(table, path, compression="zstd")
            with path.open("rb") as f:
                os.fsync(f.fileno())
        except OSError as exc:
            raise CatalogError(f"cannot write {path}: {exc.strerror or exc}") from None
        back = read_table(path)
        if back.num_rows != table.num_rows or back.schema.names != SCHEMAS[name].names:
            raise CatalogError(f"{path} does not read back as written")
        rows[name] = back.num_rows
    fsync_dir(folder)
    return rows


def _alive(owner: Path) -> bool:
    """Whether the add that made a work folder still holds its owner file's lock."""
    try:
        fd = os.open(owner, os.O_RDWR)
    except OSError:
        return False  # none yet (an add killed before it made it) or gone
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return True
    finally:
        os.close(fd)  # releases it again if it was taken
    return False


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (Linux renameat2 RENAME_EXCHANGE); False where the system cannot.

    By hand through ctypes because Python's os module has no renameat2."""
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return False
    libc = ctypes.CDLL(libc_name, use_errno=True)
    fn = getattr(libc, "renameat2", None)
    if fn is None:
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    rc = fn(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if rc == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP):
        return False
    raise CatalogError(f"cannot replace {b}: {os.strerror(err)}")


def compact(
    root: Path, structure: str | None = None, *, target_bytes: int = TARGET_BYTES, wait_s: float | None = None
) -> list[CompactResult]:
    """Compact every structure of the catalogue at `root` (or the one named)."""
    cat = Catalog(root)
    if structure is not None:
        check_structure(structure)
        if not (root / f"structure={structure}").is_dir():
            known = sorted(p.name.removeprefix("structure=") for p in root.glob("structure=*"))
            raise CatalogError(f"{root}: no structure {structure!r} (its structures: {', '.join(known) or 'none'})")
    wait = DEFAULT_WAIT_S if wait_s is None else wait_s
    out = []
    with cat.work_dir(wait) as work, cat.locked(wait):
        every = sorted(p.name.removeprefix("structure=") for p in root.glob("structure=*") if p.is_dir())
        names = [structure] if structure else every
        for i, name in enumerate(names):
            sub = work / f"s{i}"
            sub.mkdir()
            out.append(compact_structure(cat, name, sub, target_bytes))
    return out
