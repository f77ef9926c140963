"""`icgt record`: the synchroniser that runs on the drone's companion computer.

The recorder is I/O around one `icgt.sync.Synchroniser`: the device link (serial), the MAVLink
link (autopilot and ground station), the MAVLink camera component, the MCAP log and the local
control socket. Threads: one worker reads both links at the start of each step (`pump()`: the
device's stream, and the MAVLink datagrams, which carry the kernel's arrival stamps; steps every 100 ms,
and from just before the next frame is due also when input arrives on those links, see `step_schedule`
and `worker_wake`), putting what
arrived in one inbox, and then takes each input from the inbox, writes it to the log and feeds it to
the synchroniser, in that order, polls the synchroniser for frames and writes clock estimates and
counters. The device link's reader thread sends the TIME_SYNC requests at the rate the worker sets and
reads the device's answers the moment they arrive (their stamps are what the clock filter uses); on a
serial or TCP MAVLink link the link's reader thread stamps and hands on what arrives (and wakes the
worker when it watches for a frame's telemetry: `worker_wake`'s thread input). Waking a thread
costs as much CPU as handling dozens of messages: this way the worker and the device reader wake about
40 times a second while capturing at 5 fps (about 55 with the log writer and the rest), where the threads
woke about 230 times.
Because the log holds every input in the order the synchroniser saw it, `icgt.ingest.recompute` gives
back the same frames. The camera component and the control socket call start/stop/shoot, which talk
to the device.
"""

from __future__ import annotations

import contextlib
import logging
import os
import secrets
import threading
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import msgspec

from icgt.control import ControlServer, Reply, Request
from icgt.device import (
    CommandRefusedError,
    DeviceAbsentError,
    DeviceLink,
    DeviceLinkError,
)
from icgt.device.limits import BoardLimits, LimitError, for_board
from icgt.errors import IcgtError
from icgt.geotag import FrameRecord
from icgt.mavlink.camera import CameraComponent, CommandResult, HandlerResult
from icgt.mavlink.frames import UndecodedBatch
from icgt.mavlink.link import LinkConfig, MavlinkLink, MavlinkMessage, StreamRate
from icgt.mavlink.signing import load_signing_key
from icgt.protocol import Received as DeviceReceived
from icgt.protocol.messages import Hello, SetTime, Status, StopCapture
from icgt.recorder import capture, topics
from icgt.recorder.camera_link import CameraImages, build_camera
from icgt.recorder.camera_settings import capture_settings
from icgt.recorder.config import CaptureSection, RecorderConfig
from icgt.recorder.device_input import DeviceInput
from icgt.recorder.log_file import RecorderLog, board_name, device_metadata, start_metadata
from icgt.recorder.mavlink_input import MavlinkInput
from icgt.recorder.native_heap import NativeHeapTrimmer, limit_malloc_arenas
from icgt.recorder.resync import TakeOver, take_over
from icgt.recorder.step_schedule import StepSchedule
from icgt.recorder.tuning import InterpreterTuning
from icgt.recorder.worker_wake import WorkerWake
from icgt.recording import McapRecorder, RecordingError, layout
from icgt.recording.views import FoxgloveViews
from icgt.sync import SyncConfig, Synchroniser

log = logging.getLogger("icgt.recorder")

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
    timesync: str = ""  # the autopilot's TIMESYNC: answered / unanswered / not asked yet
    waiting_for_device: bool = False  # started, the device not there yet ([device] wait_s)
    frames_recovered: int = 0  # device frames that came back through RESEND
    lost_exposures: int = 0  # exposures the device could no longer send (its history ring had moved on)


# Inputs from the reader threads to the worker, tagged by kind.
_DEVICE, _EXCHANGE, _DEVICE_EVENT, _MAVLINK, _MAVLINK_EVENT, _TIMESYNC_SENT = range(6)
_DRAIN_MAX = 5000  # inputs handled before the worker polls again (bounds frame latency under a flood)
_MAVLINK_SERVICE_PERIOD_S = 0.05  # a serial/TCP MAVLink link's TIMESYNC / rate-request steps [s]
# The device reader sleeps this long between reads [s] when no stamp depends on it (DeviceLink batch_s: not
# while a reply is awaited) until the worker pumps the link, and again after: one wake-up per pause, not per USB
# frame. (A UDP MAVLink link is read by the worker; a serial or TCP one's reader reads each chunk as it comes.)
_READ_BATCH_S = 0.02


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
        self._write = self.log_file.write
        self._write_encoded = self.log_file.write_encoded
        self._log_time = self.log_file.log_time
        self.sync_config = SyncConfig.of(
            config.sync,
            config.camera,
            autopilot_system=config.mavlink.system_id,
            require_signed_autopilot=config.mavlink.signing_key_file is not None,
        )
        self.sync = Synchroniser(self.sync_config)  # fed and polled by the worker thread only
        self.schedule = StepSchedule()  # when the worker steps: every 100 ms, and when a frame is due
        self.views = FoxgloveViews(
            config.camera, self._write, self._log_time, lambda: self.sync.geotagger.origin, config.mavlink.system_id
        )
        key_file = config.mavlink.signing_key_file  # read now: a bad key file stops us before any contact
        self._signing_key = load_signing_key(key_file) if key_file is not None else None
        self._images = CameraImages(config.mavlink.system_id)
        expanded = frozenset({config.mavlink.system_id, *config.mavlink.ground_station_systems})
        self.mavlink_input = MavlinkInput(self.sync, self.log_file, self.views, self._images, expanded)
        self.device_input = DeviceInput(self.sync, self.log_file, self.views, self._device_stopped_itself)
        # Filled by the reader threads (deque.append is atomic), emptied by the worker only.
        self._inbox: deque[tuple[int, Any, int]] = deque()
        self.device: DeviceLink | None = None
        self.mavlink: MavlinkLink | None = None
        self.camera: CameraComponent | None = None
        self.control: ControlServer | None = None
        self.hello: Hello | None = None
        self.frames = 0
        self._capturing = False
        self._capture_interval_s: float | None = None  # of the capture running (what an outage took)
        self._cadence_hint = (0, 0)  # (captures started, the last one's interval [ns]), for the worker
        self._stop = threading.Event()
        self._worker_ident = 0  # the worker thread's ident once it runs
        self._nudge = WorkerWake()  # wakes the worker before its scheduled step (a capture started, stop, input)
        self._worker: threading.Thread | None = None
        self._worker_lock = threading.Lock()  # the worker's step, and stop()'s final drain
        self._next_clock_log_ns = 0
        self._heap_trimmer = NativeHeapTrimmer()  # thread arenas' free pages back to the system (soak)
        self._snapshot: dict[str, Any] = {}
        self._waiting_for_device = False
        self._takeover: TakeOver | None = None
        self._starting = threading.Event()  # set while start() runs: control start/stop wait for it to end
        self.failure: IcgtError | None = None
        self._sensors = config.sensors  # what the device was configured with (a sensor that does not answer: off)
        self._capture = config.capture  # the trigger settings in force (a ground station may change them)
        self._tuning = InterpreterTuning()
        self.recording_id = secrets.randbits(32) or 1  # named to the device in HOST_RECEIVED (nonzero)

    @property
    def last_status(self) -> Status | None:
        return self.sync.last_status

    @property
    def exposures(self) -> int:
        """Exposures the device reported in this recording."""
        return self.device_input.exposures

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> Path:
        """Connect to the device (handshake), open the log, connect to the autopilot. Returns the MCAP path.

        Nothing is left on disk by a start that fails: the log is created after the device answered, and
        removed again if anything after that fails."""
        cfg = self.config
        out = _output_dir(cfg.output.dir)
        limit_malloc_arenas(1)  # before its threads start: their free memory in one arena (native_heap)
        self._starting.set()
        if self._control_path is not None:
            # First, so that `icgt status` can say "waiting for the device" while it is not there yet.
            self.control = ControlServer(self._control_path, self._handle_control)
            self.control.start()
        try:
            self.hello = self._connect_device()
        except BaseException:
            self._stop_control()
            raise
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        path = out / f"icgt_{stamp}.mcap"
        try:
            self._open_log(path)
            self._record_hello(self.hello)
            assert self.device is not None and self.mcap is not None
            self.device.recording_id = self.recording_id
            self.mcap.add_metadata(
                layout.META_FLIGHT,
                {"kind": "recording", "recording_id": f"0x{self.recording_id:08X}", "file": path.name},
            )
            self._takeover = take_over(self.device, cfg.device.running_capture)
            if self._takeover.capturing and not self._takeover.adopted:
                self.device.command(StopCapture())
            if not self._takeover.adopted:
                self._configure_device()
            self._start_mavlink()
            if self._takeover.adopted:
                self._capturing = True
                self._capture_interval_s = self._takeover.interval_s
                if self.camera is not None:
                    self.camera.set_capturing(True, self._takeover.interval_s)
        except BaseException:
            self._abandon(path)
            raise
        self._tuning.apply()  # GIL switch interval and garbage collector (see icgt.recorder.tuning)
        self._schedule_time_sync()
        assert self.device is not None
        self.device.set_pumped(True)  # its stream read by the worker's steps (_drain), see DeviceLink.set_pumped
        self._worker = threading.Thread(target=self._work, name="icgt-recorder", daemon=True)
        self._worker.start()
        self._starting.clear()
        log.info("recording to %s (device %s, autopilot %s)", path, cfg.device.url, cfg.mavlink.url)
        return path

    def _connect_device(self) -> Hello:
        """Open the device and complete the handshake, waiting up to [device] wait_s for it to appear."""
        cfg = self.config.device
        deadline = time.monotonic() + cfg.wait_s
        next_note = 0.0
        while True:
            self.device = DeviceLink(
                cfg.url,
                on_message=self._device_received,
                on_event=lambda event: self._inbox.append((_DEVICE_EVENT, event, event.host_ns)),
                on_time_sync=lambda sample: self._inbox.append((_EXCHANGE, sample, sample.host_rx_ns)),
                batch_s=_READ_BATCH_S,
            )
            try:
                return self.device.start()
            except DeviceAbsentError as exc:
                now = time.monotonic()
                if now >= deadline or self._stop.is_set():
                    raise DeviceAbsentError(f"{exc} (waited {cfg.wait_s:g} s: [device] wait_s)") from None
                if now >= next_note:
                    log.warning("waiting for the device: %s", exc)
                    next_note = now + 10.0
                self._waiting_for_device = True
                self._stop.wait(0.5)
            finally:
                self._waiting_for_device = False

    def _open_log(self, path: Path) -> None:
        metadata = start_metadata(
            self.config, self.sync_config, signing=self._signing_key is not None, mono_to_utc_ns=self._mono_to_utc_ns
        )
        self.log_file.open(path, self.config, metadata, self._live)
        # Until the autopilot has GPS time, UTC comes from this computer's clock (flagged as such): the
        # same fixed offset as the log times, which the recompute reads back from icgt.time_bases.
        self.sync.on_host_realtime(0, self._mono_to_utc_ns)
        self.views.start(time.monotonic_ns())

    @property
    def mcap(self) -> McapRecorder | None:
        """The recording's file while it is open (`RecorderLog`)."""
        return self.log_file.mcap

    def _abandon(self, path: Path) -> None:
        """A start that failed after the log was created: close everything and remove the file."""
        if self.mavlink is not None:
            with contextlib.suppress(Exception):
                self.mavlink.stop()
        if self.device is not None:
            with contextlib.suppress(Exception):
                self.device.stop()
        self._stop_control()
        self._close_log()
        self._nudge.close()
        with contextlib.suppress(FileNotFoundError):
            path.unlink()

    def _stop_not_delivered(self, exc: IcgtError) -> None:
        """The recording ends with capture running on a device it cannot reach: the log's last records say so
        (event `unreachable_at_end` on /icgt/link_events: the exposures it was known to be taking, interval x
        outage, are unknown, not 0), and the recorder fails with the stop it could not deliver."""
        assert self.device is not None
        now = time.monotonic_ns()
        down = self.device.down_since_ns
        outage_ns = 0 if down is None else now - down
        interval = self._capture_interval_s
        taken = int(outage_ns / 1e9 / interval) if interval and outage_ns else 0
        if taken:
            known = f"about {taken} exposures (every {interval:.3f} s for {outage_ns / 1e9:.1f} s)"
        else:
            known = "exposures at an unknown rate"
        timeout_s = self.config.capture.host_timeout_s
        after = (
            f"the device stops the capture by itself {timeout_s:g} s after it last heard from this recorder "
            "([capture] host_timeout_s)"
            if timeout_s
            else "the camera may still be shooting ([capture] host_timeout_s = 0: the device never stops by itself)"
        )
        detail = (
            f"capture stop not delivered ({exc}): the device was unreachable at the end and capturing; {known} "
            f"taken while unreachable are not in this log (unknown, device unreachable at the end); {after}; "
            "icgt recover-device --flight THIS_LOG fetches what its history still holds"
        )
        log.error("%s", detail)
        self.log_file.link_event("device", "unreachable_at_end", detail, now, taken, outage_ns)
        self.failure = self.failure or StopNotDeliveredError(
            f"the capture stop could not be delivered to the device ({exc}): it may still be capturing; "
            f"{known} are not in the log"
        )

    def _stop_control(self) -> None:
        if self.control is not None:
            with contextlib.suppress(Exception):
                self.control.stop()
            self.control = None

    def stop(self) -> None:
        """Stop capture if running, emit every pending frame, close the links and the log."""
        if self._stop.is_set():
            return
        self._stop.set()
        self._nudge.set()
        if self.device is not None:
            # The worker steps no more: the device reader reads the stream again (during the wait below)
            self.device.set_pumped(False)
        if self._capturing and self.device is not None:
            try:
                self.stop_capture()
            except IcgtError as exc:
                self._stop_not_delivered(exc)
        time.sleep(0.3)  # the last exposures' feedback and telemetry are still on their way
        if self._worker is not None and self._worker is not threading.current_thread():
            self._worker.join(timeout=3.0)
        if self.device is not None:
            self.device.time_sync_interval_s = None  # no exchange after the worker's last step
        with self._step():
            self._drain(limit=None)
            self._emit(self.sync.poll(time.monotonic_ns(), flush=True))
            self._take_sync_events()
        self._stop_control()
        if self.camera is not None:
            self.camera.stop()
        if self.mavlink is not None:
            self.mavlink.stop()
        if self.device is not None:
            self.device.stop()
        with self._step():
            self._drain(limit=None)  # what arrived while the links closed is still logged
            self._emit(self.sync.poll(time.monotonic_ns(), flush=True))
            self._take_sync_events()
            self._write_counters(time.monotonic_ns())
        self._record_link_summary()
        self._close_log()
        self._tuning.restore()
        if self._worker is None or not self._worker.is_alive():
            self._nudge.close()

    def wait(self) -> None:
        """Block until stop() is called or a fatal error (full disk) ends the recording."""
        while not self._stop.wait(0.5):
            pass

    def _close_log(self) -> None:
        failure = self.log_file.close()
        self.failure = self.failure or failure

    # ------------------------------------------------------------------ log
    @contextlib.contextmanager
    def _step(self) -> Iterator[None]:
        """One worker step (or stop()'s last drains): under the worker lock, its writes handed over at its end."""
        with self._worker_lock, self.log_file.batch():
            yield

    def _fatal(self, exc: IcgtError) -> None:
        if self.failure is None:
            self.failure = exc
            log.critical("recording stopped: %s", exc)
            threading.Thread(target=self.stop, name="icgt-stop", daemon=True).start()

    def _record_hello(self, hello: Hello) -> None:
        assert self.mcap is not None
        for name, values in device_metadata(hello, self.config.device.url, self.config.camera).items():
            self.mcap.add_metadata(name, values)
        log.info(
            "device: %s on %s, firmware %s, serial %s",
            board_name(hello.board),
            self.config.device.url,
            hello.firmware_version,
            hello.serial_number,
        )

    # ------------------------------------------------------------------ device
    def _configure_device(self) -> None:
        assert self.device is not None
        sensors = self.config.sensors
        for _ in range(3):  # at most: without the IMU, then without the LiDAR
            try:
                self.device.command(capture.configure_command(sensors, self._limits()))
                break
            except CommandRefusedError as exc:
                # Never record with the device's old settings: go on only without a sensor that does not
                # answer (said loudly), refuse to start otherwise.
                sensors = capture.configure_refused(sensors, exc.code, exc.detail, str(exc))
                log.warning("%s: recording without it", exc)
        self._sensors = sensors
        if self.config.device.set_rtc:
            try:
                self.device.command(SetTime(utc_us=time.time_ns() // 1000))
                log.info("device RTC set from the host clock")
            except CommandRefusedError as exc:
                log.warning("device RTC not set: %s", exc)

    def _device_received(self, received: DeviceReceived, rx_ns: int) -> None:
        """Into the inbox (any thread). An exposure record that the device reader read (it reads the whole
        stream while a TIME_SYNC answer is awaited) wakes the worker: its frame waits for the worker's next
        step otherwise, which the worker, finding nothing on the port, would not take before the base period."""
        self._inbox.append((_DEVICE, received, rx_ns))
        if received.message.NAME == "EXPOSURE" and threading.get_ident() != self._worker_ident:
            self._nudge.set()

    def _device_stopped_itself(self) -> None:
        """The device stopped this recording's capture by itself (its host went silent): nothing left to stop."""
        self._capturing = False
        if self.camera is not None:
            self.camera.set_capturing(False)

    # ------------------------------------------------------------------ capture commands
    def start_capture(self, interval_s: float | None = None, count: int = 0) -> None:
        """Start triggering: `count` 0 runs until stopped, 1 is a single shot, N stops after N.

        Raises CaptureRequestError (naming the limit) for a value the device would refuse, before
        anything is sent."""
        assert self.device is not None
        c = self._capture
        interval_s, count = capture.check_capture_request(interval_s, count, c.shutter_pulse_s)
        config = msgspec.structs.replace(self.config, sensors=self._sensors, capture=c)
        cmd, mode = capture.start_command(config, interval_s, count, self._limits())  # LimitError: nothing sent
        interval_us = cmd.interval_us
        self.device.command(cmd)
        self._capturing = count != 1
        self._capture_interval_s = interval_us / 1e6
        if self._capturing:  # the worker gives it to its step schedule (which is its own)
            self._cadence_hint = (self._cadence_hint[0] + 1, interval_us * 1000)
            self._nudge.set()  # its first exposure is a shutter lag away: the worker's eager steps start now
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

    def _set_capture(self, section: CaptureSection) -> None:
        """A ground station's capture settings (icgt.recorder.camera_settings): from the next capture start."""
        self._capture = section

    # camera component handler (CaptureHandler protocol)
    def _limits(self) -> BoardLimits:
        return for_board(self.hello.board if self.hello is not None else None)

    def _handler_result(self, action: Any) -> CommandResult | HandlerResult:
        try:
            action()
        except LimitError as exc:  # CaptureRequestError too
            log.warning("%s", exc)
            if self.mavlink is not None:
                capture.announce(self.mavlink, exc)
            return capture.denied(exc)
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
            LinkConfig(
                url=cfg.url,
                system_id=cfg.system_id,
                stream_rates=rates,
                decode_systems=self.mavlink_input.expanded_systems,
                signing_key=self._signing_key,
                udp_receive_buffer_bytes=cfg.udp_receive_buffer_bytes,
                service_period_s=_MAVLINK_SERVICE_PERIOD_S,
                owner_pumps=True,  # UDP: read by the worker's steps (_drain), see icgt.mavlink.link
            ),
            on_event=lambda event: self._inbox.append((_MAVLINK_EVENT, event, event.host_ns)),
            on_timesync_sent=lambda tx_ns: self._inbox.append((_TIMESYNC_SENT, tx_ns, tx_ns)),
        )
        self.mavlink.subscribe(self._mavlink_received, undecoded=self._mavlink_received)  # others: in bulk
        self.mavlink_input.link = self.mavlink
        self.mavlink.start()
        settings = capture_settings(
            lambda: self._capture,
            self._set_capture,
            lambda: msgspec.structs.replace(self.config, sensors=self._sensors),
            self._limits,
        )
        self.camera = build_camera(self.config, self.mavlink, _CaptureHandler(self), settings)  # logs its refusals
        self.camera.start()

    def _mavlink_received(self, rec: MavlinkMessage | UndecodedBatch) -> None:
        """Into the inbox (the worker's thread when it pumps the link, else the link's reader thread, which
        then wakes a worker that watches for the telemetry of an expected frame: `_input_fds`)."""
        self._inbox.append((_MAVLINK, rec, rec.rx_ns))
        self._nudge.thread_input()

    def _take_sync_events(self) -> None:
        for event in self.sync.take_events():
            self.mavlink_input.on_sync_event(event)

    # ------------------------------------------------------------------ frames
    def _emit(self, records: list[FrameRecord]) -> None:
        for rec in records:
            self._on_frame(rec)

    def _on_frame(self, rec: FrameRecord) -> None:
        self.frames += 1
        self.schedule.on_frame(rec.mid_host_ns)
        # The ground station waits for its CAMERA_IMAGE_CAPTURED: sent before the log's writes and the live views.
        image = self._images.publish(self.camera, rec) if self.camera is not None else None
        self._write(topics.FRAMES, rec, rec.mid_host_ns)
        self.views.on_frame(rec)
        if image is not None:
            self._write(layout.CAMERA_IMAGES, image, rec.mid_host_ns)

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        self._worker_ident = threading.get_ident()
        # The readers never wake the worker (no switch per message): it steps on its schedule (step_schedule),
        # and while a frame is expected (the schedule is watching) also when input arrives on the links it
        # reads itself (worker_wake), at most once per watch_min_gap_s.
        timing = self.schedule.timing
        wait_s = timing.period_s
        watch: list[int] = []
        hint_seen = 0
        while True:
            woke_on_input = self._nudge.wait(wait_s, watch, timing.watch_min_gap_s)
            self._nudge.clear()
            if self._stop.is_set():
                break
            try:
                hint = self._cadence_hint
                if hint[0] != hint_seen:
                    hint_seen = hint[0]
                    self.schedule.expect_interval(hint[1], time.monotonic_ns())
                with self._step():
                    read = self._drain(limit=_DRAIN_MAX)
                    now = time.monotonic_ns()
                    self._work_once(now)
                next_ns = self.schedule.next_step_ns(now, self.sync.pending_frames)
                wait_s = max(0.0, (next_ns - time.monotonic_ns()) / 1e9)
                # Input that woke the worker but that its pumps did not take (the device reader holds the port
                # while it awaits a TIME_SYNC answer) would wake it again at once: the timer only, this time.
                # (The thread-input signal cannot: the wait's clear() emptied it.)
                took = read or not woke_on_input or self._nudge.watch_thread_input
                self._nudge.watch_thread_input = False  # _input_fds sets it again while it watches for it
                watch = self._input_fds(self.sync.pending_frames > 0) if self.schedule.watching and took else []
            except Exception:  # the worker must outlive any bug: frames keep being emitted
                log.exception("recorder worker error (recording continues)")
                wait_s = timing.period_s
                watch = []
                self._nudge.watch_thread_input = False
        self._nudge.close()

    def _input_fds(self, exposure_in: bool) -> list[int]:
        """The descriptor of the link whose input the expected frame waits for: the device's port until its
        exposure record is in, then the MAVLink socket (a UDP link the worker pumps) for the telemetry after
        mid-exposure. One link at a time: each wake-up costs a step, and the other link's input alone cannot
        complete the frame (whatever it sent is read at that step anyway). A MAVLink link read by its own
        thread (serial, TCP) hands its messages over through the wake's thread-input signal instead."""
        link = self.mavlink if exposure_in else self.device
        threaded = exposure_in and self.mavlink is not None and self.mavlink.running and not self.mavlink.pumped
        self._nudge.watch_thread_input = threaded
        if threaded:
            return [self._nudge.thread_input_fd]
        fd = link.readable_fd if link is not None else None
        return [] if fd is None else [fd]

    def _schedule_time_sync(self) -> None:
        """The device reader sends the TIME_SYNC requests (DeviceLink.time_sync_interval_s: one wake-up per
        exchange) at the rate the clock filter asks for, set again at every step (fast until settled, and
        after a reboot or a gap; dithered)."""
        if self.device is not None and not self._stop.is_set():
            self.device.time_sync_interval_s = self.sync.next_exchange_interval_s()

    def _drain(self, limit: int | None) -> int:
        """What arrived since the last step, into the inbox (the links this thread reads, see the module doc),
        then handled; returns what the pumps read (bytes and datagrams: 0 when nothing)."""
        read = 0
        if self.device is not None:
            read += self.device.pump()
        if self.mavlink is not None:
            read += self.mavlink.pump()
        inbox = self._inbox
        n = 0
        while inbox and (limit is None or n < limit):
            self._handle(inbox.popleft())
            n += 1
        if self.mavlink_input.holds_other_systems:
            self.mavlink_input.flush_other_systems()
        return read

    def _handle(self, item: tuple[int, Any, int]) -> None:
        kind, payload, rx_ns = item
        if kind == _DEVICE:
            self.device_input.on_message(payload, rx_ns)
        elif kind == _MAVLINK:
            self.mavlink_input.on_message(payload)
        elif kind == _EXCHANGE:
            self.device_input.on_time_sync(payload)
        elif kind == _TIMESYNC_SENT:
            self.mavlink_input.on_timesync_sent(payload)
        elif kind == _DEVICE_EVENT:
            self.device_input.on_link_event(payload)
        elif kind == _MAVLINK_EVENT:
            self.mavlink_input.on_event(payload)

    def _work_once(self, now: int) -> None:
        self._emit(self.sync.poll(now))
        self._take_sync_events()
        if now >= self._next_clock_log_ns:
            self._next_clock_log_ns = now + 1_000_000_000
            sync = self.sync
            device_est = sync.device_clock.estimate()
            self._write(layout.CLOCK_DEVICE, device_est.to_dict(), now)
            self._write(layout.CLOCK_AUTOPILOT, sync.autopilot_clock.estimate().to_dict(), now)
            self._write(layout.CLOCK_UTC, sync.utc.host_to_utc(now).to_dict() | {"host_ns": now}, now)
            self._write_counters(now)
            self._heap_trimmer.maybe_trim(now)
            self._snapshot = {
                "device_clock_settled": sync.device_clock.settled,
                "device_clock_uncertainty_us": device_est.uncertainty_ns / 1000.0 if device_est.valid else None,
                "pending_frames": sync.pending_frames,
                "sync": sync.counters(),
            }
        self._schedule_time_sync()

    def _write_counters(self, now: int) -> None:
        record: dict[str, Any] = {"host_ns": now, "sync": self.sync.counters()}
        if self.device is not None:
            record["device"] = {k: v for k, v in self.device.decoder_stats.items() if v is not None}
            record["device"] |= self.device.resend.counter_dict()
        if self.mavlink is not None:
            stats = asdict(self.mavlink.stats())
            stats.pop("messages_by_type", None)
            record["mavlink"] = stats
        if self.camera is not None:
            record["camera"] = self.camera.counters
        self._write(layout.COUNTERS, record, now)

    def _record_link_summary(self) -> None:
        origin = self.sync.geotagger.origin
        if origin is not None and self.mcap is not None:
            with contextlib.suppress(RecordingError):
                self.mcap.add_metadata(
                    layout.META_ENU_ORIGIN,
                    {
                        "lat_deg": repr(origin[0]),
                        "lon_deg": repr(origin[1]),
                        "alt_msl_m": repr(origin[2]),
                        "note": "origin of the frames' east/north/up: the first usable fix (or the configured origin)",
                    },
                )
        if self.device is None:
            return
        stats = self.device.decoder_stats | self.device.resend.counter_dict()
        log.info(
            "device link summary: %s frames, %s rejected, %s messages missing in %s gaps, %s recovered by RESEND; "
            "lost: %s exposures, %s PPS, %s samples, %s status/replies/logs, %s unknown",
            stats.get("frames_ok"),
            self.device.frames_rejected,
            stats.get("seq_missed"),
            stats.get("seq_gaps"),
            stats.get("resend_recovered"),
            stats.get("lost_exposures"),
            stats.get("lost_pps"),
            stats.get("lost_samples"),
            stats.get("lost_other"),
            stats.get("lost_unknown"),
        )
        if self.mcap is not None:
            with contextlib.suppress(RecordingError):
                self.mcap.add_metadata(layout.META_DEVICE_LINK, {k: str(v) for k, v in stats.items()})

    # ------------------------------------------------------------------ control socket
    def status(self) -> RecorderStatus:
        """What the recorder knows now (the synchroniser's part as of its last second: it runs on the worker)."""
        snap = self._snapshot
        stats = self.device.decoder_stats if self.device is not None else {}
        last = self.sync.last_status
        return RecorderStatus(
            file=str(self.mcap.path) if self.mcap is not None else "",
            capturing=self._capturing,
            frames=self.frames,
            exposures=self.exposures,
            device_connected=self.device is not None and self.device.connected and not self._waiting_for_device,
            waiting_for_device=self._waiting_for_device,
            # the synchroniser's account of the autopilot (waiting / up / lost), not a second one of the link's
            autopilot=self.sync.autopilot.state.value if self.mavlink is not None else "none",
            device_clock_settled=bool(snap.get("device_clock_settled", False)),
            device_clock_uncertainty_us=snap.get("device_clock_uncertainty_us"),
            sequence_gaps=int(stats.get("seq_gaps") or 0),
            messages_lost=int(stats.get("seq_missed") or 0),
            frames_rejected=self.device.frames_rejected if self.device is not None else 0,
            pending_frames=int(snap.get("pending_frames", 0)),
            last_status=asdict(last) if last is not None else None,
            timesync=_timesync_status(snap.get("sync", {})),
            frames_recovered=self.device.resend.counters.recovered if self.device is not None else 0,
            lost_exposures=self.device.resend.counters.lost_exposures if self.device is not None else 0,
        )

    def _handle_control(self, request: Request) -> Reply:
        command = request.get("command")
        if command == "status":
            return {"ok": True, "status": asdict(self.status())}
        if command in ("start", "stop") and not _wait_clear(self._starting, CONTROL_READY_WAIT_S):
            # The control socket is up while the recorder still waits for, or configures, the device: a capture
            # started then would make the device refuse its CONFIGURE (busy capturing) and fail the start.
            what = "waiting for the device" if self._waiting_for_device else "connecting and configuring"
            return {"error": f"the recorder is still starting ({what}): {command} not done; try again once "
                    "`icgt status` answers with the recording"}  # fmt: skip
        if command == "start":
            self.start_capture(request.get("interval_s"), request.get("count", 0))
            return {"ok": True}
        if command == "stop":
            self.stop_capture()
            return {"ok": True}
        return {"error": f"unknown command {command!r} (start, stop, status)"}


CONTROL_READY_WAIT_S = 4.0  # how long a start/stop on the control socket waits for a recorder still starting [s]


def _wait_clear(flag: threading.Event, timeout_s: float) -> bool:
    """True once `flag` is clear (within timeout_s)."""
    deadline = time.monotonic() + timeout_s
    while flag.is_set():
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.02)
    return True


class StopNotDeliveredError(IcgtError):
    """The recording ended with capture running on a device the recorder could not reach to stop it."""


def _output_dir(path: Path) -> Path:
    """The recordings folder, created if needed; RecordingError saying what is wrong with it otherwise."""
    if path.exists() and not path.is_dir():
        raise RecordingError(f"--out {path}: exists and is not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecordingError(f"--out {path}: cannot create the folder: {exc.strerror or exc}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise RecordingError(f"--out {path}: no permission to write in it")
    return path


def _timesync_status(counters: dict[str, int]) -> str:
    """`icgt status`'s word on the autopilot clock: answered, unanswered or not asked yet."""
    sent = counters.get("timesync_sent", 0)
    answered = counters.get("timesync_answered", 0)
    if sent == 0:
        return "not asked yet"
    if answered == 0:
        return f"unanswered ({counters.get('timesync_unanswered', 0)} of {sent} requests)"
    return f"answered ({answered} of {sent} requests)"


class _CaptureHandler:
    """The camera component's CaptureHandler: ground-station commands become device commands."""

    def __init__(self, recorder: Recorder) -> None:
        self._r = recorder

    def start(self, interval_s: float, count: int) -> CommandResult | HandlerResult:
        # MAV_CMD_IMAGE_START_CAPTURE: interval 0 asks for the camera's own (the configured one).
        interval = None if interval_s == 0 else interval_s
        return self._r._handler_result(lambda: self._r.start_capture(interval, count))

    def stop(self) -> CommandResult | HandlerResult:
        return self._r._handler_result(self._r.stop_capture)

    def shoot(self) -> CommandResult | HandlerResult:
        return self._r._handler_result(lambda: self._r.start_capture(None, 1))
