"""The simulated autopilot's telemetry streams: their schedule, and the thread that sends them.

Each stream's messages are stamped on a grid of its interval on the autopilot's boot clock (plus the
main loop's jitter, and LOCAL_POSITION_NED's lag) and leave the autopilot the latency (+- jitter) after
their stamp; parameter bursts slow the streams down. `StreamScheduler.run` (the "sim-autopilot-tx"
thread) builds each message (`icgt.sim.autopilot_telemetry`) a little before it is due and sends it on
every link on time. Split from `icgt.sim.autopilot`.
"""

from __future__ import annotations

import heapq
import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.autopilot_link import AutopilotLinks
from icgt.sim.autopilot_telemetry import TelemetryBuilder
from icgt.sim.scenario import STREAM_NAMES, Scenario

__all__ = ["STREAM_IDS", "US_STAMPED", "Stream", "StreamScheduler"]

STREAM_IDS: dict[str, int] = {
    "heartbeat": mavlink2.MAVLINK_MSG_ID_HEARTBEAT,
    "gps_raw_int": mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT,
    "global_position_int": mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "attitude": mavlink2.MAVLINK_MSG_ID_ATTITUDE,
    "attitude_quaternion": mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "local_position_ned": mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "system_time": mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME,
    "gps_global_origin": mavlink2.MAVLINK_MSG_ID_GPS_GLOBAL_ORIGIN,
}
US_STAMPED = {"gps_raw_int"}  # the others carry time_boot_ms (or no stamp)
_BUILD_LEAD_NS = 10_000_000  # messages are built this long before they are due


@dataclass
class Stream:
    name: str
    msg_id: int
    default_interval_us: int | None
    interval_us: int | None
    k: int = 0
    stamp_us: int = 0
    send_ns: int = 0


class StreamScheduler:
    """The streams by message id (guarded by ``cond``), their scheduling and the sender thread."""

    def __init__(
        self,
        scenario: Scenario,
        clock: AutopilotClock,
        links: AutopilotLinks,
        telemetry: TelemetryBuilder,
        stop: threading.Event,
        *,
        latency_ns: int,
        jitter_ns: int,
        mavlink1_messages: frozenset[str],
        sent_counts: dict[str, int],
        errors: list[str],
    ) -> None:
        self.scenario = scenario
        self.clock = clock
        self.links = links
        self.telemetry = telemetry
        self._stop = stop
        self.latency_ns = latency_ns
        self.jitter_ns = jitter_ns
        self.mavlink1_messages = mavlink1_messages
        self.sent_counts = sent_counts
        self.errors = errors
        ap = scenario.autopilot
        self.streams: dict[int, Stream] = {}
        for name in STREAM_NAMES:
            rate = ap.rates_hz.get(name, 0.0)
            interval = round(1e6 / rate) if rate > 0.0 else None
            self.streams[STREAM_IDS[name]] = Stream(name, STREAM_IDS[name], interval, interval)
        seed = scenario.seed
        self._noise = {mid: np.random.default_rng([seed, 0xA9, mid]) for mid in self.streams}
        self._jitter_rng = np.random.default_rng([seed, 0xA9, 1])
        self._stamp_rng = np.random.default_rng([seed, 0xA9, 3])
        self.cond = threading.Condition()
        self.skipped_in_param_bursts = 0
        """Stream messages not sent because a parameter burst slowed the streams down."""

    def _stamp(self, s: Stream) -> int:
        assert s.interval_us is not None
        if s.name in US_STAMPED:
            return s.k * s.interval_us
        return (s.k * s.interval_us // 1000) * 1000

    def _stamp_offset_us(self, s: Stream) -> int:
        """Where in its grid interval a stamp falls: the main-loop jitter, plus LOCAL_POSITION_NED's lag."""
        ap = self.scenario.autopilot
        assert s.interval_us is not None
        span_ms = 1e3 * (ap.stamp_jitter_s + (ap.local_position_lag_s if s.name == "local_position_ned" else 0.0))
        if span_ms <= 0.0:
            return 0
        limit_us = max(0, s.interval_us - 1000)  # stamps stay in order and one apart
        return min(limit_us, round(float(self._stamp_rng.uniform(0.0, span_ms)) * 1000.0))

    def _schedule(self, s: Stream) -> None:
        s.stamp_us = self._stamp(s)
        offset_us = self._stamp_offset_us(s)
        if offset_us:
            s.stamp_us += offset_us if s.name in US_STAMPED else (offset_us // 1000) * 1000
        tau = float(self.clock.maps.autopilot_us_to_tau(s.stamp_us))
        jitter = round(self._jitter_rng.uniform(-1.0, 1.0) * self.jitter_ns) if self.jitter_ns else 0
        s.send_ns = self.clock.maps.tau_to_host_ns(tau) + max(0, self.latency_ns + jitter)

    def restart_stream(self, s: Stream, now_ap_us: int) -> None:
        """Put a stream's next message at the first grid point at or after ``now_ap_us`` (hold ``cond``)."""
        if s.interval_us is None:
            return
        s.k = -(-max(0, now_ap_us) // s.interval_us)  # first grid point at or after now (not before boot)
        self._schedule(s)

    def set_interval(self, msg_id: int, interval_us: float) -> int:
        """MAV_CMD_SET_MESSAGE_INTERVAL: -1 stops the stream, 0 restores its default; the MAV_RESULT."""
        s = self.streams.get(msg_id)
        if s is None or interval_us < -1 or not math.isfinite(interval_us):
            return int(mavlink2.MAV_RESULT_DENIED)
        with self.cond:
            if interval_us == -1:
                s.interval_us = None
            elif interval_us == 0:
                s.interval_us = s.default_interval_us
            else:
                s.interval_us = max(1000, round(interval_us))
            self.restart_stream(s, self.clock.ap_now_us())
            self.cond.notify_all()
        return int(mavlink2.MAV_RESULT_ACCEPTED)

    def reset_rates(self) -> None:
        """Every stream back to its profile rate."""
        with self.cond:
            for stream in self.streams.values():
                stream.interval_us = stream.default_interval_us
                self.restart_stream(stream, self.clock.ap_now_us())
            self.cond.notify_all()

    def run(self) -> None:
        """Build each message _BUILD_LEAD_NS before it is due (the truth takes a while), send it on time."""
        pending: list[tuple[int, int, Any]] = []  # heap of (send_ns, sequence, message)
        sequence = 0
        while not self._stop.is_set():
            now = time.monotonic_ns()
            if pending and pending[0][0] <= now:
                _, _, msg = heapq.heappop(pending)
                try:
                    self._send_stream_message(msg)
                except Exception as exc:  # a broken link must not stop the other one
                    self.errors.append(f"send {msg.get_type()}: {exc!r}")
                continue
            with self.cond:
                active = [s for s in self.streams.values() if s.interval_us is not None]
                nxt = min(active, key=lambda s: s.send_ns) if active else None
                candidates = [pending[0][0]] if pending else []
                if nxt is not None:
                    candidates.append(nxt.send_ns - _BUILD_LEAD_NS)
                next_ns = min(candidates, default=None)
                if nxt is None or nxt.send_ns - _BUILD_LEAD_NS > now:
                    wait_ns = 100_000_000 if next_ns is None else min(100_000_000, next_ns - now)
                    if wait_ns > 0:
                        self.cond.wait(timeout=wait_ns * 1e-9)
                    continue
                name, stamp_us, send_ns, k = nxt.name, nxt.stamp_us, nxt.send_ns, nxt.k
                nxt.k += 1
                self._schedule(nxt)
            if self._slowed_by_param_burst(stamp_us, k):
                self.skipped_in_param_bursts += 1
                continue
            try:
                msg = self.telemetry.build(name, stamp_us, self._noise[STREAM_IDS[name]])
            except Exception as exc:  # keep streaming; the error is reported in self.errors
                self.errors.append(f"{name}: {exc!r}")
                continue
            if msg is not None:
                heapq.heappush(pending, (send_ns, sequence, msg))
                sequence += 1

    def _slowed_by_param_burst(self, stamp_us: int, k: int) -> bool:
        ap = self.scenario.autopilot
        if ap.param_burst_stream_divisor <= 1 or not ap.param_bursts_s:
            return False
        tau = float(self.clock.maps.autopilot_us_to_tau(stamp_us))
        in_burst = any(t <= tau < t + ap.param_burst_duration_s for t in ap.param_bursts_s)
        return in_burst and k % ap.param_burst_stream_divisor != 0

    def _send_stream_message(self, msg: Any) -> None:
        """Send a telemetry message on every link (not the companion link while it is dropped)."""
        mav1 = msg.get_type() in self.mavlink1_messages
        dropped = self.links.companion_dropped(self.clock.tau_now())
        for target in (self.links.companion, self.links.gcs):
            if target is None or (target is self.links.companion and dropped):
                continue
            target.send(msg, mavlink1=mav1)
        self.sent_counts[msg.get_type()] = self.sent_counts.get(msg.get_type(), 0) + 1
