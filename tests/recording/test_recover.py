"""recover(): unfinished, cut, zero-padded and corrupted files become complete indexed files; garbage gives
RecordingError, never a traceback from inside."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from recording_checks import read_complete

from icgt.recording import McapRecorder, RecordingError, recover
from icgt.recording.writer import MAGIC

T0 = 1_700_000_000_000_000_000


def _recording(path: Path, chunks: int = 6, per_chunk: int = 40, finish: bool = True) -> Path:
    """A recording of `chunks` flushed chunks; with finish=False it is left like after kill -9."""
    rec = McapRecorder(path, max_chunk_interval_s=60.0, fsync=False)
    rec.add_metadata("device", {"serial": "R-1"})
    rec.add_attachment("config.toml", "application/toml", b"x = 1\n", log_time_ns=T0)
    for c in range(chunks):
        for i in range(per_chunk):
            n = c * per_chunk + i
            rec.write("/fix", LocationFix(latitude=float(n), frame_id="gps"), T0 + n * 1_000_000)
        rec.flush()
    if finish:
        rec.close()
    else:
        # Stop the writer without a summary: what a killed process leaves (the thread is a daemon).
        rec._closing = True
    return path


def test_complete_file_round_trips(tmp_path: Path) -> None:
    src = _recording(tmp_path / "done.mcap")
    report = recover(src, tmp_path / "copy.mcap")
    assert report.source_was_complete and report.bytes_discarded == 0
    assert report.messages_per_topic == {"/fix": 240} and report.chunks_kept == 6
    assert report.first_log_time_ns == T0 and report.last_log_time_ns == T0 + 239 * 1_000_000
    back = read_complete(tmp_path / "copy.mcap")
    assert [m[3].latitude for m in back.messages] == [float(n) for n in range(240)]
    assert back.metadata["device"] == {"serial": "R-1"} and back.attachments == {"config.toml": b"x = 1\n"}
    assert "240 messages" in report.describe()


def test_unfinished_file_is_completed(tmp_path: Path) -> None:
    src = _recording(tmp_path / "killed.mcap", finish=False)
    report = recover(src, tmp_path / "fixed.mcap")
    assert not report.source_was_complete and report.messages == 240 and report.bytes_discarded == 0
    assert len(read_complete(tmp_path / "fixed.mcap").messages) == 240


def test_every_cut_keeps_the_complete_chunks_before_it(tmp_path: Path) -> None:
    """Cut the file at many offsets (a crash mid-write): recover keeps exactly the chunks before the cut."""
    src = _recording(tmp_path / "src.mcap", finish=False)
    data = src.read_bytes()
    rng = random.Random(7)
    cuts = sorted({*rng.sample(range(len(MAGIC), len(data)), 120), len(data) - 1})
    for i, cut in enumerate(cuts):
        cut_file = tmp_path / f"cut{i}.mcap"
        cut_file.write_bytes(data[:cut])
        try:
            report = recover(cut_file, tmp_path / f"out{i}.mcap")
        except RecordingError as exc:
            assert "no complete chunk" in str(exc) or "not an MCAP file" in str(exc), (cut, exc)
            assert not (tmp_path / f"out{i}.mcap").exists()
            continue
        back = read_complete(tmp_path / f"out{i}.mcap")
        assert report.messages == len(back.messages) and report.messages % 40 == 0, cut
        assert [m[3].latitude for m in back.messages] == [float(n) for n in range(report.messages)]
        assert report.good_bytes <= cut and report.bytes_discarded == cut - report.good_bytes


def test_zero_filled_tail_after_power_cut(tmp_path: Path) -> None:
    """ext4 after a power cut can leave the file longer than its data, the rest zeros."""
    src = _recording(tmp_path / "src.mcap", finish=False)
    with src.open("ab") as f:
        f.write(b"\x00" * 8192)
    report = recover(src, tmp_path / "fixed.mcap")
    assert report.messages == 240 and report.bytes_discarded == 8192


def test_corrupt_chunk_in_the_middle_is_skipped(tmp_path: Path) -> None:
    src = _recording(tmp_path / "src.mcap", finish=False)
    data = bytearray(src.read_bytes())
    with (tmp_path / "probe.mcap").open("wb") as f:
        f.write(data)
    # flip bytes in the middle of the third chunk's compressed payload (its CRC then fails)
    third = _find_chunks(bytes(data))[2]
    data[third + 60 : third + 70] = b"\xff" * 10
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = recover(bad, tmp_path / "fixed.mcap")
    assert report.chunks_damaged == 1 and report.chunks_kept == 5 and report.messages == 200
    assert [offset for offset, _why in report.damaged_chunks] == [third]
    assert f"damaged chunk at byte {third} skipped" in report.describe()
    lats = [m[3].latitude for m in read_complete(tmp_path / "fixed.mcap").messages]
    assert lats == [float(n) for n in range(240) if not 80 <= n < 120]


def _find_chunks(data: bytes) -> list[int]:
    """Offsets of the Chunk records (opcode 0x06), walking the record framing."""
    offsets, pos = [], len(MAGIC)
    while pos + 9 <= len(data):
        opcode, length = data[pos], int.from_bytes(data[pos + 1 : pos + 9], "little")
        if opcode == 0x06:
            offsets.append(pos)
        pos += 9 + length
    return offsets


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"", "empty"),
        (b"hello world, not a log at all", "not an MCAP file"),
        (MAGIC[:5], "not an MCAP file"),
        (MAGIC, "not an MCAP file"),
        (MAGIC + b"\x01\xff\xff\xff\xff\xff\xff\xff\x7f", "not an MCAP file"),
        (MAGIC + random.Random(4096).randbytes(4096), "not an MCAP file"),  # the same bytes in every process
        (b"\x00" * 4096, "not an MCAP file"),
    ],
)
def test_garbage_is_a_clear_error(tmp_path: Path, content: bytes, message: str) -> None:
    src = tmp_path / "garbage.mcap"
    src.write_bytes(content)
    with pytest.raises(RecordingError, match=message):
        recover(src, tmp_path / "out.mcap")
    assert not (tmp_path / "out.mcap").exists()


def test_header_without_chunks_is_a_clear_error(tmp_path: Path) -> None:
    src = _recording(tmp_path / "empty.mcap", chunks=0, finish=False)
    with pytest.raises(RecordingError, match="no complete chunk"):
        recover(src, tmp_path / "out.mcap")


def test_paths_are_checked(tmp_path: Path) -> None:
    src = _recording(tmp_path / "src.mcap")
    (tmp_path / "exists.mcap").write_bytes(b"keep")
    with pytest.raises(RecordingError, match="refusing to overwrite"):
        recover(src, tmp_path / "exists.mcap")
    assert (tmp_path / "exists.mcap").read_bytes() == b"keep"
    with pytest.raises(RecordingError, match="cannot read"):
        recover(tmp_path / "missing.mcap", tmp_path / "out.mcap")
    with pytest.raises(RecordingError, match="cannot read"):
        recover(tmp_path, tmp_path / "out.mcap")
    with pytest.raises(RecordingError, match="the source itself"):
        recover(src, src)


def _records(data: bytes) -> list[tuple[int, int, int]]:
    """(offset, opcode, length) of every top-level record, walking the framing of an intact file."""
    out, pos = [], len(MAGIC)
    while pos + 9 <= len(data):
        opcode, length = data[pos], int.from_bytes(data[pos + 1 : pos + 9], "little")
        out.append((pos, opcode, length))
        if opcode == 0x02:
            break
        pos += 9 + length
    return out


def test_zeroed_message_indexes_are_skipped_and_every_chunk_is_kept(tmp_path: Path) -> None:
    """A complete log with 4 KB zeroed inside its message-index records: resynchronise at the next chunk."""
    src = _recording(tmp_path / "src.mcap", chunks=6, per_chunk=400)
    data = bytearray(src.read_bytes())
    records = _records(bytes(data))
    first_index = next(pos for pos, op, _ in records if op == 0x07)
    next_chunk = next(pos for pos, op, _ in records if op == 0x06 and pos > first_index)
    assert next_chunk - first_index > 4096  # the zeros stay inside the indexes
    data[first_index : first_index + 4096] = bytes(4096)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = recover(bad, tmp_path / "fixed.mcap")
    assert report.messages == 2400 and report.chunks_kept == 6 and report.chunks_damaged == 0
    assert report.lossy and len(report.skipped) == 1
    start, end, why = report.skipped[0]
    assert start == first_index and end == next_chunk and "opcode 0x00" in why
    assert f"skipped bytes {start}-{end}" in report.describe()
    lats = [m[3].latitude for m in read_complete(tmp_path / "fixed.mcap").messages]
    assert lats == [float(n) for n in range(2400)]


def test_overwritten_bytes_between_chunks_and_a_damaged_chunk(tmp_path: Path) -> None:
    src = _recording(tmp_path / "src.mcap", chunks=6, per_chunk=40)
    data = bytearray(src.read_bytes())
    chunks = [pos for pos, op, _ in _records(bytes(data)) if op == 0x06]
    data[chunks[1] : chunks[1] + 9] = b"\xa5" * 9  # the second chunk's framing overwritten: that chunk is lost
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    report = recover(bad, tmp_path / "fixed.mcap")
    assert report.messages == 200 and report.chunks_kept == 5 and report.skipped[0][1] == chunks[2]
    lats = [m[3].latitude for m in read_complete(tmp_path / "fixed.mcap").messages]
    assert lats == [float(n) for n in range(240) if not 40 <= n < 80]


def test_the_command_names_the_damage_of_a_complete_file_on_stderr(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A file with its footer but a damaged chunk inside: not "already complete"; exit 1, the offset said."""
    from icgt.cli import main

    src = _recording(tmp_path / "src.mcap", finish=True)
    data = bytearray(src.read_bytes())
    third = _find_chunks(bytes(data))[2]
    data[third + 60 : third + 70] = b"\xff" * 10
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    assert main(["recover", str(bad), str(tmp_path / "fixed.mcap")]) == 1
    out, err = capsys.readouterr()
    assert "already complete" not in out and "had its end (footer) but damage inside" in out
    assert f"damaged chunk at byte {third}" in out and "damage inside the file was skipped" in err
