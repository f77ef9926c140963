"""Queries over a whole catalogue: DuckDB, embedded, with its spatial extension from PyPI; Arrow out.

    from icgt.catalog.query import query
    table = query("catalog", "SELECT structure, count(*) FROM frames GROUP BY ALL")   # a pyarrow.Table

Views `flights`, `frames`, `images`, `footprints` and `defects` read every partition's file of that table
(`read_parquet` over the partitions' files, one schema); the WKB columns `geometry` and `geometry_face`
become GEOMETRY values (ST_GeomFromWKB), so spatial functions (ST_Intersects, ST_Area, ...) apply directly.
A table without any file yet is an empty view of its declared schema.

Distances in metres: DuckDB's spheroid functions take points as (latitude, longitude) and its
ST_Distance_Sphere ignores the column's CRS, while GeoParquet's WGS84 is (longitude, latitude); so the
connection defines two macros over ST_Distance_Spheroid (WGS84 ellipsoid) with the axes in GeoParquet's
order:

    geodesic_m(a, b)         the distance between two points [m]
    within_m(a, b, metres)   geodesic_m(a, b) <= metres

(points: for a footprint or a defect use ST_Centroid(geometry)). Times: the session's time zone is UTC,
so year(start_utc) and the like are the UTC calendar's wherever the query runs.

A result's geometry columns come back as WKB with a GeoParquet ``geo`` entry in the table's metadata
(the CRS from the column's type: OGC:CRS84, or none for the face frame), so writing the table with
pyarrow gives a GeoParquet file that geopandas and GDAL read.

Nothing is downloaded: the spatial extension is loaded from the `duckdb-extension-spatial` wheel's file
(its DuckDB build's signature checked as DuckDB checks any extension), and automatic installing and
loading of extensions is switched off, so a query that needs another extension fails instead of
reaching the network. The DuckDB and extension versions are pinned together in host/pyproject.toml.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pyarrow as pa
import pyarrow.parquet as pq

from icgt.catalog import CatalogError
from icgt.catalog.schema import GEO_KEY, SCHEMAS, TABLES, crs84_projjson, table_version
from icgt.catalog.store import Catalog

if TYPE_CHECKING:
    import duckdb

_GEOMETRY_COLUMNS = ("geometry", "geometry_face")
_MACROS = (
    "CREATE MACRO geodesic_m(a, b) AS ST_Distance_Spheroid(ST_Point2D(ST_Y(a), ST_X(a)), ST_Point2D(ST_Y(b), ST_X(b)))",
    "CREATE MACRO within_m(a, b, metres) AS geodesic_m(a, b) <= metres",
)


def spatial_extension_path() -> Path:
    """The spatial extension file shipped in the duckdb-extension-spatial wheel for this DuckDB version."""
    import duckdb

    try:
        import duckdb_extension_spatial
    except ImportError:
        raise CatalogError(
            "the DuckDB spatial extension is not installed: pip install duckdb-extension-spatial"
        ) from None
    base = Path(duckdb_extension_spatial.__file__).parent / "extensions"
    path = base / f"v{duckdb.__version__}" / "spatial.duckdb_extension"
    if not path.is_file():
        found = ", ".join(sorted(p.name for p in base.iterdir())) if base.is_dir() else "none"
        raise CatalogError(
            f"duckdb {duckdb.__version__} needs duckdb-extension-spatial {duckdb.__version__} "
            f"(installed: extensions for {found})"
        )
    return path


def connect(root: Path | str) -> duckdb.DuckDBPyConnection:
    """An in-memory DuckDB with the spatial extension and the catalogue's views."""
    import duckdb

    cat = Catalog(Path(root))
    con = duckdb.connect(
        ":memory:",
        config={"autoinstall_known_extensions": False, "autoload_known_extensions": False},
    )
    try:
        con.execute(f"LOAD '{_sql_str(str(spatial_extension_path()))}'")
    except duckdb.Error as exc:
        raise CatalogError(f"cannot load DuckDB's spatial extension: {exc}") from None
    con.execute("SET TimeZone = 'UTC'")
    for macro in _MACROS:
        con.execute(macro)
    for path in cat.files("flights"):  # one per partition: a partition of another schema version is refused
        table_version(pq.read_metadata(path).metadata, str(path))
    for table in TABLES:
        files = cat.files(table)
        if files:
            listing = ", ".join(f"'{_sql_str(str(p))}'" for p in files)
            # one declared schema per version, and every partition's version is checked above: the files'
            # columns are the same, so no union_by_name (which reads every file's schema at each query)
            # and no hive partitioning: structure and flight are columns of every file, and a group's folder
            # (compact.py) is no partition key
            source = f"read_parquet([{listing}], hive_partitioning = false)"
        else:
            con.register(f"_empty_{table}", SCHEMAS[table].empty_table())
            source = f"_empty_{table}"
        con.execute(f"CREATE VIEW _raw_{table} AS SELECT * FROM {source}")
        # DuckDB reads a GeoParquet column as GEOMETRY already; a plain WKB one (an empty table) is converted
        types = dict(con.execute(f"SELECT column_name, column_type FROM (DESCRIBE _raw_{table})").fetchall())
        blobs = [c for c in _GEOMETRY_COLUMNS if types.get(c) == "BLOB"]
        replace = f" REPLACE ({', '.join(f'ST_GeomFromWKB({c}) AS {c}' for c in blobs)})" if blobs else ""
        con.execute(f"CREATE VIEW {table} AS SELECT *{replace} FROM _raw_{table}")
    return con


def _sql_str(text: str) -> str:
    return text.replace("'", "''")


def query(root: Path | str, sql: str) -> pa.Table:
    """The result of `sql` over the catalogue at `root` as an Arrow table (geometries as WKB)."""
    import duckdb

    con = connect(root)
    try:
        rel = con.sql(sql)
        if rel is None:
            return pa.table({})
        cols = rel.columns
        types = [str(t) for t in rel.types]
        geo = [c for c, t in zip(cols, types, strict=True) if t.startswith("GEOMETRY")]
        if geo:
            rel = rel.project(", ".join(f'ST_AsWKB("{c}") AS "{c}"' if c in geo else f'"{c}"' for c in cols))
        out: pa.Table = rel.to_arrow_table() if hasattr(rel, "to_arrow_table") else rel.arrow()
        if geo:
            crs = {c: t for c, t in zip(cols, types, strict=True) if c in geo}
            meta = dict(out.schema.metadata or {})
            meta[GEO_KEY] = json.dumps(_geo_metadata(out, crs)).encode()
            out = out.replace_schema_metadata(meta)
        return out
    except duckdb.Error as exc:
        raise CatalogError(f"query failed: {str(exc).splitlines()[0]}") from None
    finally:
        con.close()


def _geo_metadata(table: pa.Table, types: dict[str, str]) -> dict[str, Any]:
    """GeoParquet 1.1 metadata of a result's WKB columns: CRS84 where DuckDB's type says so, none otherwise."""
    import shapely

    columns: dict[str, Any] = {}
    for name, typ in types.items():
        geoms = [g for g in shapely.from_wkb(table[name].to_pylist()) if g is not None]
        kinds = sorted({g.geom_type for g in geoms})
        col: dict[str, Any] = {"encoding": "WKB", "geometry_types": kinds}
        col["crs"] = crs84_projjson() if "CRS84" in typ.upper() else None
        if geoms:
            col["bbox"] = [float(v) for v in shapely.total_bounds(geoms)]
        columns[name] = col
    primary = "geometry" if "geometry" in columns else next(iter(columns))
    return {"version": "1.1.0", "primary_column": primary, "columns": columns}


def format_table(table: pa.Table, max_rows: int = 50) -> str:
    """A plain text table of the first `max_rows` rows (WKB shown as well-known text)."""
    rows = table.slice(0, max_rows).to_pylist()
    names = table.column_names
    text_rows = [[_cell(r[n]) for n in names] for r in rows]
    widths = [max([len(n)] + [len(row[i]) for row in text_rows]) for i, n in enumerate(names)]
    lines = ["  ".join(n.ljust(w) for n, w in zip(names, widths, strict=True))]
    lines.append("  ".join("-" * w for w in widths))
    lines += ["  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)) for row in text_rows]
    if table.num_rows > max_rows:
        lines.append(f"... {table.num_rows - max_rows} more rows")
    lines.append(f"({table.num_rows} rows)")
    return "\n".join(lines)


def _cell(v: Any) -> str:
    if v is None:
        return "NULL"
    if isinstance(v, bytes):
        import shapely

        try:
            wkt: str = shapely.from_wkb(v).wkt
        except Exception:  # not WKB after all: shown as bytes
            return v.hex()[:40]
        return wkt if len(wkt) <= 60 else wkt[:57] + "..."
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)
