"""Issue 30: the device stops capture by itself once its host has been silent for [capture] host_timeout_s,
and `icgt recover-device` fetches what its history still holds of a recording that ended mid-outage. Both over
the simulated device's real serial path (a pty) with its unplug fault.

1. The recording that comes back after the outage: the device stopped itself (the camera made no exposure
   after the stop), the log says so and `icgt info` too, and the recorder, with no stop left to deliver, exits 0.
2. The recorder gone: record, unplug, stop the recorder mid-outage (exit 1, the stop not delivered), the
   camera stops shooting after the timeout, re-plug, `icgt recover-device --flight first.mcap`: every exposure
   the outage took is in the recovered log, which names the flight, and `icgt info` reads it.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

from icgt.cli import main
from icgt.control import request
from icgt.ingest import read
from icgt.recording import layout
from icgt.sim.recorder_setup import free_udp_port, recorder_config_text
from icgt.sim.scenario import load_scenario
from icgt.sim.session import SimSession
from icgt.sim.truth import read_events

SHORT_FLIGHT = Path(__file__).with_name("short_flight.toml")
TIMEOUT_S = 5.0  # the shortest host timeout the device accepts
INTERVAL_S = 0.2


def _session(tmp_path: Path) -> tuple[SimSession, Any, Path]:
    text = SHORT_FLIGHT.read_text()
    scenario = tmp_path / "host_silence.toml"  # the short flight without its own faults, long enough
    text = text[: text.index("[faults]")].replace('name = "short_flight"', 'name = "host_silence"')
    scenario.write_text(text.replace("duration_s = 22.0", "duration_s = 60.0"))
    sc = load_scenario(scenario)
    session = SimSession(sc, tmp_path / "sim", mavlink_port=free_udp_port(), gcs_port=free_udp_port())
    urls = session.start()
    config = tmp_path / "recorder.toml"
    config.write_text(recorder_config_text(sc, tmp_path / "recording", host_timeout_s=TIMEOUT_S))
    return session, urls, config


def _record(config: Path, urls: Any, sock: Path) -> subprocess.Popen[str]:
    recorder = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
         "--mavlink", urls.mavlink, "--socket", str(sock)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    deadline = time.monotonic() + 30
    while not sock.exists() and time.monotonic() < deadline and recorder.poll() is None:
        time.sleep(0.1)
    request(sock, {"command": "start", "interval_s": INTERVAL_S, "count": 0}, timeout_s=10.0)
    return recorder


def _wait_link_up(session: SimSession, timeout_s: float = 30.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        events = read_events(session.files.device_events)
        if any(e.get("event") == "link" and e.get("state") == "up" for e in events):
            return
        time.sleep(0.1)
    raise AssertionError("the simulated device was not plugged in again")


def _true_exposures(session: SimSession) -> list[dict[str, Any]]:
    return [e for e in read_events(session.files.device_events) if e.get("event") == "exposure" and not e["manual"]]


def _device_records(path: Path, name: str) -> list[dict[str, Any]]:
    return [m.data for m in read(path, allow_unfinished=True).records([layout.device_topic(name)])]


def test_the_recording_that_comes_back_says_the_device_stopped_itself(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session, urls, config = _session(tmp_path)
    sock = tmp_path / "rec.sock"
    recorder = _record(config, urls, sock)
    try:
        time.sleep(1.5)
        session.device_command(f"disconnect {TIMEOUT_S + 2.5}")
        _wait_link_up(session)
        time.sleep(2.0)  # reconnected, DEVICE_STATE read
        truth = _true_exposures(session)
        recorder.send_signal(signal.SIGTERM)
        _, err = recorder.communicate(timeout=60)
    finally:
        if recorder.poll() is None:
            recorder.kill()
        session.stop()
    assert recorder.returncode == 0, err  # no capture left to stop: nothing undelivered
    assert "Traceback" not in err
    (path,) = (tmp_path / "recording").glob("*.mcap")
    events = [m.data for m in read(path).records([layout.LINK_EVENTS])]
    (stopped,) = [e for e in events if e["kind"] == "device_stopped_itself"]
    assert "no frame from the host for 5 s" in stopped["detail"]
    states = _device_records(path, "DEVICE_STATE")
    stop_t_us = states[-1]["stopped_t_us"]
    assert states[-1]["stop_cause"] == 3  # host_silent
    # The camera shot on until the stop and not after it (one pulse may have been firing at the stop).
    assert truth and max(e["trigger_t_us"] for e in truth) <= stop_t_us
    assert stop_t_us - max(e["trigger_t_us"] for e in truth) < INTERVAL_S * 1e6
    assert not any(e["kind"] == "unreachable_at_end" for e in events)

    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    row = next(x for x in out.splitlines() if "capture stopped by the device" in x)
    assert "no frame from the host for 5 s" in row


def test_recover_device_fetches_the_outage_of_a_recording_that_ended_during_it(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    session, urls, config = _session(tmp_path)
    sock = tmp_path / "rec.sock"
    recorder = _record(config, urls, sock)
    recovered = tmp_path / "recovered.mcap"
    try:
        time.sleep(4.5)  # the recorder has told the device its recording id (HOST_RECEIVED, 3 s behind)
        session.device_command(f"disconnect {TIMEOUT_S + 4.0}")
        time.sleep(1.5)
        recorder.send_signal(signal.SIGTERM)  # the recorder gone mid-outage
        _, err = recorder.communicate(timeout=60)
        assert recorder.returncode == 1, err
        assert "the capture stop could not be delivered" in err
        (first,) = (tmp_path / "recording").glob("*.mcap")
        _wait_link_up(session)
        code = main(["recover-device", "--device", urls.device, "--flight", str(first), "--out", str(recovered)])
        out = capsys.readouterr().out
        truth = _true_exposures(session)
    finally:
        if recorder.poll() is None:
            recorder.kill()
        session.stop()
    assert code == 0, out
    assert f"recovered from the device for {first.name}" in out
    assert "written to" in out and "read back" in out

    logged = {e["image_index"] for e in _device_records(first, "EXPOSURE")}
    got = _device_records(recovered, "EXPOSURE")
    fetched = {e["image_index"] for e in got}
    made = {e["trigger_index"] for e in truth}
    outage = made - logged
    assert len(outage) >= 15  # about 5 s at 5 fps, the first log cut before the stop
    assert fetched == outage  # every one the outage took, none the first log holds
    assert all(e["frame_flags"] & 1 for e in got)  # resent

    state = _device_records(recovered, "DEVICE_STATE")[-1]
    assert state["stop_cause"] == 3  # host_silent: the camera stopped after the timeout
    assert max(e["trigger_t_us"] for e in truth) <= state["stopped_t_us"]
    last_logged_t_us = max(e["trigger_t_us"] for e in _device_records(first, "EXPOSURE"))
    assert TIMEOUT_S - 1.5 <= (state["stopped_t_us"] - last_logged_t_us) / 1e6 <= TIMEOUT_S + 0.5

    flight = read(recovered).metadata[layout.META_FLIGHT]
    assert flight["kind"] == "recovered" and flight["flight_file"] == first.name
    first_id = read(first, allow_unfinished=True).metadata[layout.META_FLIGHT]["recording_id"]
    assert flight["recording_id"] == first_id
    assert state["recording_id"] == int(first_id, 16)  # the device named the flight itself

    assert main(["info", str(recovered)]) == 0
    info = capsys.readouterr().out
    row = next(x for x in info.splitlines() if "recovered from the device" in x)
    assert f"{len(outage)} EXPOSURE" in row and first.name in row
