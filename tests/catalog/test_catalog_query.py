"""`icgt catalog query` and icgt.catalog.query: DuckDB spatial over the whole catalogue, checked against the
answers computed from the logs themselves (icgt.read) and from the files (pyarrow, geopandas)."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import geopandas as gpd
import pyarrow as pa
import pyarrow.parquet as pq
import pyproj
import pytest
import shapely
import synth_logs as sl
from conftest import SynthFlight, make_flight

import icgt
from icgt.catalog import CatalogError
from icgt.catalog.cli import add_flight
from icgt.catalog.query import connect, query
from icgt.catalog.schema import TABLES
from icgt.catalog.store import Catalog
from icgt.cli import main
from icgt.geodesy import LocalFrame

GEOD = pyproj.Geod(ellps="WGS84")
# a point on the first flight's path, 8 m from the face's foot: (east, north, up) in its ENU frame
POINT = tuple(float(v) for v in LocalFrame(*sl.ORIGIN).enu_to_geodetic([2.5, 8.0, 3.0]))  # lat, lon, alt
RADIUS_M = 1.1
GSD_MAX = 0.4355


@pytest.fixture(scope="module")
def catalogue(
    flight_a: SynthFlight, flight_b: SynthFlight, tmp_path_factory: pytest.TempPathFactory
) -> tuple[Path, dict[str, SynthFlight]]:
    """pier-7 inspected in 2025 (flight_a) and 2026 (flight_b), each with card and detections; bridge-2 once."""
    root = tmp_path_factory.mktemp("q")
    other = make_flight(root / "c", sl.Synth(n=12, seed=9, serial="5550001", recording_id=0x51))
    cat = root / "cat"
    flights = {}
    for f, structure in ((flight_a, "pier-7"), (flight_b, "pier-7"), (other, "bridge-2")):
        res = add_flight(cat, f.log, structure, images=f.card, detections=[f.detections])
        flights[res.flight] = f
    return cat, flights


def test_views_span_every_partition(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, flights = catalogue
    got = query(cat, "SELECT structure, flight, count(*) AS n FROM frames GROUP BY ALL ORDER BY ALL").to_pylist()
    want = sorted(
        ("bridge-2" if f.synth.serial == "5550001" else "pier-7", fid, len(list(icgt.read(f.log).frames())))
        for fid, f in flights.items()
    )
    assert [(r["structure"], r["flight"], r["n"]) for r in got] == want
    for table in TABLES:
        n = query(cat, f"SELECT count(*) AS n FROM {table}")["n"][0].as_py()
        on_disk = sum(pq.read_metadata(p).num_rows for p in Catalog(cat).files(table))
        assert n == on_disk > 0, table


def test_frames_near_a_point_with_fine_gsd_match_the_logs(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, flights = catalogue
    lat, lon, _ = POINT
    sql = f"""
        SELECT flight, frame_seq, year(mid_utc) AS year, geodesic_m(geometry, ST_Point({lon!r}, {lat!r})) AS d_m
        FROM frames
        WHERE within_m(geometry, ST_Point({lon!r}, {lat!r}), {RADIUS_M}) AND scale_mm_per_px < {GSD_MAX}
        ORDER BY flight, frame_seq"""
    got = query(cat, sql).to_pylist()
    want = []
    for fid, f in sorted(flights.items()):
        for r in icgt.read(f.log).frames():
            if r.lat_deg is None or r.lon_deg is None or r.scale_mm_per_px is None:
                continue
            d = GEOD.inv(lon, lat, r.lon_deg, r.lat_deg)[2]
            assert abs(d - RADIUS_M) > 1e-3  # no frame on the edge, where rounding could decide
            if d <= RADIUS_M and r.scale_mm_per_px < GSD_MAX:
                assert r.mid_utc_us is not None
                want.append((fid, r.frame_seq, f.synth.start_utc.year, d))
    assert 3 <= len(want) < sum(len(f.frames) for f in flights.values())  # the query selects, it does not pass all
    assert [(r["flight"], r["frame_seq"], r["year"]) for r in got] == [w[:3] for w in want]
    assert [r["d_m"] for r in got] == pytest.approx([w[3] for w in want], abs=1e-6)


def test_defects_by_class_and_length_per_structure_per_year(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, _ = catalogue
    got = query(
        cat,
        """SELECT d.structure, year(f.start_utc) AS year, d.kind, count(*) AS n, sum(d.length_mm) AS length_mm
           FROM defects d JOIN flights f USING (structure, flight) GROUP BY ALL ORDER BY ALL""",
    ).to_pylist()
    want: dict[tuple[str, int, str], list[float]] = {}
    for p in Catalog(cat).partitions():
        year = pq.read_table(p / "flights.parquet")["start_utc"][0].as_py().year
        for d in pq.read_table(p / "defects.parquet").to_pylist():
            want.setdefault((d["structure"], year, d["kind"]), []).append(d["length_mm"])
    assert [(r["structure"], r["year"], r["kind"], r["n"]) for r in got] == [
        (*k, len(v)) for k, v in sorted(want.items())
    ]
    assert [r["length_mm"] for r in got] == pytest.approx([sum(v) for _, v in sorted(want.items())])
    assert {(r["structure"], r["year"]) for r in got} == {("bridge-2", 2025), ("pier-7", 2025), ("pier-7", 2026)}


def test_flights_with_a_lost_exposure_or_a_frame_without_pose(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, flights = catalogue
    got = query(
        cat,
        """SELECT DISTINCT fl.flight FROM flights fl
           LEFT JOIN frames fr ON fr.flight = fl.flight AND fr.geometry IS NULL
           WHERE fl.lost_exposures > 0 OR fr.frame_seq IS NOT NULL ORDER BY 1""",
    )["flight"].to_pylist()
    want = sorted(
        fid
        for fid, f in flights.items()
        if f.synth.lost_exposures > 0 or any(r.lat_deg is None for r in icgt.read(f.log).frames())
    )
    assert got == want == ["1234567-00c0ffee"]


def test_duckdb_spatial_reads_every_geometry(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, _ = catalogue
    con = connect(cat)
    try:
        for table in TABLES:
            kinds = con.sql(
                f"SELECT DISTINCT ST_GeometryType(geometry)::VARCHAR, ST_IsValid(geometry) FROM {table} "
                "WHERE geometry IS NOT NULL"
            ).fetchall()
            assert kinds and all(valid for _, valid in kinds), (table, kinds)
            # the bbox covering column is the geometry's extent
            off = con.sql(
                f"SELECT count(*) FROM {table} WHERE geometry IS NOT NULL AND (abs(bbox.xmin - ST_XMin(geometry)) "
                f"> 1e-12 OR abs(bbox.ymax - ST_YMax(geometry)) > 1e-12)"
            ).fetchone()
            assert off == (0,), table
        # each defect lies on the face inside a footprint of its own flight's images
        hits = con.sql(
            """SELECT d.flight, count(DISTINCT fp.frame_seq) FROM defects d JOIN footprints fp
               ON fp.flight = d.flight AND ST_Intersects(fp.geometry_face, d.geometry_face) GROUP BY ALL"""
        ).fetchall()
        assert len(hits) == 3 and all(n >= 2 for _, n in hits)
    finally:
        con.close()


def test_geopandas_and_pyarrow_read_every_file(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, _ = catalogue
    for table in TABLES:
        for path in Catalog(cat).files(table):
            g = gpd.read_parquet(path)
            t = pq.read_table(path)
            assert len(g) == t.num_rows and g.crs is not None and g.crs.to_string() == "OGC:CRS84", path
            assert list(g.geometry.to_wkb()) == t["geometry"].to_pylist()


def test_the_python_api_returns_arrow_with_geoparquet_metadata(
    catalogue: tuple[Path, dict[str, SynthFlight]], tmp_path: Path
) -> None:
    cat, _ = catalogue
    t = query(cat, "SELECT flight, frame_seq, geometry, geometry_face, ST_Centroid(geometry) AS c FROM footprints")
    assert isinstance(t, pa.Table) and pa.types.is_binary(t.schema.field("geometry").type)
    geo = json.loads(t.schema.metadata[b"geo"])
    assert geo["columns"]["geometry"]["crs"]["id"] == {"authority": "OGC", "code": "CRS84"}
    assert geo["columns"]["geometry_face"]["crs"] is None
    assert geo["columns"]["c"]["geometry_types"] == ["Point"]
    pq.write_table(t, tmp_path / "out.parquet")
    g = gpd.read_parquet(tmp_path / "out.parquet")
    assert g.crs.to_string() == "OGC:CRS84" and g.geometry.geom_type.eq("Polygon").all()
    centroids = shapely.from_wkb(t["c"].to_pylist())
    assert shapely.contains(shapely.from_wkb(t["geometry"].to_pylist()), centroids).all()


def _run(args: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    code = main(args)
    out, err = capsys.readouterr()
    return code, out, "\n".join(line for line in err.splitlines() if " INFO " not in line)


def test_cli_prints_a_table_or_writes_csv_json_and_parquet(
    catalogue: tuple[Path, dict[str, SynthFlight]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat, _ = catalogue
    sql = "SELECT flight, year, frames, lost_exposures, geometry FROM flights ORDER BY flight"
    base = ["catalog", "query", sql, "--catalog", str(cat)]
    code, out, _ = _run(base, capsys)
    lines = out.splitlines()
    assert code == 0 and lines[0].split() == ["flight", "year", "frames", "lost_exposures", "geometry"]
    assert lines[-1] == "(3 rows)" and "1234567-00c0ffee  2025  40" in out and "POLYGON ((126.97" in out
    code, out, _ = _run([*base, "--format", "csv"], capsys)
    rows = list(csv.DictReader(io.StringIO(out)))
    assert code == 0 and [r["flight"] for r in rows] == ["1234567-00c0ffee", "5550001-00000051", "7654321-0badcafe"]
    assert rows[0]["lost_exposures"] == "2" and shapely.from_wkt(rows[0]["geometry"]).geom_type == "Polygon"
    code, _, _ = _run([*base, "--format", "json", "--out", str(tmp_path / "f.json")], capsys)
    data = json.loads((tmp_path / "f.json").read_text())
    assert code == 0 and [r["frames"] for r in data] == [40, 12, 40] and data[0]["year"] == 2025
    code, out, _ = _run([*base, "--format", "parquet", "--out", str(tmp_path / "f.parquet")], capsys)
    assert code == 0 and out.strip() == f"3 rows written to {tmp_path / 'f.parquet'}"
    g = gpd.read_parquet(tmp_path / "f.parquet")
    assert list(g["flight"]) == [r["flight"] for r in rows] and g.crs.to_string() == "OGC:CRS84"


def test_cli_errors_are_one_line(
    catalogue: tuple[Path, dict[str, SynthFlight]], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat, _ = catalogue
    cases = [
        (["SELECT nope FROM frames", "--catalog", str(cat)], "query failed: Binder Error"),
        (["SELECT 1", "--catalog", str(cat), "--format", "parquet"], "--format parquet needs --out"),
        (["SELECT 1", "--catalog", str(tmp_path / "missing")], "no such catalogue"),
        (
            ["SELECT 1", "--catalog", str(cat), "--out", str(tmp_path / "no" / "dir.csv"), "--format", "csv"],
            "cannot write",
        ),
        (["SELECT * FROM read_csv('x.csv.gz')", "--catalog", str(cat)], "query failed"),
    ]
    for extra, pattern in cases:
        code, _out, err = _run(["catalog", "query", *extra], capsys)
        assert code != 0 and len(err.splitlines()) == 1 and err.startswith("icgt: ") and pattern in err, (extra, err)


def test_an_empty_catalogue_has_empty_views_of_every_table(tmp_path: Path) -> None:
    Catalog(tmp_path / "cat", create=True)
    for table in TABLES:
        t = query(
            tmp_path / "cat", f"SELECT *, within_m(ST_Centroid(geometry), ST_Point(0, 0), 5) AS near FROM {table}"
        )
        assert t.num_rows == 0 and "geometry" in t.column_names, table
    with pytest.raises(CatalogError, match="no table"):
        Catalog(tmp_path / "cat").files("nope")


def test_calendar_functions_are_utc_whatever_the_local_zone(catalogue: tuple[Path, dict[str, SynthFlight]]) -> None:
    cat, _ = catalogue
    code = (
        "import sys; from icgt.catalog.query import query; "
        "t = query(sys.argv[1], \"SELECT min(hour(mid_utc)) AS h, min(year(TIMESTAMPTZ '2025-12-31 23:30:00+00')) AS y"
        " FROM frames WHERE flight = '1234567-00c0ffee'\"); print(t['h'][0].as_py(), t['y'][0].as_py())"
    )
    env = {**os.environ, "TZ": "Pacific/Kiritimati"}  # UTC+14: a local calendar would say 23 h and 2026
    out = subprocess.run([sys.executable, "-c", code, str(cat)], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["9", "2025"]
