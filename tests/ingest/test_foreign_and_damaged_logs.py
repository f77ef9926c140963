"""Foreign and damaged MCAP files: an IngestError saying what the file is, never a traceback (read, match, export)."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap.writer import Writer
from mcap_protobuf.schema import build_file_descriptor_set

from icgt.cli import main
from icgt.geotag.record import FrameRecord
from icgt.ingest import IngestError, read
from icgt.recording import McapRecorder

T0 = 1_700_000_000_000_000_000


def _foreign_protobuf_frames(path: Path) -> Path:
    with McapRecorder(path, fsync=False) as rec:
        for i in range(5):
            rec.write("/frames", LocationFix(latitude=float(i), frame_id="gps"), T0 + i)
    return path


def _icgt(path: Path, n: int = 30) -> Path:
    with McapRecorder(path, fsync=False, max_chunk_interval_s=60.0) as rec:
        rec.register_dataclass("/frames", FrameRecord)
        rec.add_metadata("icgt.calibration", {"focal_length_mm": "35.0"})
        for i in range(n):
            f = FrameRecord(frame_seq=i, image_index=i, camera_id=0, device_flags=0, trigger_device_us=i,
                            start_device_us=i, mid_device_us=i, duration_us=1, mid_host_ns=i,
                            mid_host_uncertainty_ns=1, time_source="pps", flags=[], position_source="none",
                            fix_type=0, pose_gap_before_ms=1.0, pose_gap_after_ms=1.0)  # fmt: skip
            rec.write("/frames", f, T0 + i)
            if i % 10 == 9:
                rec.flush()
    return path


def test_protobuf_frames_channel_is_not_an_icgt_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _foreign_protobuf_frames(tmp_path / "foreign.mcap")
    rec = read(path)
    with pytest.raises(IngestError, match=r"not an ICGT recording: its /frames channel carries protobuf"):
        list(rec.frames())
    assert len(list(rec.messages("/frames"))) == 5  # the file itself is fine: its raw messages can be read
    card = tmp_path / "card"
    card.mkdir()
    for argv in (["export", str(path), "--out", str(tmp_path / "out"), "--no-progress"],
                 ["match", "--images", str(card), str(path)]):  # fmt: skip
        assert main(argv) == 1
        err = capsys.readouterr().err
        assert "not an ICGT recording" in err and "Traceback" not in err


def test_a_json_frames_channel_of_another_schema_is_not_an_icgt_recording(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Issue 36: a foreign JSON /frames topic is "not an ICGT recording", and the refused export leaves no folder."""
    path = tmp_path / "foreign_json.mcap"
    with McapRecorder(path, fsync=False) as rec:
        rec.register_json("/frames", "acme.Frame", {"type": "object"})
        for i in range(3):
            rec.write("/frames", {"id": i, "lat": 1.0}, T0 + i)
    with pytest.raises(
        IngestError, match=r"not an ICGT recording: its /frames channel has the JSON schema 'acme.Frame'"
    ):
        list(read(path).frames())
    out = tmp_path / "out"
    assert main(["export", str(path), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "not an ICGT recording" in err and "Traceback" not in err
    assert not out.exists(), f"the refused export left {sorted(p.name for p in out.iterdir())} behind"


def test_mcap_without_frames_or_icgt_metadata_says_so(tmp_path: Path) -> None:
    path = tmp_path / "other.mcap"
    with McapRecorder(path, fsync=False) as rec:
        rec.write("/fix", LocationFix(latitude=1.0), T0)
    with pytest.raises(
        IngestError, match=r"not an ICGT recording: no /frames channel and no metadata of the ICGT recorder .*/fix"
    ):
        list(read(path).frames())


def test_an_icgt_recording_without_frames_is_fine(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    with McapRecorder(path, fsync=False) as rec:
        rec.add_metadata("icgt.device", {"serial": "1"})
        rec.write("/fix", LocationFix(latitude=1.0), T0)
    assert list(read(path).frames()) == []


def test_undecodable_protobuf_bytes_are_an_ingest_error(tmp_path: Path) -> None:
    path = tmp_path / "garbage.mcap"
    with path.open("wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema(
            "foxglove.LocationFix", "protobuf", build_file_descriptor_set(LocationFix).SerializeToString()
        )
        cid = w.register_channel("/fix", "protobuf", sid)
        w.add_message(cid, log_time=T0, data=b"\xff\xff\xff\xff\x0f", publish_time=T0)
        w.finish()
    with pytest.raises(IngestError, match="cannot decode a message on /fix"):
        list(read(path).messages("/fix"))


def test_randomly_damaged_recordings_give_ingest_errors_only(tmp_path: Path) -> None:
    """Overwrite, zero or cut a small ICGT recording at random: every reader call either works or raises IngestError."""
    data = _icgt(tmp_path / "good.mcap").read_bytes()
    rng = random.Random(11)
    failures = 0
    for k in range(150):
        bad = bytearray(data)
        kind = k % 3
        at = rng.randrange(8, len(bad) - 1)
        if kind == 0:
            bad[at : at + rng.randrange(1, 64)] = bytes(rng.randrange(256) for _ in range(64))[: len(bad[at : at + 64])]
        elif kind == 1:
            bad[at : at + 4096] = bytes(len(bad[at : at + 4096]))
        else:
            del bad[at:]
        path = tmp_path / f"bad{k}.mcap"
        path.write_bytes(bytes(bad))
        try:
            rec = read(path, allow_unfinished=True)
            list(rec.frames())
            rec.topics()
            _ = rec.metadata
            list(rec.records())
        except IngestError:
            failures += 1
    assert failures > 20  # the damage was seen, and reported the documented way
