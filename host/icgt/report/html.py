"""The flight report as one self-contained HTML page: inline CSS and SVG, no script, no network."""

from __future__ import annotations

import html
import math
from collections.abc import Sequence
from pathlib import Path

from icgt.report import plots
from icgt.report.summary import OUTSIDE, FlightData, ReportError, summarize

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; font-size: 0.85em; }
td, th { border: 1px solid #ddd; padding: 2px 6px; text-align: right; white-space: nowrap; }
th { background: #f3f3f3; position: sticky; top: 0; }
table.summary td { text-align: left; white-space: normal; }
td.flags, td.name { text-align: left; }
tr.flagged td { background: #fff1f0; }
figure { margin: 0.5em 0; } figure svg { max-width: 100%; height: auto; }
.note { color: #666; font-size: 0.9em; }
.frames { max-height: 40em; overflow: auto; }
td.change-new { color: #d62728; } td.change-grown { color: #ff7f0e; } td.change-repaired { color: #2ca02c; }
td.change-not_seen { color: #7f7f7f; } .wide { overflow-x: auto; }
"""

_COLUMNS = (
    ("frame", "frame_seq", None),
    ("image", None, None),
    ("mid UTC", None, None),
    ("lat [deg]", "lat_deg", 7),
    ("lon [deg]", "lon_deg", 7),
    ("alt MSL [m]", "alt_msl_m", 2),
    ("h acc [m]", "h_acc_m", 2),
    ("range [m]", "range_m", 3),
    ("GSD [mm/px]", "scale_mm_per_px", 3),
    ("blur [px]", "blur_px", 2),
    ("clock bound [us]", None, None),
    ("UTC bound [us]", "mid_utc_uncertainty_us", 0),
    ("flags", None, None),
)


def _cell(value: object, digits: int | None) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        if not math.isfinite(value):
            return ""
        return f"{value:.{digits}f}" if digits is not None else f"{value:g}"
    return html.escape(str(value))


def _frame_table(data: FlightData) -> str:
    from icgt.export.common import utc_iso

    head = "".join(f"<th>{html.escape(c[0])}</th>" for c in _COLUMNS)
    rows = []
    for r in data.frames:
        cells = []
        for label, name, digits in _COLUMNS:
            if label == "image":
                cells.append(f'<td class="name">{html.escape(data.images.get(r.frame_seq, ""))}</td>')
            elif label == "mid UTC":
                cells.append(f"<td>{html.escape(utc_iso(r.mid_utc_us))}</td>")
            elif label == "clock bound [us]":
                cells.append(f"<td>{r.mid_host_uncertainty_ns / 1000.0:.0f}</td>")
            elif label == "flags":
                cells.append(f'<td class="flags">{html.escape(", ".join(r.flags))}</td>')
            else:
                assert name is not None
                cells.append(f"<td>{_cell(getattr(r, name), digits)}</td>")
        cls = ' class="flagged"' if r.flags else ""
        rows.append(f"<tr{cls}>{''.join(cells)}</tr>")
    return f'<div class="frames"><table><thead><tr>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table></div>'


def _left_out_note(data: FlightData) -> str:
    """What the track figure does not draw, and why (nothing is left out silently)."""
    parts = [f"{n} track samples: {why}" for why, n in data.track_left_out.items()]
    outside = plots.frames_outside(data)
    if outside:
        parts.append(f"{outside} frames: {OUTSIDE}")
    if not parts:
        return '<p class="note" id="track-left-out">every track sample and frame position is drawn</p>'
    return f'<p class="note" id="track-left-out">not drawn: {html.escape("; ".join(parts))}</p>'


def render(data: FlightData, repeat: Sequence[tuple[str, str]] = ()) -> str:
    """The whole page; `repeat`: (title, HTML) of each repeat-inspection section (icgt.report.repeat), shown after
    the summary."""
    from icgt.version import __version__

    summary = "".join(f"<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>" for k, v in summarize(data))
    footprints = plots.footprint_figure(data)
    sections = [
        ("Summary", f'<table class="summary">{summary}</table>'),
        *repeat,
        ("Track and frame positions", f"<figure>{plots.track_figure(data)}</figure>{_left_out_note(data)}"),
        (
            "Footprints on the structure face (coverage and overlap)",
            f"<figure>{footprints}</figure>"
            if footprints
            else f'<p class="note">{html.escape(data.footprint_note or "no footprints")}</p>',
        ),
        ("Timeline: capture, outages, losses and flags", f"<figure>{plots.timeline_figure(data)}</figure>"),
        ("Clock uncertainty", f"<figure>{plots.clock_figure(data)}</figure>"),
        ("Geotag quality", f"<figure>{plots.quality_figure(data)}</figure>"),
        (f"Frames ({len(data.frames)})", _frame_table(data)),
    ]
    body = "".join(f"<h2>{html.escape(title)}</h2>\n{content}\n" for title, content in sections)
    title = f"ICGT flight report: {data.path.name}"
    return (
        "<!DOCTYPE html>\n"
        '<html lang="en"><head><meta charset="utf-8">'
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n"
        f"<h1>{html.escape(title)}</h1>\n"
        f'<p class="note">made by icgt {html.escape(__version__)}; times in seconds from the first message '
        "of the recording (host clock), positions in metres east/north/up of the recording's ENU origin.</p>\n"
        f"{body}</body></html>\n"
    )


def write_report(data: FlightData, out: Path, repeat: Sequence[tuple[str, str]] = ()) -> int:
    """Write the page to `out`; returns its size in bytes (read back)."""
    text = render(data, repeat)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(text, encoding="utf-8")
        size = out.stat().st_size
    except OSError as exc:
        raise ReportError(f"cannot write {out}: {exc.strerror or exc}") from exc
    if size != len(text.encode("utf-8")):
        raise ReportError(f"{out}: {size} bytes on disk, {len(text.encode())} written")
    return size
