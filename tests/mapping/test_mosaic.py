"""The mosaic: a checkerboard face, rendered into the same flight's images, lands where it should.

The card of the damage-map flight is re-rendered with a checkerboard face (100 mm squares, same
exposures, same EXIF and frame tags), mapped with no detections at 5 mm/px, and every 40 x 40 px
block of the mosaic (2 x 2 squares) is compared with the true checkerboard at the same face points:
the shift between them is read from the phases of the pattern's two fundamental components. The
misregistration (p95 of the blocks) stays within what the flight's poses allow: its geotag error p95
(measured against the truth, ~2 cm) plus half the LiDAR's range noise (a range error moves a point
seen 27 degrees off the axis, the image's edge, by half as much along the face), in mosaic pixels
(5 mm): about 6 px. Measured: p50 ~1.8 px, p95 ~3.5 px.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import msgspec
import numpy as np
import png
import pytest
from PIL import Image

from icgt.geodesy import LocalFrame
from icgt.ingest import read
from icgt.mapping.cli import run_map
from icgt.mapping.place import Errors
from icgt.mapping.pose import world_to_pixel
from icgt.sim.camera_card import _image, read_frame_number
from icgt.sim.face import FaceFrame
from icgt.sim.map_truth import geotag_errors_m
from icgt.sim.render import render

from .conftest import LOOKAHEAD_S, DamageFlight

MM_PER_PX = 5.0
CHECKER_MM = 100.0
RANGE_NOISE_M = 0.025
BLOCK = 40


def _checker_card(df: DamageFlight, dst: Path) -> None:
    assert df.scenario.surface is not None
    sc = msgspec.structs.replace(
        df.scenario, surface=msgspec.structs.replace(df.scenario.surface, texture="checkerboard", checker_mm=CHECKER_MM)
    )
    by_number = {e.frame_number: e for e in df.exposures}
    dst.mkdir()
    for src in sorted(df.flight.card.glob("*.JPG")):
        with Image.open(src) as im:
            exif = im.info["exif"]
        e = by_number[read_frame_number(src)]
        assert sc.surface is not None
        _image(e.frame_number, render(sc, sc.surface, e)).save(dst / src.name, format="JPEG", quality=92, exif=exif)


def test_checkerboard_mosaic_lands_in_place(damage_flight: DamageFlight, tmp_path: Path) -> None:
    card = tmp_path / "card"
    _checker_card(damage_flight, card)
    empty = tmp_path / "none.json"
    empty.write_text(json.dumps({"format": "icgt-detections", "images": {}}))
    res = run_map(damage_flight.flight.mcap, card, [empty], tmp_path / "map", calibration=damage_flight.calibration,
                  errors=Errors(position_m=0.015), mm_per_px=MM_PER_PX, lookahead_s=LOOKAHEAD_S)  # fmt: skip
    assert res.mosaic is not None and res.instances == []
    w, h, rows, _ = png.Reader(filename=str(res.mosaic.path)).asRGB8()
    rgb = np.vstack([np.frombuffer(r, dtype=np.uint8) for r in rows]).reshape(h, w, 3)
    assert (w, h) == (res.mosaic.width_px, res.mosaic.height_px)
    # the world file says where the pixel centres are on the face
    a, _, _, e, c, f = (float(x) for x in (tmp_path / "map" / "mosaic.pgw").read_text().split())
    assert a == pytest.approx(MM_PER_PX / 1000.0) and e == pytest.approx(-MM_PER_PX / 1000.0)
    s = c + np.arange(w) * a
    t = f + np.arange(h) * e
    ss, tt = np.meshgrid(s, t)
    enu = res.session.face.to_enu(np.stack([ss.ravel(), tt.ravel()], axis=1))
    lat, lon, alt = res.session.origin.enu_to_geodetic(enu)
    o = damage_flight.scenario.origin
    sc_enu = LocalFrame(o.lat_deg, o.lon_deg, o.ellipsoid_height_m).geodetic_to_enu(
        lat, lon, alt + o.geoid_separation_m
    )
    st = FaceFrame.from_scenario(damage_flight.scenario).from_enu(sc_enu).reshape(h, w, 2)
    q = CHECKER_MM / 1000.0
    ideal = np.where((np.floor(st[..., 0] / q) + np.floor(st[..., 1] / q)) % 2 == 0, 1.0, -1.0)
    grey = rgb.mean(axis=2)
    k = np.pi / q
    shifts = []
    for r0 in range(0, h - BLOCK + 1, BLOCK):
        for c0 in range(0, w - BLOCK + 1, BLOCK):
            g = grey[r0 : r0 + BLOCK, c0 : c0 + BLOCK]
            if (g < 8).any():  # not covered by any image
                continue
            g = g - g.mean()
            b = st[r0 : r0 + BLOCK, c0 : c0 + BLOCK]
            i = ideal[r0 : r0 + BLOCK, c0 : c0 + BLOCK]
            d = []
            for sign in (1.0, -1.0):
                basis = np.exp(-1j * k * (b[..., 0] + sign * b[..., 1]))
                d.append(np.angle(np.sum(g * basis) * np.conj(np.sum(i * basis))) / k)
            ds, dt = (d[0] + d[1]) / 2.0, (d[0] - d[1]) / 2.0
            shifts.append(float(np.hypot(ds, dt)) * 1000.0 / MM_PER_PX)
    frames = res.session.frames
    geotag = geotag_errors_m(frames, damage_flight.flight.truth_exposures, damage_flight.scenario, res.session.origin)
    max_shift_px = (float(np.percentile(geotag, 95)) + 0.5 * RANGE_NOISE_M) * 1000.0 / MM_PER_PX
    assert len(shifts) > 50
    p50, p95 = np.percentile(shifts, [50, 95])
    print(f"checkerboard mosaic misregistration: p50 {p50:.2f} px, p95 {p95:.2f} px, max {max(shifts):.2f} px "
          f"at {MM_PER_PX} mm/px over {len(shifts)} blocks; bound {max_shift_px:.2f} px")  # fmt: skip
    assert p95 <= max_shift_px

    # GDAL (rasterio) reads the PNG with its world file, and the GeoTIFF variant, as the same raster
    import rasterio

    with rasterio.open(res.mosaic.path) as ds:
        assert ds.transform.a == pytest.approx(a) and ds.transform.e == pytest.approx(e)
        assert ds.transform.c == pytest.approx(c - a / 2) and ds.transform.f == pytest.approx(f - e / 2)
        assert np.array_equal(ds.read().transpose(1, 2, 0), rgb)
    tif = run_map(damage_flight.flight.mcap, card, [empty], tmp_path / "map_tif", calibration=damage_flight.calibration,
                  errors=Errors(position_m=0.015), mm_per_px=MM_PER_PX, mosaic_format="tif",
                  lookahead_s=LOOKAHEAD_S)  # fmt: skip
    assert tif.mosaic is not None
    with rasterio.open(tif.mosaic.path) as ds:
        assert ds.driver == "GTiff" and ds.crs is None
        assert ds.transform.c == pytest.approx(c - a / 2) and ds.transform.f == pytest.approx(f - e / 2)
        assert np.array_equal(ds.read().transpose(1, 2, 0), rgb)


def test_world_to_pixel_inverts_pixel_to_world(damage_flight: DamageFlight, tmp_path: Path) -> None:
    """The mosaic's projection (pose.py) is the exact inverse of the Projector's, distortion included."""
    from icgt.geometry import Projector, load_calibration

    cam = load_calibration(damage_flight.calibration)
    assert cam.has_distortion
    frames = [f for f in read(damage_flight.flight.mcap).frames() if f.range_valid][:5]
    proj = Projector(cam, surface_normal=damage_flight.scenario.structure.normal)
    uu, vv = np.meshgrid(np.linspace(0, cam.width_px - 1, 9), np.linspace(0, cam.height_px - 1, 7))
    for rec in frames:
        pts = proj.pixel_to_world(rec, uu.ravel(), vv.ravel()).enu
        uv = world_to_pixel(cam, rec, pts)
        assert np.abs(uv - np.stack([uu.ravel(), vv.ravel()], axis=1)).max() < 1e-6
    shutil.rmtree(tmp_path, ignore_errors=True)
