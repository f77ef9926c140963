"""`make demo` / `icgt demo`: a whole flight on simulated hardware, scored against ground truth.

1. start the scenario's simulated device, autopilot and camera (`icgt sim`);
2. start `icgt record` on them as a user would (a separate process, real serial and UDP links);
3. act as the ground station: wait for the camera component, ask for CAMERA_INFORMATION, send
   MAV_CMD_IMAGE_START_CAPTURE and, later, MAV_CMD_IMAGE_STOP_CAPTURE, counting the ACKs and the
   CAMERA_IMAGE_CAPTURED messages;
4. stop the recorder (SIGTERM, as systemd would), stop the simulator (which writes the truth and
   the camera card) and print the summary; everything lands in the output directory.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pymavlink import mavutil

from icgt.errors import IcgtError
from icgt.sim.evaluate import evaluate, read_frames, read_truth
from icgt.sim.recorder_setup import GCS_SYSTEM, free_udp_port, recorder_config_text
from icgt.sim.scenario import Scenario, load_scenario
from icgt.sim.session import HOLD_MAX_S, SimSession
from icgt.sim.tcp_bridge import TcpBridge
from icgt.sim.truth import ClockMaps

GCS_COMPONENT = 190
CAMERA_COMPONENT = 100


class GroundStation:
    """A minimal pymavlink ground station talking to the camera through the autopilot's routing."""

    def __init__(self, url: str, target_system: int = 1) -> None:
        self.conn = mavutil.mavlink_connection(url, source_system=GCS_SYSTEM, source_component=GCS_COMPONENT)
        self.target_system = target_system  # the vehicle's system id: the camera is its component 100
        self.acks: dict[int, int] = {}
        self.images: list[Any] = []
        self.image_rx_ns: list[int] = []  # host monotonic arrival of each CAMERA_IMAGE_CAPTURED
        self.camera_info: Any = None
        self.camera_seen = False

    def pump(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.conn.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            stop = min(end, time.monotonic() + 1.0)
            while time.monotonic() < stop:
                msg = self.conn.recv_match(blocking=True, timeout=0.1)
                if msg is None or msg.get_srcComponent() != CAMERA_COMPONENT:
                    continue
                if msg.get_srcSystem() != self.target_system:
                    continue
                kind = msg.get_type()
                if kind == "HEARTBEAT":
                    self.camera_seen = True
                elif kind == "COMMAND_ACK":
                    self.acks[int(msg.command)] = int(msg.result)
                elif kind == "CAMERA_IMAGE_CAPTURED":
                    self.images.append(msg)
                    self.image_rx_ns.append(time.monotonic_ns())
                elif kind == "CAMERA_INFORMATION":
                    self.camera_info = msg

    def command(self, command: int, *params: float) -> None:
        p = [*params, 0, 0, 0, 0, 0, 0, 0][:7]
        self.conn.mav.command_long_send(self.target_system, CAMERA_COMPONENT, command, 0, *p)

    def command_acked(self, command: int, *params: float, attempts: int = 3) -> None:
        """Send a command and resend it after 1 s without a COMMAND_ACK, as ground stations do."""
        for _ in range(attempts):
            self.acks.pop(command, None)
            self.command(command, *params)
            end = time.monotonic() + 1.0
            while command not in self.acks and time.monotonic() < end:
                self.pump(0.1)
            if command in self.acks:
                return

    def close(self) -> None:
        self.conn.close()


def _result_name(result: int | None) -> str:
    if result is None:
        return "not ACKed"
    entry = mavutil.mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else str(result)


def _fmt(p: dict[str, Any], unit: str, scale: float = 1.0) -> str:
    if not p["n"]:
        return "n/a"
    return f"p50 {p['p50'] * scale:.3g} / p95 {p['p95'] * scale:.3g} / max {p['max'] * scale:.3g} {unit} (n={p['n']})"


@dataclass
class Flight:
    """What one simulated flight left behind."""

    scenario: Scenario
    out_dir: Path
    mcap: Path
    truth_exposures: Path
    card: Path
    recorder_log: Path
    recorder_exit: int
    gcs: GroundStation
    recorder_cpu_s: float  # user + system CPU time of the recorder process over the flight
    recorder_wall_s: float
    held_s: float = 0.0  # how long the simulator held its scenario clock for the recorder to come up [s]
    clocks: ClockMaps | None = None  # the simulator's clock maps in force from the release on (the truth's)


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a live process, from /proc (Linux)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def fly(
    sc: Scenario,
    out_dir: Path,
    record_args: Sequence[str] = (),
    *,
    recorder_delay_s: float = 0.0,
    recorder_nice: int | None = None,
    mavlink_over_tcp: bool = False,
    recorder_cpus: set[int] | None = None,
) -> Flight:
    """Run one scenario: simulator, `icgt record` as a separate process, a ground station commanding it.

    The simulator holds its scenario clock until the ground station sees the recorder's camera (and it
    has answered CAMERA_INFORMATION where that matters), so the scenario and the ground station's
    schedule in it run whole however long the recorder takes to come up (`SimSession.release`).
    `record_args`: more arguments for `icgt record` (e.g. ``--live PORT``).
    `recorder_delay_s`: start the recorder that much later (a test of a slow start) [s].
    `recorder_nice`: the recorder's niceness, set right after it starts (before it makes its threads), when
    the simulator runs at another one (a benchmark that stands the simulator in for separate machines).
    `mavlink_over_tcp`: the recorder reaches the autopilot through a TCP stream (`icgt.sim.tcp_bridge`), as
    over a serial port or ArduPilot SITL's TCP port, instead of UDP.
    `recorder_cpus`: the CPUs the recorder may run on (its affinity, set with its niceness), e.g. one core
    for a companion computer's share.
    """
    out_dir = out_dir.resolve()
    for stale in ("sim", "recording"):
        shutil.rmtree(out_dir / stale, ignore_errors=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    rec_dir = out_dir / "recording"
    config_path = out_dir / "recorder.toml"
    config_path.write_text(recorder_config_text(sc, rec_dir))
    mav_port, gcs_port = free_udp_port(), free_udp_port()
    session = SimSession(sc, out_dir / "sim", mavlink_port=mav_port, gcs_port=gcs_port, hold=True)
    bridge = TcpBridge(mav_port) if mavlink_over_tcp else None
    urls = session.start()
    mavlink_url = bridge.url if bridge is not None else urls.mavlink
    log_path = out_dir / "recorder.log"
    recorder_log = log_path.open("w")
    time.sleep(recorder_delay_s)
    recorder = subprocess.Popen(
        [sys.executable, "-m", "icgt.cli", "record", "--config", str(config_path), "--device", urls.device,
         "--mavlink", mavlink_url, "--out", str(rec_dir), "--socket", str(out_dir / "recorder.sock"), *record_args],
        stdout=recorder_log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )  # fmt: skip
    if recorder_nice is not None:
        os.setpriority(os.PRIO_PROCESS, recorder.pid, recorder_nice)
    if recorder_cpus is not None:
        os.sched_setaffinity(recorder.pid, recorder_cpus)
    gcs = GroundStation(urls.gcs, sc.autopilot.system_id)
    started = time.monotonic()
    cpu_s = wall_s = held_s = 0.0
    try:
        print(f"recorder: icgt record --device {urls.device} --mavlink {mavlink_url}", flush=True)
        cap = sc.camera.capture
        # Like QGroundControl: talk to the camera once its HEARTBEAT has been seen. With a second camera at
        # component 100 of the vehicle (scenario foreign_camera) a HEARTBEAT does not say which one is ours:
        # then wait until ours has answered CAMERA_INFORMATION (the foreign one only sends HEARTBEATs).
        deadline = time.monotonic() + HOLD_MAX_S - 10.0  # a recorder that slow would start late anyway
        while not gcs.camera_seen and time.monotonic() < deadline:
            gcs.pump(0.2)
        if not gcs.camera_seen:
            raise IcgtError(f"the recorder's camera component never appeared; see {log_path}")
        gcs.command(mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, mavutil.mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION)
        next_request = time.monotonic() + 1.0
        while sc.autopilot.foreign_camera and gcs.camera_info is None and time.monotonic() < deadline:
            if time.monotonic() >= next_request:  # ask again if the answer was lost
                gcs.command(mavutil.mavlink.MAV_CMD_REQUEST_MESSAGE, mavutil.mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION)
                next_request = time.monotonic() + 1.0
            gcs.pump(0.1)
        if sc.autopilot.foreign_camera and gcs.camera_info is None:
            raise IcgtError(f"the recorder's camera never answered CAMERA_INFORMATION; see {log_path}")
        held_s = session.release()
        print(f"simulator: scenario clock held {held_s:.1f} s until the recorder's camera was seen", flush=True)
        gcs.pump(max(0.2, cap.start_s - session.tau_s))
        interval_s = cap.interval_s if cap.mode == "interval" else 1.0 / cap.burst_fps
        print(f"ground station: start capture at tau {session.tau_s:.1f} s", flush=True)
        gcs.command_acked(mavutil.mavlink.MAV_CMD_IMAGE_START_CAPTURE, 0, interval_s, cap.count, 0)
        stop_at = cap.stop_s if cap.stop_s is not None else sc.duration_s - 2.0
        gcs.pump(max(0.0, stop_at - session.tau_s))
        print(f"ground station: stop capture at tau {session.tau_s:.1f} s", flush=True)
        gcs.command_acked(mavutil.mavlink.MAV_CMD_IMAGE_STOP_CAPTURE, 0)
        gcs.pump(max(1.5, sc.duration_s - session.tau_s))
        if recorder.poll() is None:
            cpu_s, wall_s = _cpu_seconds(recorder.pid), time.monotonic() - started
    finally:
        if recorder.poll() is None:
            recorder.send_signal(signal.SIGTERM)
        try:
            recorder.wait(timeout=20)
        except subprocess.TimeoutExpired:
            recorder.kill()
            recorder.wait()
        recorder_log.close()
        gcs.close()
        session.stop()
        if bridge is not None:
            bridge.close()
    mcaps = sorted(rec_dir.glob("*.mcap"))
    if recorder.returncode != 0 or not mcaps:
        raise IcgtError(f"the recorder failed (exit {recorder.returncode}); see {log_path}")
    return Flight(
        sc,
        out_dir,
        mcaps[-1],
        session.files.truth_exposures,
        session.files.card,
        log_path,
        recorder.returncode,
        gcs,
        cpu_s,
        wall_s,
        held_s,
        session.clocks,
    )


def run_demo(scenario_name: str, out_dir: Path) -> dict[str, Any]:
    sc = load_scenario(scenario_name)
    print(f"scenario {sc.name}: {sc.description} ({sc.duration_s:.0f} s)", flush=True)
    flight = fly(sc, out_dir)
    out_dir = flight.out_dir
    gcs = flight.gcs
    frames = read_frames(flight.mcap)
    truth = read_truth(flight.truth_exposures)
    result = evaluate(sc, frames, truth)
    images = sorted(flight.card.glob("*.JPG"))
    start_ack = gcs.acks.get(mavutil.mavlink.MAV_CMD_IMAGE_START_CAPTURE)
    stop_ack = gcs.acks.get(mavutil.mavlink.MAV_CMD_IMAGE_STOP_CAPTURE)
    summary = {
        **result,
        "mcap": str(flight.mcap),
        "truth": str(flight.truth_exposures),
        "camera_card_images": len(images),
        "ground_station": {
            "camera_heartbeat_seen": gcs.camera_seen,
            "camera_information_received": gcs.camera_info is not None,
            "start_capture_ack": start_ack,
            "stop_capture_ack": stop_ack,
            "camera_image_captured_received": len(gcs.images),
        },
    }
    recorder_errors = flight.recorder_log.read_text().count("Traceback")
    summary["recorder_log_tracebacks"] = recorder_errors
    summary["ok"] = bool(
        recorder_errors == 0
        and start_ack == mavutil.mavlink.MAV_RESULT_ACCEPTED
        and stop_ack == mavutil.mavlink.MAV_RESULT_ACCEPTED
        and result["matched"] > 0
        and result["exposures_missing_from_log"] == 0
        and result["frames_without_exposure_not_flagged"] == 0
    )
    (out_dir / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    gs = summary["ground_station"]
    print(
        "\n".join(
            [
                "",
                f"== ICGT demo: {sc.name} ==",
                f"frames recorded           {result['frames']} ({result['matched']} matched to true exposures, "
                f"{result['frames_without_exposure']} triggers the camera ignored, all flagged)",
                f"true exposures            {result['true_exposures']} ({result['exposures_missing_from_log']} "
                "missing from the log)",
                f"images on the camera card {len(images)}",
                f"ground station            start {_result_name(gs['start_capture_ack'])}, "
                f"stop {_result_name(gs['stop_capture_ack'])}, "
                f"{gs['camera_image_captured_received']} CAMERA_IMAGE_CAPTURED",
                f"geotag error (3D)         {_fmt(result['geotag_error_cm'], 'cm')}",
                f"  frames without pose flags {_fmt(result['geotag_error_unflagged_cm'], 'cm')}",
                f"  horizontal              {_fmt(result['geotag_horizontal_error_cm'], 'cm')}",
                f"  timing part             {_fmt(result['timing_part_of_geotag_error_cm'], 'cm')}",
                f"mid-exposure time error   {_fmt(result['mid_exposure_time_error_ms'], 'us', 1000.0)}"
                " (device->host clock)",
                f"UTC error                 {_fmt(result['utc_error_ms'], 'ms')}",
                f"quality flags             {result['flags']}",
                f"results                   {out_dir} (summary.json, recording/*.mcap, sim/truth_*.jsonl, sim/card/)",
                f"demo {'OK' if summary['ok'] else 'FAILED'}",
            ]
        ),
        flush=True,
    )
    return summary
