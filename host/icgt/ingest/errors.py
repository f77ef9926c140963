"""The error of everything that reads a recording."""

from __future__ import annotations

from icgt.errors import IcgtError

__all__ = ["IngestError"]


class IngestError(IcgtError):
    """A recording cannot be read (missing, not MCAP, unfinished, damaged) or a request on it is invalid."""
