"""Flights through the simulator with the faults retransmission must survive (issue 12), and their count.

`fly_faults` runs `icgt record` as a user would (a subprocess, started and stopped over its control socket)
on the simulated device and autopilot, injects the faults of a `FaultPlan` at scenario times (USB unplugs,
bit flips on the link, a kill -9 of the recorder and a restart), and then counts per fault window: the
exposures the camera made (the simulator's truth), those in the recordings (live or resent, once each, the
killed recorder's file recovered first), and those the recordings say are lost (the device's RESEND_LOST
counts, as the recorder logged them). Used by tests/e2e/test_resend_faults.py and
benchmarks/resend_faults.py.
"""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icgt.control import request
from icgt.sim.evaluate import read_truth
from icgt.sim.recorder_setup import free_udp_port, recorder_config_text
from icgt.sim.scenario import Scenario
from icgt.sim.session import SimSession


@dataclass(frozen=True)
class Fault:
    """One fault: what (unplug / flips / kill), when [scenario s] and for how long [s]."""

    name: str
    kind: str  # "unplug", "flips", "kill"
    start_s: float
    duration_s: float
    flip_probability: float = 0.0  # per byte, for "flips"


@dataclass(frozen=True)
class FaultPlan:
    capture_start_s: float
    capture_stop_s: float
    faults: tuple[Fault, ...]


@dataclass
class FaultCount:
    name: str
    exposures: int = 0  # made by the camera during the fault (and until 1 s after it)
    recorded: int = 0  # of those, in a recording
    recovered: int = 0  # of those, in a recording only through RESEND (flagged retransmit)


@dataclass
class FlightResult:
    faults: list[FaultCount]
    true_exposures: int
    recorded_exposures: int  # distinct image indices in the recordings
    reported_lost_exposures: int  # the recordings' own count (device RESEND_LOST, as logged)
    recordings: list[Path]
    link_summary: dict[str, str] = field(default_factory=dict)
    truth: list[dict[str, Any]] = field(default_factory=list)  # the simulator's exposure truth (triggered ones)


def _exposures_in(path: Path) -> tuple[dict[int, bool], int, dict[str, str]]:
    """image_index -> came only as a retransmit, lost exposures the log reports, the device-link summary."""
    from mcap.reader import make_reader

    seen: dict[int, bool] = {}
    lost = 0
    with path.open("rb") as f:
        reader = make_reader(f)
        for _, channel, message in reader.iter_messages(topics=["/device/exposure", "/icgt/link_events"]):
            data = json.loads(message.data)
            if channel.topic == "/icgt/link_events":
                if data.get("kind") == "history_lost":
                    detail = str(data.get("detail", ""))
                    lost += int(detail.split(" exposures")[0].rsplit(" ", 1)[-1])
                continue
            index = int(data.get("image_index", 0))
            if index == 0:
                continue  # unsolicited (a manual shot)
            retx = bool(int(data.get("frame_flags", 0)) & 1)
            seen[index] = seen.get(index, True) and retx
        summary = reader.get_summary()
        meta: dict[str, str] = {}
        if summary is not None:
            for m in reader.iter_metadata():
                if m.name == "icgt.device_link":
                    meta = dict(m.metadata)
    return seen, lost, meta


def _start_recorder(config: Path, urls: Any, sock: Path, log: Any) -> subprocess.Popen[bytes]:
    proc = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
         "--mavlink", urls.mavlink, "--socket", str(sock)],
        stdout=log, stderr=subprocess.STDOUT,
    )  # fmt: skip
    log.flush()
    path = Path(log.name)
    started = path.read_text().count("recording to ")
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        if path.read_text().count("recording to ") > started:  # `icgt record` says so when start() is done
            return proc
        if proc.poll() is not None:
            raise RuntimeError(f"icgt record exited with {proc.returncode}; see {log.name}")
        time.sleep(0.1)
    raise RuntimeError(f"icgt record did not come up; see {log.name}")


def fly_faults(sc: Scenario, plan: FaultPlan, out: Path) -> FlightResult:
    """One flight with every fault of `plan`; see the module doc."""
    from icgt.recording import recover

    out.mkdir(parents=True, exist_ok=True)
    for previous in ("recording", "sim", "ctl"):  # a folder reused (make bench): only this flight's files count
        shutil.rmtree(out / previous, ignore_errors=True)
    # Held until the recorder is up: on a loaded machine its start-up can take longer than the scenario's time
    # before the first fault, and the fault would then meet a recorder whose clocks had no time to settle.
    session = SimSession(sc, out / "sim", mavlink_port=free_udp_port(), gcs_port=free_udp_port(), hold=True)
    urls = session.start()
    rec_dir = out / "recording"
    config = out / "recorder.toml"
    # These flights measure what the history ring brings back after an unplug of any length: the device must
    # not stop its capture by itself meanwhile.
    config.write_text(recorder_config_text(sc, rec_dir, host_timeout_s=0.0))
    sock = out / "ctl" / "rec.sock"
    sock.parent.mkdir(mode=0o700, exist_ok=True)
    log = (out / "recorder.log").open("w")
    killed: list[Path] = []
    recorder: subprocess.Popen[bytes] | None = None
    try:
        recorder = _start_recorder(config, urls, sock, log)
        session.release()
        session.wait_until(plan.capture_start_s)
        request(sock, {"command": "start"})
        for fault in sorted(plan.faults, key=lambda f: f.start_s):
            session.wait_until(fault.start_s)
            if fault.kind == "unplug":
                session.device_command(f"disconnect {fault.duration_s}")
            elif fault.kind == "flips":
                session.device_command(f"impair flip={fault.flip_probability}")
                session.wait_until(fault.start_s + fault.duration_s)
                session.device_command("impair flip=0")
            elif fault.kind == "kill":
                before = set(rec_dir.glob("*.mcap"))
                recorder.send_signal(signal.SIGKILL)
                recorder.wait(timeout=5)
                killed += sorted(before)
                session.wait_until(fault.start_s + fault.duration_s)
                recorder = _start_recorder(config, urls, sock, log)
        session.wait_until(plan.capture_stop_s)
        request(sock, {"command": "stop"})
        time.sleep(1.5)
        recorder.send_signal(signal.SIGINT)
        recorder.wait(timeout=20)
    finally:
        if recorder is not None and recorder.poll() is None:
            recorder.kill()
        log.close()
        session.stop()

    truth = [t for t in read_truth(session.files.truth_exposures) if not t.get("manual")]
    recordings = sorted(rec_dir.glob("*.mcap"))
    seen: dict[int, bool] = {}
    lost = 0
    summary: dict[str, str] = {}
    for path in recordings:
        source = path
        if path in killed:
            source = out / f"{path.stem}.recovered.mcap"
            recover(path, source)
        got, n_lost, meta = _exposures_in(source)
        lost += n_lost
        summary = meta or summary
        for index, retx in got.items():
            seen[index] = seen.get(index, True) and retx
    counts = []
    for fault in plan.faults:
        c = FaultCount(fault.name)
        for t in truth:
            if fault.start_s <= float(t["start_tau_s"]) < fault.start_s + fault.duration_s + 1.0:
                c.exposures += 1
                index = int(t["trigger_index"])
                if index in seen:
                    c.recorded += 1
                    c.recovered += int(seen[index])
        counts.append(c)
    return FlightResult(
        faults=counts,
        true_exposures=len(truth),
        recorded_exposures=sum(1 for t in truth if int(t["trigger_index"]) in seen),
        reported_lost_exposures=lost,
        recordings=recordings,
        link_summary=summary,
        truth=truth,
    )
