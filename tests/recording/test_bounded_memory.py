"""What the recorder holds in memory stays bounded or compact over a long capture (issue 30, part 4: soak).

Deterministic: counts of entries held, and tracemalloc's bytes for structures that legitimately grow with
the recording (the MCAP chunk index, the camera image history), per item, against a stated bound."""

from __future__ import annotations

import dataclasses
import errno
import io
import logging
import os
import random
import tracemalloc

from mcap.reader import make_reader

from icgt.mavlink.camera_images import CapturedImage, ImageHistory
from icgt.mavlink.telemetry import TelemetryBuffer
from icgt.recording.mcap_file import McapFileWriter, message_record

CHUNK_BYTES_BOUND = 16
"""Memory per closed chunk [bytes]: its ChunkIndex record waits in a temporary file until the summary."""
RETENTION_S = 742.7  # the default retention at 5 fps (icgt.device.history.telemetry_retention_s)
MAX_RATE_HZ = 100  # capacity per stream = retention * MAX_STREAM_RATE_HZ, as TelemetryStore.retain sets it


def test_a_slow_stream_holds_its_retention_and_at_most_a_quarter_more():
    # GPS_RAW_INT at 10 Hz for 30 min: the retention is 12.4 min; before the fix the held entries were
    # deleted only once a quarter of the capacity (74 270 / 4 entries, 31 min at 10 Hz) had expired.
    buf: TelemetryBuffer[object] = TelemetryBuffer(round(RETENTION_S * MAX_RATE_HZ), retain_us=int(RETENTION_S * 1e6))

    class _S:
        __slots__ = ("boot_us",)

        def __init__(self, t: int) -> None:
            self.boot_us = t

    rate_hz = 10
    kept = int(RETENTION_S * rate_hz)
    peak = 0
    for i in range(30 * 60 * rate_hz):
        buf.push(_S(i * 100_000))
        peak = max(peak, buf.held)
    assert len(buf) <= kept + 1
    assert peak <= 1.25 * kept + 64, (peak, kept)


def test_chunk_index_takes_little_memory_per_chunk():
    stream = io.BytesIO()
    writer = McapFileWriter(stream, compression="none")
    for ch in range(12):
        writer.add_schema(ch + 1, f"s{ch}", "jsonschema", b"{}")
        writer.add_channel(ch + 1, f"/t{ch}", "json", ch + 1, {})
    n_chunks = 2000
    payload = b'{"x":1}'

    def one_chunk(k: int) -> None:
        for ch in range(12):
            t = k * 1000 + ch
            writer.add_message_record(ch + 1, t, message_record(ch + 1, 0, t, t, payload))
        writer.close_chunk()

    one_chunk(0)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for k in range(1, n_chunks + 1):
            one_chunk(k)
            stream.seek(0)
            stream.truncate()  # what is written is on disk, not in memory: only the writer's state counts
        per_chunk = (tracemalloc.get_traced_memory()[0] - before) / n_chunks
    finally:
        tracemalloc.stop()
    # The encoded ChunkIndex record of 12 channels (257 B) waits in a temporary file: in memory it took 257 B a
    # chunk (0.05 MiB/min at 4 chunks/s), as mcap.records objects about 1.4 kB.
    assert per_chunk < CHUNK_BYTES_BOUND, per_chunk
    assert writer.chunk_count == n_chunks + 1


def test_chunk_index_written_at_close_is_complete():
    stream = io.BytesIO()
    writer = McapFileWriter(stream, compression="none")
    writer.add_schema(1, "s", "jsonschema", b"{}")
    writer.add_channel(1, "/t", "json", 1, {})
    for k in range(5):
        writer.add_message_record(1, k, message_record(1, k, k, k, b"{}"))
        writer.close_chunk()
    writer.finish()
    summary = make_reader(io.BytesIO(stream.getvalue())).get_summary()
    assert summary is not None
    assert [ci.message_start_time for ci in summary.chunk_indexes] == [0, 1, 2, 3, 4]
    assert summary.statistics is not None and summary.statistics.chunk_count == 5


def _image(rng: random.Random) -> CapturedImage:
    def u() -> float:
        return rng.uniform(-1.0, 1.0)

    return CapturedImage(rng.getrandbits(31), rng.getrandbits(51), u(), u(), u(), u(), (u(), u(), u(), u()))


IMAGE_BYTES_BOUND = 16
"""Memory per image in the history [bytes]: the images wait packed in a temporary file (in memory, packed,
they took about 200 B each, as dataclass objects about 490 B)."""


def test_image_history_is_compact_and_returns_what_was_kept():
    history = ImageHistory()
    rng = random.Random(3)
    history.append(_image(rng))
    n = 3000
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        for _ in range(n):
            history.append(_image(rng))  # made here: what the history keeps of it is counted, nothing else
        per_image = (tracemalloc.get_traced_memory()[0] - before) / n
    finally:
        tracemalloc.stop()
    assert per_image < IMAGE_BYTES_BOUND, per_image
    again = random.Random(3)
    images = [_image(again) for _ in range(n + 1)]
    got = history.get(1235)
    assert got is not None and got.image_index == 1235
    assert got == dataclasses.replace(images[1235], image_index=1235)
    none_pose = CapturedImage(1, 0, None, None, None, None, None, capture_result=False, file_url="img.jpg")
    kept = history.append(none_pose)
    assert history.get(kept.image_index) == kept


def test_a_disk_that_refuses_the_spill_loses_nothing(monkeypatch, caplog):
    # The chunk index and the image history wait in temporary files; when the disk refuses a write (full),
    # what follows is kept in memory and the log says so once: the summary and every image are still whole.
    stream = io.BytesIO()
    writer = McapFileWriter(stream, compression="none")
    history = ImageHistory()
    writer.add_schema(1, "s", "jsonschema", b"{}")
    writer.add_channel(1, "/t", "json", 1, {})
    rng = random.Random(5)
    images = [history.append(_image(rng)) for _ in range(3)]
    real_pwrite = os.pwrite

    def full(fd: int, data: bytes, offset: int) -> int:
        raise OSError(errno.ENOSPC, "No space left on device")

    for k in range(3):
        writer.add_message_record(1, k, message_record(1, k, k, k, b"{}"))
        writer.close_chunk()
    monkeypatch.setattr(os, "pwrite", full)
    with caplog.at_level(logging.WARNING, logger="icgt.spill"):
        for k in range(3, 6):
            writer.add_message_record(1, k, message_record(1, k, k, k, b"{}"))
            writer.close_chunk()
        images += [history.append(_image(rng)) for _ in range(3)]
    monkeypatch.setattr(os, "pwrite", real_pwrite)
    images.append(history.append(_image(rng)))  # after a refusal, later ones stay in memory too
    writer.finish()
    refusals = [r.getMessage() for r in caplog.records if "kept in memory" in r.getMessage()]
    assert len(refusals) == 2 and "chunk index" in refusals[0] and "image history" in refusals[1], refusals
    summary = make_reader(io.BytesIO(stream.getvalue())).get_summary()
    assert summary is not None
    assert [ci.message_start_time for ci in summary.chunk_indexes] == [0, 1, 2, 3, 4, 5]
    assert [history.get(i) for i in range(len(images))] == images
    reader = make_reader(io.BytesIO(stream.getvalue()))
    assert [m.log_time for _s, _c, m in reader.iter_messages()] == [0, 1, 2, 3, 4, 5]
