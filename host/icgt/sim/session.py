"""`icgt sim`: start the simulated device, autopilot and camera for one scenario, then write the truth.

A session owns three things that run in real time on one scenario clock (hil_sim/README.md):
the `icgt-sim-device` program (the firmware on the simulated board, reachable as a serial
device), the pymavlink autopilot (UDP towards the companion computer and a ground-station
port it routes), and a fault scheduler. When it stops it turns what really happened into
ground-truth files and a camera card of JPEGs.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from icgt.sim.autopilot import SimAutopilot
from icgt.sim.camera_card import write_card
from icgt.sim.resources import DEVICE_BINARY_ENV, DEVICE_PROGRAM, device_candidates
from icgt.sim.scenario import Scenario, SimError
from icgt.sim.truth import (
    ClockMaps,
    exposure_truth,
    read_events,
    write_clock_offsets,
    write_exposure_truth,
    write_sensor_truth,
)


def find_device_binary() -> Path:
    """The simulated device program: $ICGT_SIM_DEVICE, the wheel's copy, else the checkout's CMake build."""
    candidates = device_candidates()
    for c in candidates:
        if c.is_file() and os.access(c, os.X_OK):
            return c
    raise SimError(
        f"{DEVICE_PROGRAM} not found (looked at {', '.join(str(c) for c in candidates)}): in a checkout run "
        f"`make build`; else install icgt from its wheel (which builds it), or set {DEVICE_BINARY_ENV} to the program"
    )


@dataclass(frozen=True)
class SessionUrls:
    """What to give the recorder and the ground station."""

    device: str  # a serial device path or socket://
    mavlink: str  # for `icgt record --mavlink`
    gcs: str  # a pymavlink URL a ground-station script connects with


@dataclass(frozen=True)
class SessionFiles:
    sensor_truth: Path
    device_events: Path
    truth_exposures: Path
    truth_clocks: Path
    card: Path
    device_log: Path


class SimSession:
    """One run of one scenario. Use as a context manager, or start()/stop()."""

    def __init__(
        self,
        scenario: Scenario,
        out_dir: Path,
        *,
        mavlink_port: int = 14550,
        gcs_port: int = 14551,
        device_link: str = "pty",
        device_binary: Path | None = None,
    ) -> None:
        self.scenario = scenario
        self.out_dir = out_dir
        self._mavlink_port = mavlink_port
        self._gcs_port = gcs_port
        self._device_link = device_link
        self._binary = device_binary or find_device_binary()
        self.files = SessionFiles(
            sensor_truth=out_dir / "sensor_truth.csv",
            device_events=out_dir / "device_events.jsonl",
            truth_exposures=out_dir / "truth_exposures.jsonl",
            truth_clocks=out_dir / "truth_clocks.jsonl",
            card=out_dir / "card",
            device_log=out_dir / "sim_device.log",
        )
        self.clocks: ClockMaps | None = None
        self.urls: SessionUrls | None = None
        self._device: subprocess.Popen[bytes] | None = None
        self._device_log: object = None
        self._autopilot: SimAutopilot | None = None
        self._control_path = Path(f"/tmp/icgt-sim-{os.getpid()}-{id(self)}.sock")
        self._faults: list[threading.Timer] = []
        self._stopped = False

    def __enter__(self) -> SimSession:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def tau_s(self) -> float:
        """Scenario time now [s]."""
        assert self.clocks is not None
        return self.clocks.host_ns_to_tau(time.monotonic_ns())

    def start(self) -> SessionUrls:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        sc = self.scenario
        t0 = time.monotonic_ns() + 300_000_000  # the origin is set a little ahead so every part starts before it
        utc0_us = time.time_ns() // 1000 + 300_000
        self.clocks = ClockMaps.from_scenario(sc, t0, utc0_us)
        write_sensor_truth(sc, self.files.sensor_truth)
        link_arg = "pty:" + str(self.out_dir / "device") if self._device_link == "pty" else self._device_link
        cam = sc.camera
        cmd = [
            str(self._binary),
            "--truth", str(self.files.sensor_truth),
            "--t0-monotonic-ns", str(t0),
            "--utc0-us", str(utc0_us),
            "--link", link_arg,
            "--device-offset-us", str(sc.clocks.device.offset_us),
            "--device-drift-ppm", str(sc.clocks.device.drift_ppm),
            "--camera-latency-us", str(cam.shutter_latency_us),
            "--camera-jitter-us", str(cam.shutter_jitter_us),
            "--camera-exposure-us", str(cam.exposure_us),
            "--lidar-model", sc.sensors.lidar_model,
            "--range-noise-cm", str(sc.sensors.range_noise_cm),
            "--seed", str(sc.seed),
            "--events-out", str(self.files.device_events),
            "--control", str(self._control_path),
        ]  # fmt: skip
        if sc.sensors.pps:
            cmd.append("--pps")
        if sc.link.usb_latency_us:
            cmd += ["--usb-frame-us", str(sc.link.usb_latency_us)]
        if sc.link.usb_jitter_us:
            cmd += ["--usb-jitter-us", str(sc.link.usb_jitter_us)]
        if cam.max_fps > 0:
            cmd += ["--camera-min-frame-us", str(round(1e6 / cam.max_fps))]
        if cam.buffer_shots:
            cmd += ["--camera-buffer-shots", str(cam.buffer_shots), "--camera-write-us", str(round(cam.write_ms * 1e3))]
        if sc.faults.camera_missed_triggers:
            cmd += ["--camera-miss-triggers", ",".join(str(i) for i in sc.faults.camera_missed_triggers)]
        log = self.files.device_log.open("wb")
        self._device_log = log
        self._device = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=log, start_new_session=True)
        assert self._device.stdout is not None
        first = self._device.stdout.readline().decode().strip()
        if not first.startswith("link: "):
            self.stop()
            raise SimError(f"icgt-sim-device did not start ({first!r}); see {self.files.device_log}")
        device_url = first.removeprefix("link: ")
        self._autopilot = SimAutopilot(
            sc,
            self.clocks,
            companion_url=f"udpout:127.0.0.1:{self._mavlink_port}",
            gcs_url=f"udpin:127.0.0.1:{self._gcs_port}",
        )
        self._autopilot.start()
        self.urls = SessionUrls(
            device=device_url,
            mavlink=f"udpin:0.0.0.0:{self._mavlink_port}",
            gcs=f"udpout:127.0.0.1:{self._gcs_port}",
        )
        self._schedule_faults()
        return self.urls

    def _schedule_faults(self) -> None:
        sc = self.scenario
        for tau in sc.faults.manual_shots_s:
            self._at(tau, "manual_shot")
        if sc.link.drop_probability or sc.link.flip_probability:
            self._at(0.0, f"impair drop={sc.link.drop_probability} flip={sc.link.flip_probability}")
        for start, duration in sc.faults.device_unplugs_s:  # [start_s, duration_s]
            self._at(start, f"disconnect {duration}")

    def _at(self, tau_s: float, command: str) -> None:
        timer = threading.Timer(max(0.0, tau_s - self.tau_s), self.device_command, args=(command,))
        timer.daemon = True
        timer.start()
        self._faults.append(timer)

    def device_command(self, command: str) -> str:
        """Send one control line to the simulated device (hil_sim/README.md); returns its reply."""
        with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
            s.settimeout(2.0)
            s.connect(str(self._control_path))
            s.sendall(command.encode() + b"\n")
            reply = s.makefile("r").readline().strip()
        if reply != "ok":
            raise SimError(f"simulated device refused {command!r}: {reply}")
        return reply

    def wait_until(self, tau_s: float, stop_event: threading.Event | None = None) -> None:
        """Sleep until scenario time tau_s (returns early if stop_event is set)."""
        while self.tau_s < tau_s:
            if stop_event is not None and stop_event.wait(min(0.2, tau_s - self.tau_s)):
                return
            if stop_event is None:
                time.sleep(min(0.2, max(0.0, tau_s - self.tau_s)))

    def stop(self) -> None:
        """Stop everything (idempotent), leaving no process or thread behind, then write the truth."""
        if self._stopped:
            return
        self._stopped = True
        for t in self._faults:
            t.cancel()
        if self._autopilot is not None:
            self._autopilot.stop()
        if self._device is not None:
            if self._device.poll() is None:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(self._device.pid, signal.SIGTERM)
                try:
                    self._device.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    os.killpg(self._device.pid, signal.SIGKILL)
                    self._device.wait()
            if self._device.stdout is not None:
                self._device.stdout.close()
        log = self._device_log
        if log is not None:
            log.close()  # type: ignore[attr-defined]
        with contextlib.suppress(FileNotFoundError):
            self._control_path.unlink()
        self._write_truth()

    def _write_truth(self) -> None:
        if self.clocks is None or not self.files.device_events.exists():
            return
        events = read_events(self.files.device_events)
        truth = exposure_truth(self.scenario, events, self.clocks)
        write_exposure_truth(self.files.truth_exposures, truth)
        write_clock_offsets(self.files.truth_clocks, self.clocks, self.scenario.duration_s)
        if self.files.card.exists():
            shutil.rmtree(self.files.card)
        write_card(self.files.card, truth, self.clocks, self.scenario.camera, scenario=self.scenario)
        if self.scenario.surface is not None:
            from icgt.sim.surface import calibration_toml, write_defects_truth

            write_defects_truth(self.out_dir / "truth_defects.json", self.scenario, self.scenario.surface)
            (self.out_dir / "camera_calibration.toml").write_text(calibration_toml(self.scenario), encoding="utf-8")
