"""The repeat-inspection section of `icgt report`: an `icgt compare` output shown on the flight's page.

    icgt report AFTER.mcap --compare compare-BEFORE-AFTER [--compare ...]

`--compare` names the folder `icgt compare --out` wrote (or its compare.geojson): the section reads the
GeoJSON (`icgt_comparison`: the flights, the alignment and the counts; one feature per defect with its change
and the numbers behind it) and embeds compare.png from beside it. The recording must be one of the two
compared flights (its flight id, `icgt catalog`'s: the device serial and the recording id), so a comparison of
other flights is not attached to this one's page by mistake.
"""

from __future__ import annotations

import base64
import html
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from icgt.recording.identity import file_sha256, flight_id
from icgt.report.summary import ReportError

GEOJSON = "compare.geojson"
IMAGE = "compare.png"
CHANGES = ("new", "grown", "unchanged", "repaired", "not_seen")
"""icgt.catalog.compare.CHANGES (not imported: the report stays importable without the catalogue's packages)."""


@dataclass(frozen=True)
class RepeatInspection:
    """One `icgt compare` output, as read from its folder."""

    path: Path
    """The compare.geojson read."""
    structure: str
    before: str
    after: str
    alignment: dict[str, Any]
    counts: dict[str, int]
    defects: list[dict[str, Any]]
    """Every feature's properties (change, ids, lengths, widths, their changes and sigmas)."""
    png: bytes | None
    """compare.png from beside the GeoJSON (None: not there)."""


def load(where: Path) -> RepeatInspection:
    """Read an `icgt compare` output: its folder or its compare.geojson."""
    path = where / GEOJSON if where.is_dir() else where
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ReportError(f"--compare {where}: no such file or folder ({GEOJSON} of `icgt compare --out`)") from None
    except OSError as exc:
        raise ReportError(f"--compare {where}: cannot read {path}: {exc.strerror or exc}") from None
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ReportError(f"--compare {where}: {path} is not JSON ({exc})") from None
    meta = data.get("icgt_comparison") if isinstance(data, dict) else None
    feats = data.get("features") if isinstance(data, dict) else None
    if not isinstance(meta, dict) or not isinstance(feats, list):
        raise ReportError(f"--compare {where}: {path} is not an `icgt compare` output (no icgt_comparison)")
    try:
        defects = [dict(f["properties"]) for f in feats]
        bad = sorted({str(d.get("change")) for d in defects} - set(CHANGES))
        if bad:
            raise ReportError(f"--compare {where}: {path}: unknown change {', '.join(bad)}")
        png_path = path.parent / IMAGE
        png = png_path.read_bytes() if png_path.is_file() else None
        return RepeatInspection(
            path,
            str(meta["structure"]),
            str(meta["before"]),
            str(meta["after"]),
            dict(meta["alignment"]),
            {k: int(meta["counts"].get(k, 0)) for k in CHANGES},
            defects,
            png,
        )
    except (KeyError, TypeError, AttributeError, ValueError) as exc:
        raise ReportError(f"--compare {where}: {path}: missing or malformed field {exc}") from None


def check_flight(rep: RepeatInspection, flight: str) -> None:
    """Refuse a comparison that is not of this recording's flight."""
    if flight not in (rep.before, rep.after):
        raise ReportError(
            f"--compare {rep.path}: compares {rep.before} -> {rep.after} ({rep.structure}); "
            f"this recording is flight {flight}"
        )


def _num(v: object, digits: int) -> str:
    if v is None or not isinstance(v, int | float) or not math.isfinite(float(v)):
        return ""
    return f"{float(v):.{digits}f}"


def _change(v: object, sigma: object, digits: int) -> str:
    if v is None or not isinstance(v, int | float):
        return ""
    s = _num(sigma, digits)
    return f"{float(v):+.{digits}f}" + (f" &plusmn; {s}" if s else "")


_COLUMNS = (
    "change",
    "kind",
    "before",
    "after",
    "length before [mm]",
    "length after [mm]",
    "length change [mm]",
    "width before [mm]",
    "width after [mm]",
    "width change [mm]",
    "area change [mm&sup2;]",
    "offset [mm]",
    "place seen before",
)


def _row(d: dict[str, Any]) -> str:
    seen = d.get("seen_before")
    cells = [
        f'<td class="name change-{html.escape(str(d["change"]))}">{html.escape(str(d["change"]))}</td>',
        f'<td class="name">{html.escape(str(d.get("kind") or ""))}</td>',
        f'<td class="name">{html.escape(str(d.get("before_id") or "-"))}</td>',
        f'<td class="name">{html.escape(str(d.get("after_id") or "-"))}</td>',
        f"<td>{_num(d.get('length_before_mm'), 1)}</td>",
        f"<td>{_num(d.get('length_after_mm'), 1)}</td>",
        f"<td>{_change(d.get('length_change_mm'), d.get('length_change_sigma_mm'), 1)}</td>",
        f"<td>{_num(d.get('width_before_mm'), 3)}</td>",
        f"<td>{_num(d.get('width_after_mm'), 3)}</td>",
        f"<td>{_change(d.get('width_change_mm'), d.get('width_change_sigma_mm'), 3)}</td>",
        f"<td>{_change(d.get('area_change_mm2'), d.get('area_change_sigma_mm2'), 0)}</td>",
        f"<td>{_num(d.get('distance_mm'), 1)}</td>",
        f'<td class="name">{"" if seen is None else ("yes" if seen else "no")}</td>',
    ]
    return f'<tr class="repeat-defect">{"".join(cells)}</tr>'


def section(rep: RepeatInspection, flight: str) -> tuple[str, str]:
    """(title, HTML) of the section: the alignment, the counts, every defect's change, the side-by-side image."""
    al = rep.alignment
    role = "before" if flight == rep.before else "after"
    mm = 1000.0
    shift = (
        f"s {float(al['shift_s_m']) * mm:+.1f} &plusmn; {float(al['sigma_s_m']) * mm:.1f} mm, "
        f"t {float(al['shift_t_m']) * mm:+.1f} &plusmn; {float(al['sigma_t_m']) * mm:.1f} mm"
    )
    rms = _num(al.get("residual_rms_mm"), 2)
    facts = [
        ("structure", html.escape(rep.structure)),
        ("before", html.escape(rep.before) + (" (this recording)" if role == "before" else "")),
        ("after", html.escape(rep.after) + (" (this recording)" if role == "after" else "")),
        (
            "alignment",
            f'<span id="repeat-alignment">{shift}</span> (added to the after flight\'s face coordinates; '
            f"estimated from {int(al.get('defects_used', 0))} defects"
            + (f", residual rms {rms} mm" if rms else "")
            + ")",
        ),
        ("defects", html.escape(", ".join(f"{k} {n}" for k, n in rep.counts.items()))),
        ("read from", html.escape(str(rep.path))),
    ]
    head = "".join(f"<th>{c}</th>" for c in _COLUMNS)
    rows = "".join(_row(d) for d in rep.defects)
    table = (
        f'<div class="wide"><table class="repeat"><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table></div>'
        '<p class="note">changes are after minus before, &plusmn; 1 sigma from both flights\' pose bounds and the '
        "detector; offset: the distance between the matched defects after the alignment; place seen before: "
        "whether the before flight's footprints covered a new defect's place.</p>"
    )
    if rep.png is not None:
        src = base64.b64encode(rep.png).decode("ascii")
        figure = (
            f'<figure><img id="repeat-image" alt="the face: {html.escape(rep.before)} left, '
            f'{html.escape(rep.after)} right (aligned), defects coloured by their change" '
            f'style="max-width: 100%" src="data:image/png;base64,{src}"></figure>'
        )
    else:
        figure = f'<p class="note">no {IMAGE} beside {html.escape(str(rep.path))}: the face image is not shown</p>'
    summary = "".join(f"<tr><th>{k}</th><td>{v}</td></tr>" for k, v in facts)
    body = f'<div class="repeat-inspection"><table class="summary">{summary}</table>{figure}{table}</div>'
    return f"Repeat inspection: {rep.before} -> {rep.after}", body


def recording_flight(recording: Any) -> str:
    """The recording's flight id, as `icgt catalog add` names it."""
    ident, _rid, _kind = flight_id(recording.metadata, "")
    if ident.startswith("log-"):  # no serial or recording id: identified by its content
        try:
            digest = file_sha256(Path(recording.path))
        except OSError as exc:
            raise ReportError(f"cannot read {recording.path}: {exc.strerror or exc}") from None
        ident, _rid, _kind = flight_id(recording.metadata, digest)
    return ident
