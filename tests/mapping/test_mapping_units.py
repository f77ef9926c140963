"""The damage map's parts on small made-up inputs (no flight): readers, shapes, merging, the scenario table."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from pycocotools import mask as coco_mask

from icgt.geometry import Plane
from icgt.mapping import MappingError
from icgt.mapping.detections import read_detections
from icgt.mapping.merge import build_instances, group
from icgt.mapping.model import Detection, Placed
from icgt.mapping.shapes import centreline, decode_rle, outlines
from icgt.mapping.surface import _face
from icgt.sim.scenario import ScenarioError, load_scenario, parse_scenario

HERE = Path(__file__).resolve().parent


def _size(_: str) -> tuple[int, int]:
    return (40, 30)


def test_rle_compressed_and_uncompressed_decode_alike() -> None:
    m = np.zeros((30, 40), dtype=np.uint8, order="F")
    m[5:9, 10:31] = 1
    rle = coco_mask.encode(m)
    a = decode_rle({"size": [30, 40], "counts": rle["counts"].decode("ascii")}, "x")
    flat = m.ravel(order="F")
    runs, cur, n = [], 0, 0
    for v in flat:
        if v != cur:
            runs.append(n)
            cur, n = v, 0
        n += 1
    runs.append(n)
    b = decode_rle({"size": [30, 40], "counts": runs}, "x")
    assert np.array_equal(a, m.astype(bool)) and np.array_equal(b, a)
    with pytest.raises(MappingError, match="sum to"):
        decode_rle({"size": [30, 40], "counts": [5, 5]}, "x")


def test_crack_mask_centreline_and_width() -> None:
    m = np.zeros((30, 40), dtype=bool)
    m[10:13, 5:36] = True  # 3 px wide, 31 px long
    line, width = centreline(m)  # type: ignore[misc]
    assert line[0] == pytest.approx([5.0, 11.0]) and line[-1] == pytest.approx([35.0, 11.0])
    assert width == pytest.approx(3.0)
    (ring,) = outlines(m)
    assert {tuple(p) for p in ring} == {(4.5, 9.5), (35.5, 9.5), (35.5, 12.5), (4.5, 12.5)}


def test_coco_reader(tmp_path: Path) -> None:
    coco = {
        "images": [{"id": 7, "file_name": "DCIM/DSC00001.JPG", "width": 40, "height": 30}],
        "categories": [{"id": 1, "name": "Crack"}, {"id": 2, "name": "spalling"}],
        "annotations": [
            {"image_id": 7, "category_id": 2, "segmentation": [[10, 10, 20, 10, 20, 20, 10, 20]], "score": 0.5},
            {"image_id": 7, "category_id": 1, "segmentation": [[5, 10, 36, 10, 36, 13, 5, 13]]},
        ],
    }
    p = tmp_path / "c.json"
    p.write_text(json.dumps(coco))
    spall, crack = read_detections(p, _size, {})
    assert spall.image == "DSC00001.JPG" and spall.kind == "spalling" and spall.score == 0.5
    assert spall.points_px[0] == pytest.approx([9.5, 9.5])  # COCO counts from the pixel corner
    assert crack.kind == "crack" and crack.width_px == pytest.approx(3.0)
    coco["annotations"][0]["image_id"] = 3  # type: ignore[index]
    p.write_text(json.dumps(coco))
    with pytest.raises(MappingError, match="image_id 3"):
        read_detections(p, _size, {})
    p.write_text(json.dumps(coco["annotations"]))
    with pytest.raises(MappingError, match="cannot name its images"):
        read_detections(p, _size, {})


def test_yolo_reader(tmp_path: Path) -> None:
    d = tmp_path / "labels"
    d.mkdir()
    (d / "DSC00001.txt").write_text("1 0.25 0.25 0.5 0.25 0.5 0.5 0.25 0.5 0.9\n")
    with pytest.raises(MappingError, match="class names"):
        read_detections(d, _size, {"DSC00001": "DSC00001.JPG"})
    (d / "data.yaml").write_text("path: x\nnames:\n  0: crack\n  1: spalling\n")
    (det,) = read_detections(d, _size, {"DSC00001": "DSC00001.JPG"})
    assert det.kind == "spalling" and det.score == pytest.approx(0.9)
    assert det.points_px[0] == pytest.approx([0.25 * 40 - 0.5, 0.25 * 30 - 0.5])
    (d / "DSC00001.txt").write_text("0 0.25 0.25 1.5 0.25 0.5 0.5\n")
    with pytest.raises(MappingError, match="normalised"):
        read_detections(d, _size, {"DSC00001": "DSC00001.JPG"})


def _placed(image: str, pts: list[list[float]], cut: tuple[bool, bool] = (False, False)) -> Placed:
    face = np.asarray(pts, dtype=np.float64)
    enu = np.column_stack([face[:, 0], np.zeros(len(face)), face[:, 1]])
    length = float(np.sum(np.linalg.norm(np.diff(face, axis=0), axis=1)) * 1000)
    det = Detection(image, "crack", "crack", np.zeros((2, 2)), 1.0)
    return Placed(det, 1, face, enu, length, 1.0, None, 5.0, 1.0, 2.0, any(cut), cut)


def test_merge_pieces_and_keep_neighbours_apart() -> None:
    face = _face(Plane((0.0, 0.0, 0.0), (0.0, -1.0, 0.0)), np.array([[0.0, -2.0, 0.0]]), "test")
    whole = _placed("a", [[0.0, 0.0], [1.0, 0.0]])
    left = _placed("b", [[-0.002, 0.003], [0.6, 0.003]], (False, True))
    right = _placed("c", [[0.5, -0.002], [1.001, -0.002]], (True, False))
    other = _placed("d", [[0.0, 0.1], [1.0, 0.1]])  # a parallel crack 100 mm away
    assert sorted(map(sorted, group([whole, left, right, other]))) == [[0, 1, 2], [3]]
    (one,) = build_instances([left, right], face, 5.0)
    assert one.images == ["b", "c"]
    assert one.length_mm == pytest.approx(1003.0, abs=3.0)


def test_scenario_surface_table(tmp_path: Path) -> None:
    sc = load_scenario(HERE / "damage_flight.toml")
    assert sc.surface is not None and len(sc.surface.cracks) == 5 and sc.camera.k1 == -0.06
    text = (HERE / "damage_flight.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('texture = "concrete"', 'texture = "concrete"\nglitter = 1'))
    with pytest.raises(ScenarioError, match=r"surface\.glitter"):
        load_scenario(bad)
    import tomllib

    data = tomllib.loads(text)
    data["surface"]["spalls"][0]["points_m"] = data["surface"]["cracks"][0]["points_m"][:3]
    with pytest.raises(ScenarioError, match="closer than 50 mm"):
        parse_scenario(data, "x.toml")
