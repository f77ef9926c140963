"""Other systems' MAVLink frames taken in bulk (`UndecodedBatch`) by the recorder's worker: the same
/mavlink/other_systems records and the same synchroniser counts as one message per frame, and the recompute
counts them back to the live counts without decoding."""

from __future__ import annotations

from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.ingest.reader import LogMessage, read
from icgt.ingest.recompute import _Feeder
from icgt.mavlink.frames import ForeignFrame, UndecodedBatch, split_foreign
from icgt.mavlink.link import MavlinkMessage
from icgt.recorder import Recorder
from icgt.recorder.config import RecorderConfig
from icgt.recorder.log_file import register_channels
from icgt.recorder.mavlink_input import OTHER_SYSTEMS_BATCH
from icgt.recording import McapRecorder, layout
from icgt.sync import Synchroniser

T0 = 1_000_000_000_000


def _foreign_frames(n: int) -> list[ForeignFrame]:
    """n frames of three foreign systems (telemetry types and others, a v1 one), one datagram each."""
    frames: list[ForeignFrame] = []
    for k in range(n):
        mav = mavlink2.MAVLink(None, srcSystem=40 + k % 3, srcComponent=1 + k % 2)
        msg = (
            mav.attitude_encode(k, 0.1, 0.2, 0.3, 0, 0, 0),
            mav.param_value_encode(b"P%d" % k, float(k), 9, 900, k),
            mav.global_position_int_encode(k, 473_977_419, 85_455_938, 488_000, 10_000, 0, 0, 0, 0),
        )[k % 3]
        buf = bytes(msg.pack(mav, force_mavlink1=k % 7 == 0))
        assert split_foreign(buf, T0 + k * 100_000, frozenset({1}), frames) == b""
    return frames


def _record(tmp: Path, name: str, feed) -> tuple[list[dict], dict[str, int]]:
    rec = Recorder(RecorderConfig())
    rec.log_file.mcap = mcap = McapRecorder(tmp / f"{name}.mcap")
    register_channels(mcap)
    feed(rec)
    rec.worker.drain(limit=None)
    counters = rec.sync.counters()
    mcap.close()
    records = [d for _, d in read(tmp / f"{name}.mcap").messages(layout.MAVLINK_OTHER_SYSTEMS)]
    return records, counters


def test_batches_give_the_records_and_counts_of_one_message_per_frame(tmp_path: Path) -> None:
    frames = _foreign_frames(1234)
    batch = UndecodedBatch(frames)

    def one_each(rec: Recorder) -> None:
        for frame, rx in batch.undecoded_frames():
            rec.mavlink_input.on_message(MavlinkMessage(frame, rx))

    def in_batches(rec: Recorder) -> None:
        for i in range(0, len(frames), 100):  # as drains of the socket would cut them
            rec.mavlink_input.on_message(UndecodedBatch(frames[i : i + 100]))

    per_frame, counts_each = _record(tmp_path, "each", one_each)
    bulk, counts_bulk = _record(tmp_path, "bulk", in_batches)
    assert counts_bulk == counts_each
    assert counts_bulk["mavlink_messages"] == 1234 and counts_bulk["telemetry_other_source"] == sum(
        k % 3 != 1 for k in range(1234)
    )
    logged = [f for r in bulk for f in r["frames"]]
    assert logged == [f for r in per_frame for f in r["frames"]]
    assert len(logged) == 1234 and [f["host_rx_ns"] for f in logged] == [f[4] for f in frames]
    assert max(len(r["frames"]) for r in bulk) <= OTHER_SYSTEMS_BATCH

    # the recompute counts the logged frames back to the live counts, without decoding them
    sync = Synchroniser()
    feeder = _Feeder(sync, None, 100.0, requests_logged=True)
    for r in bulk:
        feeder.feed(LogMessage(layout.MAVLINK_OTHER_SYSTEMS, T0, r))
    assert {k: sync.counters()[k] for k in ("mavlink_messages", "telemetry_other_source")} == {
        "mavlink_messages": 1234,
        "telemetry_other_source": counts_bulk["telemetry_other_source"],
    }
    assert feeder.counts["mavlink_undecodable"] == 0


def test_recompute_decodes_a_logged_frame_of_the_autopilots_system(tmp_path: Path) -> None:
    """Recomputing with another autopilot_system: that system's frames in /mavlink/other_systems are fed whole."""
    frames = _foreign_frames(6)
    records, _ = _record(tmp_path, "one", lambda rec: rec.mavlink_input.on_message(UndecodedBatch(frames)))
    sync = Synchroniser()
    sync.autopilot.system = 40  # the sender of frames 0 and 3 (ATTITUDE both)
    whole: list[tuple[str, int, int]] = []
    on_mavlink = sync.on_mavlink

    def spy(msg, rx_ns):
        whole.append((msg.get_type(), msg.get_srcSystem(), rx_ns))
        return on_mavlink(msg, rx_ns)

    sync.on_mavlink = spy  # type: ignore[method-assign]
    feeder = _Feeder(sync, None, 100.0, requests_logged=True)
    feeder.feed(LogMessage(layout.MAVLINK_OTHER_SYSTEMS, T0, records[0]))
    assert whole == [("ATTITUDE", 40, frames[0][4]), ("ATTITUDE", 40, frames[3][4])]
    assert sync.counters()["mavlink_messages"] == 6
