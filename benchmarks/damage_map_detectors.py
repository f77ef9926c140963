#!/usr/bin/env python3
"""Benchmark: the damage map from detectors that err and from pixels, against the truth and the paper's method.

    .venv/bin/python benchmarks/damage_map_detectors.py [--regenerate] [--seeds N]

The damage-map test flight (tests/mapping/damage_flight.toml, cached by benchmarks/damage_map.py under
build/bench/damage_flight/) with stains and a formwork joint painted on the face
(tests/mapping/conftest.py: with_lookalikes). Detectors, each into `icgt map` (merged, multi-view
consensus; only *confirmed* defects are counted), and the same detections by the paper's per-image
method (each detection its own defect, on its own image's plane; eqs 5-7):

  - projected: the truth projected into each image with the true pose (icgt.sim.detector), the
    old benchmark's detector, for reference;
  - projected + errors: the same through icgt.sim.detector_errors (per-image precision 0.8, recall
    0.85, pieces, gaps, end and width noise, random false positives, look-alikes reported at 0.25);
    seed 7 in the table, and the worst of `--seeds` seeds below it;
  - pixels: icgt.mapping.pixel_detector on the card rendered again at 1800 px wide (1.13 mm/px at the
    2 m standoff, cached), COCO polygons. Cracks only (it detects no spalls). A crack narrower than
    0.3 px at the GSD is under the detection limit (docs/damage-detectors.md); here only C3 (0.3 mm,
    0.27 px) is, and it is scored all the same: all five cracks count.

Then the bare face: the same flight over the face with its stains and joint and no defect, both
detectors: confirmed defects (target 0) and what the per-image method reports.
Targets per detector: merged precision and recall >= 0.95; crack length p95 <= 5 % (10 % for pixels);
position p95 <= the flight's geotag p95 + the LiDAR's range noise (2.5 cm).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import shapely

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "benchmarks"))
RANGE_NOISE_M = 0.025
PIXEL_WIDTH = 1800


@dataclass
class Row:
    name: str
    truth: int
    reported: int
    matched: int
    length: tuple[float, float]
    position: tuple[float, float]

    @property
    def precision(self) -> float:
        return self.matched / self.reported if self.reported else float("nan")

    @property
    def recall(self) -> float:
        return self.matched / self.truth if self.truth else float("nan")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--regenerate", action="store_true", help="fly and render the cached inputs again")
    ap.add_argument("--seeds", type=int, default=5, help="error-model seeds for the worst case (default 5)")
    args = ap.parse_args()

    from damage_map import SCENARIO, _flight
    from mapping.conftest import LOOKAHEAD_S, read_exposures, with_lookalikes

    from icgt.geometry import Projector
    from icgt.mapping.cli import MapResult, run_map
    from icgt.mapping.model import CRACK, midpoint
    from icgt.mapping.pixel_detector import PixelDetector, detect_cards
    from icgt.mapping.place import Errors
    from icgt.sim.camera_card import rerender_card
    from icgt.sim.detector import SimDetection, detect_all, write_polylines
    from icgt.sim.detector_errors import detect_with_errors
    from icgt.sim.map_truth import MappedItem, TrueDefect, compare, geotag_errors_m, load_truth, p50_p95
    from icgt.sim.render import TAG_BOX_PX
    from icgt.sim.scenario import load_scenario

    base = _flight(args.regenerate)
    info = json.loads((base / "done.json").read_text())
    mcap, card = base / info["mcap"], base / info["card"]
    sim = card.parent
    sc0 = load_scenario(SCENARIO)
    exposures = read_exposures(sim / "truth_exposures.jsonl")
    out = base / "detectors"
    out.mkdir(exist_ok=True)

    def run(dets_path: Path, images: Path, name: str) -> MapResult:
        return run_map(mcap, images, [dets_path], out / f"map_{name}", calibration=sim / "camera_calibration.toml",
                       errors=Errors(position_m=0.015), mm_per_px=None, lookahead_s=LOOKAHEAD_S)  # fmt: skip

    def merged(res: MapResult) -> list[MappedItem]:
        items = []
        for inst in res.instances:
            if inst.status != "confirmed":
                continue
            mid = midpoint(inst.enu) if inst.kind == CRACK else res.session.face.to_enu(
                np.asarray(shapely.Polygon(inst.face).centroid.coords[0]))  # fmt: skip
            items.append(MappedItem(inst.kind, mid, inst.length_mm, inst.area_mm2))
        return items

    def paper(res: MapResult) -> list[MappedItem]:
        ses = res.session
        proj = Projector(ses.camera, origin=ses.origin)
        items = []
        for p in res.placed:
            rec = ses.images[p.det.image][1]
            f = ses.camera.width_px / ses.size(p.det.image)[0]
            px = (p.det.points_px + 0.5) * f - 0.5
            if p.det.kind == CRACK:
                c = proj.crack_position(rec, px)
                items.append(MappedItem(CRACK, c.midpoint_enu, c.length_mm_paper))
            else:
                w = proj.pixel_to_world(rec, px[:, 0], px[:, 1])
                items.append(MappedItem(p.det.kind, w.enu.mean(axis=0), None, shapely.Polygon(w.plane_st).area * 1e6))
        return items

    def row(name: str, truth: list[TrueDefect], items: list[MappedItem]) -> Row:
        c = compare(truth, items)
        return Row(name, len(truth), c.reported, c.matched, p50_p95(c.length_err_pct), p50_p95(c.position_err_mm))

    def polylines(dets: list[SimDetection], name: str) -> Path:
        path = out / f"{name}.json"
        write_polylines(path, dets)
        return path

    rows: list[Row] = []
    t0 = time.process_time()
    # projected, exact
    res = run(polylines(detect_all(sc0, exposures, seed=7), "projected"), card, "projected")
    truth = load_truth(sim / "truth_defects.json", res.session.origin)
    cracks = [t for t in truth if t.kind == CRACK]
    geotag = geotag_errors_m(res.session.frames, sim / "truth_exposures.jsonl", sc0, res.session.origin)
    bound = (float(np.percentile(geotag, 95)) + RANGE_NOISE_M) * 1000.0
    rows += [row("projected: icgt map", truth, merged(res)), row("projected: paper per image", truth, paper(res))]
    # projected + errors, on the face with look-alikes
    sc = with_lookalikes(sc0)
    worst: dict[str, float] = {"precision": 1.0, "recall": 1.0, "length_p95": 0.0, "position_p95": 0.0}
    for seed in [7, *range(1, args.seeds + 1)]:
        dets, rep = detect_with_errors(sc, exposures, seed=seed)
        res = run(polylines(dets, f"errors_{seed}"), card, f"errors_{seed}")
        r = row("projected + errors: icgt map", truth, merged(res))
        if seed == 7:
            print(f"error model, seed 7: per image precision {rep.precision:.3f}, recall {rep.recall:.3f} "
                  f"({rep.true_reports} true, {rep.lookalike_reports} look-alike, "
                  f"{rep.random_reports} random reports)")  # fmt: skip
            rows += [r, row("projected + errors: paper per image", truth, paper(res))]
        worst["precision"] = min(worst["precision"], r.precision)
        worst["recall"] = min(worst["recall"], r.recall)
        worst["length_p95"] = max(worst["length_p95"], r.length[1])
        worst["position_p95"] = max(worst["position_p95"], r.position[1])
    # pixels
    pix_sc = with_lookalikes(sc0, render_width_px=PIXEL_WIDTH)
    pix_card = base / f"card_{PIXEL_WIDTH}"
    if args.regenerate or not pix_card.is_dir():
        print(f"rendering the card at {PIXEL_WIDTH} px (a minute or two, cached) ...", flush=True)
        rerender_card(pix_sc, exposures, card, pix_card)
    n = detect_cards(sorted(pix_card.glob("*.JPG")), out / "pixels.json", PixelDetector(exclude=(TAG_BOX_PX,)))
    res = run(out / "pixels.json", pix_card, "pixels")
    rows += [row("pixels: icgt map", cracks, merged(res)), row("pixels: paper per image", cracks, paper(res))]
    # the bare face
    bare_sc = with_lookalikes(sc0, defects=False)
    dets, _ = detect_with_errors(bare_sc, exposures, seed=7)
    res_e = run(polylines(dets, "bare_errors"), card, "bare_errors")
    bare_card = base / f"card_{PIXEL_WIDTH}_bare"
    if args.regenerate or not bare_card.is_dir():
        rerender_card(with_lookalikes(sc0, defects=False, render_width_px=PIXEL_WIDTH), exposures, card, bare_card)
    detect_cards(sorted(bare_card.glob("*.JPG")), out / "bare_pixels.json", PixelDetector(exclude=(TAG_BOX_PX,)))
    res_p = run(out / "bare_pixels.json", bare_card, "bare_pixels")
    cpu = time.process_time() - t0

    print(f"\n{len(truth)} true defects ({len(cracks)} cracks), {len(res.session.images)} images, pixel detector "
          f"{n} cracks at {PIXEL_WIDTH} px; geotag p95 {np.percentile(geotag, 95) * 1000:.1f} mm, position target "
          f"p95 <= {bound:.1f} mm; CPU {cpu:.0f} s")  # fmt: skip
    print(
        f"| {'detector: method':<36} | reported | precision | recall | length err % p50 / p95 | position mm p50 / p95 |"
    )
    print(f"|{'-' * 38}|---------:|----------:|-------:|-----------------------:|----------------------:|")
    for r in rows:
        print(f"| {r.name:<36} | {r.reported:>8} | {r.precision:>9.3f} | {r.recall:>6.3f} | "
              f"{r.length[0]:>10.2f} / {r.length[1]:<9.2f} | "
              f"{r.position[0]:>9.1f} / {r.position[1]:<9.1f} |")  # fmt: skip
    print(f"\nprojected + errors, worst of seeds 7 and 1..{args.seeds}: precision {worst['precision']:.3f}, "
          f"recall {worst['recall']:.3f}, length p95 {worst['length_p95']:.2f} %, "
          f"position p95 {worst['position_p95']:.1f} mm")  # fmt: skip
    for name, rb in (("projected + errors", res_e), ("pixels", res_p)):
        conf = sum(i.status == "confirmed" for i in rb.instances)
        seen = max((i.n_seen for i in rb.instances), default=0)
        print(f"bare face (stains + joint, no defect), {name}: {conf} confirmed of {len(rb.instances)} merged "
              f"(most consistent: seen in {seen} images); the paper's method reports {len(rb.placed)}")  # fmt: skip
    ok = True
    for r in rows:
        if "icgt map" not in r.name or r.name.startswith("projected:"):
            continue
        lim = 10.0 if r.name.startswith("pixels") else 5.0
        ok &= r.precision >= 0.95 and r.recall >= 0.95 and r.length[1] <= lim and r.position[1] <= bound
    ok &= worst["precision"] >= 0.95 and worst["recall"] >= 0.95 and worst["length_p95"] <= 5.0
    ok &= not any(i.status == "confirmed" for rb in (res_e, res_p) for i in rb.instances)
    print(f"targets: {'met' if ok else 'NOT MET'}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
