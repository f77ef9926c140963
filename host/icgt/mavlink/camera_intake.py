"""The camera component's command intake, on the link's reader thread (it must not block).

COMMAND_LONG / COMMAND_INT not addressed to the camera are ignored silently. A command without a valid
signature while signing is required, from a system that may not command the camera, or finding the
worker's queue full is refused: counted (``counts``), logged throttled, answered with a rate-limited
COMMAND_ACK (none for an untrusted one) and reported to ``on_rejected``. Every other command goes to the
worker's queue as a `Command`. The rules are in `icgt.mavlink.camera`'s docstring; split from it.
"""

from __future__ import annotations

import logging
import queue
import threading
from collections.abc import Callable

from icgt.mavlink.camera_clients import ClientTracker
from icgt.mavlink.camera_commands import Command, command_params
from icgt.mavlink.camera_types import CameraConfig, CommandResult, RejectedCommand
from icgt.mavlink.link import MavlinkLink, MavlinkMessage
from icgt.mavlink.ratelimit import ThrottledLog, TokenBucket
from icgt.mavlink.signing import frame_has_signature

__all__ = ["CommandIntake"]

log = logging.getLogger("icgt.mavlink.camera")  # the camera component's log lines keep its logger's name


class CommandIntake:
    """Filters, refuses and enqueues the commands the link's reader hands to ``on_message``."""

    def __init__(
        self,
        link: MavlinkLink,
        config: CameraConfig,
        commands: queue.Queue[object],
        lock: threading.Lock,
        clients: ClientTracker,
        *,
        allowed: frozenset[int],
        ground_stations: frozenset[int],
        on_rejected: Callable[[RejectedCommand], None] | None = None,
    ) -> None:
        self.link = link
        self.config = config
        self._queue = commands
        self._lock = lock  # the component's: it guards ``counts`` too
        self.clients = clients
        self._on_rejected = on_rejected
        self._system = link.config.system_id
        self._component = link.config.component_id
        self._allowed = allowed
        self._ground_stations = ground_stations
        # refusals: counted here, logged throttled, answered at most refusal_ack_hz
        self._refusal_acks = TokenBucket(config.refusal_ack_hz, max(1, int(config.refusal_ack_hz)))
        period = config.log_period_s
        self._log_untrusted = ThrottledLog(log, "ignored commands without a valid signature", period_s=period)
        self._log_denied = ThrottledLog(
            log, "denied commands from systems not in [mavlink] ground_station_systems", period_s=period
        )
        self._log_overflow = ThrottledLog(log, "commands refused, camera queue full", period_s=period)
        self.throttled_logs = (self._log_untrusted, self._log_denied, self._log_overflow)
        self.counts = {
            "rejected_commands": 0,  # every command addressed to us that was not executed
            "denied_systems": 0,  # ... from a system that may not command the camera (ACK DENIED)
            "unsigned_commands": 0,  # ... without a signature while signing is required (no ACK)
            "badly_signed_commands": 0,  # ... with a signature that is not valid (no ACK)
            "queue_overflows": 0,  # ... that found the queue full (ACK TEMPORARILY_REJECTED)
            "refusal_acks_sent": 0,
            "refusal_acks_suppressed": 0,  # refusals past the rate limit: counted, not answered
            "broadcasts_ignored": 0,  # broadcast commands this camera does not implement (no ACK, not an error)
        }

    def on_message(self, rec: MavlinkMessage) -> None:
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
        params, confirmation = command_params(rec)
        item = Command(rec.rx_ns, rec.src_system, rec.src_component, command, confirmation, params, target_comp == 0)
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
            self.counts["rejected_commands"] += 1
            self.counts[kind] += 1
            if answer is not None:
                self.counts["refusal_acks_sent" if ack else "refusal_acks_suppressed"] += 1
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
