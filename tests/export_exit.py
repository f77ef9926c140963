"""What `icgt export` must exit with for its problems (0: no error row, 1: errors; --strict: warnings too)."""

from __future__ import annotations

import csv
from pathlib import Path


def expected_export_exit(out: Path, *, errors_allowed: bool = False, strict: bool = False) -> int:
    """The exit status problems.csv in `out` calls for; asserts there is no error row unless allowed.

    A simulated flight may carry flagged poses (warnings) when the machine running it is loaded: those
    make the exit status 1 only with --strict, and are not what the export tests check."""
    with (out / "problems.csv").open(newline="", encoding="utf-8") as fh:
        problems = list(csv.DictReader(fh))
    if not errors_allowed:
        assert not [p for p in problems if p["severity"] == "error"], problems
    failing = ("error", "warning") if strict else ("error",)
    return 1 if any(p["severity"] in failing for p in problems) else 0
