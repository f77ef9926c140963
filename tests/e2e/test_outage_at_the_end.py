"""A recording that ends while the device is unplugged (issue 30, part 2): the log's last records say so, `icgt
info` gives the exposures the device was known to be taking as unknown (never 0), and the recorder exits 1
naming the capture stop it could not deliver."""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from icgt.cli import main
from icgt.control import request
from icgt.ingest import read
from icgt.recording import layout
from icgt.sim.recorder_setup import free_udp_port, recorder_config_text
from icgt.sim.scenario import load_scenario
from icgt.sim.session import SimSession

SHORT_FLIGHT = Path(__file__).with_name("short_flight.toml")


def test_an_outage_that_outlives_the_recording_is_reported(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    text = SHORT_FLIGHT.read_text()
    scenario = tmp_path / "unplugged_at_the_end.toml"  # the short flight without its own faults
    scenario.write_text(text[: text.index("[faults]")].replace('name = "short_flight"', 'name = "unplugged_end"'))
    sc = load_scenario(scenario)
    session = SimSession(sc, tmp_path / "sim", mavlink_port=free_udp_port(), gcs_port=free_udp_port())
    urls = session.start()
    rec_dir = tmp_path / "recording"
    config = tmp_path / "recorder.toml"
    config.write_text(recorder_config_text(sc, rec_dir))
    sock = tmp_path / "rec.sock"
    recorder = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
         "--mavlink", urls.mavlink, "--socket", str(sock)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        deadline = time.monotonic() + 30
        while not sock.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        request(sock, {"command": "start", "interval_s": 0.1, "count": 0}, timeout_s=10.0)
        time.sleep(1.0)
        session.device_command("disconnect 600")  # the cable pulled, not plugged in again before the end
        time.sleep(3.0)
        recorder.send_signal(signal.SIGTERM)
        _, err = recorder.communicate(timeout=60)
    finally:
        if recorder.poll() is None:
            recorder.kill()
        session.stop()
    assert recorder.returncode == 1, err
    assert "Traceback" not in err
    last = err.strip().splitlines()[-1]
    assert last.startswith("icgt: the capture stop could not be delivered to the device"), err
    assert "it may still be capturing" in last

    (path,) = rec_dir.glob("*.mcap")
    events = [m.data for m in read(path).records([layout.LINK_EVENTS])]
    (end,) = [e for e in events if e["kind"] == "unreachable_at_end"]
    assert events.index(end) >= len(events) - 3  # among the log's last link events
    outage_s = end["outage_ns"] / 1e9
    assert outage_s >= 3.0
    assert end["count"] == int(outage_s / 0.1) > 0  # capture interval x outage

    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if "exposures lost at the end" in x)
    assert f"unknown, device unreachable at the end: it was taking about {end['count']}" in line
    assert not re.search(r"lost: 0 exposures,", out)  # never claimed as 0
