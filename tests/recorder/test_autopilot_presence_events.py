"""One autopilot outage and one reboot in a recording: each is one event on /icgt/link_events (the synchroniser's
account, the only one), and the recorder's MAVLink link asks the stream rates again after each, on the hint.

The recorder's own MAVLink link (UDP, read by the worker's steps), synchroniser and log, stepped here as its
worker steps them, against a scripted autopilot peer (tests/mavlink/mavlink_peers.py); no device is needed for
what the autopilot link does.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from icgt.ingest.reader import read
from icgt.recorder import Recorder, RecorderConfig
from icgt.recorder.log_file import register_channels
from icgt.recording import McapRecorder, layout

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "mavlink"))
from mavlink_peers import AutopilotPeer, free_udp_port

STEP_S = 0.05  # the worker's period is 100 ms; quicker here, as when frames are due


def _step_for(rec: Recorder, seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        with rec.worker.step():
            rec.worker.drain(limit=None)
            rec.worker.work_once(time.monotonic_ns())
        time.sleep(STEP_S)


def test_one_outage_and_one_reboot_are_each_one_event_and_rates_are_asked_again(tmp_path: Path) -> None:
    port = free_udp_port()
    rec = Recorder(RecorderConfig().with_overrides(mavlink_url=f"udpin:127.0.0.1:{port}", out_dir=tmp_path))
    timeout_s = rec.sync_config.autopilot_timeout_s
    path = tmp_path / "presence.mcap"
    rec.log_file.mcap = mcap = McapRecorder(path)
    register_channels(mcap)
    rec._start_mavlink()
    ap = AutopilotPeer(port)
    rounds: list[int] = []  # interval requests the peer had at each phase's end
    try:
        ap.stream(hz=50)
        _step_for(rec, 2.0)
        rounds.append(len(ap.interval_requests))
        ap.silence()  # an outage: longer than the timeout
        _step_for(rec, timeout_s + 0.8)
        ap.stream()
        _step_for(rec, 2.0)
        rounds.append(len(ap.interval_requests))
        ap.silence()  # a reboot: silent while it boots (shorter than the timeout), then its clock starts again
        _step_for(rec, 1.5)
        ap.boot_ns = time.monotonic_ns()
        ap.mav.seq = 0
        ap.stream()
        _step_for(rec, 2.0)
        rounds.append(len(ap.interval_requests))
    finally:
        ap.close()
        assert rec.camera is not None and rec.mavlink is not None
        rec.camera.stop()
        rec.mavlink.stop()
        with rec.worker.step():
            rec.worker.drain(limit=None)
            rec.worker.work_once(time.monotonic_ns())
        mcap.close()
    events = [d for _, d in read(path).messages(layout.LINK_EVENTS)]
    presence = [e for e in events if e["kind"].startswith("autopilot_") and e["kind"] != "autopilot_second_sender"]
    assert [(e["link"], e["kind"]) for e in presence] == [
        ("mavlink", "autopilot_seen"),
        ("mavlink", "autopilot_lost"),
        ("mavlink", "autopilot_back"),
        ("mavlink", "autopilot_rebooted"),
    ], events
    lost, back = presence[1], presence[2]
    assert timeout_s * 1e9 < lost["outage_ns"] < (timeout_s + 0.5) * 1e9
    assert (timeout_s + 0.6) * 1e9 < back["outage_ns"] < (timeout_s + 1.5) * 1e9
    # the link's rate requests: all of them at first, again after the outage, again after the reboot
    n_rates = 6
    assert rounds[0] >= n_rates and rounds[1] >= rounds[0] + n_rates and rounds[2] >= rounds[1] + n_rates, rounds
    assert rec.sync.counters()["autopilot_outages"] == 1 and rec.sync.counters()["autopilot_reboots"] == 1
