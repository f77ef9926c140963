"""Which flight a log is: the id `icgt catalog add` files it under, and that `icgt report --compare` checks.

The device's serial number and the recording id the recorder named to it (metadata ``icgt.flight``) identify a
flight, so a re-geotagged or recovered copy of it has the same id; a log without them is identified by its
content (its SHA-256). Here, below both the catalogue and the report, so that neither imports the other.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from icgt.recording import layout

__all__ = ["file_sha256", "flight_id"]


def file_sha256(path: Path) -> str:
    """The file's SHA-256 (hex); OSError if it cannot be read."""
    with path.open("rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def flight_id(metadata: dict[str, dict[str, str]], log_sha256: str) -> tuple[str, str | None, str]:
    """(flight id, recording id, kind) of a log's metadata; ``log_sha256`` names a log without device ids."""
    flight = metadata.get(layout.META_FLIGHT, {})
    serial = metadata.get(layout.META_DEVICE, {}).get("serial_number")
    rid = flight.get("recording_id")
    kind = flight.get("kind", "recording")
    if serial and rid:
        ident = f"{serial}-{rid.removeprefix('0x').lower()}"
        return (ident if kind == "recording" else f"{ident}-{kind}"), rid, kind
    return f"log-{log_sha256[:16]}", rid, kind
