"""Small file helpers of the catalogue shared by its folder (store.py) and its compaction (compact.py): the
structure name check, reading one catalogue file with its schema version checked, and fsync of a folder."""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import pyarrow as pa
import pyarrow.parquet as pq

from icgt.catalog import CatalogError
from icgt.catalog.schema import table_version

__all__ = ["check_structure", "fsync_dir", "read_table"]

_FORBIDDEN = re.compile(r'[/\\\x00-\x1f\x7f:*?"<>|\[\]{}=]')


def check_structure(name: str) -> str:
    """The structure name if it can name a partition folder as it is; CatalogError saying why not."""
    if not name or name.strip() != name or name.startswith(".") or len(name) > 128 or _FORBIDDEN.search(name):
        raise CatalogError(
            f"--structure {name!r}: a structure name is 1-128 characters without path or glob characters "
            '(/ \\ : * ? " < > | [ ] { } =), control characters, a leading dot or surrounding spaces'
        )
    return name


def read_table(path: Path, **kwargs: Any) -> pa.Table:
    """One catalogue file, its schema version checked (CatalogError naming both versions); kwargs: those of
    pyarrow.parquet.read_table (columns, filters)."""
    try:
        meta = pq.read_metadata(path).metadata
    except (OSError, pa.ArrowException) as exc:
        raise CatalogError(f"{path}: not a readable Parquet file ({exc})") from None
    table_version(meta, str(path))
    return pq.read_table(path, **kwargs)


def fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
