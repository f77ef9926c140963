"""icgt.read(): the frames of a real recording as records and as columns, its raw streams and metadata,
bounded memory on a large log, and clear errors (never a traceback) for files that are not readable."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
import tracemalloc
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader

import icgt
from icgt.demo import Flight
from icgt.geotag import FrameRecord
from icgt.ingest.reader import FLAG_BITS, INT_MISSING, FrameTable, IngestError, read
from icgt.recording import McapRecorder


def _official(path: Path, topic: str) -> list[dict[str, Any]]:
    with path.open("rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic], log_time_order=False)]


def _frame(n: int) -> FrameRecord:
    return FrameRecord(
        frame_seq=n,
        image_index=n,
        camera_id=0,
        device_flags=0,
        trigger_device_us=1_000_000 + n * 200_000,
        start_device_us=1_048_000 + n * 200_000,
        mid_device_us=1_048_500 + n * 200_000,
        duration_us=1000,
        mid_host_ns=5_000_000_000 + n * 200_000_000,
        mid_host_uncertainty_ns=600_000,
        time_source="system_time",
        flags=["range_invalid"] if n % 7 == 0 else [],
        position_source="gps_3d",
        fix_type=3,
        pose_gap_before_ms=3.0,
        pose_gap_after_ms=17.0,
        mid_utc_us=1_795_000_000_000_000 + n * 200_000,
        lat_deg=37.88 + n * 1e-7,
        lon_deg=127.73,
        alt_msl_m=80.0,
        east_m=float(n),
        north_m=0.5,
        up_m=6.0,
        body_qw=1.0,
        body_qx=0.0,
        body_qy=0.0,
        body_qz=0.0,
        range_m=None if n % 7 == 0 else 3.0,
        range_valid=n % 7 != 0,
    )


# ----------------------------------------------------------------------------- a real recording
def test_icgt_read_is_the_package_entry_point(flight: Flight) -> None:
    rec = icgt.read(flight.mcap)
    assert rec.complete and rec.note is None
    assert rec.path == flight.mcap


def test_frames_carry_every_field_as_recorded(flight: Flight) -> None:
    rec = read(flight.mcap)
    frames = list(rec.frames())
    raw = _official(flight.mcap, "/frames")
    assert len(frames) == len(raw) >= 60
    assert [f.frame_seq for f in frames] == list(range(1, len(frames) + 1))  # log order
    for f, r in zip(frames, raw, strict=True):
        for fld in fields(FrameRecord):
            value = getattr(f, fld.name)
            if fld.name in r:
                assert value == r[fld.name], fld.name
            elif fld.name.startswith("pose_gap"):
                assert value == math.inf  # the recorder leaves non-finite floats out
            else:
                assert value is None or (fld.name == "range_valid" and value is False), fld.name
    flags = {fl for f in frames for fl in f.flags}
    assert {"feedback_missing", "unsolicited"} <= flags


def test_frame_table_columns_equal_the_frames(flight: Flight) -> None:
    rec = read(flight.mcap)
    frames = list(rec.frames())
    table = rec.frame_table()
    assert len(table) == len(frames)
    assert set(table.names) == {f.name for f in fields(FrameRecord)}
    for fld in fields(FrameRecord):
        col = table[fld.name]
        assert len(col) == len(frames)
        for i, f in enumerate(frames):
            value = getattr(f, fld.name)
            if fld.name == "flags":
                assert table.flag_list(i) == sorted(value, key=list(FLAG_BITS).index)
                assert int(col[i]) == sum(FLAG_BITS[x] for x in value)
            elif value is None:
                assert math.isnan(col[i]) if col.dtype.kind == "f" else col[i] == INT_MISSING, fld.name
                assert not table.valid(fld.name)[i]
            elif col.dtype.kind == "f":
                assert col[i] == value or (math.isinf(value) and math.isinf(col[i]))
            else:
                assert col[i] == value, fld.name
    assert table["lat_deg"].dtype == np.float64 and table["frame_seq"].dtype == np.int64
    missed = table.has_flag("feedback_missing")
    assert missed.sum() == sum("feedback_missing" in f.flags for f in frames) >= 3


def test_metadata_topics_and_raw_streams(flight: Flight) -> None:
    rec = read(flight.mcap)
    assert {"icgt.device", "icgt.config", "icgt.calibration", "icgt.time_bases", "icgt.enu_origin"} <= set(rec.metadata)
    origin = rec.enu_origin
    assert origin is not None and abs(origin[0] - 37.8813) < 1e-3 and abs(origin[1] - 127.7298) < 1e-3
    assert rec.monotonic_to_utc_offset_ns is not None
    topics = rec.topics()
    for topic in ("/frames", "/device/exposure", "/device/imu", "/clock/device/exchanges", "/mavlink/timesync"):
        assert topics[topic] > 0, topic
    exposures = list(rec.messages("/device/exposure"))
    assert len(exposures) == topics["/device/exposure"]
    # messages() gives the data's time (the MCAP publish time: here its receipt), not the log time (when
    # the recorder queued it, later, which keeps the file in log-time order)
    times = _times(flight.mcap, "/device/exposure")
    assert exposures == [(t, d) for (t, _), d in zip(times, _official(flight.mcap, "/device/exposure"), strict=True)]
    assert all(log_time >= publish for publish, log_time in times)
    t, gpi = next(rec.messages("/mavlink/global_position_int"))
    assert {"raw", "host_rx_ns", "lat", "lon"} <= set(gpi) and t > 1.7e18
    fix = next(rec.messages("/frames/location"))[1]  # a protobuf topic comes back as a dict too
    assert "latitude" in fix
    order = [m.topic for m in rec.records({"/device/exposure", "/frames"})]
    assert order.count("/frames") == topics["/frames"] and order.index("/device/exposure") < order.index("/frames")


def _times(path: Path, topic: str) -> list[tuple[int, int]]:
    """(publish time, log time) of each message of a topic in file order, by the official reader [ns]."""
    with path.open("rb") as f:
        reader = make_reader(f)
        return [(m.publish_time, m.log_time) for _, _, m in reader.iter_messages(topics=[topic], log_time_order=False)]


def test_importing_icgt_stays_light() -> None:
    code = (
        "import sys, icgt; icgt.read; "
        "print(any(m.startswith(('mcap', 'numpy', 'icgt.ingest.reader')) for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


# ----------------------------------------------------------------------------- unreadable files
def test_missing_empty_and_non_mcap_files_give_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(IngestError, match="no such file"):
        read(tmp_path / "nope.mcap")
    with pytest.raises(IngestError, match="not a file"):
        read(tmp_path)
    (tmp_path / "empty.mcap").write_bytes(b"")
    with pytest.raises(IngestError, match="empty file"):
        read(tmp_path / "empty.mcap")
    (tmp_path / "notes.txt").write_text("frame,lat,lon\n1,37.8,127.7\n")
    with pytest.raises(IngestError, match="not an MCAP file"):
        read(tmp_path / "notes.txt")


def test_unfinished_recording_says_how_to_recover_and_can_be_read_as_far_as_it_goes(
    flight: Flight, tmp_path: Path
) -> None:
    cut = tmp_path / "cut.mcap"
    data = flight.mcap.read_bytes()
    cut.write_bytes(data[: len(data) * 2 // 3])  # killed mid-flight: no summary, a record cut in half
    with pytest.raises(IngestError, match=r"unfinished recording .*icgt recover") as info:
        read(cut)
    assert str(cut) in str(info.value)
    rec = read(cut, allow_unfinished=True)
    assert not rec.complete and rec.note is not None and "icgt recover" in rec.note
    frames = list(rec.frames())
    full = list(read(flight.mcap).frames())
    assert 10 <= len(frames) < len(full)
    assert frames == full[: len(frames)]
    assert "icgt.device" in rec.metadata and rec.topics()["/frames"] == len(frames)


def test_damaged_chunk_gives_an_error_not_a_traceback(flight: Flight, tmp_path: Path) -> None:
    bad = tmp_path / "bad.mcap"
    data = bytearray(flight.mcap.read_bytes())
    with flight.mcap.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.chunk_indexes
    # the middle of the largest chunk's compressed records (the middle of the file need not be in a chunk);
    # footer and summary intact
    chunk = max(summary.chunk_indexes, key=lambda c: c.chunk_length)
    middle = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[middle : middle + 64] = bytes(64)
    bad.write_bytes(bytes(data))
    rec = read(bad)
    with pytest.raises(IngestError, match=r"damaged recording .*icgt recover"):
        for _ in rec.records():
            pass


# ----------------------------------------------------------------------------- bounded memory
@pytest.mark.timeout(300)
def test_iterating_a_large_log_uses_bounded_memory(tmp_path: Path) -> None:
    path = tmp_path / "large.mcap"
    n = 100_000
    # Uncompressed, so the file's size is the data's (zstd shrinks these regular records 15-fold).
    rec = McapRecorder(path, max_chunk_bytes=1 << 20, compression="none", fsync=False, queue_size=200_000)
    rec.register_dataclass("/frames", FrameRecord)
    for k in range(1, n + 1):
        rec.write("/frames", _frame(k), 1_795_000_000_000_000_000 + k * 200_000_000)
    rec.close()
    size = path.stat().st_size
    recording = read(path)
    tracemalloc.start()
    try:
        count = 0
        last = None
        for f in recording.frames():
            count += 1
            last = f
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert count == n and last == _frame(n)
    assert size > 50e6
    assert peak < size / 10, f"peak {peak / 1e6:.1f} MB for a {size / 1e6:.1f} MB file"


def test_frame_table_of_synthetic_frames_roundtrips() -> None:
    frames = [_frame(k) for k in range(1, 30)]
    table = FrameTable.from_frames(frames)
    assert np.isnan(table["range_m"][table.has_flag("range_invalid")]).all()
    assert (table["imu_calib_sys"] == INT_MISSING).all() and not table.valid("imu_calib_sys").any()
    assert table["time_source"][0] == "system_time"


def test_reading_a_copy_elsewhere_works(flight: Flight, tmp_path: Path) -> None:
    copy = tmp_path / "copy.mcap"
    shutil.copy(flight.mcap, copy)
    assert sum(1 for _ in read(copy).frames()) == read(flight.mcap).topics()["/frames"]
