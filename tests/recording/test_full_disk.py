"""A full disk stops the recording cleanly: RecordingError with a clear message, a readable file, no traceback
from inside, and the recorder still closes. Tried on a file object that fails like the kernel does, on a
real 200 KiB tmpfs (root) and under a real file size limit (RLIMIT_FSIZE, any user)."""

from __future__ import annotations

import errno
import io
import os
import subprocess
import sys
import tempfile
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap_protobuf.schema import build_file_descriptor_set
from recording_checks import read_complete, read_unfinished

from icgt.recording import McapFileWriter, McapRecorder, RecordingError, recover

T0 = 1_700_000_000_000_000_000


class FillingDisk(io.BytesIO):
    """An in-memory file on a disk with `capacity` bytes: a write past it stores what fits, then ENOSPC."""

    def __init__(self, capacity: int) -> None:
        super().__init__()
        self.capacity = capacity
        self.final = b""

    def write(self, data: bytes) -> int:  # type: ignore[override]
        room = self.capacity - self.tell()
        if room <= 0:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return super().write(bytes(data)[:room])

    def close(self) -> None:
        if not self.closed:
            self.final = self.getvalue()
        super().close()


def _fixes() -> Iterator[tuple[LocationFix, int]]:
    i = 0
    while True:
        fix = LocationFix(latitude=47.0 + i * 1e-6, longitude=8.0 + i * 1e-6, altitude=float(i), frame_id="gps")
        yield fix, T0 + i * 1_000_000
        i += 1


def _record_until_full(rec: McapRecorder, per_chunk: int = 300, limit: int = 1_000_000) -> RecordingError:
    """Writes chunks of `per_chunk` messages until the recorder reports the disk full."""
    for n, (fix, t) in enumerate(_fixes()):
        try:
            rec.write("/fix", fix, t)
            if n % per_chunk == per_chunk - 1:
                rec.flush()
        except RecordingError as exc:
            return exc
        assert n < limit, "the disk never filled up"
    raise AssertionError("unreachable")


def test_disk_full_on_a_file_object(tmp_path: Path) -> None:
    disk = FillingDisk(capacity=40_000)
    rec = McapRecorder(tmp_path / "full.mcap", opener=lambda _: disk)
    error = _record_until_full(rec)
    assert "disk full at" in str(error) and "recording stopped, file is readable up to" in str(error)
    assert "complete and indexed" in str(error)
    assert rec.error is not None
    with pytest.raises(RecordingError, match="disk full"):
        rec.close()
    stats = rec.close()  # stopping again is quiet
    assert stats.complete and stats.messages > 0
    (tmp_path / "full.mcap").write_bytes(disk.final)
    back = read_complete(tmp_path / "full.mcap")
    assert len(back.messages) == stats.messages
    assert max(m[1] for m in back.messages) == stats.last_log_time_ns
    assert len(disk.final) <= disk.capacity


def test_disk_full_when_even_the_summary_does_not_fit(tmp_path: Path) -> None:
    """Chunks of one message leave no room for the summary: the file ends with a bare footer or at the last
    complete record, and stays readable either way."""
    disk = FillingDisk(capacity=6_000)
    rec = McapRecorder(tmp_path / "tight.mcap", opener=lambda _: disk)
    error = _record_until_full(rec, per_chunk=1)
    with pytest.raises(RecordingError):
        rec.close()
    (tmp_path / "tight.mcap").write_bytes(disk.final)
    streamed, _ = read_unfinished(tmp_path / "tight.mcap")
    assert len(streamed) == rec.stats().messages > 0, str(error)
    if "run `icgt recover`" in str(error) or "recover" in str(error):
        report = recover(tmp_path / "tight.mcap", tmp_path / "fixed.mcap")
        assert report.messages == len(streamed)


def _tmpfs(mountpoint: Path) -> bool:
    if os.geteuid() != 0:
        return False
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=200k", "tmpfs", str(mountpoint)], capture_output=True)
    return done.returncode == 0


def test_disk_full_on_a_real_small_filesystem(tmp_path: Path) -> None:
    mountpoint = Path(tempfile.mkdtemp(prefix="icgt-tmpfs-"))
    mounted = _tmpfs(mountpoint)
    try:
        if not mounted:
            # No root here: the same run under a real kernel limit instead (EFBIG, via RLIMIT_FSIZE).
            _run_under_file_size_limit(tmp_path)
            return
        path = mountpoint / "flight.mcap"
        rec = McapRecorder(path)
        error = _record_until_full(rec)
        assert str(error).startswith(f"disk full at {path} after ")
        with pytest.raises(RecordingError):
            rec.close()
        stats = rec.stats()
        # readable as it is; complete if the freed tail made room for the summary
        streamed, _ = read_unfinished(path)
        assert len(streamed) == stats.messages > 1000
        if stats.complete:
            assert len(read_complete(path).messages) == stats.messages
        else:
            assert recover(path, tmp_path / "fixed.mcap").messages == stats.messages
    finally:
        if mounted:
            subprocess.run(["umount", str(mountpoint)], check=True)
        mountpoint.rmdir()


def test_file_size_limit_is_handled_like_a_full_disk(tmp_path: Path) -> None:
    _run_under_file_size_limit(tmp_path)


def _run_under_file_size_limit(tmp_path: Path) -> None:
    path = tmp_path / "limited.mcap"
    script = textwrap.dedent(
        f"""
        import resource, signal, sys
        sys.path.insert(0, {str(Path(__file__).parent)!r})
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # get EFBIG from write() instead of being killed
        resource.setrlimit(resource.RLIMIT_FSIZE, (150_000, 150_000))
        from test_full_disk import _record_until_full
        from icgt.recording import McapRecorder, RecordingError
        rec = McapRecorder({str(path)!r})
        print(_record_until_full(rec))
        try:
            rec.close()
        except RecordingError:
            print("closed", rec.stats().messages, rec.stats().complete)
        """
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    message, closed = done.stdout.strip().splitlines()
    assert message.startswith(f"file size limit reached at {path}") and "readable up to" in message
    _, messages, complete = closed.split()
    assert path.stat().st_size <= 150_000
    streamed, _ = read_unfinished(path)
    assert len(streamed) == int(messages) > 1000
    if complete == "True":
        assert len(read_complete(path).messages) == int(messages)


@pytest.mark.parametrize(
    ("room", "outcome"),
    [(20_000, "complete and indexed"), (60, "complete but not indexed"), (0, "unfinished (no summary)")],
)
def test_salvage_makes_the_most_of_the_room_left(tmp_path: Path, room: int, outcome: str) -> None:
    """However little room the failed write leaves, the file ends at a record boundary and reads."""
    disk = FillingDisk(capacity=10**9)
    writer = McapFileWriter(disk)
    writer.add_schema(1, "foxglove.LocationFix", "protobuf", build_file_descriptor_set(LocationFix).SerializeToString())
    writer.add_channel(1, "/fix", "protobuf", 1, {})
    fixes = _fixes()
    for _ in range(3):
        for _ in range(50):
            fix, t = next(fixes)
            writer.add_message(1, t, t, fix.SerializeToString(), 0)
        writer.close_chunk()
    disk.capacity = writer.committed_bytes + room
    for _ in range(5000):  # a chunk (with its message index) larger than the room
        fix, t = next(fixes)
        writer.add_message(1, t, t, fix.SerializeToString(), 0)
    with pytest.raises(OSError):
        writer.close_chunk()
    assert writer.salvage().startswith(outcome)
    writer.close_stream()
    path = tmp_path / "salvaged.mcap"
    path.write_bytes(disk.final)
    streamed, stopped_by = read_unfinished(path)
    assert len(streamed) == writer.message_count == 150
    assert (stopped_by is None) == (room > 0)  # a footer ends the stream; without one it just ends
    if room >= 20_000:
        assert len(read_complete(path).messages) == 150
