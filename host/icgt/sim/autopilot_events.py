"""The simulated autopilot's scheduled events, on scenario time ("sim-autopilot-events" thread).

Forwarded ground stations' HEARTBEATs (`gcs_heartbeat_systems`), a foreign camera's HEARTBEAT
(`foreign_camera`), its own TIMESYNC requests (`own_timesync_hz`), the stream reset at the end of
ArduPilot's boot (`stream_reset_s`), the camera backend's updates, GPS_GLOBAL_ORIGIN when the origin is
set and at each reset (`origin_on_change`), and the parameter bursts (`param_bursts_s`, sent in chunks).
Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import heapq
import math
import threading
from typing import Any

from pymavlink.dialects.v20 import common as mavlink2

from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.autopilot_link import AutopilotLinks
from icgt.sim.autopilot_streams import StreamScheduler
from icgt.sim.autopilot_telemetry import TelemetryBuilder
from icgt.sim.camera_trigger import UPDATE_PERIOD_S, CameraTrigger
from icgt.sim.scenario import Scenario, SimError

__all__ = ["CAMERA_COMPONENT", "GCS_COMPONENT", "EventScheduler"]

GCS_COMPONENT = 190  # MAV_COMP_ID_MISSIONPLANNER: what QGroundControl, MAVProxy and MAVSDK ground stations use
CAMERA_COMPONENT = 100  # MAV_COMP_ID_CAMERA
_EVENT_PERIOD_S = 1.0  # HEARTBEATs of forwarded ground stations and of the foreign camera
_BURST_CHUNK_S = 0.01  # a parameter burst goes out in chunks this far apart


class EventScheduler:
    """Plans the scenario's events and runs them at their time (see the module docstring)."""

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
        camera_trigger: CameraTrigger | None,
        trigger_lock: threading.Lock,
        sent_counts: dict[str, int],
        errors: list[str],
    ) -> None:
        self.scenario = scenario
        self.clock = clock
        self.links = links
        self.scheduler = scheduler
        self.telemetry = telemetry
        self._codec = codec
        self._stop = stop
        self.camera_trigger = camera_trigger
        self._trigger_lock = trigger_lock
        self.sent_counts = sent_counts
        self.errors = errors
        ap = scenario.autopilot
        # other senders whose messages reach the companion link through this autopilot's routing
        self._gcs_codecs = [
            mavlink2.MAVLink(None, srcSystem=g, srcComponent=GCS_COMPONENT) for g in ap.gcs_heartbeat_systems
        ]
        self._camera_codec = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=CAMERA_COMPONENT)
        self.stream_resets = 0
        """Times every stream went back to its profile rate (`stream_reset_s`)."""

    def _event_plan(self) -> list[tuple[float, int, str, int]]:
        """The one-off and first periodic events as (tau, sequence, kind, argument)."""
        ap = self.scenario.autopilot
        start = max(0.0, self.clock.tau_now())
        plan: list[tuple[float, str, int]] = []
        if ap.gcs_heartbeat_systems:
            plan.append((start, "gcs_heartbeats", 0))
        if ap.foreign_camera:
            plan.append((start, "camera_heartbeat", 0))
        if ap.own_timesync_hz > 0.0:
            plan.append((start, "own_timesync", 0))
        if ap.stream_reset_s > 0.0:
            plan.append((max(start, ap.stream_reset_s), "stream_reset", 0))
        if self.camera_trigger is not None:
            plan.append((start, "camera_update", 0))
        if ap.origin_on_change:
            plan.append((max(start, self.scenario.gps.fix_acquired_after_s), "origin", 0))
            plan += [(t, "origin", 0) for t in ap.origin_resets_s if t > self.scenario.gps.fix_acquired_after_s]
        for t in ap.param_bursts_s:
            n_chunks = max(1, math.ceil(ap.param_burst_duration_s / _BURST_CHUNK_S))
            per_chunk = -(-ap.param_burst_count // n_chunks)
            for c in range(n_chunks):
                first = c * per_chunk
                if first < ap.param_burst_count:
                    plan.append((t + c * _BURST_CHUNK_S, "params", first))
        return [(tau, i, kind, arg) for i, (tau, kind, arg) in enumerate(plan)]

    def run(self) -> None:
        heap = self._event_plan()
        heapq.heapify(heap)
        sequence = len(heap)
        while heap and not self._stop.is_set():
            tau, _, kind, arg = heap[0]
            wait_s = tau - self.clock.tau_now()
            if wait_s > 0.0:
                self._stop.wait(min(wait_s, 0.1))
                continue
            heapq.heappop(heap)
            try:
                again = self._event(kind, arg)
            except Exception as exc:  # keep going; the error is reported in self.errors
                self.errors.append(f"event {kind}: {exc!r}")
                again = None
            if again is not None:
                heapq.heappush(heap, (tau + again, sequence, kind, arg))
                sequence += 1

    def _event(self, kind: str, arg: int) -> float | None:
        """Do one event; returns the period after which it repeats (None: once)."""
        ap = self.scenario.autopilot
        if kind == "gcs_heartbeats":
            # what the autopilot forwards from its GCS links: each ground station's HEARTBEAT
            for codec in self._gcs_codecs:
                hb = codec.heartbeat_encode(mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                for link in self.links.links_now(companion_only=True):
                    link.send_as(hb, codec)
            return _EVENT_PERIOD_S
        if kind == "camera_heartbeat":
            c = self._camera_codec
            hb = c.heartbeat_encode(
                mavlink2.MAV_TYPE_CAMERA, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, mavlink2.MAV_STATE_ACTIVE
            )
            for link in self.links.links_now():
                link.send_as(hb, c)
            return _EVENT_PERIOD_S
        if kind == "own_timesync":
            if self.links.companion is not None and not self.links.companion_dropped(self.clock.tau_now()):
                self.links.companion.send(self._codec.timesync_encode(0, self.clock.ap_now_us() * 1000))
            return 1.0 / ap.own_timesync_hz
        if kind == "stream_reset":  # ArduPilot's boot ends: SRn_ rates applied over earlier requests
            self.scheduler.reset_rates()
            self.stream_resets += 1
            return None
        if kind == "camera_update":
            if self.camera_trigger is not None:
                with self._trigger_lock:
                    self.camera_trigger.update(self.clock.tau_now(), self.clock.ap_now_us() // 1000)
            return UPDATE_PERIOD_S
        if kind == "origin":
            msg = self.telemetry.origin_message(self.clock.ap_now_us())
            for link in self.links.links_now():
                link.send(msg)
            self.sent_counts["GPS_GLOBAL_ORIGIN"] = self.sent_counts.get("GPS_GLOBAL_ORIGIN", 0) + 1
            return None
        if kind == "params":
            n_chunks = max(1, math.ceil(ap.param_burst_duration_s / _BURST_CHUNK_S))
            per_chunk = -(-ap.param_burst_count // n_chunks)
            for index in range(arg, min(arg + per_chunk, ap.param_burst_count)):
                msg = self._codec.param_value_encode(
                    f"SIM_P{index:05d}".encode(),
                    float(index),
                    mavlink2.MAV_PARAM_TYPE_REAL32,
                    ap.param_burst_count,
                    index,
                )
                for link in self.links.links_now():
                    link.send(msg)
                self.sent_counts["PARAM_VALUE"] = self.sent_counts.get("PARAM_VALUE", 0) + 1
            return None
        raise SimError(f"unknown autopilot event {kind!r}")
