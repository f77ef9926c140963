"""What the simulated autopilot does with what arrives: routing, TIMESYNC answers and commands.

`CommandHandler.run` (the "sim-autopilot-rx" thread) reads both links. A message not addressed to the
autopilot alone is forwarded unchanged to the other link (ArduPilot's routing); the companion link's
messages feed the camera backend (`icgt.sim.camera_trigger`); TIMESYNC requests are answered, and
COMMAND_LONG SET_MESSAGE_INTERVAL / GET_MESSAGE_INTERVAL / REQUEST_MESSAGE /
REQUEST_AUTOPILOT_CAPABILITIES get COMMAND_ACK (other commands addressed to it UNSUPPORTED). During the
companion link's drops what arrives on it is ignored. Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import select
import threading
import time
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.autopilot_link import COMPONENT_ID, AutopilotLink, AutopilotLinks
from icgt.sim.autopilot_streams import US_STAMPED, StreamScheduler
from icgt.sim.autopilot_telemetry import TelemetryBuilder
from icgt.sim.camera_trigger import CameraTrigger
from icgt.sim.scenario import Scenario

__all__ = ["CommandHandler"]

_SELECT_TIMEOUT_S = 0.02


class CommandHandler:
    """The receiver thread and the answers of one simulated autopilot (see the module docstring)."""

    def __init__(
        self,
        scenario: Scenario,
        clock: AutopilotClock,
        links: AutopilotLinks,
        scheduler: StreamScheduler,
        telemetry: TelemetryBuilder,
        codec: Any,
        stop: threading.Event,
        *,
        system_id: int,
        mavlink1_messages: frozenset[str],
        camera_trigger: CameraTrigger | None,
        trigger_lock: threading.Lock,
        forwarded_counts: dict[str, int],
        errors: list[str],
    ) -> None:
        self.scenario = scenario
        self.clock = clock
        self.links = links
        self.scheduler = scheduler
        self.telemetry = telemetry
        self._codec = codec
        self._stop = stop
        self.system_id = system_id
        self.mavlink1_messages = mavlink1_messages
        self.camera_trigger = camera_trigger
        self._trigger_lock = trigger_lock
        self.forwarded_counts = forwarded_counts
        self.errors = errors
        self._oneoff_rng = np.random.default_rng([scenario.seed, 0xA9, 0])

    def run(self) -> None:
        while not self._stop.is_set():
            links = [link for link in (self.links.companion, self.links.gcs) if link is not None]
            fds = [fd for link in links if (fd := link.fileno()) is not None]
            try:
                if fds:
                    select.select(fds, [], [], _SELECT_TIMEOUT_S)
                else:
                    time.sleep(_SELECT_TIMEOUT_S)
            except (OSError, ValueError):
                time.sleep(_SELECT_TIMEOUT_S)
            for link in links:
                try:
                    for msg in link.read():
                        self._on_message(link, msg)
                except Exception as exc:  # keep serving; the error is reported in self.errors
                    self.errors.append(f"{link.name} receive: {exc!r}")

    def _on_message(self, link: AutopilotLink, msg: Any) -> None:
        if link is self.links.companion and self.links.companion_dropped(self.clock.tau_now()):
            return
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if src == (self.system_id, COMPONENT_ID):
            return  # our own frames echoed back by a loop
        tgt_sys = int(getattr(msg, "target_system", 0))
        tgt_comp = int(getattr(msg, "target_component", 0))
        other = self.links.gcs if link is self.links.companion else self.links.companion
        addressed_to_me_only = tgt_sys == self.system_id and tgt_comp == COMPONENT_ID
        to_companion = other is self.links.companion
        if (
            other is not None
            and not addressed_to_me_only
            and not (to_companion and self.links.companion_dropped(self.clock.tau_now()))
        ):
            other.forward(bytes(msg.get_msgbuf()))
            self.forwarded_counts["to_companion" if to_companion else "to_gcs"] += 1
        if self.camera_trigger is not None and link is self.links.companion:
            with self._trigger_lock:
                self.camera_trigger.on_message(msg)
        for_me = tgt_sys in (0, self.system_id) and tgt_comp in (0, COMPONENT_ID)
        if not for_me:
            return
        mtype = msg.get_type()
        if mtype == "TIMESYNC" and msg.tc1 == 0:
            if not self.scenario.autopilot.answer_timesync:
                return
            link.send(self._codec.timesync_encode(self.clock.ap_now_us() * 1000, msg.ts1))
        elif mtype == "COMMAND_LONG":
            self._on_command(link, msg, addressed=tgt_comp == COMPONENT_ID)

    def _ack(self, link: AutopilotLink, msg: Any, result: int) -> None:
        link.send(
            self._codec.command_ack_encode(msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())
        )

    def _on_command(self, link: AutopilotLink, msg: Any, *, addressed: bool) -> None:
        cmd = int(msg.command)
        if cmd == mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL:
            if not self.scenario.autopilot.honour_message_interval:
                return  # no COMMAND_ACK, the default rates stay
            self._ack(link, msg, self.scheduler.set_interval(int(msg.param1), float(msg.param2)))
        elif cmd == mavlink2.MAV_CMD_GET_MESSAGE_INTERVAL:
            mid = int(msg.param1)
            s = self.scheduler.streams.get(mid)
            interval = 0 if s is None else (-1 if s.interval_us is None else s.interval_us)
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self._codec.message_interval_encode(mid, interval))
        elif cmd == mavlink2.MAV_CMD_REQUEST_MESSAGE:
            self._request_message(link, msg, int(msg.param1))
        elif cmd == mavlink2.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self.telemetry.autopilot_version())
        elif addressed:
            self._ack(link, msg, mavlink2.MAV_RESULT_UNSUPPORTED)

    def _request_message(self, link: AutopilotLink, msg: Any, msg_id: int) -> None:
        if msg_id == mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
            link.send(self.telemetry.autopilot_version())
            return
        s = self.scheduler.streams.get(msg_id)
        if s is None:
            self._ack(link, msg, mavlink2.MAV_RESULT_DENIED)
            return
        stamp_us = self.clock.ap_now_us()
        if s.name not in US_STAMPED:
            stamp_us = (stamp_us // 1000) * 1000
        built = self.telemetry.build(s.name, stamp_us, self._oneoff_rng)
        if built is None:  # e.g. GLOBAL_POSITION_INT while GPS-denied
            self._ack(link, msg, mavlink2.MAV_RESULT_FAILED)
            return
        self._ack(link, msg, mavlink2.MAV_RESULT_ACCEPTED)
        link.send(built, mavlink1=built.get_type() in self.mavlink1_messages)
