"""`icgt report` and `icgt info` on one simulated flight; the page rendered in headless Chromium.

The page is checked as a browser sees it: Chromium (Debian's package, installed by .ci/run)
renders it to a screenshot that must be a real picture (not blank) with no console message, and
the same console check must catch a page that does log errors (so it can fail). The HTML itself
must be self-contained: no script, no reference outside the page, every figure inline, one table
row per frame.
"""

from __future__ import annotations

import html
import html.parser
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from icgt.cli import main
from icgt.ingest import read

WIDTH, HEIGHT = 1280, 3000


def chromium() -> str:
    exe = shutil.which("chromium")
    if exe is None:
        pytest.fail("chromium is missing: run .ci/run (it installs Debian's chromium package)")
    return exe


def render(page: Path, png: Path) -> list[str]:
    """Screenshot `page` with headless Chromium; returns the page's console messages."""
    cmd = [
        chromium(),
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--hide-scrollbars",
        "--no-first-run",
        f"--window-size={WIDTH},{HEIGHT}",
        f"--screenshot={png}",
        "--enable-logging=stderr",
        "--v=0",
        page.resolve().as_uri(),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return [line for line in done.stderr.splitlines() if ":CONSOLE" in line]


class _Page(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[str] = []
        self.refs: list[str] = []
        self.rows = 0
        self._tbody = False

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append(tag)
        for name, value in attrs:
            if (
                name in ("src", "href", "xlink:href", "srcset", "action")
                and value
                and not value.startswith(("#", "data:"))
            ):
                self.refs.append(value)
        if tag == "tbody":
            self._tbody = True
        elif tag == "tr" and self._tbody:
            self.rows += 1

    def handle_endtag(self, tag: str) -> None:
        if tag == "tbody":
            self._tbody = False


@pytest.fixture(scope="module")
def report(export_flight: Any, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("report") / "report.html"
    args = ["report", str(export_flight.mcap), "--images", str(export_flight.card), "--out", str(out)]
    assert main(args) == 0
    return out


def test_page_is_self_contained(report: Path, export_flight: Any) -> None:
    text = report.read_text(encoding="utf-8")
    page = _Page()
    page.feed(text)
    assert "script" not in page.tags
    assert page.refs == [], page.refs  # only in-page anchors and inline data: (the coverage raster)
    assert not re.search(r"url\(\s*['\"]?(?!#)", text), "a CSS url() reference"
    assert page.tags.count("svg") == 5  # track, footprints, timeline, clock, quality
    frames = list(read(export_flight.mcap).frames())
    assert page.rows == len(frames) > 10  # ~45 (5 fps), fewer on a loaded machine
    names = sorted(p.name for p in export_flight.card.glob("*.JPG"))
    assert sum(name in text for name in names) == len(names)  # every card image matched and listed
    for section in ("Track and frame positions", "Footprints on the structure face", "Timeline", "Clock uncertainty"):
        assert section in text


def test_chromium_renders_it_without_console_messages(report: Path, tmp_path: Path) -> None:
    png = tmp_path / "report.png"
    console = render(report, png)
    assert console == []
    with Image.open(png) as img:
        assert img.size == (WIDTH, HEIGHT)
        pixels = np.asarray(img.convert("L"), dtype=np.float64)
    # a real page: mostly background, with a good share of drawn pixels in every band of the page
    ink = pixels < 200
    assert 0.02 < ink.mean() < 0.6
    bands = np.array_split(ink[: HEIGHT // 2], 6)
    assert all(band.mean() > 0.005 for band in bands)


def test_console_check_catches_errors(tmp_path: Path) -> None:
    bad = tmp_path / "bad.html"
    bad.write_text(
        '<!DOCTYPE html><html><body><p>x</p><script>console.error("boom"); missing();</script></body></html>'
    )
    console = render(bad, tmp_path / "bad.png")
    assert any("boom" in line for line in console)
    assert any("ReferenceError" in line for line in console)


def test_info_prints_the_summary(export_flight: Any, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(export_flight.mcap)]) == 0
    out = capsys.readouterr().out
    frames = list(read(export_flight.mcap).frames())
    assert re.search(rf"^frames\s+{len(frames)}$", out, re.M)
    assert re.search(r"^face coverage\s+\d+\.\d+ m\^2 covered", out, re.M)
    assert re.search(r"^device->host clock bound\s+median [\d.e+]+, 95% [\d.e+]+, max [\d.e+]+ us$", out, re.M)
    assert "feedback_missing 1" in out  # the one trigger the camera ignored (export_flight.toml)


def test_report_refuses_a_missing_log(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", str(tmp_path / "nope.mcap"), "--out", str(tmp_path / "r.html")]) == 1
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()


def test_the_track_plot_spans_the_flight_not_the_positions_before_the_fix(export_flight: Any) -> None:
    """The flight's telemetry starts without a fix (latitude/longitude 0, as real autopilots send): those
    samples are counted on the page, not drawn, and the plan and elevation views span what the frames span."""
    from icgt.report.plots import _plt, track_axes
    from icgt.report.summary import NO_FIX, gather

    data = gather(read(export_flight.mcap))
    assert data.track_left_out.get(NO_FIX, 0) > 10, data.track_left_out
    pos = np.array([(r.east_m, r.north_m, r.up_m) for r in data.frames if r.east_m is not None], dtype=float)
    assert len(pos) > 20
    fig, plan, elev = track_axes(data)
    try:
        margin_m = 5.0  # the hover's sway and the track's ends beyond the frames, and the axes' padding
        (x0, x1), (y0, y1) = plan.get_xlim(), plan.get_ylim()
        e, n = pos[:, 0], pos[:, 1]
        span = max(e.max() - e.min(), n.max() - n.min())
        assert x0 <= e.min() and e.max() <= x1 and y0 <= n.min() and n.max() <= y1
        assert max(x1 - x0, y1 - y0) < span + 2 * margin_m + 10.0, ((x0, x1), (y0, y1), span)
        (_a0, _a1), (z0, z1) = elev.get_xlim(), elev.get_ylim()
        assert z0 <= pos[:, 2].min() and pos[:, 2].max() <= z1
        assert z1 - z0 < (pos[:, 2].max() - pos[:, 2].min()) + 2 * margin_m + 10.0 + span, (z0, z1)
    finally:
        _plt().close(fig)
    page = Path(str(export_flight.mcap)).parent / "track_report.html"
    assert main(["report", str(export_flight.mcap), "--out", str(page)]) == 0
    note = re.search(r'id="track-left-out">([^<]*)<', page.read_text())
    assert note is not None and "not drawn:" in note.group(1) and NO_FIX in html.unescape(note.group(1))
