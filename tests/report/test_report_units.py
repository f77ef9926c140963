"""The report's pieces without a flight: link events to outages and losses, the coverage grid."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from icgt.report.plots import coverage_grid
from icgt.report.summary import FlightData, Loss, Outage, _events, summarize


def _data() -> FlightData:
    return FlightData(
        path=Path("x.mcap"),
        t0_host_ns=1_000_000_000,
        duration_s=20.0,
        frames=[],
        track_t_s=np.zeros(0),
        track_enu_m=np.zeros((0, 3)),
        device_clock=[],
        utc_clock=[],
        outages=[],
        losses=[],
        status={},
        metadata={},
        topics={},
    )


def test_link_events_become_outages_and_losses() -> None:
    s = 1_000_000_000
    events = [
        {"link": "device", "kind": "disconnected", "outage_ns": 0, "detail": "unplugged", "_host": 4 * s},
        {"link": "mavlink", "kind": "autopilot_lost", "outage_ns": 3 * s, "detail": "no message", "_host": 10 * s},
        {"link": "mavlink", "kind": "autopilot_back", "outage_ns": 4 * s, "detail": "back", "_host": 11 * s},
        {"link": "device", "kind": "connected", "outage_ns": 2 * s, "detail": "back", "_host": 5 * s},
        {"link": "device", "kind": "sequence_gap", "count": 7, "_host": 6 * s},
        {"link": "device", "kind": "frames_rejected", "count": 2, "_host": 7 * s},
        {"link": "device", "kind": "disconnected", "outage_ns": 0, "detail": "unplugged again", "_host": 15 * s},
    ]
    data = _data()
    _events(data, events)
    assert data.outages == [
        Outage("mavlink", 6.0, 10.0, "no message"),  # silent since 3 s before the lost event (t = 9 s)
        Outage("device", 3.0, 4.0, "unplugged"),
        Outage("device", 14.0, 20.0, "unplugged again (not back by the end)"),
    ]
    assert data.losses == [Loss("device", 5.0, "sequence_gap", 7), Loss("device", 6.0, "frames_rejected", 2)]


def test_coverage_grid_counts_overlaps() -> None:
    a = np.array([[0.0, 0.0], [2.0, 0.0], [2.0, 1.0], [0.0, 1.0]])
    b = a + np.array([1.0, 0.0])
    counts, extent = coverage_grid([a, b], cells=300)
    assert extent == (0.0, 3.0, 0.0, 1.0)
    cell = (3.0 / 300) ** 2
    assert abs(np.sum(counts == 2) * cell - 1.0) < 0.02  # the 1 m^2 both cover
    assert abs(np.sum(counts >= 1) * cell - 3.0) < 0.03


def test_a_recording_without_frames_still_reports(tmp_path: Path) -> None:
    from icgt.cli import main
    from icgt.recorder import topics
    from icgt.recording import McapRecorder

    path = tmp_path / "log.mcap"
    with McapRecorder(path, fsync=False) as rec:
        rec.add_metadata("icgt.config", {"source": "test", "config": "{}"})  # as the recorder writes
        rec.register_json(topics.LINK_EVENTS, "icgt.link_event", {"type": "object"})
        for i, kind in enumerate(("disconnected", "connected")):
            event = {"link": "device", "kind": kind, "detail": kind, "count": 0, "outage_ns": i * 10**9}
            rec.write(topics.LINK_EVENTS, event | {"host_ns": 5 * 10**9 + i * 10**9}, 5 * 10**9 + i * 10**9)
    out = tmp_path / "report.html"
    assert main(["report", str(path), "--out", str(out)]) == 0
    text = out.read_text()
    assert "Frames (0)" in text and "no camera calibration in the recording" in text
    assert text.count("<svg") == 4  # no footprints to draw


def test_the_summary_states_what_resend_recovered_and_what_is_lost_by_kind() -> None:
    from icgt.report.summary import summarize

    s = 1_000_000_000
    data = _data()
    _events(data, [{"link": "device", "kind": "history_lost", "count": 5, "_host": 3 * s}])
    assert data.losses == [Loss("device", 2.0, "history_lost", 5)]
    rows = dict(summarize(data))
    assert rows["device frames lost (exposures + PPS + samples)"] == "5"  # a killed recorder: events only
    data.metadata = {
        "icgt.device_link": {
            "resend_recovered": "1559",
            "lost_exposures": "2",
            "lost_pps": "1",
            "lost_samples": "1512",
            "lost_other": "233",
            "lost_unknown": "0",
        }
    }
    rows = dict(summarize(data))
    assert rows["device frames recovered (RESEND) / lost"] == (
        "1559 recovered; lost: 2 exposures, 1 PPS, 1512 samples, 233 status/replies/logs, 0 unknown"
    )


def test_the_summary_says_how_many_messages_with_the_autopilots_id_were_not_believed() -> None:
    data = _data()
    assert not [label for label, _ in summarize(data) if "not believed" in label]  # none: no row
    data.sync_counters = {"autopilot_second_sender_messages": 70, "autopilot_unsigned_messages": 3}
    rows = dict(summarize(data))
    assert rows["messages with the autopilot's id not believed"].startswith(
        "70 from a second sender, 3 without a valid signature"
    )


def test_the_summary_counts_frames_without_pose_or_range_because_of_an_outage() -> None:
    from icgt.geotag.record import FrameRecord
    from icgt.report.summary import summarize

    def frame(seq: int, flags: list[str]) -> FrameRecord:
        return FrameRecord(
            frame_seq=seq, image_index=seq, camera_id=0, device_flags=0, trigger_device_us=seq,
            start_device_us=seq, mid_device_us=seq, duration_us=0, mid_host_ns=seq, mid_host_uncertainty_ns=0,
            time_source="none", flags=flags, position_source="none", fix_type=0, pose_gap_before_ms=0.0,
            pose_gap_after_ms=0.0,
        )  # fmt: skip

    data = _data()
    data.frames = [
        frame(1, []),
        frame(2, ["resent"]),
        frame(3, ["resent", "range_invalid", "range_samples_lost"]),
        frame(4, ["resent", "no_fix", "telemetry_expired", "range_invalid", "range_samples_lost"]),
        frame(5, ["resent", "range_invalid"]),  # the LiDAR saw nothing: not the outage's doing
        frame(6, ["resent", "range_from_snapshot"]),  # its samples were gone: the exposure's own snapshot ranged it
    ]
    rows = dict(summarize(data))
    assert rows["frames resent after an outage"] == (
        "5; because of the outage 1 without a pose, 2 without a range; 1 ranged from the device's snapshot"
    )
