"""What `icgt export` must exit with for the problems it reported (0: none that matter, 1: warnings or errors)."""

from __future__ import annotations

import csv
from pathlib import Path


def expected_export_exit(out: Path, *, errors_allowed: bool = False) -> int:
    """The exit status problems.csv in `out` calls for; asserts there is no error row unless allowed.

    A simulated flight may carry flagged poses (warnings) when the machine running it is loaded: those
    make the exit status 1 by design, and are not what the export tests check."""
    with (out / "problems.csv").open(newline="", encoding="utf-8") as fh:
        problems = list(csv.DictReader(fh))
    if not errors_allowed:
        assert not [p for p in problems if p["severity"] == "error"], problems
    return 1 if any(p["severity"] in ("error", "warning") for p in problems) else 0
