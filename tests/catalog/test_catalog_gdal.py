"""GDAL reads every file of a populated catalogue: the summary `ogrinfo -ro -so -al` prints (driver, geometry
column and type, CRS, feature count, extent, fields) and every feature's geometries, checked against pyarrow.

Which GDAL: the one pyogrio's wheel bundles (pyogrio is a dependency of icgt; 0.13 bundles GDAL 3.12). No GDAL
that Debian 12 or PyPI offers here has GDAL's own (Arrow) Parquet driver: Debian builds GDAL without libarrow
(`ogrinfo --formats` of gdal-bin 3.6 lists no Parquet), and neither do the wheels of pyogrio, fiona or
gdal-wheel. GDAL >= 3.11 reads GeoParquet through its ADBC driver instead, with DuckDB's ADBC driver (in the
duckdb wheel icgt pins) reading the Parquet: GDAL itself interprets the file's GeoParquet metadata (the
primary and the other geometry columns, their PROJJSON CRS, the bbox covering used for its spatial filter)
and decodes the WKB into OGR geometries. That is the path tested here, as pyogrio's read_info (the layer
summary of `ogrinfo -so`) and read_arrow (the features, as `ogrinfo -al` would list them).
"""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path
from typing import Any

import pyarrow.parquet as pq
import pyogrio
import pyproj
import pytest
import shapely
import synth_logs as sl
from conftest import SynthFlight, make_flight

from icgt.catalog.cli import add_flight
from icgt.catalog.schema import TABLES
from icgt.catalog.store import Catalog, compact

GEOARROW_WKB = b"geoarrow.wkb"


def duckdb_adbc_driver() -> str:
    """The DuckDB ADBC driver: the duckdb wheel's own extension module (entry point duckdb_adbc_init)."""
    spec = importlib.util.find_spec("_duckdb")
    assert spec is not None and spec.origin, "the duckdb wheel is missing (a dependency of icgt)"
    return spec.origin


def gdal(path: Path) -> tuple[str, dict[str, str]]:
    """GDAL's name for a catalogue file and the open options: its ADBC driver on DuckDB."""
    return f"ADBC:{path}", {"ADBC_DRIVER": duckdb_adbc_driver()}


@pytest.fixture(scope="module", params=["per flight", "compacted"])
def catalogue(
    request: pytest.FixtureRequest,
    flight_a: SynthFlight,
    flight_b: SynthFlight,
    tmp_path_factory: pytest.TempPathFactory,
) -> Path:
    """Two structures, three flights, with cards and detections: every table has rows, frames some without pose;
    each flight in its own files, or (compacted) pier-7's two flights in one group's files (compact.py)."""
    root = tmp_path_factory.mktemp("gdal")
    other = make_flight(root / "c", sl.Synth(n=12, seed=9, serial="5550001", recording_id=0x51))
    cat = root / "cat"
    for f, structure in ((flight_a, "pier-7"), (flight_b, "pier-7"), (other, "bridge-2")):
        add_flight(cat, f.log, structure, images=f.card, detections=[f.detections])
    if request.param == "compacted":
        assert [r.merged for r in compact(cat)] == [0, 2]
    return cat


def _files(cat: Path) -> list[tuple[str, Path]]:
    files = [(table, p) for table in TABLES for p in Catalog(cat).files(table)]
    folders = len(Catalog(cat).units())  # every table of every flight's folder: 3 flights, or a group and 1
    assert len(files) == folders * len(TABLES) and folders in (2, 3)
    assert all(pq.read_metadata(p).num_rows > 0 for _, p in files)
    return files


def test_the_gdal_is_one_that_reads_geoparquet() -> None:
    assert pyogrio.__gdal_version__ >= (3, 11, 0), pyogrio.__gdal_version_string__  # ADBC with GeoParquet
    assert "ADBC" in pyogrio.list_drivers()


def test_gdal_summarises_every_file_as_the_file_declares(catalogue: Path) -> None:
    for table, path in _files(catalogue):
        name, opts = gdal(path)
        info = pyogrio.read_info(name, **opts)
        t = pq.read_table(path)
        geo = json.loads(t.schema.metadata[b"geo"])
        declared = geo["columns"][geo["primary_column"]]
        assert info["driver"] == "ADBC" and info["layer_name"] == path.stem, (path, info["driver"])
        assert info["features"] == t.num_rows > 0, path
        assert info["geometry_name"] == geo["primary_column"] == "geometry", path
        types = declared["geometry_types"]
        assert info["geometry_type"] == (types[0] if len(types) == 1 else "Unknown"), (path, types)
        # the CRS GDAL reports is the PROJJSON the file declares: WGS 84, longitude first (OGC:CRS84)
        crs = pyproj.CRS.from_user_input(info["crs"])
        assert crs == pyproj.CRS.from_json_dict(declared["crs"]) == pyproj.CRS("OGC:CRS84"), (path, info["crs"])
        assert crs.to_authority() == ("OGC", "CRS84") and crs.ellipsoid is not None
        assert crs.ellipsoid.name == "WGS 84"
        # every column is a field or a geometry; the bbox covering column is recognised as such, not a field
        geoms = set(geo["columns"])
        assert list(info["fields"]) == [c for c in t.column_names if c not in geoms and c != "bbox"], path
        assert "bbox" in t.column_names and table in TABLES
        wkb = [g for g in t["geometry"].to_pylist() if g is not None]
        want = shapely.total_bounds(shapely.from_wkb(wkb))
        assert info["total_bounds"] == pytest.approx(tuple(want), abs=1e-9), path


def _column_crs(field: Any) -> pyproj.CRS | None:
    assert field.metadata[b"ARROW:extension:name"] == GEOARROW_WKB, field
    meta = json.loads(field.metadata.get(b"ARROW:extension:metadata", b"{}") or b"{}")
    return pyproj.CRS.from_json_dict(meta["crs"]) if "crs" in meta else None


def test_gdal_reads_every_feature_and_geometry_column_as_pyarrow_does(catalogue: Path) -> None:
    for _table, path in _files(catalogue):
        name, opts = gdal(path)
        meta, got = pyogrio.read_arrow(name, **opts)
        t = pq.read_table(path)
        geo = json.loads(t.schema.metadata[b"geo"])
        assert got.num_rows == t.num_rows and meta["geometry_name"] == "geometry", path
        for col, declared in geo["columns"].items():
            # each geometry column as GDAL decoded it (OGR geometries written back as WKB) is the file's
            assert got[col].to_pylist() == t[col].to_pylist(), (path, col)
            crs = _column_crs(got.schema.field(col))
            if declared.get("crs") is None:  # the face's (s, t) metres: no CRS, and GDAL invents none
                assert crs is None, (path, col)
            else:
                assert crs == pyproj.CRS.from_json_dict(declared["crs"]), (path, col)
        for col in got.column_names:
            if col not in geo["columns"] and col != "OGC_FID":
                assert got[col].to_pylist() == t[col].to_pylist(), (path, col)


def test_gdal_spatial_filter_selects_the_frames_in_a_box(catalogue: Path) -> None:
    """GDAL's bbox filter (through the covering column) picks exactly the frames whose point is in the box."""
    for path in Catalog(catalogue).files("frames"):
        t = pq.read_table(path, columns=["frame_seq", "geometry"])
        pts = [(s, shapely.from_wkb(g)) for s, g in zip(t["frame_seq"].to_pylist(), t["geometry"].to_pylist(),
                                                          strict=True) if g is not None]  # fmt: skip
        xs = sorted(p.x for _, p in pts)
        ys = sorted(p.y for _, p in pts)
        box = (xs[0] - 1e-9, ys[0] - 1e-9, xs[len(xs) // 2], ys[-1] + 1e-9)  # the western half, or so
        want = sorted(s for s, p in pts if box[0] <= p.x <= box[2] and box[1] <= p.y <= box[3])
        assert 0 < len(want) < len(pts), path
        name, opts = gdal(path)
        _meta, got = pyogrio.read_arrow(name, bbox=box, **opts)
        assert sorted(got["frame_seq"].to_pylist()) == want, path
