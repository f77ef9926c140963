"""McapRecorder's log times from its clock (the file in log-time order), its sinks, and the live view alone.

The live view is checked here with a Foxglove WebSocket client written with `websockets`
(protocol foxglove.sdk.v1) against the real SDK server, without a flight; the flight test
(tests/e2e/test_foxglove_flight.py) checks it during a simulated flight.
"""

from __future__ import annotations

import asyncio
import json
import socket
import struct
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader

from icgt.recording import McapRecorder, layout
from icgt.recording.live import LiveView
from icgt.recording.writer import sink_failures


def _file_messages(path: Path) -> list[tuple[str, int, int, bytes]]:
    channels: dict[int, str] = {}
    out = []
    with path.open("rb") as f:
        for r in StreamReader(f).records:
            if isinstance(r, Channel):
                channels[r.id] = r.topic
            elif isinstance(r, Message):
                out.append((channels[r.channel_id], r.log_time, r.publish_time, r.data))
    return out


class _Sink:
    def __init__(self) -> None:
        self.channels: list[str] = []
        self.messages: list[tuple[str, int, int, bytes]] = []
        self.lock = threading.Lock()

    def add_channel(self, topic: str, encoding: str, schema: tuple[str, str, bytes], meta: Mapping[str, str]) -> None:
        with self.lock:
            self.channels.append(topic)

    def message(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
        with self.lock:
            assert topic in self.channels
            self.messages.append((topic, log_time_ns, publish_time_ns, data))


def test_threads_writing_without_log_times_give_a_file_in_log_time_order(tmp_path: Path) -> None:
    sink = _Sink()
    path = tmp_path / "a.mcap"
    rec = McapRecorder(path, max_chunk_interval_s=0.05, sinks=(sink,))
    rec.register_json("/a", "a", {"type": "object"})

    def writer(k: int) -> None:
        for i in range(1500):
            # data times deliberately out of order (a frame stamped at its past mid-exposure)
            rec.write("/a", {"k": k, "i": i}, publish_time_ns=time.time_ns() - (i % 7) * 100_000_000)
            fix = LocationFix(latitude=1.0, longitude=2.0, altitude=float(i))
            rec.write("/fix", fix, publish_time_ns=1000 + i)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    rec.close()
    got = _file_messages(path)
    assert len(got) == 12_000
    times = [m[1] for m in got]
    assert times == sorted(times)  # strictly what mcap doctor --strict-message-order asks
    fixes = [m for m in got if m[0] == "/fix"]
    assert sorted(m[2] for m in fixes) == sorted(1000 + i for i in range(1500) for _ in range(4))
    assert sorted(sink.messages) == sorted(got)  # the sink saw every message, same bytes and times
    assert sink.channels == ["/a", "/fix"]


def test_a_caller_that_passes_log_times_keeps_them(tmp_path: Path) -> None:
    path = tmp_path / "b.mcap"
    with McapRecorder(path) as rec:
        rec.register_json("/b", "b", {"type": "object"})
        rec.write("/b", {"x": 1}, 5_000, 4_000)
        rec.write("/b", {"x": 2}, 6_000)
    assert [(m[1], m[2]) for m in _file_messages(path)] == [(5_000, 4_000), (6_000, 6_000)]


def test_a_failing_sink_does_not_stop_the_recording(tmp_path: Path) -> None:
    class Broken(_Sink):
        def message(self, topic: str, data: bytes, log_time_ns: int, publish_time_ns: int) -> None:
            raise RuntimeError("sink is down")

    before = sink_failures()
    path = tmp_path / "c.mcap"
    with McapRecorder(path, sinks=(Broken(),)) as rec:
        rec.register_json("/c", "c", {"type": "object"})
        for i in range(10):
            rec.write("/c", {"i": i})
    assert len([m for m in _file_messages(path) if m[0] == "/c"]) == 10
    assert sink_failures() >= before + 10


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def _client(port: int, topics: set[str], want: int, joined: threading.Event) -> list[tuple[str, int, bytes]]:
    import websockets

    got: list[tuple[str, int, bytes]] = []
    ids: dict[int, str] = {}
    async with websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1"]) as ws:  # type: ignore[list-item]
        deadline = time.monotonic() + 10.0
        while len(got) < want and time.monotonic() < deadline:
            try:
                raw = await asyncio.wait_for(ws.recv(), timeout=0.2)
            except TimeoutError:
                continue
            if isinstance(raw, str):
                msg = json.loads(raw)
                if msg["op"] == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        if ch["topic"] in topics:
                            ids[len(ids) + 1] = ch["topic"]
                            subs.append({"id": len(ids), "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                    await asyncio.sleep(0.3)  # the server takes the subscription
                    joined.set()
            elif raw[0] == 1:
                sub, log_ns = struct.unpack_from("<IQ", raw, 1)
                got.append((ids[sub], log_ns, bytes(raw[13:])))
    return got


def test_the_live_view_serves_the_files_channels_and_replays_the_latched_ones(tmp_path: Path) -> None:
    port = _free_port()
    live = LiveView(port=port)
    assert live.port == port and live.host == "127.0.0.1"
    try:
        path = tmp_path / "d.mcap"
        rec = McapRecorder(path, sinks=(live,))
        mount = FrameTransforms()
        mount.transforms.add(parent_frame_id=layout.BASE_FRAME, child_frame_id=layout.MOUNT_FRAME)
        rec.write(layout.TF_STATIC, mount)  # sent before any client: replayed on subscribe
        rec.register_protobuf(layout.FRAMES_LOCATION, LocationFix)
        joined = threading.Event()
        result: dict[str, Any] = {}

        def run() -> None:
            result["got"] = asyncio.run(_client(port, {layout.TF_STATIC, layout.FRAMES_LOCATION}, 6, joined))

        t = threading.Thread(target=run)
        t.start()
        assert joined.wait(10.0)
        for i in range(5):
            rec.write(layout.FRAMES_LOCATION, LocationFix(latitude=float(i)))
        t.join(timeout=15.0)
        rec.close()
    finally:
        live.stop()
    got = result["got"]
    assert [g[0] for g in got].count(layout.TF_STATIC) == 1
    fixes = [(g[1], g[2]) for g in got if g[0] == layout.FRAMES_LOCATION]
    in_file = [(m[1], m[3]) for m in _file_messages(path) if m[0] == layout.FRAMES_LOCATION]
    assert fixes == in_file and len(fixes) == 5


def test_the_live_view_says_when_its_port_is_taken() -> None:
    from icgt.recording.live import LiveViewError

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(LiveViewError, match=r"cannot serve on 127\.0\.0\.1"):
            LiveView(port=s.getsockname()[1])


def test_a_recovered_recording_stays_in_log_time_order(tmp_path: Path) -> None:
    """`icgt recover` on a file cut off mid-recording (as a power cut leaves it): still in log-time order."""
    from icgt.recording import recover

    path = tmp_path / "cut.mcap"
    rec = McapRecorder(path, max_chunk_interval_s=0.02)
    rec.register_json("/a", "a", {"type": "object"})
    for i in range(3000):
        rec.write("/a", {"i": i}, publish_time_ns=time.time_ns() - (i % 5) * 50_000_000)
        if i % 300 == 0:
            time.sleep(0.03)  # let chunks close
    rec.close()
    data = path.read_bytes()[: path.stat().st_size * 6 // 10]  # no summary, a chunk cut in the middle
    cut = tmp_path / "cut_copy.mcap"
    cut.write_bytes(data)
    out = tmp_path / "recovered.mcap"
    report = recover(cut, out)
    got = _file_messages(out)
    assert 0 < len(got) == report.messages < 3000
    times = [m[1] for m in got]
    assert times == sorted(times)
