"""`icgt record`: the synchroniser that runs on the drone's companion computer.

Composition: the device link (serial), the MAVLink link (autopilot and ground station), the
clock filters, the geotagger, the MAVLink camera component, the MCAP recorder and the local
control socket. Threads: the device reader and the MAVLink reader deliver into the filters,
the geotagger and the MCAP queue (never blocking); one worker thread schedules TIME_SYNC,
emits geotagged frames and writes clock estimates; the camera component and the control
socket call start/stop/shoot, which talk to the device.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, cast

import numpy as np

from icgt import __version__
from icgt.clocks.autopilot_clock import AutopilotClockFilter, UtcMapper
from icgt.clocks.device_clock import DeviceClockFilter, PpsUtcMapper
from icgt.clocks.shared import Synchronized
from icgt.control import ControlServer, Reply, Request
from icgt.device import CommandRefusedError, DeviceLink, DeviceLinkError, LinkEvent, TimeSyncSample
from icgt.errors import IcgtError
from icgt.geodesy import q_conjugate, q_multiply
from icgt.geotag import FrameRecord, Geotagger
from icgt.geotag.clock_views import AutopilotClockView, UtcView, add_pps_edge
from icgt.geotag.geotagger import _Q_CAM_TO_BODY_BASE
from icgt.mavlink.camera import CameraComponent, CameraConfig, CameraInfo, CapturedImage, CommandResult
from icgt.mavlink.link import LinkConfig, MavlinkLink, Received, StreamRate, TimesyncSample
from icgt.mavlink.link import LinkEvent as MavlinkLinkEvent
from icgt.mavlink.telemetry import TelemetryStore
from icgt.protocol import MESSAGE_TYPES, PROTOCOL_VERSION, TABLE_HASH
from icgt.protocol import Received as DeviceReceived
from icgt.protocol.messages import (
    Board,
    CaptureMode,
    ClockSource,
    Configure,
    Exposure,
    Hello,
    Imu,
    Log,
    LogLevel,
    PinPolarity,
    Pps,
    Range,
    SetTime,
    StartCapture,
    Status,
    StopCapture,
)
from icgt.recorder import topics
from icgt.recorder.config import RecorderConfig
from icgt.recording import McapRecorder, RecordingError
from icgt.recording.writer import McapLogHandler

log = logging.getLogger("icgt.recorder")

_DEVICE_LOG_LEVELS: dict[int, int] = {
    LogLevel.DEBUG: logging.DEBUG,
    LogLevel.INFO: logging.INFO,
    LogLevel.WARNING: logging.WARNING,
    LogLevel.ERROR: logging.ERROR,
    LogLevel.FATAL: logging.CRITICAL,
}
_LIDAR_MODELS = {"none": 0, "v3": 1, "v3hp": 2}


@dataclass
class RecorderStatus:
    """What `icgt status` prints."""

    file: str
    capturing: bool
    frames: int
    exposures: int
    device_connected: bool
    autopilot: str
    device_clock_settled: bool
    device_clock_uncertainty_us: float | None
    sequence_gaps: int
    messages_lost: int
    frames_rejected: int
    pending_frames: int
    last_status: dict[str, Any] | None


class Recorder:
    """One recording session. start() connects and begins writing; stop() ends it cleanly."""

    def __init__(self, config: RecorderConfig, *, control_socket: Path | None = None) -> None:
        self.config = config
        self._control_path = control_socket
        self._mono_to_utc_ns = time.time_ns() - time.monotonic_ns()  # fixed: log times stay monotonic
        # Fed by the link readers, queried by the worker and the geotagger: one lock for all four
        # (the UTC mapper reads the autopilot filter).
        clock_lock = threading.RLock()
        self.device_clock: DeviceClockFilter = cast(
            DeviceClockFilter,
            Synchronized(DeviceClockFilter(slow_interval_s=0.1), clock_lock),
        )
        autopilot = AutopilotClockFilter()
        self.autopilot_clock: AutopilotClockFilter = cast(AutopilotClockFilter, Synchronized(autopilot, clock_lock))
        self.utc: UtcMapper = cast(UtcMapper, Synchronized(UtcMapper(autopilot), clock_lock))
        self.pps: PpsUtcMapper = cast(PpsUtcMapper, Synchronized(PpsUtcMapper(), clock_lock))
        self.telemetry = TelemetryStore(autopilot_system=config.mavlink.system_id)
        self.geotagger = Geotagger(
            self.telemetry,
            self.device_clock,
            AutopilotClockView(self.autopilot_clock),
            UtcView(self.pps, self.utc),
            config.camera,
            self._on_frame,
        )
        self.mcap: McapRecorder | None = None
        self.device: DeviceLink | None = None
        self.mavlink: MavlinkLink | None = None
        self.camera: CameraComponent | None = None
        self.control: ControlServer | None = None
        self.hello: Hello | None = None
        self.last_status: Status | None = None
        self.frames = 0
        self.exposures = 0
        self._capturing = False
        self._stop = threading.Event()
        self._worker: threading.Thread | None = None
        self._log_handler: McapLogHandler | None = None
        self._registered: set[str] = set()
        self._reg_lock = threading.Lock()
        self._next_sync_ns = 0
        self._next_clock_log_ns = 0
        self.failure: IcgtError | None = None

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Path:
        """Connect to the device (handshake), open the log, connect to the autopilot. Returns the MCAP path."""
        cfg = self.config
        cfg.output.dir.mkdir(parents=True, exist_ok=True)
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        path = cfg.output.dir / f"icgt_{stamp}.mcap"
        self.mcap = McapRecorder(path, max_chunk_interval_s=cfg.output.chunk_interval_s)
        # Until the autopilot has GPS time, UTC comes from this computer's clock (flagged as such).
        self.utc.add_host_realtime(time.monotonic_ns(), time.time_ns())
        self._log_handler = McapLogHandler(self.mcap, topics.LOG)
        logging.getLogger("icgt").addHandler(self._log_handler)
        self._register_topics()
        self.mcap.add_metadata(
            "icgt.config",
            {"source": cfg.source, "config": cfg.as_text(), "host_software": f"icgt {__version__}"},
        )
        self.mcap.add_metadata(
            "icgt.time_bases",
            {
                "log_time": "host CLOCK_MONOTONIC + a fixed offset to UTC taken at start [ns since the Unix epoch]",
                "monotonic_to_utc_offset_ns": str(self._mono_to_utc_ns),
                "device_clock": "device microseconds since boot (DeviceClockFilter maps it to host monotonic)",
                "autopilot_clock": "autopilot boot microseconds (TIMESYNC maps it to host monotonic)",
            },
        )
        self.device = DeviceLink(
            cfg.device.url,
            on_message=self._on_device_message,
            on_event=self._on_device_link_event,
            on_time_sync=self._on_time_sync,
        )
        try:
            self.hello = self.device.start()
        except IcgtError:
            self._close_log()
            raise
        self._record_hello(self.hello)
        self._configure_device()
        self._start_mavlink()
        if self._control_path is not None:
            self.control = ControlServer(self._control_path, self._handle_control)
            self.control.start()
        self._worker = threading.Thread(target=self._work, name="icgt-recorder", daemon=True)
        self._worker.start()
        log.info("recording to %s (device %s, autopilot %s)", path, cfg.device.url, cfg.mavlink.url)
        return path

    def stop(self) -> None:
        """Stop capture if running, emit every pending frame, close the links and the log."""
        if self._stop.is_set():
            return
        self._stop.set()
        if self._capturing and self.device is not None:
            with contextlib.suppress(IcgtError):
                self.stop_capture()
        time.sleep(0.3)  # the last exposures' feedback and telemetry are still on their way
        if self._worker is not None:
            self._worker.join(timeout=3.0)
        self.geotagger.poll(time.monotonic_ns(), flush=True)
        if self.control is not None:
            self.control.stop()
        if self.camera is not None:
            self.camera.stop()
        if self.mavlink is not None:
            self.mavlink.stop()
        if self.device is not None:
            self.device.stop()
        self._record_link_summary()
        self._close_log()

    def wait(self) -> None:
        """Block until stop() is called or a fatal error (full disk) ends the recording."""
        while not self._stop.wait(0.5):
            pass

    def _close_log(self) -> None:
        if self._log_handler is not None:
            logging.getLogger("icgt").removeHandler(self._log_handler)
        if self.mcap is not None:
            try:
                stats = self.mcap.close()
                log.info("log closed: %s", stats)
            except RecordingError as exc:
                log.error("%s", exc)
                self.failure = self.failure or exc

    # ------------------------------------------------------------------ device
    def _register_topics(self) -> None:
        assert self.mcap is not None
        for cls in MESSAGE_TYPES.values():
            if cls.DIRECTION == "device_to_host":
                self.mcap.register_json(
                    topics.device_topic(cls.NAME), f"icgt.device.{cls.NAME}", topics.device_schema(cls)
                )
        self.mcap.register_dataclass(topics.FRAMES, FrameRecord)
        for name, schema in (
            (topics.CLOCK_DEVICE, "icgt.clock.estimate"),
            (topics.CLOCK_AUTOPILOT, "icgt.clock.estimate"),
        ):
            self.mcap.register_json(name, schema, _ESTIMATE_SCHEMA)
        self.mcap.register_json(topics.CLOCK_DEVICE_EXCHANGES, "icgt.clock.exchange", _EXCHANGE_SCHEMA)
        self.mcap.register_json(topics.CLOCK_UTC, "icgt.clock.utc", _UTC_SCHEMA)
        self.mcap.register_json(topics.LINK_EVENTS, "icgt.link_event", _LINK_EVENT_SCHEMA)

    def _log_time(self, host_ns: int) -> int:
        return host_ns + self._mono_to_utc_ns

    def _write(self, topic: str, message: Any, host_ns: int) -> None:
        if self.mcap is None:
            return
        try:
            self.mcap.write(topic, message, self._log_time(host_ns))
        except RecordingError as exc:
            self._fatal(exc)

    def _fatal(self, exc: IcgtError) -> None:
        if self.failure is None:
            self.failure = exc
            log.critical("recording stopped: %s", exc)
            threading.Thread(target=self.stop, name="icgt-stop", daemon=True).start()

    def _record_hello(self, hello: Hello) -> None:
        assert self.mcap is not None
        try:
            board = Board(hello.board).name.lower()
        except ValueError:
            board = str(hello.board)
        try:
            clock = ClockSource(hello.clock_source).name.lower()
        except ValueError:
            clock = str(hello.clock_source)
        self.mcap.add_metadata(
            "icgt.device",
            {
                "firmware_version": hello.firmware_version,
                "protocol_version": str(hello.protocol_version),
                "host_protocol_version": str(PROTOCOL_VERSION),
                "table_hash": f"0x{hello.table_hash:08X}",
                "host_table_hash": f"0x{TABLE_HASH:08X}",
                "board": board,
                "serial_number": str(hello.serial_number),
                "clock_source": clock,
                "device_url": self.config.device.url,
            },
        )
        c = self.config.camera
        self.mcap.add_metadata(
            "icgt.calibration",
            {k: repr(v) for k, v in asdict(c).items()},
        )
        log.info(
            "device: %s on %s, firmware %s, serial %s",
            board,
            self.config.device.url,
            hello.firmware_version,
            hello.serial_number,
        )

    def _configure_device(self) -> None:
        assert self.device is not None
        s = self.config.sensors
        polarity = int(PinPolarity.FOCUS_ACTIVE_HIGH | PinPolarity.SHUTTER_ACTIVE_HIGH | PinPolarity.PPS_RISING)
        if s.feedback_active_high:
            polarity |= int(PinPolarity.FEEDBACK_ACTIVE_HIGH)
        cmd = Configure(
            imu_rate_hz=s.imu_rate_hz,
            imu_mode=0x0C if s.imu_mode == "ndof" else 0x08,
            imu_ext_crystal=0,
            range_rate_hz=s.range_rate_hz if s.lidar_model != "none" else 0,
            lidar_model=_LIDAR_MODELS[s.lidar_model],
            lidar_preset=s.lidar_preset,
            lidar_bias_every=s.lidar_bias_every,
            polarity=polarity,
            feedback_enabled=1 if s.feedback else 0,
            feedback_timeout_us=int(s.feedback_timeout_s * 1e6),
        )
        try:
            self.device.command(cmd)
        except CommandRefusedError as exc:
            # A missing sensor must not stop capture: record why and go on with what the device has.
            log.warning("device kept its configuration: %s", exc)
        if self.config.device.set_rtc:
            try:
                self.device.command(SetTime(utc_us=time.time_ns() // 1000))
                log.info("device RTC set from the host clock")
            except CommandRefusedError as exc:
                log.warning("device RTC not set: %s", exc)

    def _on_device_message(self, received: DeviceReceived, host_rx_ns: int) -> None:
        msg = received.message
        self._write(
            topics.device_topic(msg.NAME),
            topics.device_payload(msg, received.seq, received.flags, host_rx_ns),
            host_rx_ns,
        )
        if isinstance(msg, Exposure):
            self.exposures += 1
            self.geotagger.add_exposure(msg, host_rx_ns)
        elif isinstance(msg, Imu):
            self.geotagger.add_imu(msg)
        elif isinstance(msg, Range):
            self.geotagger.add_range(msg)
        elif isinstance(msg, Pps):
            add_pps_edge(self.pps, self.utc, self.device_clock, msg.t_us, msg.pps_count)
        elif isinstance(msg, Status):
            self.last_status = msg
        elif isinstance(msg, Log):
            log.log(_DEVICE_LOG_LEVELS.get(msg.level, logging.INFO), "device: %s", msg.text)
        elif isinstance(msg, Hello) and self.hello is not None and msg.t_us < self.hello.t_us:
            log.warning("device rebooted (HELLO at device time %d us): its clock restarts", msg.t_us)
            self.device_clock.reset()
            self.hello = msg

    def _on_device_link_event(self, event: LinkEvent) -> None:
        level = logging.INFO if event.kind == "connected" else logging.WARNING
        log.log(level, "device link: %s", event.detail)
        self._write(
            topics.LINK_EVENTS,
            {
                "link": "device",
                "kind": event.kind,
                "detail": event.detail,
                "count": event.count,
                "outage_ns": event.outage_ns,
                "host_ns": event.host_ns,
            },
            event.host_ns,
        )
        if event.kind == "connected":
            self._next_sync_ns = 0  # resynchronise at the fast rate

    def _on_time_sync(self, sample: TimeSyncSample) -> None:
        status = self.device_clock.add_exchange(
            sample.host_tx_ns, sample.device_rx_us, sample.device_tx_us, sample.host_rx_ns
        )
        self._write(
            topics.CLOCK_DEVICE_EXCHANGES,
            {
                "host_tx_ns": sample.host_tx_ns,
                "device_rx_us": sample.device_rx_us,
                "device_tx_us": sample.device_tx_us,
                "host_rx_ns": sample.host_rx_ns,
                "status": status.value,
            },
            sample.host_rx_ns,
        )

    # ------------------------------------------------------------------ capture commands
    def start_capture(self, interval_s: float | None = None, count: int = 0) -> None:
        """Start triggering: `count` 0 runs until stopped, 1 is a single shot, N stops after N."""
        assert self.device is not None
        c = self.config.capture
        interval_us = int((interval_s if interval_s and interval_s > 0 else c.interval_s) * 1e6)
        if count == 1:
            mode = CaptureMode.SINGLE
        elif count > 1:
            mode = CaptureMode.COUNT
        else:
            mode = CaptureMode.FOCUS_BURST if c.mode == "focus_burst" else CaptureMode.INTERVAL
        cmd = StartCapture(
            mode=int(mode),
            interval_us=interval_us,
            count=count if count > 1 else 0,
            focus_lead_us=int(c.focus_lead_s * 1e6) if mode == CaptureMode.FOCUS_BURST else 0,
            burst_us=int(c.burst_s * 1e6) if mode == CaptureMode.FOCUS_BURST else 0,
            shutter_pulse_us=int(c.shutter_pulse_s * 1e6),
        )
        self.device.command(cmd)
        self._capturing = count != 1
        if self.camera is not None:
            self.camera.set_capturing(self._capturing, interval_us / 1e6)
        log.info("capture started: %s, interval %.3f s, count %d", mode.name.lower(), interval_us / 1e6, count)

    def stop_capture(self) -> None:
        assert self.device is not None
        self.device.command(StopCapture())
        self._capturing = False
        if self.camera is not None:
            self.camera.set_capturing(False)
        log.info("capture stopped")

    # camera component handler (CaptureHandler protocol)
    def _handler_result(self, action: Any) -> CommandResult:
        try:
            action()
        except CommandRefusedError as exc:
            log.warning("%s", exc)
            return CommandResult.DENIED
        except DeviceLinkError as exc:
            log.error("%s", exc)
            return CommandResult.FAILED
        return CommandResult.ACCEPTED

    # ------------------------------------------------------------------ MAVLink
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
        self.mavlink = MavlinkLink(
            LinkConfig(url=cfg.url, system_id=cfg.system_id, stream_rates=rates),
            on_event=self._on_mavlink_event,
            on_timesync=self._on_autopilot_timesync,
        )
        self.telemetry.attach(self.mavlink)
        self.mavlink.subscribe(self._on_mavlink_message)
        self.mavlink.start()
        c = self.config.camera
        info = CameraInfo(
            focal_length_mm=c.focal_length_mm,
            sensor_size_h_mm=c.sensor_width_mm,
            sensor_size_v_mm=c.sensor_width_mm * c.image_height_px / c.image_width_px,
            resolution_h=c.image_width_px,
            resolution_v=c.image_height_px,
        )
        self.camera = CameraComponent(
            self.mavlink,
            CameraConfig(
                output_dir=self.config.output.dir,
                info=info,
                ground_station_systems=frozenset(cfg.ground_station_systems),
            ),
            _CaptureHandler(self),
            on_rejected=lambda r: log.warning(
                "ignored command %d from system %d component %d: %s",
                r.command,
                r.src_system,
                r.src_component,
                r.reason,
            ),
            on_command=lambda r: log.info(
                "ground station command %d from %d/%d -> result %s%s",
                r.command,
                r.src_system,
                r.src_component,
                r.result,
                " (duplicate)" if r.duplicate else "",
            ),
        )
        self.camera.start()

    def _on_mavlink_message(self, rec: Received) -> None:
        name = rec.type
        if name == "BAD_DATA":
            return
        topic = topics.mavlink_topic(name)
        if topic not in self._registered:
            with self._reg_lock:
                if topic not in self._registered and self.mcap is not None:
                    with contextlib.suppress(RecordingError):
                        self.mcap.register_json(topic, f"mavlink.{name}", topics.mavlink_schema(rec.msg))
                    self._registered.add(topic)
        self._write(topic, topics.mavlink_payload(rec.msg, rec.rx_ns), rec.rx_ns)
        if name == "SYSTEM_TIME" and rec.src_system == self.config.mavlink.system_id:
            self.utc.add_system_time(int(rec.msg.time_unix_usec), int(rec.msg.time_boot_ms))

    def _on_mavlink_event(self, event: MavlinkLinkEvent) -> None:
        # MavlinkLink logs the event itself (icgt.mavlink.link, also on /icgt/log); here it only goes on the topic.
        self._write(
            topics.LINK_EVENTS,
            {
                "link": "mavlink",
                "kind": event.kind.value,
                "detail": event.detail,
                "count": 0,
                "outage_ns": event.outage_ns or 0,
                "host_ns": event.host_ns,
            },
            event.host_ns,
        )

    def _on_autopilot_timesync(self, sample: TimesyncSample) -> None:
        self.autopilot_clock.add_timesync(sample.host_tx_ns, sample.autopilot_tc1_ns, sample.host_rx_ns)

    # ------------------------------------------------------------------ frames
    def _on_frame(self, rec: FrameRecord) -> None:
        self.frames += 1
        utc_ns = rec.mid_utc_us * 1000 if rec.mid_utc_us is not None else self._log_time(rec.mid_host_ns)
        self._write(topics.FRAMES, rec, rec.mid_host_ns)
        fix = topics.location_fix(rec, utc_ns)
        if fix is not None:
            self._write(topics.FRAMES_LOCATION, fix, rec.mid_host_ns)
        pose = topics.pose_and_transform(rec, utc_ns)
        if pose is not None:
            self._write(topics.FRAMES_POSE, pose[0], rec.mid_host_ns)
            self._write(topics.TF, pose[1], rec.mid_host_ns)
        if self.camera is not None:
            q = None
            if rec.cam_qw is not None:
                # MAVLink's camera quaternion is the camera body (x forward) in NED: undo the optical base.
                cq = np.array([rec.cam_qw, rec.cam_qx, rec.cam_qy, rec.cam_qz], dtype=float)
                q = tuple(float(v) for v in q_multiply(cq, q_conjugate(_Q_CAM_TO_BODY_BASE)))
            image = CapturedImage(
                image_index=rec.image_index,
                time_boot_ms=self.camera.time_boot_ms(rec.mid_host_ns),
                time_utc_us=rec.mid_utc_us or 0,
                lat_deg=rec.lat_deg,
                lon_deg=rec.lon_deg,
                alt_msl_m=rec.alt_msl_m,
                relative_alt_m=rec.up_m,
                q_wxyz=q,  # type: ignore[arg-type]
                capture_result="feedback_missing" not in rec.flags,
            )
            with contextlib.suppress(IcgtError):
                self.camera.publish_image_captured(image)

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        while not self._stop.wait(0.02):
            try:
                self._work_once()
            except Exception:  # the worker must outlive any bug: frames keep being emitted
                log.exception("recorder worker error (recording continues)")

    def _work_once(self) -> None:
        now = time.monotonic_ns()
        if self.device is not None and self.device.connected and now >= self._next_sync_ns:
            with contextlib.suppress(DeviceLinkError):
                self.device.request_time_sync()
            self._next_sync_ns = now + int(self.device_clock.next_exchange_interval_s() * 1e9)
        self.geotagger.poll(now)
        if now >= self._next_clock_log_ns:
            self._next_clock_log_ns = now + 1_000_000_000
            self._write(topics.CLOCK_DEVICE, self.device_clock.estimate().to_dict(), now)
            self._write(topics.CLOCK_AUTOPILOT, self.autopilot_clock.estimate().to_dict(), now)
            self._write(topics.CLOCK_UTC, self.utc.host_to_utc(now).to_dict() | {"host_ns": now}, now)

    def _record_link_summary(self) -> None:
        origin = self.geotagger.origin
        if origin is not None and self.mcap is not None:
            with contextlib.suppress(RecordingError):
                self.mcap.add_metadata(
                    "icgt.enu_origin",
                    {
                        "lat_deg": repr(origin[0]),
                        "lon_deg": repr(origin[1]),
                        "alt_msl_m": repr(origin[2]),
                        "note": "origin of the frames' east/north/up: the first usable fix (or the configured origin)",
                    },
                )
        if self.device is None:
            return
        stats = self.device.decoder_stats
        log.info(
            "device link summary: %s frames, %s rejected, %s messages lost in %s gaps",
            stats.get("frames_ok"),
            self.device.frames_rejected,
            stats.get("seq_missed"),
            stats.get("seq_gaps"),
        )
        if self.mcap is not None:
            with contextlib.suppress(RecordingError):
                self.mcap.add_metadata("icgt.device_link", {k: str(v) for k, v in stats.items()})

    # ------------------------------------------------------------------ control socket
    def status(self) -> RecorderStatus:
        est = self.device_clock.estimate()
        stats = self.device.decoder_stats if self.device is not None else {}
        return RecorderStatus(
            file=str(self.mcap.path) if self.mcap is not None else "",
            capturing=self._capturing,
            frames=self.frames,
            exposures=self.exposures,
            device_connected=self.device is not None and self.device.connected,
            autopilot=self.mavlink.state.value if self.mavlink is not None else "none",
            device_clock_settled=self.device_clock.settled,
            device_clock_uncertainty_us=est.uncertainty_ns / 1000.0 if est.valid else None,
            sequence_gaps=int(stats.get("seq_gaps") or 0),
            messages_lost=int(stats.get("seq_missed") or 0),
            frames_rejected=self.device.frames_rejected if self.device is not None else 0,
            pending_frames=self.geotagger.pending,
            last_status=asdict(self.last_status) if self.last_status is not None else None,
        )

    def _handle_control(self, request: Request) -> Reply:
        command = request.get("command")
        if command == "status":
            return {"ok": True, "status": asdict(self.status())}
        if command == "start":
            interval = request.get("interval_s")
            count = int(request.get("count", 0))
            self.start_capture(float(interval) if interval else None, count)
            return {"ok": True}
        if command == "stop":
            self.stop_capture()
            return {"ok": True}
        return {"error": f"unknown command {command!r} (start, stop, status)"}


class _CaptureHandler:
    """The camera component's CaptureHandler: ground-station commands become device commands."""

    def __init__(self, recorder: Recorder) -> None:
        self._r = recorder

    def start(self, interval_s: float, count: int) -> CommandResult:
        return self._r._handler_result(lambda: self._r.start_capture(interval_s, count))

    def stop(self) -> CommandResult:
        return self._r._handler_result(self._r.stop_capture)

    def shoot(self) -> CommandResult:
        return self._r._handler_result(lambda: self._r.start_capture(None, 1))


_NUM = {"type": "number"}
_INT = {"type": "integer"}
_ESTIMATE_SCHEMA = {
    "type": "object",
    "description": "clock line: host_ns = ref_host_ns + (clock_us - ref_clock_us) * 1000 / (1 + drift_ppm * 1e-6)",
    "properties": {
        "valid": {"type": "boolean"},
        "settled": {"type": "boolean"},
        "n_used": _INT,
        "ref_clock_us": _NUM,
        "ref_host_ns": _INT,
        "drift_ppm": _NUM,
        "uncertainty_ns": _INT,
        "t_host_ns": _INT,
        "min_rtt_ns": _INT,
        "span_s": _NUM,
        "resets": _INT,
    },
}
_EXCHANGE_SCHEMA = {
    "type": "object",
    "description": "one TIME_SYNC exchange with the device",
    "properties": {
        "host_tx_ns": _INT,
        "device_rx_us": _INT,
        "device_tx_us": _INT,
        "host_rx_ns": _INT,
        "status": {"type": "string"},
    },
}
_UTC_SCHEMA = {
    "type": "object",
    "description": "UTC of host_ns",
    "properties": {
        "valid": {"type": "boolean"},
        "utc_us": _NUM,
        "uncertainty_us": _NUM,
        "source": {"type": "string"},
        "fallback": {"type": "boolean"},
        "host_ns": _INT,
    },
}
_LINK_EVENT_SCHEMA = {
    "type": "object",
    "description": "a link state change, sequence gap or rejected frames",
    "properties": {
        "link": {"type": "string"},
        "kind": {"type": "string"},
        "detail": {"type": "string"},
        "count": _INT,
        "outage_ns": _INT,
        "host_ns": _INT,
    },
}
