"""A simulated flight with `icgt record` running on it, for clients that drive the camera themselves.

`LiveRecorder` starts a scenario's simulator (`SimSession`) and `icgt record` as its own process with the
configuration a crew would write (`icgt.sim.recorder_setup.recorder_config_text`, plus the ground-station ids and
signing key file given), and leaves the ground station to the caller: ``urls.gcs`` is the simulated
autopilot's ground-station port (pymavlink ``udpout:`` form; MAVSDK's is `mavsdk_url`). Unlike
`icgt.demo.fly`, nothing is commanded: tests and benchmarks bring their own client (MAVSDK, pymavlink).
`stop()` ends the recorder (SIGTERM, as a user's Ctrl-C) and the simulator and returns the log.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

from icgt.errors import IcgtError
from icgt.sim.recorder_setup import GROUND_STATIONS, free_udp_port, recorder_config_text
from icgt.sim.scenario import Scenario
from icgt.sim.session import SessionUrls, SimSession

__all__ = ["LiveRecorder"]


class LiveRecorder:
    """Simulator + `icgt record` for one scenario. Context manager; `stop()` returns the MCAP path."""

    def __init__(
        self,
        scenario: Scenario,
        out_dir: Path,
        *,
        ground_stations: tuple[int, ...] = GROUND_STATIONS,
        signing_key_file: Path | None = None,
    ) -> None:
        self.scenario = scenario
        self.out_dir = out_dir.resolve()
        self._ground_stations = ground_stations
        self._key_file = signing_key_file
        self.session: SimSession | None = None
        self.urls: SessionUrls | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self.recorder_log = self.out_dir / "recorder.log"
        self.mcap: Path | None = None

    @property
    def mavsdk_url(self) -> str:
        """The ground-station port as a MAVSDK connection URL."""
        assert self.urls is not None
        return "udpout://" + self.urls.gcs.removeprefix("udpout:")

    def start(self) -> SessionUrls:
        self.out_dir.mkdir(parents=True, exist_ok=True)
        rec_dir = self.out_dir / "recording"
        config = self.out_dir / "recorder.toml"
        config.write_text(
            recorder_config_text(
                self.scenario, rec_dir, ground_stations=self._ground_stations, signing_key_file=self._key_file
            )
        )
        self.session = SimSession(
            self.scenario, self.out_dir / "sim", mavlink_port=free_udp_port(), gcs_port=free_udp_port()
        )
        urls = self.session.start()
        self.urls = urls
        with self.recorder_log.open("w") as log:
            self._proc = subprocess.Popen(
                [sys.executable, "-m", "icgt.cli", "record", "--config", str(config), "--device", urls.device,
                 "--mavlink", urls.mavlink, "--out", str(rec_dir), "--socket", str(self.out_dir / "recorder.sock")],
                stdout=log, stderr=subprocess.STDOUT, env={**os.environ, "PYTHONUNBUFFERED": "1"},
            )  # fmt: skip
        return urls

    def stop(self) -> Path:
        proc = self._proc
        if proc is not None:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if self.session is not None:
            self.session.stop()
        mcaps = sorted((self.out_dir / "recording").glob("*.mcap"))
        if proc is None or proc.returncode != 0 or not mcaps:
            code = proc.returncode if proc is not None else None
            raise IcgtError(f"the recorder failed (exit {code}); see {self.recorder_log}")
        self.mcap = mcaps[-1]
        return self.mcap

    def __enter__(self) -> LiveRecorder:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        if self.mcap is None:
            try:
                self.stop()
            except IcgtError:
                if exc[0] is None:
                    raise
