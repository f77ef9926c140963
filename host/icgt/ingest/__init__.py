"""Ingest: read a recording's frames and raw streams, recompute poses offline, match camera images.

`icgt.read(path)` opens a recording (see `icgt.ingest.reader`). Importing this package is cheap:
the reader, the recomputation (`icgt.ingest.recompute`) and the image matcher (`icgt.ingest.match`)
load their dependencies (mcap, numpy, pymavlink, exifread) only when used; the names below are
imported from them on first access (`recompute` itself: from icgt.ingest.recompute, whose module
name it shares).
"""

from __future__ import annotations

import importlib
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from icgt.ingest.match import MatchResult, match_images
    from icgt.ingest.reader import FrameTable, IngestError, LogMessage, Recording
    from icgt.ingest.recompute import RecomputeResult, recording_config

__all__ = [
    "FrameTable",
    "IngestError",
    "LogMessage",
    "MatchResult",
    "RecomputeResult",
    "Recording",
    "match_images",
    "read",
    "recording_config",
]

_LAZY = {
    "FrameTable": "icgt.ingest.reader",
    "IngestError": "icgt.ingest.reader",
    "LogMessage": "icgt.ingest.reader",
    "Recording": "icgt.ingest.reader",
    "MatchResult": "icgt.ingest.match",
    "match_images": "icgt.ingest.match",
    "RecomputeResult": "icgt.ingest.recompute",
    "recording_config": "icgt.ingest.recompute",
}


def read(path: str | Path, *, allow_unfinished: bool = False) -> Recording:
    """Open the MCAP recording at `path`; see `icgt.ingest.reader.read`."""
    from icgt.ingest.reader import read as _read

    return _read(path, allow_unfinished=allow_unfinished)


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'icgt.ingest' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)
