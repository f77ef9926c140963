"""`icgt sim`: start the simulated device, autopilot and camera for one scenario, then write the truth.

A session owns three things that run in real time on one scenario clock (hil_sim/README.md):
the `icgt-sim-device` program (the firmware on the simulated board, reachable as a serial
device), the pymavlink autopilot (UDP towards the companion computer and a ground-station
port it routes), and a fault scheduler. When it stops it turns what really happened into
ground-truth files and a camera card of JPEGs.
"""

from __future__ import annotations

import contextlib
import dataclasses
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

HOLD_MAX_S = 120.0
"""How long a session started with `hold=True` can wait for `release()` before its scenario starts anyway [s]."""
RELEASE_LEAD_S = 0.3
"""Scenario time 0 is this far after `release()` (and after `start()` without a hold) [s]."""


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


def shifted_origin(clocks: ClockMaps, shift_ns: int) -> ClockMaps:
    """The same clocks with scenario time 0 `shift_ns` later: every offset moves along, so the device,
    autopilot and UTC clocks read the same at each host instant (the camera's is set from UTC at tau = 0)."""
    shift_s = shift_ns * 1e-9
    return dataclasses.replace(
        clocks,
        t0_monotonic_ns=clocks.t0_monotonic_ns + shift_ns,
        utc0_us=clocks.utc0_us + shift_ns // 1000,
        device_offset_us=clocks.device_offset_us + shift_s * 1e6 * (1.0 + clocks.device_drift_ppm * 1e-6),
        autopilot_offset_us=clocks.autopilot_offset_us + shift_s * 1e6 * (1.0 + clocks.autopilot_drift_ppm * 1e-6),
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
    autopilot_camera: Path
    """The autopilot's own log of the pictures it commanded (only with `[autopilot.camera]`)."""


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
        hold: bool = False,
        autopilot: bool = True,
    ) -> None:
        """`hold`: the scenario clock waits for `release()` (see there); without it, it starts with `start()`.
        `autopilot` False: only the device (a real autopilot, e.g. SITL, flies; `urls.mavlink` is then "")."""
        self._with_autopilot = autopilot
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
            autopilot_camera=out_dir / "autopilot_camera.json",
        )
        self.clocks: ClockMaps | None = None
        self.urls: SessionUrls | None = None
        self._device: subprocess.Popen[bytes] | None = None
        self._device_log: object = None
        self._autopilot: SimAutopilot | None = None
        self._control_path = Path(f"/tmp/icgt-sim-{os.getpid()}-{id(self)}.sock")
        self._faults: list[threading.Timer] = []
        self._stopped = False
        self._hold = hold
        self._started_ns = 0
        self.held_s: float | None = None
        """How long the scenario clock was held (None: not held, or not released yet) [s]."""

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
        lead_ns = round(RELEASE_LEAD_S * 1e9)  # the origin is set a little ahead so every part starts before it
        t0 = time.monotonic_ns() + lead_ns
        utc0_us = time.time_ns() // 1000 + lead_ns // 1000
        self.clocks = ClockMaps.from_scenario(sc, t0, utc0_us)
        if self._hold:
            # Held: the origin goes HOLD_MAX_S further ahead, every clock's offset along with it, so that
            # each reads what it would without the hold. Until release() all parts run before tau = 0,
            # as they do for RELEASE_LEAD_S in any session: the vehicle at its starting pose, no fix yet.
            self.clocks = shifted_origin(self.clocks, round(HOLD_MAX_S * 1e9))
        write_sensor_truth(sc, self.files.sensor_truth)
        link_arg = "pty:" + str(self.out_dir / "device") if self._device_link == "pty" else self._device_link
        cam = sc.camera
        cmd = [
            str(self._binary),
            "--truth", str(self.files.sensor_truth),
            "--t0-monotonic-ns", str(self.clocks.t0_monotonic_ns),
            "--utc0-us", str(self.clocks.utc0_us),
            "--link", link_arg,
            "--device-offset-us", repr(float(self.clocks.device_offset_us)),
            "--device-drift-ppm", str(sc.clocks.device.drift_ppm),
            "--camera-latency-us", str(round(cam.shutter_latency_s * 1e6)),
            "--camera-jitter-us", str(round(cam.shutter_jitter_s * 1e6)),
            "--camera-exposure-us", str(round(cam.exposure_s * 1e6)),
            "--lidar-model", sc.sensors.lidar_model,
            "--range-noise-cm", str(sc.sensors.range_noise_cm),
            "--seed", str(sc.seed),
            "--events-out", str(self.files.device_events),
            "--control", str(self._control_path),
        ]  # fmt: skip
        if sc.sensors.pps:
            cmd.append("--pps")
        if sc.link.usb_latency_s:
            cmd += ["--usb-frame-us", str(round(sc.link.usb_latency_s * 1e6))]
        if sc.link.usb_jitter_s:
            cmd += ["--usb-jitter-us", str(round(sc.link.usb_jitter_s * 1e6))]
        if cam.max_fps > 0:
            cmd += ["--camera-min-frame-us", str(round(1e6 / cam.max_fps))]
        if cam.buffer_shots:
            cmd += ["--camera-buffer-shots", str(cam.buffer_shots), "--camera-write-us", str(round(cam.write_s * 1e6))]
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
        if not self._with_autopilot:
            self.urls = SessionUrls(device=device_url, mavlink="", gcs="")
            self._schedule_faults()
            self._started_ns = time.monotonic_ns()
            return self.urls
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
        if not self._hold:
            self._schedule_faults()
        self._started_ns = time.monotonic_ns()
        return self.urls

    def release(self) -> float:
        """Start the scenario clock of a held session: tau = 0 comes RELEASE_LEAD_S from now.

        For tests whose schedule is in scenario time but whose recorder takes a while to come up (a
        loaded machine): held until then, the scenario runs whole and exactly as written, trajectory,
        faults and capture schedule alike, however late the recorder was. Every clock runs on without a
        step (the device's, the autopilot's, UTC): what moves is only the instant that is tau = 0, so
        each clock's reading at tau = 0 is larger by the time held (a board booted that much earlier).
        The truth is written with the clocks in force from here on (`clocks`), which are those every
        part uses from here on: exact. Returns the time held [s]; a session not held, released already,
        or held past HOLD_MAX_S (its scenario then started by itself) is left as it is (0.0).
        """
        assert self.clocks is not None and self._autopilot is not None
        lead_ns = round(RELEASE_LEAD_S * 1e9)
        now = time.monotonic_ns()
        if not self._hold or self.held_s is not None or now + lead_ns >= self.clocks.t0_monotonic_ns:
            if self._hold and self.held_s is None:
                self.held_s = 0.0
                self._schedule_faults()
            return 0.0
        shift_ns = (now + lead_ns - self.clocks.t0_monotonic_ns) // 1000 * 1000  # whole us: UTC stays exact
        clocks = shifted_origin(self.clocks, shift_ns)
        self.device_command(f"origin {clocks.t0_monotonic_ns} {clocks.device_offset_us!r} {clocks.utc0_us}")
        self.clocks = clocks
        self._autopilot.clocks = clocks
        self.held_s = (now - self._started_ns) * 1e-9
        self._schedule_faults()
        return self.held_s

    def _schedule_faults(self) -> None:
        sc = self.scenario
        for tau in sc.faults.manual_shots_s:
            self._at(tau, "manual_shot between" if sc.faults.manual_shots_between_triggers else "manual_shot")
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
            if self._autopilot.camera_trigger is not None:
                self._autopilot.camera_trigger.log.write(self.files.autopilot_camera)
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
            from icgt.sim.face import calibration_toml, write_defects_truth

            write_defects_truth(self.out_dir / "truth_defects.json", self.scenario, self.scenario.surface)
            (self.out_dir / "camera_calibration.toml").write_text(calibration_toml(self.scenario), encoding="utf-8")
