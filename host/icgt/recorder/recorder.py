"""`icgt record`: the composition root of the recorder that runs on the drone's companion computer.

The recorder is I/O around one `icgt.sync.Synchroniser`: the device link (serial), the MAVLink link (autopilot
and ground station), the MAVLink camera component, the MCAP log and the local control socket. This module only
builds the parts and wires them together, and opens and closes the links in order (`start`, `stop`); each part
has its own module:
- `inbox`: what the links' threads hand over, in arrival order; `device_input` and `mavlink_input` log each
  input and feed it to the synchroniser, in that order;
- `worker`: the thread that steps the recording (pump the links, handle the inbox, poll for frames, emit them),
  on the schedule of `step_schedule` and woken by `worker_wake`;
- `capture_control`: the capture's commands and state (the control socket, the camera component, the device
  stopping by itself all change it there);
- `device_setup`: connecting to and configuring the device; `resync`: taking over a capture already running;
- `health`: `icgt status`, the once-a-second clock and counter records, the end-of-run summary;
- `control_requests`: the control socket's requests; `shutdown`: the stop sequence and a start abandoned;
- `log_file`: the MCAP file; `camera_link`, `camera_settings`: the camera component's side.
Threads: the worker; the device link's reader (it sends the TIME_SYNC requests at the rate the worker sets and
reads their answers the moment they arrive); on a serial or TCP MAVLink link, that link's reader. Because the
log holds every input in the order the synchroniser saw it, `icgt.ingest.recompute` gives back the same frames.
"""

from __future__ import annotations

import contextlib
import logging
import secrets
import threading
import time
from datetime import UTC, datetime
from pathlib import Path

from icgt.control import ControlServer
from icgt.device import DeviceLink
from icgt.errors import IcgtError
from icgt.mavlink.camera import CameraComponent
from icgt.mavlink.link import LinkConfig, MavlinkLink, StreamRate
from icgt.mavlink.signing import load_signing_key
from icgt.protocol.messages import Hello, Status, StopCapture
from icgt.recorder.camera_link import CameraImages, build_camera
from icgt.recorder.camera_settings import capture_settings
from icgt.recorder.capture_control import CaptureControl, CaptureHandler
from icgt.recorder.config import RecorderConfig
from icgt.recorder.control_requests import ControlRequests
from icgt.recorder.device_input import DeviceInput
from icgt.recorder.device_setup import DeviceConnector, configure_device, record_hello
from icgt.recorder.health import Health, RecorderStatus
from icgt.recorder.inbox import Inbox
from icgt.recorder.links import Links
from icgt.recorder.log_file import RecorderLog, output_dir, start_metadata
from icgt.recorder.mavlink_input import MavlinkInput
from icgt.recorder.native_heap import limit_malloc_arenas
from icgt.recorder.resync import take_over
from icgt.recorder.shutdown import Shutdown, StopNotDeliveredError
from icgt.recorder.tuning import InterpreterTuning
from icgt.recorder.worker import Worker
from icgt.recorder.worker_wake import WorkerWake
from icgt.recording import McapRecorder, layout
from icgt.recording.views import FoxgloveViews
from icgt.sync import SyncConfig, Synchroniser

__all__ = ["Recorder", "RecorderStatus", "StopNotDeliveredError"]

log = logging.getLogger("icgt.recorder")

_MAVLINK_SERVICE_PERIOD_S = 0.05  # a serial/TCP MAVLink link's TIMESYNC / rate-request steps [s]


class Recorder:
    """One recording session. start() connects and begins writing; stop() ends it cleanly."""

    def __init__(
        self,
        config: RecorderConfig,
        *,
        control_socket: Path | None = None,
        live_port: int | None = None,
        live_host: str = "127.0.0.1",
    ) -> None:
        """`live_port`: also serve every channel to the Foxglove app over WebSocket on `live_host`:`live_port`."""
        self.config = config
        self._live = (live_port, live_host)
        self._control_path = control_socket
        self._mono_to_utc_ns = time.time_ns() - time.monotonic_ns()  # fixed: log times stay monotonic
        self.log_file = RecorderLog(self._mono_to_utc_ns, self._fatal)
        self.sync_config = SyncConfig.of(
            config.sync,
            config.camera,
            autopilot_system=config.mavlink.system_id,
            require_signed_autopilot=config.mavlink.signing_key_file is not None,
        )
        self.sync = Synchroniser(self.sync_config)  # fed and polled by the worker thread only
        self.views = FoxgloveViews(
            config.camera,
            self.log_file.write,
            self.log_file.log_time,
            lambda: self.sync.geotagger.origin,
            config.mavlink.system_id,
        )
        key_file = config.mavlink.signing_key_file  # read now: a bad key file stops us before any contact
        self._signing_key = load_signing_key(key_file) if key_file is not None else None
        self.links = Links()
        self.control: ControlServer | None = None
        self.hello: Hello | None = None
        self.failure: IcgtError | None = None
        self.recording_id = secrets.randbits(32) or 1  # named to the device in HOST_RECEIVED (nonzero)
        self._stop = threading.Event()
        self._starting = threading.Event()  # set while start() runs: control start/stop wait for it to end
        self._tuning = InterpreterTuning()
        self._wake = WorkerWake()  # wakes the worker before its scheduled step (a capture started, stop, input)
        images = CameraImages(config.mavlink.system_id)
        self._images = images
        self.capture = CaptureControl(config, self.links, self._wake.set)
        expanded = frozenset({config.mavlink.system_id, *config.mavlink.ground_station_systems})
        self.mavlink_input = MavlinkInput(self.sync, self.log_file, self.views, images, expanded)
        # The device saying it stopped this recording's capture by itself changes the capture state there.
        self.device_input = DeviceInput(self.sync, self.log_file, self.views, self.capture.device_stopped_itself)
        self.inbox = Inbox(self.device_input, self.mavlink_input, self._wake)
        self.health = Health(self.sync, self.links, self.log_file)
        self.worker = Worker(
            sync=self.sync,
            links=self.links,
            inbox=self.inbox,
            wake=self._wake,
            log_file=self.log_file,
            views=self.views,
            images=images,
            mavlink_input=self.mavlink_input,
            health=self.health,
            cadence_hint=lambda: self.capture.cadence_hint,
            stopping=self._stop,
        )
        self._connector = DeviceConnector(config, self.links, self.inbox, self._stop)
        self.control_requests = ControlRequests(
            self.capture, self.status, self._starting, lambda: self._connector.waiting
        )
        self._shutdown = Shutdown(
            config=config,
            links=self.links,
            capture=self.capture,
            worker=self.worker,
            wake=self._wake,
            log_file=self.log_file,
            health=self.health,
            tuning=self._tuning,
            stop_control=self._stop_control,
            on_failure=self._failed,
        )

    # ------------------------------------------------------------------ what the parts know
    @property
    def device(self) -> DeviceLink | None:
        return self.links.device

    @property
    def mavlink(self) -> MavlinkLink | None:
        return self.links.mavlink

    @property
    def camera(self) -> CameraComponent | None:
        return self.links.camera

    @property
    def mcap(self) -> McapRecorder | None:
        """The recording's file while it is open (`RecorderLog`)."""
        return self.log_file.mcap

    @property
    def frames(self) -> int:
        """Frames emitted in this recording."""
        return self.worker.frames

    @property
    def last_status(self) -> Status | None:
        return self.sync.last_status

    @property
    def exposures(self) -> int:
        """Exposures the device reported in this recording."""
        return self.device_input.exposures

    def status(self) -> RecorderStatus:
        """What the recorder knows now (the synchroniser's part as of its last second: it runs on the worker)."""
        return self.health.status(
            capturing=self.capture.capturing,
            frames=self.worker.frames,
            exposures=self.exposures,
            waiting_for_device=self._connector.waiting,
        )

    def start_capture(self, interval_s: float | None = None, count: int = 0) -> None:
        """Start triggering (`CaptureControl.start`)."""
        self.capture.start(interval_s, count)

    def stop_capture(self) -> None:
        self.capture.stop()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Path:
        """Connect to the device (handshake), open the log, connect to the autopilot. Returns the MCAP path.

        Nothing is left on disk by a start that fails: the log is created after the device answered, and
        removed again if anything after that fails."""
        cfg = self.config
        out = output_dir(cfg.output.dir)
        limit_malloc_arenas(1)  # before its threads start: their free memory in one arena (native_heap)
        self._starting.set()
        if self._control_path is not None:
            # First, so that `icgt status` can say "waiting for the device" while it is not there yet.
            self.control = ControlServer(self._control_path, self.control_requests.handle)
            self.control.start()
        try:
            self.hello = self.capture.hello = self._connector.connect()
        except BaseException:
            self._stop_control()
            raise
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        path = out / f"icgt_{stamp}.mcap"
        try:
            self._open_log(path)
            device = self.links.device
            assert device is not None and self.mcap is not None
            record_hello(self.mcap, self.hello, cfg)
            device.recording_id = self.recording_id
            self.mcap.add_metadata(
                layout.META_FLIGHT,
                {"kind": "recording", "recording_id": f"0x{self.recording_id:08X}", "file": path.name},
            )
            takeover = take_over(device, cfg.device.running_capture)
            if takeover.capturing and not takeover.adopted:
                device.command(StopCapture())
            if not takeover.adopted:
                self.capture.sensors = configure_device(device, cfg, self.capture.limits())
            self._start_mavlink()
            if takeover.adopted:
                self.capture.adopt(takeover.interval_s)
        except BaseException:
            self._shutdown.abandon(path)
            raise
        self._tuning.apply()  # GIL switch interval and garbage collector (see icgt.recorder.tuning)
        self.worker.schedule_time_sync()
        device.set_pumped(True)  # its stream read by the worker's steps (Worker.drain), see DeviceLink.set_pumped
        self.worker.start()
        self._starting.clear()
        log.info("recording to %s (device %s, autopilot %s)", path, cfg.device.url, cfg.mavlink.url)
        return path

    def _open_log(self, path: Path) -> None:
        metadata = start_metadata(
            self.config, self.sync_config, signing=self._signing_key is not None, mono_to_utc_ns=self._mono_to_utc_ns
        )
        self.log_file.open(path, self.config, metadata, self._live)
        # Until the autopilot has GPS time, UTC comes from this computer's clock (flagged as such): the
        # same fixed offset as the log times, which the recompute reads back from icgt.time_bases.
        self.sync.on_host_realtime(0, self._mono_to_utc_ns)
        self.views.start(time.monotonic_ns())

    def _start_mavlink(self) -> None:
        cfg = self.config.mavlink
        rates = (
            StreamRate(33, "GLOBAL_POSITION_INT", cfg.global_position_hz),
            StreamRate(24, "GPS_RAW_INT", 10.0),
            StreamRate(30, "ATTITUDE", 50.0),
            StreamRate(31, "ATTITUDE_QUATERNION", 50.0),
            StreamRate(32, "LOCAL_POSITION_NED", 30.0),
            StreamRate(2, "SYSTEM_TIME", 2.0),
        )
        self.links.mavlink = mavlink = MavlinkLink(
            LinkConfig(
                url=cfg.url,
                system_id=cfg.system_id,
                stream_rates=rates,
                decode_systems=self.mavlink_input.expanded_systems,
                signing_key=self._signing_key,
                udp_receive_buffer_bytes=cfg.udp_receive_buffer_bytes,
                service_period_s=_MAVLINK_SERVICE_PERIOD_S,
                owner_pumps=True,  # UDP: read by the worker's steps (Worker.drain), see icgt.mavlink.link
            ),
            on_event=self.inbox.mavlink_event,
            on_timesync_sent=self.inbox.timesync_sent,
        )
        mavlink.subscribe(self.inbox.mavlink_message, undecoded=self.inbox.mavlink_message)  # others: in bulk
        self.mavlink_input.link = mavlink
        mavlink.start()
        c = self.capture
        settings = capture_settings(lambda: c.settings, c.set_settings, c.configured, c.limits)
        self.links.camera = build_camera(self.config, mavlink, CaptureHandler(c), settings)  # logs its refusals
        self.links.camera.start()

    def stop(self) -> None:
        """Stop capture if running, emit every pending frame, close the links and the log (`Shutdown.run`)."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._shutdown.run()

    def wait(self) -> None:
        """Block until stop() is called or a fatal error (full disk) ends the recording."""
        while not self._stop.wait(0.5):
            pass

    def _stop_control(self) -> None:
        if self.control is not None:
            with contextlib.suppress(Exception):
                self.control.stop()
            self.control = None

    def _failed(self, exc: IcgtError) -> None:
        """What made the recording fail: the first failure counts."""
        self.failure = self.failure or exc

    def _fatal(self, exc: IcgtError) -> None:
        if self.failure is None:
            self.failure = exc
            log.critical("recording stopped: %s", exc)
            threading.Thread(target=self.stop, name="icgt-stop", daemon=True).start()
