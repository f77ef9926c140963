"""`icgt compare`: the comparison of two inspections (icgt.catalog.compare) as GeoJSON, a side-by-side image of
the face and a table in the terminal.

    icgt compare --structure pier-7 --before FLIGHT --after FLIGHT [--catalog DIR] [--out DIR]

writes DIR/compare.geojson (the before flight's face frame, (s, t) metres, as `icgt map`'s face GeoJSON:
`icgt_face_frame` names it; every defect once, with its change and the numbers behind it) and
DIR/compare.png (the face: the before flight on the left, the after one aligned on the right, the
footprints shaded, every defect coloured by its change).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import shapely

from icgt.catalog import CatalogError
from icgt.catalog.compare import CHANGES, Change, Comparison, compare

COLOURS = {"new": "#d62728", "grown": "#ff7f0e", "unchanged": "#1f77b4", "repaired": "#2ca02c", "not_seen": "#7f7f7f"}


def _r(v: float | None, nd: int = 2) -> float | None:
    return None if v is None else round(float(v), nd)


def _coords(g: Any) -> list[list[float]]:
    return [[round(float(x), 5), round(float(y), 5)] for x, y in shapely.get_coordinates(g)]


def _feature(c: Change) -> dict[str, Any]:
    d = c.after if c.after is not None else c.before
    assert d is not None
    geom = (
        {"type": "LineString", "coordinates": _coords(d.geom)}
        if d.geom.geom_type == "LineString"
        else {"type": "Polygon", "coordinates": [_coords(d.geom.exterior)]}
    )
    b, a = c.before, c.after
    props = {
        "change": c.change,
        "kind": d.kind,
        "before_id": b.id if b else None,
        "after_id": a.id if a else None,
        "length_before_mm": _r(b.length_mm, 1) if b else None,
        "length_after_mm": _r(a.length_mm, 1) if a else None,
        "length_change_mm": _r(c.length_change_mm),
        "length_change_sigma_mm": _r(c.length_change_sigma_mm),
        "width_before_mm": _r(b.width_mm, 3) if b else None,
        "width_after_mm": _r(a.width_mm, 3) if a else None,
        "width_change_mm": _r(c.width_change_mm, 3),
        "width_change_sigma_mm": _r(c.width_change_sigma_mm, 3),
        "area_change_mm2": _r(c.area_change_mm2, 0),
        "area_change_sigma_mm2": _r(c.area_change_sigma_mm2, 0),
        "distance_mm": _r(c.distance_mm),
        "seen_before": c.seen_before,
        "before_geometry": _coords(b.geom) if b and a else None,
    }
    return {"type": "Feature", "geometry": geom, "properties": props}


def to_geojson(cmp: Comparison) -> dict[str, Any]:
    al = cmp.alignment
    s_sig, t_sig = al.sigma_m
    return {
        "type": "FeatureCollection",
        "icgt_face_frame": cmp.face_frame,
        "icgt_comparison": {
            "structure": cmp.before.structure,
            "before": cmp.before.flight,
            "after": cmp.after.flight,
            "alignment": {
                "note": "added to the after flight's face coordinates to put them on the before flight's face",
                "shift_s_m": round(float(al.shift_m[0]), 5),
                "shift_t_m": round(float(al.shift_m[1]), 5),
                "sigma_s_m": round(s_sig, 5),
                "sigma_t_m": round(t_sig, 5),
                "defects_used": al.pairs,
                "residual_rms_mm": _r(al.rms_mm, 3),
            },
            "counts": cmp.counts(),
        },
        "features": [_feature(c) for c in cmp.changes],
    }


def render(cmp: Comparison, path: Path) -> None:
    """The face, before on the left and after (aligned) on the right, defects coloured by their change."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    fig, axes = plt.subplots(1, 2, figsize=(12, 5), sharex=True, sharey=True)
    shift = cmp.alignment.shift_m
    panels = [
        (axes[0], cmp.before.coverage, [(c, c.before) for c in cmp.changes if c.before], cmp.before.flight),
        (axes[1], shapely.transform(cmp.after.coverage, lambda p: p + shift),
         [(c, c.after) for c in cmp.changes if c.after], cmp.after.flight),
    ]  # fmt: skip
    for ax, cover, defects, title in panels:
        for poly in getattr(cover, "geoms", [cover]):
            if not poly.is_empty and poly.geom_type == "Polygon":
                x, y = poly.exterior.xy
                ax.fill(x, y, color="#dddddd", zorder=0)
        for c, d in defects:
            xy = shapely.get_coordinates(d.geom if d.geom.geom_type == "LineString" else d.geom.exterior)
            ax.plot(xy[:, 0], xy[:, 1], color=COLOURS[c.change], lw=2.5, zorder=2)
        ax.set_title(title)
        ax.set_xlabel("s along the face [m]")
        ax.set_aspect("equal")
    axes[0].set_ylabel("t up the face [m]")
    handles = [Line2D([], [], color=COLOURS[k], lw=2.5, label=f"{k} ({n})") for k, n in cmp.counts().items()]
    fig.legend(handles=handles, loc="lower center", ncol=len(CHANGES))
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    try:
        fig.savefig(path, dpi=100)
    except OSError as exc:
        raise CatalogError(f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        plt.close(fig)


def summary(cmp: Comparison) -> str:
    al = cmp.alignment
    s_sig, t_sig = al.sigma_m
    lines = [
        f"{cmp.before.structure}: {cmp.before.flight} -> {cmp.after.flight}",
        f"alignment: shift s {al.shift_m[0] * 1000:+.1f} +- {s_sig * 1000:.1f} mm, "
        f"t {al.shift_m[1] * 1000:+.1f} +- {t_sig * 1000:.1f} mm ({al.pairs} defects, rms {al.rms_mm:.2f} mm)",
        "  ".join(f"{k} {n}" for k, n in cmp.counts().items()),
    ]
    for c in cmp.changes:
        ids = f"{c.before.id if c.before else '-'} -> {c.after.id if c.after else '-'}"
        extra = ""
        if c.length_change_mm is not None:
            extra = f"  length {c.length_change_mm:+.1f} +- {c.length_change_sigma_mm:.1f} mm"
        lines.append(f"  {c.change:<9} {ids}{extra}")
    return "\n".join(lines)


def run_compare(root: Path, structure: str, before: str, after: str, out: Path, **kw: Any) -> Comparison:
    cmp = compare(root, structure, before=before, after=after, **kw)
    try:
        out.mkdir(parents=True, exist_ok=True)
        text = json.dumps(to_geojson(cmp), indent=1) + "\n"
        (out / "compare.geojson").write_text(text, encoding="utf-8")
    except OSError as exc:
        raise CatalogError(f"cannot write {out}: {exc.strerror or exc}") from None
    if (
        json.loads((out / "compare.geojson").read_text(encoding="utf-8"))["icgt_comparison"]
        != json.loads(text)["icgt_comparison"]
    ):
        raise CatalogError(f"{out / 'compare.geojson'} does not read back as written")
    render(cmp, out / "compare.png")
    return cmp


def cmd_compare(args: argparse.Namespace) -> int:
    from icgt.catalog.files import check_structure

    check_structure(args.structure)
    out = args.out or Path(f"compare-{args.before}-{args.after}")
    cmp = run_compare(args.catalog, args.structure, args.before, args.after, out, k_sigma=args.k_sigma,
                      search_m=args.search_m, min_gate_mm=args.min_gate_mm)  # fmt: skip
    print(summary(cmp))
    print(f"written: {out / 'compare.geojson'}, {out / 'compare.png'}")
    return 0


def add_compare_arguments(p: argparse.ArgumentParser) -> None:
    from icgt.catalog.cli import default_catalog

    p.add_argument("--structure", required=True, help="the structure both flights inspected")
    p.add_argument("--before", required=True, help="the earlier flight's id (icgt catalog query 'FROM flights')")
    p.add_argument("--after", required=True, help="the later flight's id")
    p.add_argument("--catalog", type=Path, default=default_catalog(), help="the catalogue folder ($ICGT_CATALOG)")
    p.add_argument("--out", type=Path, help="output folder (compare-BEFORE-AFTER)")
    p.add_argument("--k-sigma", type=float, default=3.0, help="a change is real beyond this many sigma (3)")
    p.add_argument("--search-m", type=float, default=2.0, help="largest shift between the flights searched [m] (2)")
    p.add_argument("--min-gate-mm", type=float, default=20.0, help="smallest matching distance [mm] (20)")
    p.set_defaults(func=cmd_compare)
