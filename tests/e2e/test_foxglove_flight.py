"""Foxglove end to end: one short flight recorded with `icgt record --live`, watched over WebSocket.

A Foxglove WebSocket client written here with the `websockets` package (protocol foxglove.sdk.v1:
the server advertises channels in JSON, the client subscribes, the server sends binary
MessageData: opcode 1, u32 subscription id, u64 log time, payload) connects to the recorder's
live view while the simulated flight runs, subscribes, and must receive each frame's LocationFix
within 1 s of the frame being written (its log time, on the host's CLOCK_MONOTONIC shared by both
processes). The finished recording, its `icgt export --formats mcap,ros2` outputs and the Foxglove
layout are then checked: messages in log-time order in the data section (what `mcap doctor
--strict-message-order` checks), the vehicle track and transform tree at telemetry rate, the static
camera mount, the calibration, the device log, the images on the timeline, and every reader
(icgt.read, the exact replay, the report, the ROS 2 bag) on the new channels.
"""

from __future__ import annotations

import asyncio
import io
import itertools
import json
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransforms_pb2 import FrameTransforms
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, ChunkIndex, Message
from mcap.stream_reader import StreamReader
from PIL import Image
from replay_check import assert_replay_reproduces_every_frame

from icgt.demo import Flight, fly
from icgt.ingest import read
from icgt.recording import layout
from icgt.sim.scenario import load_scenario

SCENARIO = Path(__file__).with_name("foxglove_flight.toml")
MIN_FRAMES = 10  # 35 at 5 fps for 7 s; fewer if a loaded machine started the recorder very late
SUBSCRIBED = (
    layout.FRAMES_LOCATION,
    layout.VEHICLE_LOCATION,
    layout.TF_STATIC,
    layout.CAMERA_CALIBRATION,
)


def _free_tcp_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@dataclass
class LiveClient:
    """A Foxglove WebSocket client in its own thread: connects when the server appears, records what it gets."""

    port: int
    received: list[tuple[str, int, int, bytes]] = field(default_factory=list)  # topic, log ns, monotonic rx, data
    advertised: dict[str, dict[str, Any]] = field(default_factory=dict)
    subscribed_at_ns: dict[str, int] = field(default_factory=dict)  # topic -> CLOCK_MONOTONIC of our subscribe
    error: str | None = None
    stop: threading.Event = field(default_factory=threading.Event)

    def run(self) -> None:
        try:
            asyncio.run(self._main())
        except Exception as exc:  # reported by the test, not swallowed
            self.error = f"{type(exc).__name__}: {exc}"

    async def _main(self) -> None:
        import websockets

        deadline = time.monotonic() + 60.0
        while True:
            try:
                ws = await websockets.connect(f"ws://127.0.0.1:{self.port}", subprotocols=["foxglove.sdk.v1"])  # type: ignore[list-item]
                break
            except OSError:
                if time.monotonic() > deadline or self.stop.is_set():
                    raise
                await asyncio.sleep(0.05)
        topics: dict[int, str] = {}
        async with ws:
            while not self.stop.is_set():
                try:
                    raw = await asyncio.wait_for(ws.recv(), timeout=0.5)
                except TimeoutError:
                    continue
                except websockets.ConnectionClosed:
                    return
                rx = time.monotonic_ns()
                if isinstance(raw, str):
                    msg = json.loads(raw)
                    if msg.get("op") == "advertise":
                        subs = []
                        for ch in msg["channels"]:
                            self.advertised[ch["topic"]] = ch
                            if ch["topic"] in SUBSCRIBED:
                                topics[len(topics) + 1] = ch["topic"]
                                subs.append({"id": len(topics), "channelId": ch["id"]})
                        if subs:
                            await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
                            for sub in subs:
                                self.subscribed_at_ns[topics[sub["id"]]] = time.monotonic_ns()
                elif raw[0] == 1:  # MessageData
                    sub_id, log_ns = struct.unpack_from("<IQ", raw, 1)
                    self.received.append((topics[sub_id], log_ns, rx, bytes(raw[13:])))


@dataclass
class Run:
    flight: Flight
    client: LiveClient
    export: Path
    export_code: int


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    from icgt.export.cli import add_export_arguments, cmd_export

    base = tmp_path_factory.mktemp("foxglove")
    client = LiveClient(_free_tcp_port())
    thread = threading.Thread(target=client.run, name="foxglove-client", daemon=True)
    thread.start()
    try:
        flight = fly(
            load_scenario(SCENARIO),
            base / "flight",
            record_args=["--live", str(client.port)],
        )
    finally:
        client.stop.set()
        thread.join(timeout=10)
    import argparse

    parser = argparse.ArgumentParser()
    add_export_arguments(parser)
    out = base / "export"
    args = parser.parse_args(
        [
            str(flight.mcap),
            "--images",
            str(flight.card),
            "--out",
            str(out),
            "--formats",
            "mcap,ros2",
            "--no-progress",
        ]
    )
    code = cmd_export(args)
    return Run(flight, client, out, code)


def _data_section(path: Path) -> tuple[list[tuple[str, int, int]], list[tuple[int, int]]]:
    """(topic, log time, publish time) of every message in file order, and each chunk record's (start, end)."""
    messages: list[tuple[str, int, int]] = []
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        for record in StreamReader(f).records:  # chunks opened, CRCs checked
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message):
                messages.append((channels[record.channel_id], record.log_time, record.publish_time))
    with path.open("rb") as f:
        chunks = [
            (r.message_start_time, r.message_end_time)
            for r in StreamReader(f, emit_chunks=True).records
            if isinstance(r, Chunk)
        ]
    return messages, chunks


def assert_strict_log_time_order(path: Path) -> dict[str, int]:
    """The checks of `mcap doctor --strict-message-order`: no message's log time below an earlier one's,
    and no chunk starting before the previous chunk ended; the summary's chunk indexes agree. Returns counts."""
    messages, chunks = _data_section(path)
    assert messages, path
    running = 0
    out_of_order = []
    for i, (topic, log_ns, _) in enumerate(messages):
        if log_ns < running:
            out_of_order.append((i, topic, running - log_ns))
        running = max(running, log_ns)
    assert not out_of_order, f"{path}: {len(out_of_order)} messages before a later log time"
    assert all(b[0] >= a[1] for a, b in itertools.pairwise(chunks)), f"{path}: chunks overlap in time"
    with path.open("rb") as f:
        summary = make_reader(f).get_summary()
    assert summary is not None and summary.statistics is not None
    indexes: list[ChunkIndex] = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert [(c.message_start_time, c.message_end_time) for c in indexes] == chunks
    assert summary.statistics.message_count == len(messages)
    counts: dict[str, int] = {}
    for topic, _, _ in messages:
        counts[topic] = counts.get(topic, 0) + 1
    return counts


def _decoded(path: Path, topic: str, kind: Any) -> list[tuple[int, int, Any]]:
    with path.open("rb") as f:
        return [
            (m.log_time, m.publish_time, kind.FromString(m.data))
            for _, _, m in make_reader(f).iter_messages(topics=[topic], log_time_order=False)
        ]


# --- the live view ------------------------------------------------------------------------------------


def test_the_live_view_delivers_each_frames_location_within_a_second(run: Run) -> None:
    client = run.client
    assert client.error is None, client.error
    assert set(SUBSCRIBED) <= set(client.advertised), sorted(client.advertised)
    offset = read(run.flight.mcap).monotonic_to_utc_offset_ns
    assert offset is not None
    recorded = _decoded(run.flight.mcap, layout.FRAMES_LOCATION, LocationFix)
    assert len(recorded) >= MIN_FRAMES
    # the recorder declares its topics when the log opens, before any frame: we subscribed before the first
    subscribed = client.subscribed_at_ns[layout.FRAMES_LOCATION]
    due = [r for r in recorded if r[0] - offset > subscribed]
    assert len(due) == len(recorded), "the client subscribed late: capture had already run"
    live = {log_ns: (rx, data) for topic, log_ns, rx, data in client.received if topic == layout.FRAMES_LOCATION}
    latencies = []
    for log_ns, _, fix in due:
        assert log_ns in live, f"frame LocationFix logged at {log_ns} never reached the client"
        rx, data = live[log_ns]
        assert LocationFix.FromString(data) == fix  # the same message as in the file
        latencies.append((rx + offset - log_ns) / 1e9)
    print(f"live view: {len(latencies)} frame LocationFix, latency median {np.median(latencies) * 1e3:.1f} ms, "
          f"max {max(latencies) * 1e3:.1f} ms")  # fmt: skip
    assert max(latencies) < 1.0, f"live latency up to {max(latencies):.3f} s"
    assert min(latencies) >= 0.0  # received after it was written: the clocks are the same one


def test_the_live_view_sends_the_latched_mount_and_calibration_to_a_client_that_joined_late(
    run: Run,
) -> None:
    got = {topic for topic, *_ in run.client.received}
    counts = {t: sum(1 for r in run.client.received if r[0] == t) for t in got}
    # Seen once in CI without /vehicle/location (47d19a0, 9f19886; not reproduced): say what the client saw.
    assert {layout.TF_STATIC, layout.CAMERA_CALIBRATION, layout.VEHICLE_LOCATION} <= got, (
        f"received {counts}; advertised {sorted(run.client.advertised)}; subscribed {run.client.subscribed_at_ns}; "
        f"client error {run.client.error}"
    )
    static = [FrameTransforms.FromString(d) for t, _, _, d in run.client.received if t == layout.TF_STATIC]
    assert static[0].transforms[0].child_frame_id == layout.MOUNT_FRAME


# --- the recording ------------------------------------------------------------------------------------


def test_the_recording_is_in_log_time_order(run: Run) -> None:
    counts = assert_strict_log_time_order(run.flight.mcap)
    assert counts[layout.FRAMES] >= MIN_FRAMES


def test_the_vehicle_track_and_base_link_are_at_telemetry_rate(run: Run) -> None:
    path = run.flight.mcap
    rec = read(path)
    topics = rec.topics()
    gpi = [(t, d) for t, d in rec.messages(layout.mavlink_topic("GLOBAL_POSITION_INT")) if d["lat"] or d["lon"]]
    track = _decoded(path, layout.VEHICLE_LOCATION, LocationFix)
    assert len(gpi) > 200 and len(track) == len(gpi)  # 50 Hz
    for (_, publish, fix), (t, d) in zip(track, gpi, strict=True):
        assert publish == t and fix.timestamp.ToNanoseconds() == t
        assert fix.latitude == d["lat"] / 1e7 and fix.altitude == d["alt"] / 1000.0
        assert fix.frame_id == layout.BASE_FRAME
    assert track[-1][2].position_covariance_type == LocationFix.DIAGONAL_KNOWN
    tf = _decoded(path, layout.TF, FrameTransforms)
    telemetry = [m for m in tf if len(m[2].transforms) == 1]
    # from the moment the ENU origin is fixed (the geotagger's: at the first frame), every attitude sample
    first_frame_logged = _frame_times(path)[0][0]  # the origin was fixed just before the frame was logged
    attitude = [t for t, _ in rec.messages(layout.mavlink_topic("ATTITUDE_QUATERNION"))]
    assert len(attitude) == topics[layout.mavlink_topic("ATTITUDE_QUATERNION")]
    after = [t for t in attitude if t > first_frame_logged]
    assert len(after) >= 100  # 50 Hz
    assert set(after) <= {m[1] for m in telemetry} <= set(attitude)  # stamped with their receipt
    assert {m[2].transforms[0].child_frame_id for m in telemetry} == {layout.BASE_FRAME}
    # base_link is where the last GLOBAL_POSITION_INT put the vehicle in the recording's ENU frame
    from icgt.geodesy import LocalFrame

    assert rec.enu_origin is not None
    local = LocalFrame(*rec.enu_origin)
    positions = np.array([local.geodetic_to_enu(d["lat"] / 1e7, d["lon"] / 1e7, d["alt"] / 1000.0) for _, d in gpi])
    for m in telemetry:
        t = m[2].transforms[0].translation
        assert float(np.min(np.linalg.norm(positions - [t.x, t.y, t.z], axis=1))) < 1e-6


def test_the_frames_transforms_end_at_the_geotagged_camera(run: Run) -> None:
    from icgt.geodesy import q_rotate

    path = run.flight.mcap
    frames = {f.mid_host_ns: f for f in read(path).frames()}
    offset = read(path).monotonic_to_utc_offset_ns
    assert offset is not None
    static = _decoded(path, layout.TF_STATIC, FrameTransforms)
    assert len(static) == 1
    mount = static[0][2].transforms[0]
    assert (mount.parent_frame_id, mount.child_frame_id) == (
        layout.BASE_FRAME,
        layout.MOUNT_FRAME,
    )
    lever = [mount.translation.x, mount.translation.y, mount.translation.z]
    assert lever == pytest.approx([0.25, 0.0, -0.12])  # the scenario's FRD lever arm in FLU
    checked = 0
    for _, publish, msg in _decoded(path, layout.TF, FrameTransforms):
        if len(msg.transforms) != 2:
            continue
        base, cam = msg.transforms
        assert (cam.parent_frame_id, cam.child_frame_id) == (
            layout.MOUNT_FRAME,
            layout.CAMERA_FRAME,
        )
        rec = frames[publish - offset]
        q = [base.rotation.w, base.rotation.x, base.rotation.y, base.rotation.z]
        t = np.array([base.translation.x, base.translation.y, base.translation.z]) + q_rotate(q, lever)
        assert t == pytest.approx([rec.east_m, rec.north_m, rec.up_m], abs=1e-9)
        checked += 1
    assert checked >= MIN_FRAMES


def test_the_calibration_and_the_device_log(run: Run) -> None:
    path = run.flight.mcap
    rec = read(path)
    cfg = json.loads(rec.metadata[layout.META_SYNC]["json"])["geotag"]
    cals = _decoded(path, layout.CAMERA_CALIBRATION, CameraCalibration)
    assert len(cals) == rec.topics()[layout.FRAMES] + 1  # the start, then with every frame
    cal = cals[0][2]
    f = cfg["focal_length_mm"] * cfg["image_width_px"] / cfg["sensor_width_mm"]
    assert (cal.width, cal.height) == (cfg["image_width_px"], cfg["image_height_px"])
    assert list(cal.K) == pytest.approx([f, 0, cal.width / 2, 0, f, cal.height / 2, 0, 0, 1])
    assert cal.frame_id == layout.CAMERA_FRAME
    device = list(rec.messages(layout.device_topic("LOG")))
    views = list(rec.messages(layout.DEVICE_LOG_VIEW))
    assert len(device) >= 1 and [v["message"] for _, v in views] == [d["text"] for _, d in device]
    assert all(v["name"] == "icgt.device" for _, v in views)


def test_readers_keep_working_on_the_new_channels(run: Run) -> None:
    from icgt.report.summary import gather

    path = run.flight.mcap
    n = assert_replay_reproduces_every_frame(path)
    assert n >= MIN_FRAMES
    data = gather(read(path))
    assert len(data.track_t_s) > 200  # the report's track still comes from the telemetry
    assert np.all(np.diff(data.track_t_s) >= 0) and 10.0 < data.duration_s < 60.0


# --- the exports --------------------------------------------------------------------------------------


def test_the_export_puts_every_image_on_the_timeline(run: Run) -> None:
    from icgt.export.foxglove_mcap import (
        CALIBRATION_TOPIC,
        DEFAULT_MAX_SIDE_PX,
        FOXGLOVE_FILE,
    )

    assert run.export_code in (
        0,
        1,
    )  # 1: problems.csv has warnings (the missed trigger)
    out = run.export / FOXGLOVE_FILE
    counts = assert_strict_log_time_order(out)
    source = assert_strict_log_time_order(run.flight.mcap)
    assert {t: counts[t] for t in source} == source  # every recorded message is there
    images = _decoded(out, layout.CAMERA_IMAGE, CompressedImage)
    card = sorted(run.flight.card.glob("*.JPG"))
    assert len(images) == len(card) >= MIN_FRAMES  # each card image paired with its frame
    frames = {m[0]: m[1] for m in _frame_times(run.flight.mcap)}
    cals = {m[0]: m[2] for m in _decoded(out, CALIBRATION_TOPIC, CameraCalibration)}
    for log_ns, publish, img in images:
        assert frames[log_ns] == publish == img.timestamp.ToNanoseconds()  # with its frame, at mid-exposure
        assert img.format == "jpeg" and img.frame_id == layout.CAMERA_FRAME
        pic = Image.open(io.BytesIO(img.data))
        assert pic.format == "JPEG" and max(pic.size) <= DEFAULT_MAX_SIDE_PX
        cal = cals[log_ns]
        assert (cal.width, cal.height) == pic.size
    with Image.open(card[0]) as full:
        first = Image.open(io.BytesIO(images[0][2].data))
        assert first.size[0] / first.size[1] == pytest.approx(full.size[0] / full.size[1], rel=0.01)


def _frame_times(path: Path) -> list[tuple[int, int]]:
    with path.open("rb") as f:
        return [(m.log_time, m.publish_time) for _, _, m in make_reader(f).iter_messages(topics=[layout.FRAMES])]


def test_the_ros2_bag_is_in_log_time_order(run: Run) -> None:
    bags = sorted((run.export / "ros2").glob("*.mcap"))
    assert len(bags) == 1
    counts = assert_strict_log_time_order(bags[0])
    assert counts["/frames"] >= MIN_FRAMES and counts["/tf_static"] == 1


def test_the_shipped_layout_names_only_topics_the_logs_have(run: Run) -> None:
    from icgt.export.foxglove_mcap import FOXGLOVE_FILE

    topics = set(assert_strict_log_time_order(run.export / FOXGLOVE_FILE))
    named = layout_topics(layout.FOXGLOVE_LAYOUT.read_text())
    assert {layout.VEHICLE_LOCATION, layout.CAMERA_IMAGE, layout.CAMERA_CALIBRATION, layout.DEVICE_LOG_VIEW} <= named
    assert named <= topics, sorted(named - topics)


def layout_topics(text: str) -> set[str]:
    """Every topic a Foxglove layout names (as a value or a key; message paths cut at their first field)."""
    import re

    return set(re.findall(r'"(/[a-z_/]+)(?:\.[a-z_]+)*"', text))


def test_the_export_derives_the_views_for_a_recording_that_lacks_them(run: Run, tmp_path: Path) -> None:
    """A recording as the recorder wrote it before the views: the export derives them exactly as the recorder did."""
    from mcap.writer import Writer

    from icgt.export.foxglove_mcap import FOXGLOVE_FILE, write_foxglove_mcap
    from icgt.ingest.recompute import recording_sync_config
    from icgt.recording.views import TOPICS

    old = tmp_path / "old.mcap"
    with run.flight.mcap.open("rb") as src, old.open("wb") as dst:
        reader = make_reader(src)
        writer = Writer(dst)
        writer.start()
        ids: dict[int, int] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            if channel.topic in TOPICS:
                continue
            if channel.id not in ids:
                assert schema is not None
                sid = writer.register_schema(schema.name, schema.encoding, schema.data)
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, sid)
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
        for record in reader.iter_metadata():
            writer.add_metadata(record.name, dict(record.metadata))
        writer.finish()  # type: ignore[no-untyped-call]
    recording = read(old)
    sync = recording_sync_config(recording)
    out = tmp_path / "out"
    out.mkdir()
    counts = write_foxglove_mcap(old, out, {}, sync.geotag, recording=recording, vehicle_system=sync.autopilot_system)
    assert counts["derived"] > 0
    assert_strict_log_time_order(out / FOXGLOVE_FILE)

    def payloads(path: Path, topic: str) -> list[tuple[int, bytes]]:
        with path.open("rb") as f:
            return [(m.publish_time, m.data) for _, _, m in make_reader(f).iter_messages(topics=[topic])]

    for topic in (layout.VEHICLE_LOCATION, layout.FRAMES_LOCATION, layout.FRAMES_POSE, layout.DEVICE_LOG_VIEW):
        assert payloads(out / FOXGLOVE_FILE, topic) == payloads(run.flight.mcap, topic), topic
    assert [d for _, d in payloads(out / FOXGLOVE_FILE, layout.CAMERA_CALIBRATION)][1:] == [
        d for _, d in payloads(run.flight.mcap, layout.CAMERA_CALIBRATION)
    ][1:]  # with every frame (the first: at each file's own start)
    static = payloads(out / FOXGLOVE_FILE, layout.TF_STATIC)
    assert len(static) == 1
    assert FrameTransforms.FromString(static[0][1]).transforms[0].child_frame_id == layout.MOUNT_FRAME
    # base_link from the start here (the origin is known), from the first frame in the recorder
    assert set(payloads(run.flight.mcap, layout.TF)) <= set(payloads(out / FOXGLOVE_FILE, layout.TF))
