"""GeoPackage and KML exports of one simulated flight, read back without the writer's code.

- GeoPackage (sqlite3 and the OGC tables): application id, every FrameRecord field under its full
  name, times to the millisecond with their zone and to the microsecond, heights MSL on EPSG:9707;
  the footprints on the face are valid 2D polygons whose areas are the geometry's footprint areas;
- KML (ElementTree): every placemark's altitudeMode is absolute and its height the MSL altitude;
- the same files read back through GDAL (pyogrio): field names and types, UTC times, CRS, 3D
  coordinates, valid face polygons; KML's altitudeMode as GDAL's LIBKML driver reports it;
- FlatGeobuf (--formats fgb): the three layers read back through GDAL, the list field (flags) as
  one comma-separated string;
- GeoJSON is still written next to them.
"""

from __future__ import annotations

import json
import sqlite3
import struct
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import shapely
from export_exit import expected_export_exit
from pyogrio import list_layers, read_info
from pyogrio.raw import read as ogr_read

from icgt.cli import main
from icgt.export.common import RECORD_FIELDS, utc_iso
from icgt.ingest import read

KML = "{http://www.opengis.net/kml/2.2}"


@pytest.fixture(scope="module")
def out(export_flight: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("gis")
    args = ["export", str(export_flight.mcap), "--images", str(export_flight.card), "--out", str(out), "--no-progress"]
    assert main(args) == expected_export_exit(out)
    return out


@pytest.fixture(scope="module")
def frames(export_flight: Any) -> dict[int, Any]:
    return {f.frame_seq: f for f in read(export_flight.mcap).frames()}


def _gpkg_geometry(blob: bytes) -> Any:
    """The WKB inside a GeoPackage geometry blob (GPKG header: magic, version, flags, srs_id, envelope)."""
    assert blob[:2] == b"GP"
    flags = blob[3]
    envelope = {0: 0, 1: 32, 2: 48, 3: 48, 4: 64}[(flags >> 1) & 0x07]
    return shapely.from_wkb(blob[8 + envelope :])


def test_gpkg_tables_fields_and_times(out: Path, frames: dict[int, Any]) -> None:
    db = sqlite3.connect(out / "icgt.gpkg")
    (app_id,) = db.execute("PRAGMA application_id").fetchone()
    assert struct.pack(">I", app_id & 0xFFFFFFFF) == b"GPKG"
    contents = {r[0]: r[1] for r in db.execute("SELECT table_name, data_type FROM gpkg_contents")}
    assert contents == {"cameras": "features", "footprints": "features", "footprints_face": "features"}
    query = "SELECT table_name, geometry_type_name, srs_id, z FROM gpkg_geometry_columns"
    geo = {r[0]: (r[1], r[2], r[3]) for r in db.execute(query)}
    assert geo["cameras"] == ("POINT", 9707, 1)
    assert geo["footprints"] == ("POLYGON", 9707, 1)
    assert geo["footprints_face"][0] == "POLYGON" and geo["footprints_face"][2] == 0
    columns = [r[1] for r in db.execute("PRAGMA table_info(cameras)")]
    assert set(RECORD_FIELDS) <= set(columns), set(RECORD_FIELDS) - set(columns)
    rows = db.execute("SELECT frame_seq, mid_utc, mid_utc_us, alt_msl_m, flags, geom FROM cameras").fetchall()
    assert len(rows) == len(frames) > 10  # ~45 (5 fps), fewer on a loaded machine
    for seq, mid_utc, mid_utc_us, alt, flags, geom in rows:
        rec = frames[seq]
        assert mid_utc_us == rec.mid_utc_us
        assert mid_utc == utc_iso(rec.mid_utc_us)[:23] + "Z"  # milliseconds, UTC
        assert alt == rec.alt_msl_m
        assert flags == ",".join(rec.flags)
        point = _gpkg_geometry(geom)
        assert (point.x, point.y, point.z) == (rec.lon_deg, rec.lat_deg, rec.alt_msl_m)


def test_face_footprints_are_valid_polygons(out: Path) -> None:
    db = sqlite3.connect(out / "icgt.gpkg")
    face = {seq: _gpkg_geometry(g) for seq, g in db.execute("SELECT frame_seq, geom FROM footprints_face")}
    areas = dict(db.execute("SELECT frame_seq, area_m2 FROM footprints_face").fetchall())
    mapped = {seq: _gpkg_geometry(g) for seq, g in db.execute("SELECT frame_seq, geom FROM footprints")}
    assert len(face) == len(mapped) > 10  # ~45 (5 fps), fewer on a loaded machine
    for seq, poly in face.items():
        assert poly.geom_type == "Polygon" and not poly.has_z
        assert poly.is_valid, shapely.is_valid_reason(poly)
        assert poly.exterior.is_ccw
        assert poly.area == pytest.approx(areas[seq], rel=1e-6)
        assert 0.5 < poly.area < 50.0  # a 24 mm lens 3 m from the face: a few square metres
    # on the vertical pier face the map outlines collapse: the face coordinates are what keep their area
    flat = [shapely.Polygon([(x, y) for x, y, _ in p.exterior.coords]).area for p in mapped.values()]
    assert max(flat) < 1e-12


def test_kml_heights_are_absolute_msl(out: Path, frames: dict[int, Any]) -> None:
    root = ET.parse(out / "icgt.kml").getroot()
    placemarks = list(root.iter(f"{KML}Placemark"))
    points = polygons = 0
    for pm in placemarks:
        seq = int(pm.find(f".//{KML}SimpleData[@name='frame_seq']").text)
        for geom in list(pm.iter(f"{KML}Point")) + list(pm.iter(f"{KML}Polygon")):
            assert geom.find(f"{KML}altitudeMode").text == "absolute"
        for point in pm.iter(f"{KML}Point"):
            lon, lat, alt = (float(c) for c in point.find(f"{KML}coordinates").text.strip().split(","))
            rec = frames[seq]
            assert (lon, lat, alt) == pytest.approx((rec.lon_deg, rec.lat_deg, rec.alt_msl_m), abs=1e-9)
            points += 1
        for poly in pm.iter(f"{KML}Polygon"):
            coords = poly.find(f".//{KML}coordinates").text.split()
            assert len(coords) >= 4 and coords[0] == coords[-1]
            polygons += 1
    assert points == polygons == len(frames)


def test_geojson_still_written(out: Path, frames: dict[int, Any]) -> None:
    cams = json.loads((out / "cameras.geojson").read_text())
    assert len(cams["features"]) == len(frames)


def _gdal_layer(path: Path, layer: str | None = None) -> tuple[dict[str, Any], list[Any], dict[str, Any]]:
    """(metadata, shapely geometries, columns by field name) of one layer, read by GDAL."""
    meta, _, geometry, fields = ogr_read(path, layer=layer, datetime_as_string=True)
    return meta, list(shapely.from_wkb(geometry)), dict(zip(meta["fields"], fields, strict=True))


def _check_gdal_cameras(path: Path, frames: dict[int, Any], layer: str | None = None) -> None:
    meta, geoms, cols = _gdal_layer(path, layer)
    assert meta["crs"] == "EPSG:9707" and meta["geometry_type"] == "Point Z"
    assert set(RECORD_FIELDS) <= set(cols), set(RECORD_FIELDS) - set(cols)  # full names, none cut
    types = dict(zip(meta["fields"], meta["ogr_types"], strict=True))
    assert types["mid_utc"] == "OFTDateTime" and types["mid_utc_us"] == "OFTInteger64"
    assert types["alt_msl_m"] == "OFTReal" and types["flags"] == "OFTString"
    assert len(geoms) == len(frames)
    for i, seq in enumerate(cols["frame_seq"]):
        rec = frames[int(seq)]
        assert cols["mid_utc"][i] == utc_iso(rec.mid_utc_us)[:23] + "Z"
        assert int(cols["mid_utc_us"][i]) == rec.mid_utc_us
        assert cols["flags"][i] == ",".join(rec.flags)
        assert (geoms[i].x, geoms[i].y, geoms[i].z) == (rec.lon_deg, rec.lat_deg, rec.alt_msl_m)


def _check_gdal_face(path: Path, n: int, layer: str | None = None) -> None:
    meta, geoms, cols = _gdal_layer(path, layer)
    assert meta["geometry_type"] == "Polygon" and len(geoms) == n
    for poly, area in zip(geoms, cols["area_m2"], strict=True):
        assert not poly.has_z and poly.is_valid, shapely.is_valid_reason(poly)
        assert poly.area == pytest.approx(float(area), rel=1e-6)


def test_gpkg_read_back_by_gdal(out: Path, frames: dict[int, Any]) -> None:
    path = out / "icgt.gpkg"
    assert {str(name) for name, _ in list_layers(path)} == {"cameras", "footprints", "footprints_face"}
    _check_gdal_cameras(path, frames, "cameras")
    meta, geoms, _ = _gdal_layer(path, "footprints")
    assert meta["geometry_type"] == "Polygon Z" and len(geoms) == len(frames)
    _check_gdal_face(path, len(frames), "footprints_face")


def test_kml_read_back_by_gdal(out: Path, frames: dict[int, Any]) -> None:
    path = out / "icgt.kml"
    info = read_info(path, layer="cameras")
    assert info["features"] == len(frames)
    _, geoms, cols = _gdal_layer(path, "cameras")
    assert set(cols["altitudeMode"]) == {"absolute"}  # LIBKML reports each placemark's altitudeMode
    alts = {int(seq): g.z for seq, g in zip(cols["frame_seq"], geoms, strict=True)}
    assert alts == pytest.approx({seq: rec.alt_msl_m for seq, rec in frames.items()}, abs=1e-6)
    _, polys, cols = _gdal_layer(path, "footprints")
    assert len(polys) == len(frames) and set(cols["altitudeMode"]) == {"absolute"}
    assert all(p.has_z for p in polys)


def test_flatgeobuf_read_back_by_gdal(export_flight: Any, frames: dict[int, Any], tmp_path: Path) -> None:
    args = ["export", str(export_flight.mcap), "--images", str(export_flight.card), "--out", str(tmp_path),
            "--formats", "fgb", "--no-progress"]  # fmt: skip
    assert main(args) == expected_export_exit(tmp_path)
    _check_gdal_cameras(tmp_path / "cameras.fgb", frames)
    assert any("," in f for f in _gdal_layer(tmp_path / "cameras.fgb")[2]["flags"])  # lists with several items
    meta, geoms, cols = _gdal_layer(tmp_path / "footprints.fgb")
    assert meta["geometry_type"] == "Polygon Z" and len(geoms) == len(frames)
    assert list(cols["flags"]) == [",".join(frames[int(s)].flags) for s in cols["frame_seq"]]
    assert np.all(np.diff(cols["frame_seq"].astype(np.int64)) > 0)  # no spatial index: the frames' order
    _check_gdal_face(tmp_path / "footprints_face.fgb", len(frames))
