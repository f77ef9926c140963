"""The recorder as a MAVLink camera (Camera Protocol v2) that a ground station can drive.

`CameraComponent` runs on a `MavlinkLink` whose source ids are (vehicle system id, 100): it sends
HEARTBEAT (MAV_TYPE_CAMERA, MAV_AUTOPILOT_INVALID) at 1 Hz, answers the information requests (both
MAV_CMD_REQUEST_MESSAGE and the older MAV_CMD_REQUEST_CAMERA_INFORMATION / _CAMERA_SETTINGS /
_STORAGE_INFORMATION / _CAMERA_CAPTURE_STATUS / _CAMERA_IMAGE_CAPTURE that QGroundControl 4.x sends),
executes IMAGE_START_CAPTURE / IMAGE_STOP_CAPTURE / DO_DIGICAM_CONTROL through the recorder's
`CaptureHandler`, answers every command it acts on with COMMAND_ACK, reports CAMERA_CAPTURE_STATUS on
change and at ``status_hz`` (1 Hz; idle too: MAVSDK's list_photos waits for one), and sends
CAMERA_IMAGE_CAPTURED for each exposure (`publish_image_captured`), keeping every image for re-requests.

Threads: the link's reader only filters, refuses and enqueues (``on_rejected`` runs there: it must not
block); one worker thread ("icgt-camera") runs the handler, sends the replies and the periodic messages
(``on_command`` runs there). A slow handler delays only the ACK; a ground station that
re-sends meanwhile is recognised as a retransmission (see below) and not executed twice.

Who may command it: COMMAND_LONG / COMMAND_INT must target our system (or 0) and our component (or 0,
broadcast); others are not for us and ignored silently. With a signing key on the link
(``require_signing``), a command without a valid signature (unsigned, another key, replayed) is not
trusted: no answer at all, counted and logged (rate-limited). A command from a system outside
``ground_station_systems`` and the autopilot's system is answered COMMAND_ACK DENIED (at most
``refusal_ack_hz`` such answers per second), counted and logged (one line per ``log_period_s`` with the
counts). These checks run on the link's reader and never queue, so a flood of refused commands does not
delay a legitimate one. A command that finds the queue full (``command_queue``) is answered
MAV_RESULT_TEMPORARILY_REJECTED (same rate limit) and counted. Broadcast commands we do not implement (MAVProxy's
GET_HOME_POSITION to component 0 every few seconds) get no ACK (the component they concern answers), no
command record and one debug line per command for the whole run; they are counted (``broadcasts_ignored``).
Targeted ones get MAV_RESULT_UNSUPPORTED.

Duplicates: a command is executed once however often it is transmitted. A retransmission is a command
with confirmation > 0 (the command protocol's rule), or one with the same capture sequence number
(IMAGE_START_CAPTURE single shot, param4 > 0; DO_DIGICAM_CONTROL command identity, param6 > 0) from the
same sender within ``retransmit_window_s`` of the first (for clients that resend without counting
confirmation). It gets the first ACK again, not a second photo. A first transmission (confirmation 0)
that reuses a sequence number after that window is a new command (a ground station that restarted, or a
second client with the same ids, counts from 1 again) and is executed.

Settings: with ``CameraConfig.settings``, CAMERA_INFORMATION names a camera definition file served over
MAVLink FTP and the parameters are read and set with PARAM_EXT (`icgt.mavlink.camera_settings`); those
messages are handled on the worker too.

Images: see `icgt.mavlink.camera_images` (indices, the poor-pose policy, history, re-requests of one, a
range or all images, sent paced at ``resend_rate_hz``).

This module is the composition: the intake on the link's reader (`icgt.mavlink.camera_intake`), the
command records and their dedupe (`icgt.mavlink.camera_commands`), what each command does
(`icgt.mavlink.camera_dispatch`), the capture state (`icgt.mavlink.camera_status`) and the messages it
sends (`icgt.mavlink.camera_messages`), with the worker thread and the public API here.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable

from icgt.mavlink.camera_clients import ClientTracker
from icgt.mavlink.camera_commanded import ShotPairing
from icgt.mavlink.camera_commands import Command, Outcome, RecentCommands, dedupe_keys
from icgt.mavlink.camera_dispatch import CommandDispatcher, InformationSenders
from icgt.mavlink.camera_images import CameraError, CapturedImage, ImageHistory, encode_image_captured
from icgt.mavlink.camera_intake import CommandIntake
from icgt.mavlink.camera_messages import CameraMessages
from icgt.mavlink.camera_settings import SETTINGS_MESSAGES, SettingsService
from icgt.mavlink.camera_status import IMAGE_STATUS_IDLE, IMAGE_STATUS_INTERVAL_CAPTURING, CaptureState
from icgt.mavlink.camera_types import (
    CameraConfig,
    CameraInfo,
    CaptureHandler,
    CaptureStatus,
    CommandRecord,
    CommandResult,
    HandlerResult,
    RejectedCommand,
)
from icgt.mavlink.link import MavlinkLink, MavlinkMessage, Subscription, mavlink2

__all__ = [
    "CameraComponent",
    "CameraConfig",
    "CameraError",
    "CameraInfo",
    "CaptureHandler",
    "CaptureStatus",
    "CapturedImage",
    "CommandRecord",
    "CommandResult",
    "HandlerResult",
    "RejectedCommand",
]

log = logging.getLogger(__name__)

_WAKE = object()


class CameraComponent:
    """MAVLink Camera Protocol v2 on top of a `MavlinkLink` (which the caller starts and stops)."""

    def __init__(
        self,
        link: MavlinkLink,
        config: CameraConfig,
        handler: CaptureHandler,
        *,
        on_rejected: Callable[[RejectedCommand], None] | None = None,
        on_command: Callable[[CommandRecord], None] | None = None,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        self.link = link
        self.config = config
        self.handler = handler
        self._on_command = on_command
        self._clock = clock
        self._boot_ns = clock()
        self._component = link.config.component_id
        ap = config.autopilot_system if config.autopilot_system is not None else link.config.effective_autopilot_system
        self._allowed = frozenset(config.ground_station_systems) | {ap}
        self._queue: queue.Queue[object] = queue.Queue(maxsize=config.command_queue)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sub: Subscription | None = None
        self._lock = threading.Lock()
        # capture state (icgt.mavlink.camera_status)
        self._status = CaptureState()
        self.images = ImageHistory()
        self._resend: deque[range] = deque()  # re-requested images still to send (worker only)
        self._resend_period_ns = int(1e9 / max(config.resend_rate_hz, 1e-3))
        # which images each ground station may have missed (away, restarted): icgt.mavlink.camera_clients
        self.clients = ClientTracker(gap_s=config.client_gap_s, push_delay_s=config.client_push_delay_s)
        self._ground_stations = frozenset(config.ground_station_systems) - {ap}
        self._hb_sub: Subscription | None = None
        # executed commands by key: icgt.mavlink.camera_commands
        self._recent = RecentCommands()
        self.pairing = ShotPairing()  # PX4 asks for one shot twice (icgt.mavlink.camera_commanded)
        if config.require_signing and link.signing is None:
            raise CameraError("require_signing needs a link with a signing key (LinkConfig.signing_key)")
        # the reader side: filtering, refusals (counted, logged throttled, answered at most refusal_ack_hz)
        self.intake = CommandIntake(
            link,
            config,
            self._queue,
            self._lock,
            self.clients,
            allowed=self._allowed,
            ground_stations=self._ground_stations,
            on_rejected=on_rejected,
        )
        self._ignored_seen: set[tuple[int, int]] = set()
        # settings (definition file over MAVLink FTP, PARAM_EXT values): icgt.mavlink.camera_settings
        self.settings: SettingsService | None = None
        if config.settings is not None:
            self.settings = SettingsService(
                link,
                config.settings,
                model=config.info.model,
                vendor=config.info.vendor,
                allowed_systems=self._allowed,
                require_signing=config.require_signing,
            )
        self._settings_sub: Subscription | None = None
        # the replies and informational messages (icgt.mavlink.camera_messages) and what each command does
        # (icgt.mavlink.camera_dispatch)
        self.messages = CameraMessages(link.mav, config, self.time_boot_ms)
        senders = InformationSenders(
            self._send_camera_information,
            self._send_camera_settings,
            self._send_storage_information,
            self._send_capture_status,
        )
        self.dispatcher = CommandDispatcher(
            handler,
            self._status,
            self._lock,
            self.images,
            self.clients,
            self._resend,
            senders,
            component=self._component,
        )

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self._thread is not None:
            raise CameraError("camera component already started")
        self._stop.clear()
        self._sub = self.link.subscribe(self.intake.on_message, ("COMMAND_LONG", "COMMAND_INT"))
        self._hb_sub = self.link.subscribe(self._on_heartbeat, ("HEARTBEAT",))
        if self.settings is not None:
            self._settings_sub = self.link.subscribe(self._on_settings_message, SETTINGS_MESSAGES)
        self._thread = threading.Thread(target=self._worker, name="icgt-camera", daemon=True)
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        for sub in (self._sub, self._hb_sub, self._settings_sub):
            if sub is not None:
                self.link.unsubscribe(sub)
        self._sub = self._hb_sub = self._settings_sub = None
        self._stop.set()
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(_WAKE)
        if self._thread is not None:
            self._thread.join(timeout_s)
            self._thread = None
        for throttled in self.intake.throttled_logs:
            throttled.flush()

    def __enter__(self) -> CameraComponent:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ public API
    def time_boot_ms(self, host_ns: int | None = None) -> int:
        """The component's boot clock (ms since it was created) at ``host_ns`` (default now), as uint32."""
        t = self._clock() if host_ns is None else host_ns
        return max(0, (t - self._boot_ns) // 1_000_000) & 0xFFFFFFFF

    @property
    def capture_status(self) -> CaptureStatus:
        with self._lock:
            return CaptureStatus(self._status.image_status, self._status.interval_s, len(self.images))

    @property
    def counters(self) -> dict[str, int]:
        """Refusals by kind (see ``counts`` in `CommandIntake.__init__`) and the images published."""
        with self._lock:
            settings = self.settings.counters if self.settings is not None else {}
            return {**self.intake.counts, **self.clients.counts, **settings, "images": len(self.images)}

    def set_capturing(self, capturing: bool, interval_s: float = 0.0) -> None:
        """The recorder reports a capture state change the camera did not cause (e.g. it stopped itself)."""
        with self._lock:
            status = IMAGE_STATUS_INTERVAL_CAPTURING if capturing else IMAGE_STATUS_IDLE
            self._status.set_locked(status, interval_s if capturing else 0.0)
        self._wake()

    def publish_image_captured(self, image: CapturedImage) -> CapturedImage:
        """Give one exposure the next image index, keep it for re-requests and send CAMERA_IMAGE_CAPTURED.
        Thread-safe. Returns the image with its index (sent or not: a send failure is counted by the link).

        Raises CameraError for values MAVLink cannot carry (the image then gets no index)."""
        encode_image_captured(self.link.mav, image)  # checks the values before an index is spent
        with self._lock:
            indexed = self.images.append(image)
            self._status.image_published_locked()
        if self._status.dirty:
            self._wake()
        self.link.send(encode_image_captured(self.link.mav, indexed))
        self.clients.published(indexed.image_index, self._clock())
        return indexed

    # ------------------------------------------------------------------ reader side (must not block)
    def _on_heartbeat(self, rec: MavlinkMessage) -> None:
        if rec.src_system in self._ground_stations:
            self.clients.heard((rec.src_system, rec.src_component), rec.rx_ns)

    def _on_settings_message(self, rec: MavlinkMessage) -> None:
        """FTP and PARAM_EXT messages for this component: handled on the worker (a full queue drops one; the
        client asks again)."""
        service = self.settings
        if service is not None and service.for_us(rec):
            with contextlib.suppress(queue.Full):
                self._queue.put_nowait(lambda: service.handle(rec))

    def _wake(self) -> None:
        with contextlib.suppress(queue.Full):
            self._queue.put_nowait(_WAKE)

    # ------------------------------------------------------------------ worker thread
    def _worker(self) -> None:
        hb_period = int(1e9 / max(self.config.heartbeat_hz, 1e-3))
        status_period = int(1e9 / max(self.config.status_hz, 1e-3))
        next_hb = self._clock()
        next_status = next_hb
        next_resend = next_hb
        while not self._stop.is_set():
            now = self._clock()
            with self._lock:
                dirty = self._status.dirty
            try:
                if now >= next_hb:
                    self._send_heartbeat()
                    next_hb = now + hb_period
                if dirty or now >= next_status:  # idle too: MAVSDK lists photos only once it has a status
                    self._send_capture_status()
                    next_status = now + status_period
            except Exception:
                log.exception("camera periodic message failed")
            for throttled in self.intake.throttled_logs:
                throttled.tick(now)
            self._resend.extend(self.clients.due(now))
            if self._resend and now >= next_resend:
                self._resend_one()
                next_resend = now + self._resend_period_ns
            deadline = min(next_hb, next_status)
            push_ns = self.clients.next_due_ns()
            if push_ns is not None:
                deadline = min(deadline, push_ns)
            if self._resend:
                deadline = min(deadline, next_resend)
            wait_s = min(max(0.0, (deadline - self._clock()) / 1e9), 0.5)
            try:
                item = self._queue.get(timeout=wait_s) if wait_s > 0 else self._queue.get_nowait()
            except queue.Empty:
                continue
            try:
                if isinstance(item, Command):
                    self._execute(item)
                elif callable(item):
                    item()
            except Exception:
                log.exception("camera command handling failed")

    def _resend_one(self) -> None:
        span = self._resend[0]
        image = self.images.get(span.start)
        rest = span[1:]
        if len(rest):
            self._resend[0] = rest
        else:
            self._resend.popleft()
        if image is not None:
            self.link.send(encode_image_captured(self.link.mav, image))

    def _execute(self, cmd: Command) -> None:
        now = self._clock()
        self._recent.expire(now)
        lookup, record = dedupe_keys(cmd)
        retransmit_ns = int(self.config.retransmit_window_s * 1e9)
        outcome = self._recent.duplicate(cmd, lookup, retransmit_ns)
        duplicate = outcome is not None
        if outcome is None:
            args = (cmd.rx_ns, cmd.src_system, cmd.src_component, cmd.command)
            paired = self.pairing.match(*args, cmd.confirmation, cmd.params)
            outcome = Outcome(int(CommandResult.ACCEPTED), reason=paired) if paired else self.dispatcher.dispatch(cmd)
            if not paired and outcome.result == CommandResult.ACCEPTED:
                self.pairing.taken(*args, cmd.params)
            if record and outcome.result is not None:
                expires = now + int(self.config.dedupe_window_s * 1e9)
                self._recent.remember(record, cmd.rx_ns, expires, outcome)
        if outcome.result is not None:
            self._send_ack(cmd, outcome)
        if outcome.after is not None:
            outcome.after()
        if self._status.dirty:
            self._send_capture_status()
        if outcome.result is None:
            self._ignored_broadcast(cmd, outcome)
            return
        log.info(
            "command %d from %d:%d params %s -> %s%s %s",
            cmd.command,
            cmd.src_system,
            cmd.src_component,
            [round(p, 3) for p in cmd.params],
            outcome.result,
            " (duplicate, not executed)" if duplicate else "",
            outcome.reason,
        )
        if self._on_command is not None:
            record_ = CommandRecord(
                cmd.rx_ns,
                cmd.src_system,
                cmd.src_component,
                cmd.command,
                cmd.params,
                outcome.result,
                duplicate,
                outcome.reason,
            )
            try:
                self._on_command(record_)
            except Exception:
                log.exception("on_command callback raised")

    def _ignored_broadcast(self, cmd: Command, outcome: Outcome) -> None:
        """A broadcast command (or message request) this camera does not implement: not ours to answer (the
        command protocol: only the component it concerns ACKs a broadcast), so no ACK, no record and no log
        line but one debug line per command (and requested message) for the whole run; counted."""
        key = (cmd.command, int(cmd.params[0]) if cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE else 0)
        with self._lock:
            self.intake.counts["broadcasts_ignored"] += 1
            first = key not in self._ignored_seen
            self._ignored_seen.add(key)
        if first:
            log.debug(
                "broadcast command %d from %d:%d ignored (%s); further ones silently",
                cmd.command,
                cmd.src_system,
                cmd.src_component,
                outcome.reason,
            )

    # ------------------------------------------------------------------ messages (icgt.mavlink.camera_messages)
    def _send_ack(self, cmd: Command, outcome: Outcome) -> None:
        self.link.send(self.messages.ack(cmd, outcome))

    def _send_heartbeat(self) -> None:
        with self._lock:
            capturing = self._status.image_status != IMAGE_STATUS_IDLE
        self.link.send(self.messages.heartbeat(capturing))

    def _send_camera_information(self) -> None:
        info = self.config.info
        uri, version = info.cam_definition_uri, info.cam_definition_version
        if self.settings is not None:
            uri, version = self.settings.uri, self.settings.version
        self.link.send(self.messages.camera_information(uri, version))

    def _send_camera_settings(self) -> None:
        self.link.send(self.messages.camera_settings())

    def _send_storage_information(self) -> None:
        self.link.send(self.messages.storage_information())

    def _send_capture_status(self) -> None:
        with self._lock:
            status, interval, count = self._status.image_status, self._status.interval_s, len(self.images)
            self._status.dirty = False
        self.link.send(self.messages.capture_status(status, interval, count))
