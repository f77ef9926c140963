"""McapRecorder: every topic kind decodes with the official reader, threads, metadata, refusals, timing."""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass
from itertools import pairwise
from pathlib import Path
from typing import Annotated

import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from recording_checks import read_complete, read_unfinished

from icgt.recording import Doc, McapLogHandler, McapRecorder, RecordingError

T0 = 1_700_000_000_000_000_000  # ns since the Unix epoch


@dataclass(frozen=True)
class ClockEstimate:
    """Device-to-host clock mapping."""

    offset_ns: Annotated[int, Doc("host minus device time", unit="ns")]
    sigma_ns: Annotated[float, Doc("1-sigma uncertainty", unit="ns")]


def _fix(i: int) -> LocationFix:
    fix = LocationFix(latitude=47.0 + i * 1e-6, longitude=8.0, altitude=500.0, frame_id="gps")
    fix.timestamp.FromNanoseconds(T0 + i)
    return fix


def _pose() -> PoseInFrame:
    pose = PoseInFrame(frame_id="enu")
    pose.pose.position.x = 1.5
    pose.pose.orientation.w = 1.0
    return pose


def _transforms() -> FrameTransforms:
    tfs = FrameTransforms()
    tf = tfs.transforms.add(parent_frame_id="enu", child_frame_id="camera")
    tf.rotation.w = 1.0
    return tfs


STATUS_SCHEMA = {
    "type": "object",
    "properties": {"state": {"type": "string", "description": "link state"}},
    "required": ["state"],
    "additionalProperties": False,
}


def test_every_topic_kind_is_readable_and_decodable(tmp_path: Path) -> None:
    path = tmp_path / "all.mcap"
    with McapRecorder(path) as rec:
        rec.register_json("/link", "icgt.LinkEvent", STATUS_SCHEMA)
        rec.add_metadata("device", {"firmware": "1.2.3", "protocol": "1", "serial": "T41-0001"})
        rec.add_attachment("icgt.toml", "application/toml", b"rate_hz = 5\n", log_time_ns=T0)
        for i in range(50):
            rec.write("/fix", _fix(i), T0 + i * 1_000_000)
            rec.write("/pose", _pose(), T0 + i * 1_000_000, publish_time_ns=T0)
            rec.write("/tf", _transforms(), T0 + i * 1_000_000)
            rec.write("/clock", ClockEstimate(1000 + i, float("nan") if i == 3 else 20.0), T0 + i * 1_000_000)
        rec.write("/link", {"state": "up"}, T0)
        handler = McapLogHandler(rec, topic="/icgt/log")
        log = logging.getLogger("icgt.test.recorder")
        log.addHandler(handler)
        try:
            log.warning("range out of band: %d", 42)
        finally:
            log.removeHandler(handler)
    stats = rec.close()  # idempotent
    assert stats.complete and stats.messages == 202 and stats.error is None

    back = read_complete(path)
    topics = [m[0] for m in back.messages]
    assert {t: topics.count(t) for t in set(topics)} == {
        "/fix": 50,
        "/pose": 50,
        "/tf": 50,
        "/clock": 50,
        "/link": 1,
        "/icgt/log": 1,
    }
    assert set(back.schemas) >= {"foxglove.LocationFix", "foxglove.PoseInFrame", "foxglove.FrameTransforms",
                                 "foxglove.Log", "icgt.ClockEstimate", "icgt.LinkEvent"}  # fmt: skip
    fixes = [m for m in back.messages if m[0] == "/fix"]
    assert [m[2] for m in fixes] == list(range(50))  # per-channel sequence numbers
    assert fixes[7][3].latitude == pytest.approx(47.000007)
    log_msg = next(m[3] for m in back.messages if m[0] == "/icgt/log")
    assert log_msg.message == "range out of band: 42" and log_msg.level == 3  # WARNING
    clock = [m[3] for m in back.messages if m[0] == "/clock"]
    assert "sigma_ns" not in clock[3] and clock[4] == {"offset_ns": 1004, "sigma_ns": 20.0}
    assert back.metadata["device"] == {"firmware": "1.2.3", "protocol": "1", "serial": "T41-0001"}
    assert "icgt.recording" in back.metadata
    assert back.attachments == {"icgt.toml": b"rate_hz = 5\n"}
    clock_schema = json.loads(back.schemas["icgt.ClockEstimate"][1])
    assert clock_schema["properties"]["sigma_ns"]["description"] == "1-sigma uncertainty [ns]"


def test_refuses_to_overwrite(tmp_path: Path) -> None:
    path = tmp_path / "exists.mcap"
    path.write_bytes(b"precious")
    with pytest.raises(RecordingError, match="refusing to overwrite"):
        McapRecorder(path)
    assert path.read_bytes() == b"precious"


def test_missing_directory_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(RecordingError, match="cannot create"):
        McapRecorder(tmp_path / "no" / "such" / "dir.mcap")


def test_wrong_use_raises_recording_error(tmp_path: Path) -> None:
    rec = McapRecorder(tmp_path / "x.mcap")
    rec.write("/fix", _fix(0), T0)
    with pytest.raises(RecordingError, match="records LocationFix"):
        rec.write("/fix", _pose(), T0)
    with pytest.raises(RecordingError, match="register_json"):
        rec.write("/dict", {"a": 1}, T0)
    with pytest.raises(RecordingError, match="times must be integers"):
        rec.write("/fix", _fix(1), -5)
    with pytest.raises(RecordingError, match="another schema"):
        rec.register_json("/fix", "x", STATUS_SCHEMA)
    rec.close()
    with pytest.raises(RecordingError, match="closed"):
        rec.write("/fix", _fix(2), T0)


def test_many_threads_lose_nothing(tmp_path: Path) -> None:
    path = tmp_path / "threads.mcap"
    per_thread = 2000
    with McapRecorder(path, max_chunk_interval_s=0.05) as rec:

        def produce(k: int) -> None:
            for i in range(per_thread):
                rec.write(f"/t{k % 2}", ClockEstimate(k * per_thread + i, 1.0), T0 + i)

        threads = [threading.Thread(target=produce, args=(k,)) for k in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    back = read_complete(path)
    assert sorted(m[3]["offset_ns"] for m in back.messages) == list(range(4 * per_thread))
    for topic in ("/t0", "/t1"):
        assert sorted(m[2] for m in back.messages if m[0] == topic) == list(range(2 * per_thread))
    assert back.chunk_count >= 1


def test_a_lone_message_reaches_the_disk_within_the_chunk_interval(tmp_path: Path) -> None:
    """The 1 MiB default chunk of a plain writer would hold this message in memory for hours."""
    path = tmp_path / "slow.mcap"
    rec = McapRecorder(path, max_chunk_interval_s=0.2)
    try:
        rec.write("/fix", _fix(0), T0)
        deadline = time.monotonic() + 2.0
        while not read_unfinished(path)[0] and time.monotonic() < deadline:
            time.sleep(0.02)
        waited = 2.0 - (deadline - time.monotonic())
        assert read_unfinished(path)[0] == [("/fix", T0)], "the chunk was not closed by the timer"
        assert waited < 1.5  # a 0.2 s timer, with room for a shared machine's scheduling
        assert rec.stats().chunks == 1 and rec.stats().messages == 1
    finally:
        rec.close()


def test_flush_puts_everything_on_disk_at_once(tmp_path: Path) -> None:
    """With a 60 s chunk interval only the flush request can wake the writer: a lost wake-up would show."""
    path = tmp_path / "flush.mcap"
    with McapRecorder(path, max_chunk_interval_s=60.0) as rec:
        started = time.monotonic()
        for i in range(300):
            rec.write("/fix", _fix(i), T0 + i)
            rec.flush(timeout_s=5.0)
        assert time.monotonic() - started < 5.0
        assert len(read_unfinished(path)[0]) == 300 and rec.stats().chunks == 300


def test_compressions_all_read_back(tmp_path: Path) -> None:
    for kind in ("zstd", "lz4", "none"):
        path = tmp_path / f"{kind}.mcap"
        with McapRecorder(path, compression=kind) as rec:  # type: ignore[arg-type]
            for i in range(20):
                rec.write("/fix", _fix(i), T0 + i)
        assert len(read_complete(path).messages) == 20
    with pytest.raises(RecordingError, match="unknown chunk compression"):
        McapRecorder(tmp_path / "bad.mcap", compression="brotli")  # type: ignore[arg-type]


def test_write_many_queues_in_order_each_with_its_log_time(tmp_path: Path) -> None:
    """A worker's step handed over at once: every message, in order, with its own publish time and its own
    reading of the clock when queued as log time (a live client keys messages by it); sinks see the same; an
    unregistered topic is refused whole."""
    from mcap.reader import make_reader

    seen: list[tuple[str, bytes, int, int]] = []

    class Sink:
        def add_channel(self, *args: object) -> None:
            pass

        def message(self, topic: str, data: bytes, log_time: int, publish_time: int) -> None:
            seen.append((topic, data, log_time, publish_time))

    path = tmp_path / "many.mcap"
    clock = iter(range(T0, T0 + 10**9, 1000))
    with McapRecorder(path, clock=lambda: next(clock), sinks=(Sink(),)) as rec:  # type: ignore[arg-type]
        rec.register_json("/a", "a", {"type": "object"})
        rec.register_json("/b", "b", {"type": "object"})
        batch = [(("/a", "/b")[i % 2], rec.encode("/a", {"i": i}), T0 - 10**6 + i) for i in range(100)]
        rec.write_many(batch)
        rec.write("/a", {"i": 100}, publish_time_ns=T0)
        with pytest.raises(RecordingError, match="register it"):
            rec.write_many([("/a", b"{}", T0), ("/nope", b"{}", T0)])
    with path.open("rb") as f:
        back = [
            (c.topic, json.loads(m.data)["i"], m.log_time, m.publish_time) for _, c, m in make_reader(f).iter_messages()
        ]
    assert [b[1] for b in back] == list(range(101))
    assert [b[0] for b in back[:100]] == [("/a", "/b")[i % 2] for i in range(100)]
    log_times = [b[2] for b in back]
    assert all(b - a == 1000 for a, b in pairwise(log_times[:100]))  # one clock reading each
    assert log_times[100] > log_times[99]
    assert [b[3] for b in back[:100]] == [T0 - 10**6 + i for i in range(100)]
    assert [(t, lt, pt) for t, _, lt, pt in seen] == [(t, lt, pt) for t, _, lt, pt in back]
