"""`icgt report` and `icgt info`: a flight at a glance, as one HTML page or a terminal summary.

`icgt.report.summary` gathers what the report shows from a recording (`icgt.read`), `plots` draws
the figures (matplotlib, inline SVG) and `html` writes the page. Importing this package is cheap.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def cmd_report(args: argparse.Namespace) -> int:
    from icgt.ingest import read
    from icgt.report import repeat
    from icgt.report.html import write_report
    from icgt.report.summary import ReportError, gather

    images: Path | None = args.images
    if images is not None and not images.is_dir():
        raise ReportError(f"--images {images}: not a folder")
    compared = [repeat.load(where) for where in args.compare or ()]  # a bad --compare fails before the log is read
    recording = read(args.log)
    flight = repeat.recording_flight(recording) if compared else ""
    for rep in compared:
        repeat.check_flight(rep, flight)
    data = gather(recording, images)
    size = write_report(data, args.out, [repeat.section(rep, flight) for rep in compared])
    also = f", {len(compared)} repeat inspection{'s' if len(compared) != 1 else ''}" if compared else ""
    print(f"report of {len(data.frames)} frames{also} written to {args.out} ({size / 1024:.0f} KiB)", file=sys.stdout)
    return 0


def cmd_info(args: argparse.Namespace) -> int:
    from icgt.ingest import read
    from icgt.report.summary import format_text, gather, summarize

    print(format_text(summarize(gather(read(args.log), args.images))))
    return 0


def add_report_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", type=Path, help="the recording (.mcap)")
    parser.add_argument("--images", type=Path, help="folder of the camera card's JPEGs: match them to the frames")
    parser.add_argument("--out", type=Path, default=Path("report.html"), help="the page to write (report.html)")
    parser.add_argument(
        "--compare",
        type=Path,
        action="append",
        metavar="DIR",
        help="add a repeat-inspection section: the folder `icgt compare --out` wrote (or its compare.geojson), "
        "a comparison of this recording's flight with another; every defect's change (new, grown, unchanged, "
        "repaired, not_seen) with length and width change +- sigma, the alignment and the side-by-side image "
        "(compare.png beside it). Repeatable.",
    )


def add_info_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", type=Path, help="the recording (.mcap)")
    parser.add_argument("--images", type=Path, help="folder of the camera card's JPEGs: match them to the frames")
