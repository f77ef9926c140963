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
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import queue
import shutil
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from pathlib import Path

from icgt.mavlink.camera_clients import ClientTracker, is_unspecified_image_request
from icgt.mavlink.camera_commanded import ShotPairing
from icgt.mavlink.camera_images import CameraError, CapturedImage, ImageHistory, encode_image_captured, image_range
from icgt.mavlink.camera_settings import SETTINGS_MESSAGES, SettingsService
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
from icgt.mavlink.ratelimit import ThrottledLog, TokenBucket
from icgt.mavlink.signing import frame_has_signature

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

_MIB = 1024 * 1024
IMAGE_STATUS_IDLE = 0
IMAGE_STATUS_CAPTURING = 1
IMAGE_STATUS_INTERVAL_IDLE = 2
IMAGE_STATUS_INTERVAL_CAPTURING = 3


@dataclasses.dataclass(frozen=True, slots=True)
class _Command:
    rx_ns: int
    src_system: int
    src_component: int
    command: int
    confirmation: int
    params: tuple[float, float, float, float, float, float, float]
    broadcast: bool


@dataclasses.dataclass(frozen=True, slots=True)
class _Outcome:
    result: int | None
    progress: int = 0
    result_param2: int = 0
    reason: str = ""
    after: Callable[[], None] | None = None  # runs after the ACK (the requested message follows it)


_WAKE = object()


def _fixed_bytes(text: str, size: int) -> list[int]:
    raw = text.encode("utf-8")[:size]
    return list(raw.ljust(size, b"\0"))


def _truncate_utf8(text: str, size: int) -> bytes:
    return text.encode("utf-8")[:size].decode("utf-8", errors="ignore").encode("utf-8")


def _command_params(rec: MavlinkMessage) -> tuple[tuple[float, float, float, float, float, float, float], int]:
    msg = rec.msg
    if rec.type == "COMMAND_INT":
        return (
            float(msg.param1),
            float(msg.param2),
            float(msg.param3),
            float(msg.param4),
            float(msg.x),
            float(msg.y),
            float(msg.z),
        ), 0
    return (
        float(msg.param1),
        float(msg.param2),
        float(msg.param3),
        float(msg.param4),
        float(msg.param5),
        float(msg.param6),
        float(msg.param7),
    ), int(msg.confirmation)


def _disk_mib(path: Path) -> tuple[float, float, float] | None:
    """(total, used, free) MiB of the file system holding ``path`` (or its nearest existing parent)."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        usage = shutil.disk_usage(probe)
    except OSError:
        return None
    return usage.total / _MIB, usage.used / _MIB, usage.free / _MIB


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
        self._on_rejected = on_rejected
        self._on_command = on_command
        self._clock = clock
        self._boot_ns = clock()
        self._system = link.config.system_id
        self._component = link.config.component_id
        ap = config.autopilot_system if config.autopilot_system is not None else link.config.effective_autopilot_system
        self._allowed = frozenset(config.ground_station_systems) | {ap}
        self._queue: queue.Queue[object] = queue.Queue(maxsize=config.command_queue)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sub: Subscription | None = None
        self._lock = threading.Lock()
        # capture state
        self._image_status = IMAGE_STATUS_IDLE
        self._interval_s = 0.0
        self._count_target = 0
        self._images_since_start = 0
        self._status_dirty = False
        self.images = ImageHistory()
        self._resend: deque[range] = deque()  # re-requested images still to send (worker only)
        self._resend_period_ns = int(1e9 / max(config.resend_rate_hz, 1e-3))
        # which images each ground station may have missed (away, restarted): icgt.mavlink.camera_clients
        self.clients = ClientTracker(gap_s=config.client_gap_s, push_delay_s=config.client_push_delay_s)
        self._ground_stations = frozenset(config.ground_station_systems) - {ap}
        self._hb_sub: Subscription | None = None
        # executed commands by key: (first receipt, expiry, outcome)
        self._recent: OrderedDict[tuple[object, ...], tuple[int, int, _Outcome]] = OrderedDict()
        self.pairing = ShotPairing()  # PX4 asks for one shot twice (icgt.mavlink.camera_commanded)
        if config.require_signing and link.signing is None:
            raise CameraError("require_signing needs a link with a signing key (LinkConfig.signing_key)")
        # refusals: counted here, logged throttled, answered at most refusal_ack_hz
        self._refusal_acks = TokenBucket(config.refusal_ack_hz, max(1, int(config.refusal_ack_hz)))
        period = config.log_period_s
        self._log_untrusted = ThrottledLog(log, "ignored commands without a valid signature", period_s=period)
        self._log_denied = ThrottledLog(
            log, "denied commands from systems not in [mavlink] ground_station_systems", period_s=period
        )
        self._log_overflow = ThrottledLog(log, "commands refused, camera queue full", period_s=period)
        self._counts = {
            "rejected_commands": 0,  # every command addressed to us that was not executed
            "denied_systems": 0,  # ... from a system that may not command the camera (ACK DENIED)
            "unsigned_commands": 0,  # ... without a signature while signing is required (no ACK)
            "badly_signed_commands": 0,  # ... with a signature that is not valid (no ACK)
            "queue_overflows": 0,  # ... that found the queue full (ACK TEMPORARILY_REJECTED)
            "refusal_acks_sent": 0,
            "refusal_acks_suppressed": 0,  # refusals past the rate limit: counted, not answered
            "broadcasts_ignored": 0,  # broadcast commands this camera does not implement (no ACK, not an error)
        }
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

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        if self._thread is not None:
            raise CameraError("camera component already started")
        self._stop.clear()
        self._sub = self.link.subscribe(self._on_message, ("COMMAND_LONG", "COMMAND_INT"))
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
        for throttled in (self._log_untrusted, self._log_denied, self._log_overflow):
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
            return CaptureStatus(self._image_status, self._interval_s, len(self.images))

    @property
    def counters(self) -> dict[str, int]:
        """Refusals by kind (see ``_counts`` in __init__) and the images published."""
        with self._lock:
            settings = self.settings.counters if self.settings is not None else {}
            return {**self._counts, **self.clients.counts, **settings, "images": len(self.images)}

    def set_capturing(self, capturing: bool, interval_s: float = 0.0) -> None:
        """The recorder reports a capture state change the camera did not cause (e.g. it stopped itself)."""
        with self._lock:
            status = IMAGE_STATUS_INTERVAL_CAPTURING if capturing else IMAGE_STATUS_IDLE
            self._set_status_locked(status, interval_s if capturing else 0.0)
        self._wake()

    def publish_image_captured(self, image: CapturedImage) -> CapturedImage:
        """Give one exposure the next image index, keep it for re-requests and send CAMERA_IMAGE_CAPTURED.
        Thread-safe. Returns the image with its index (sent or not: a send failure is counted by the link).

        Raises CameraError for values MAVLink cannot carry (the image then gets no index)."""
        encode_image_captured(self.link.mav, image)  # checks the values before an index is spent
        with self._lock:
            indexed = self.images.append(image)
            if self._image_status == IMAGE_STATUS_INTERVAL_CAPTURING and self._count_target > 0:
                self._images_since_start += 1
                if self._images_since_start >= self._count_target:
                    self._set_status_locked(IMAGE_STATUS_IDLE, 0.0)
        if self._status_dirty:
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

    def _on_message(self, rec: MavlinkMessage) -> None:
        msg = rec.msg
        target_sys, target_comp = int(msg.target_system), int(msg.target_component)
        if target_sys not in (0, self._system) or target_comp not in (0, self._component):
            return
        command = int(msg.command)
        if self.config.require_signing and not msg.get_signed():
            badly = frame_has_signature(msg)
            kind = "badly_signed_commands" if badly else "unsigned_commands"
            why = "an invalid signature (another key, or replayed)" if badly else "no signature"
            reason = f"command {command} from {rec.src_system}:{rec.src_component} has {why}"
            self._refused(rec, command, kind, reason, self._log_untrusted, None)
            return
        if rec.src_system not in self._allowed:
            reason = (
                f"command {command} from system {rec.src_system} (component {rec.src_component}): not an allowed "
                f"ground station {sorted(self.config.ground_station_systems)} or the autopilot; add "
                f"{rec.src_system} to [mavlink] ground_station_systems to let it command the camera"
            )
            self._refused(rec, command, "denied_systems", reason, self._log_denied, CommandResult.DENIED)
            return
        if rec.src_system in self._ground_stations:
            self.clients.heard((rec.src_system, rec.src_component), rec.rx_ns)
        params, confirmation = _command_params(rec)
        item = _Command(rec.rx_ns, rec.src_system, rec.src_component, command, confirmation, params, target_comp == 0)
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            reason = f"command {command} from {rec.src_system}:{rec.src_component}: queue of {self._queue.maxsize} full"
            self._refused(
                rec, command, "queue_overflows", reason, self._log_overflow, CommandResult.TEMPORARILY_REJECTED
            )

    def _refused(
        self,
        rec: MavlinkMessage,
        command: int,
        kind: str,
        reason: str,
        throttled: ThrottledLog,
        answer: CommandResult | None,
    ) -> None:
        """Count, log (throttled), answer (rate-limited; None: not at all) a command we do not execute."""
        ack = answer is not None and self._refusal_acks.allow(rec.rx_ns)
        with self._lock:
            self._counts["rejected_commands"] += 1
            self._counts[kind] += 1
            if answer is not None:
                self._counts["refusal_acks_sent" if ack else "refusal_acks_suppressed"] += 1
        throttled.report(rec.rx_ns, reason)
        if ack and answer is not None:
            self.link.send(
                self.link.mav.command_ack_encode(command, int(answer), 0, 0, rec.src_system, rec.src_component)
            )
        if self._on_rejected is not None:
            try:
                self._on_rejected(RejectedCommand(rec.rx_ns, rec.src_system, rec.src_component, command, reason))
            except Exception:
                log.exception("on_rejected callback raised")

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
                dirty = self._status_dirty
            try:
                if now >= next_hb:
                    self._send_heartbeat()
                    next_hb = now + hb_period
                if dirty or now >= next_status:  # idle too: MAVSDK lists photos only once it has a status
                    self._send_capture_status()
                    next_status = now + status_period
            except Exception:
                log.exception("camera periodic message failed")
            for throttled in (self._log_untrusted, self._log_denied, self._log_overflow):
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
                if isinstance(item, _Command):
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

    def _execute(self, cmd: _Command) -> None:
        now = self._clock()
        self._expire_recent(now)
        lookup, record = self._dedupe_keys(cmd)
        outcome: _Outcome | None = None
        duplicate = False
        retransmit_ns = int(self.config.retransmit_window_s * 1e9)
        for key in lookup:
            hit = self._recent.get(key)
            # a repeated sequence number is a retransmission if it says so (confirmation > 0) or comes soon
            if hit is not None and (cmd.confirmation > 0 or cmd.rx_ns - hit[0] <= retransmit_ns):
                outcome = dataclasses.replace(hit[2], reason="duplicate of " + hit[2].reason)
                duplicate = True
                break
        if outcome is None:
            args = (cmd.rx_ns, cmd.src_system, cmd.src_component, cmd.command)
            paired = self.pairing.match(*args, cmd.confirmation, cmd.params)
            outcome = _Outcome(int(CommandResult.ACCEPTED), reason=paired) if paired else self._dispatch(cmd)
            if not paired and outcome.result == CommandResult.ACCEPTED:
                self.pairing.taken(*args, cmd.params)
            if record and outcome.result is not None:
                expires = now + int(self.config.dedupe_window_s * 1e9)
                for key in record:
                    self._recent[key] = (cmd.rx_ns, expires, dataclasses.replace(outcome, after=None))
                    self._recent.move_to_end(key)
                while len(self._recent) > 256:
                    self._recent.popitem(last=False)
        if outcome.result is not None:
            self._send_ack(cmd, outcome)
        if outcome.after is not None:
            outcome.after()
        if self._status_dirty:
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

    def _ignored_broadcast(self, cmd: _Command, outcome: _Outcome) -> None:
        """A broadcast command (or message request) this camera does not implement: not ours to answer (the
        command protocol: only the component it concerns ACKs a broadcast), so no ACK, no record and no log
        line but one debug line per command (and requested message) for the whole run; counted."""
        key = (cmd.command, int(cmd.params[0]) if cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE else 0)
        with self._lock:
            self._counts["broadcasts_ignored"] += 1
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

    def _dedupe_keys(self, cmd: _Command) -> tuple[list[tuple[object, ...]], list[tuple[object, ...]]]:
        """(keys that make this command a duplicate, keys to remember it by once executed)."""
        if cmd.command not in (
            mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
            mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
            mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
        ):
            return [], []
        p = cmd.params
        src = (cmd.src_system, cmd.src_component, cmd.command)
        sequence: list[tuple[object, ...]] = []
        if cmd.command == mavlink2.MAV_CMD_IMAGE_START_CAPTURE and p[2] == 1 and math.isfinite(p[3]) and p[3] > 0:
            sequence.append(("sequence", *src, int(p[3])))
        if cmd.command == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL and math.isfinite(p[5]) and p[5] > 0:
            sequence.append(("sequence", *src, int(p[5])))
        retransmission = ("retransmission", *src, p)
        lookup = [*sequence, retransmission] if cmd.confirmation > 0 else sequence
        return lookup, [*sequence, retransmission]

    def _expire_recent(self, now: int) -> None:
        for key in [k for k, (_, expires, _) in self._recent.items() if expires <= now]:
            del self._recent[key]

    # ------------------------------------------------------------------ command implementations
    def _dispatch(self, cmd: _Command) -> _Outcome:
        c = cmd.command
        p = cmd.params
        if c == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            return self._request_message(cmd, int(p[0]) if math.isfinite(p[0]) else -1, p[1], p[2])
        legacy = {
            mavlink2.MAV_CMD_REQUEST_CAMERA_INFORMATION: mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION,
            mavlink2.MAV_CMD_REQUEST_CAMERA_SETTINGS: mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS,
            mavlink2.MAV_CMD_REQUEST_STORAGE_INFORMATION: mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION,
            mavlink2.MAV_CMD_REQUEST_CAMERA_CAPTURE_STATUS: mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS,
            mavlink2.MAV_CMD_REQUEST_CAMERA_IMAGE_CAPTURE: mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED,
        }
        if c in legacy:
            # 525 carries the storage id in param1, 2002 the image index in param1
            return self._request_message(cmd, legacy[c], p[0])
        if c == mavlink2.MAV_CMD_IMAGE_START_CAPTURE:
            return self._start_capture(p)
        if c == mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE:
            outcome = self._call("stop", self.handler.stop)
            if outcome.result == CommandResult.ACCEPTED:
                with self._lock:
                    self._set_status_locked(IMAGE_STATUS_IDLE, 0.0)
            return outcome
        if c == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL:
            if p[4] == 1:
                return self._call("shoot", self.handler.shoot)
            return _Outcome(int(CommandResult.UNSUPPORTED), reason="DO_DIGICAM_CONTROL without shoot (param5 != 1)")
        if c == mavlink2.MAV_CMD_SET_CAMERA_MODE:
            if p[1] == mavlink2.CAMERA_MODE_IMAGE:
                return _Outcome(int(CommandResult.ACCEPTED), reason="image mode (the only mode)")
            return _Outcome(int(CommandResult.DENIED), reason="only image mode is supported")
        if c == mavlink2.MAV_CMD_RESET_CAMERA_SETTINGS:
            return _Outcome(int(CommandResult.ACCEPTED), reason="no settings to reset")
        if cmd.broadcast:
            return _Outcome(None, reason="broadcast command not implemented here")
        return _Outcome(int(CommandResult.UNSUPPORTED), reason="command not supported by this camera")

    def _start_capture(self, p: tuple[float, ...]) -> _Outcome:
        target_camera, interval, count_f = p[0], p[1], p[2]
        if math.isfinite(target_camera) and int(target_camera) not in (0, 1, self._component):
            return _Outcome(int(CommandResult.DENIED), reason=f"param1 names camera {int(target_camera)}, not this one")
        if not math.isfinite(count_f) or count_f < 0 or count_f != int(count_f):
            return _Outcome(int(CommandResult.DENIED), reason=f"invalid image count {count_f}")
        count = int(count_f)
        if count == 1:
            return self._call("shoot", self.handler.shoot)
        if not math.isfinite(interval) or interval <= 0:
            return _Outcome(int(CommandResult.DENIED), reason=f"invalid interval {interval} s for {count} images")
        outcome = self._call(f"start({interval:g} s, {count})", lambda: self.handler.start(interval, count))
        if outcome.result == CommandResult.ACCEPTED:
            with self._lock:
                self._count_target = count
                self._images_since_start = 0
                self._set_status_locked(IMAGE_STATUS_INTERVAL_CAPTURING, interval)
        return outcome

    def _call(self, what: str, fn: Callable[[], CommandResult | HandlerResult]) -> _Outcome:
        try:
            answer = fn()
        except Exception as exc:
            log.exception("capture handler %s raised", what)
            return _Outcome(int(CommandResult.FAILED), reason=f"{what} raised {exc!r}")
        if isinstance(answer, HandlerResult):
            return _Outcome(int(answer.result), answer.progress, answer.result_param2, f"{what}: {answer.reason}")
        if isinstance(answer, CommandResult):
            return _Outcome(int(answer), reason=what)
        return _Outcome(int(CommandResult.FAILED), reason=f"{what} returned {answer!r}")

    def _request_message(self, cmd: _Command, msg_id: int, arg: float, last: float = 0.0) -> _Outcome:
        send: Callable[[], None]
        if msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_INFORMATION:
            self.clients.discovered((cmd.src_system, cmd.src_component), cmd.rx_ns)
            send = self._send_camera_information
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_SETTINGS:
            send = self._send_camera_settings
        elif msg_id == mavlink2.MAVLINK_MSG_ID_STORAGE_INFORMATION:
            storage = int(arg) if math.isfinite(arg) else -1
            if storage not in (0, 1):
                return _Outcome(int(CommandResult.DENIED), reason=f"no storage {storage}")
            send = self._send_storage_information
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_CAPTURE_STATUS:
            send = self._send_capture_status
        elif msg_id == mavlink2.MAVLINK_MSG_ID_CAMERA_IMAGE_CAPTURED:
            spans: list[range] = []
            if cmd.command == mavlink2.MAV_CMD_REQUEST_MESSAGE and is_unspecified_image_request(arg, last):
                # MAVSDK's form, whatever it misses (icgt.mavlink.camera_clients): what it names, and the rest
                wanted, why = image_range(0.0, 0.0, len(self.images)) if arg == 0 else (range(0), "param2 unset")
                spans = self.clients.take_undelivered((cmd.src_system, cmd.src_component))
                if wanted and not any(wanted.start in r for r in spans):
                    spans.insert(0, wanted)
            else:
                wanted, why = image_range(arg, last, len(self.images))
                spans = [wanted] if wanted else []
            if not spans:
                return _Outcome(int(CommandResult.DENIED), reason=why)

            def send() -> None:
                self._resend.extend(spans)
        else:
            if cmd.broadcast:
                return _Outcome(None, reason=f"message {msg_id} not provided here")
            return _Outcome(int(CommandResult.UNSUPPORTED), reason=f"message {msg_id} not provided")
        return _Outcome(int(CommandResult.ACCEPTED), reason=f"message {msg_id}", after=send)

    # ------------------------------------------------------------------ messages
    def _send_ack(self, cmd: _Command, outcome: _Outcome) -> None:
        assert outcome.result is not None
        msg = self.link.mav.command_ack_encode(
            cmd.command,
            outcome.result,
            outcome.progress & 0xFF,
            outcome.result_param2,
            cmd.src_system,
            cmd.src_component,
        )
        self.link.send(msg)

    def _send_heartbeat(self) -> None:
        with self._lock:
            capturing = self._image_status != IMAGE_STATUS_IDLE
        state = mavlink2.MAV_STATE_ACTIVE if capturing else mavlink2.MAV_STATE_STANDBY
        msg = self.link.mav.heartbeat_encode(mavlink2.MAV_TYPE_CAMERA, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, state, 3)
        self.link.send(msg)

    def _send_camera_information(self) -> None:
        info = self.config.info
        uri, version = info.cam_definition_uri, info.cam_definition_version
        if self.settings is not None:
            uri, version = self.settings.uri, self.settings.version
        major, minor, patch, dev = (v & 0xFF for v in info.firmware_version)
        msg = self.link.mav.camera_information_encode(
            self.time_boot_ms(),
            _fixed_bytes(info.vendor, 32),
            _fixed_bytes(info.model, 32),
            (dev << 24) | (patch << 16) | (minor << 8) | major,
            float(info.focal_length_mm),
            float(info.sensor_size_h_mm),
            float(info.sensor_size_v_mm),
            int(info.resolution_h),
            int(info.resolution_v),
            int(info.lens_id),
            mavlink2.CAMERA_CAP_FLAGS_CAPTURE_IMAGE,
            int(version),
            _truncate_utf8(uri, 140),
        )
        self.link.send(msg)

    def _send_camera_settings(self) -> None:
        msg = self.link.mav.camera_settings_encode(self.time_boot_ms(), mavlink2.CAMERA_MODE_IMAGE, math.nan, math.nan)
        self.link.send(msg)

    def _send_storage_information(self) -> None:
        disk = _disk_mib(self.config.output_dir)
        if disk is None:
            status, total, used, free = mavlink2.STORAGE_STATUS_NOT_SUPPORTED, 0.0, 0.0, 0.0
        else:
            status, (total, used, free) = mavlink2.STORAGE_STATUS_READY, disk
        msg = self.link.mav.storage_information_encode(
            self.time_boot_ms(),
            1,
            1,
            status,
            total,
            used,
            free,
            0.0,
            0.0,
            mavlink2.STORAGE_TYPE_OTHER,
            b"ICGT output",
            mavlink2.STORAGE_USAGE_FLAG_SET | mavlink2.STORAGE_USAGE_FLAG_PHOTO,
        )
        self.link.send(msg)

    def _send_capture_status(self) -> None:
        with self._lock:
            status, interval, count = self._image_status, self._interval_s, len(self.images)
            self._status_dirty = False
        disk = _disk_mib(self.config.output_dir)
        msg = self.link.mav.camera_capture_status_encode(
            self.time_boot_ms(), status, 0, float(interval), 0, disk[2] if disk else 0.0, count
        )
        self.link.send(msg)

    def _set_status_locked(self, status: int, interval_s: float) -> None:
        if (status, interval_s) != (self._image_status, self._interval_s):
            self._image_status = status
            self._interval_s = interval_s
            self._status_dirty = True
        if status == IMAGE_STATUS_IDLE:
            self._count_target = 0
            self._images_since_start = 0
