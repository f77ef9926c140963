"""Bytes kept on disk instead of in memory while a recording runs: what must be kept whole but is rarely read.

Two things grow with a recording's length and are needed only now and then: the MCAP summary's chunk
index (a ChunkIndex record per chunk, a chunk every quarter second: about 0.05 MiB a minute, read once at
the end) and the camera's image history (every CAMERA_IMAGE_CAPTURED a ground station may re-request,
300 a minute at 5 fps). Held in memory they make the recorder's resident set grow for as long as it
records (issue 30's soak). A `Spill` is an anonymous temporary file (``tempfile.TemporaryFile``: on Linux
O_TMPFILE, unlinked from the start, so a crash leaves nothing behind) that takes appends and reads by
offset with `os.pwrite` / `os.pread` (no shared file position: safe from several threads).

When the disk refuses a write (full, quota, I/O error) the bytes are kept in memory instead, and the spill
says so once in the log: nothing is lost, only the memory is no longer flat. Written here because the
standard library's `tempfile.SpooledTemporaryFile` does the opposite (memory first, disk after a size)
and keeps one file position for every reader.
"""

from __future__ import annotations

import logging
import os
import tempfile
import threading
from pathlib import Path

__all__ = ["Spill"]

logger = logging.getLogger(__name__)


class Spill:
    """An append-only byte store on disk, with an in-memory fallback for what the disk refused."""

    def __init__(self, what: str, directory: str | os.PathLike[str] | None = None) -> None:
        self.what = what
        self._lock = threading.Lock()
        self._size = 0
        self._held: dict[int, bytes] = {}  # offset -> bytes the disk refused (or all of them: no file)
        self._file = None
        try:
            # closed by close() (the writer's end) or with the object: no `with` spans a recording
            self._file = tempfile.TemporaryFile(dir=None if directory is None else Path(directory))  # noqa: SIM115
        except OSError as exc:
            logger.warning("%s is kept in memory: no temporary file could be made (%s)", what, exc)

    def append(self, data: bytes) -> int:
        """Keeps ``data`` and returns its offset (for `read`)."""
        with self._lock:
            offset = self._size
            self._size += len(data)
            if self._file is not None and not self._held:
                try:
                    written = os.pwrite(self._file.fileno(), data, offset)
                    if written == len(data):
                        return offset
                    raise OSError(f"short write ({written} of {len(data)} bytes)")
                except OSError as exc:
                    logger.warning(
                        "%s is kept in memory from now on: the temporary file refused a write (%s)", self.what, exc
                    )
            # once one write failed, later ones stay in memory too (a hole in the file would read as zeros)
            self._held[offset] = bytes(data)
            return offset

    def read(self, offset: int, length: int) -> bytes:
        """The ``length`` bytes appended at ``offset`` (one `append`'s whole data, or a part of the file's)."""
        with self._lock:
            held = self._held.get(offset)
            if held is not None:
                return held[:length]
            if self._file is None or offset + length > self._size:
                raise ValueError(f"{self.what}: nothing kept at {offset}+{length} (size {self._size})")
            data = os.pread(self._file.fileno(), length, offset)
        if len(data) != length:
            raise OSError(f"{self.what}: the temporary file returned {len(data)} of {length} bytes at {offset}")
        return data

    def read_all(self) -> bytes:
        """Everything appended, in order."""
        with self._lock:
            held = sorted(self._held.items())
            on_disk = held[0][0] if held else self._size
        out = bytearray(self.read(0, on_disk) if on_disk else b"")
        for _offset, data in held:
            out += data
        return bytes(out)

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
            self._held.clear()
            self._size = 0
