"""A simulated autopilot on a real MAVLink link: the scenario's truth as ArduPilot or PX4 would report it.

`SimAutopilot` is component 1 of the scenario's vehicle system id (MAV_TYPE_QUADROTOR, armed,
MAV_AUTOPILOT_ARDUPILOTMEGA or MAV_AUTOPILOT_PX4 by `[autopilot] firmware`). The scenario's
`[autopilot] profile` (icgt.sim.profiles: "ideal", "ardupilot", "px4") sets what it streams and
how it stamps; every knob is a field of `icgt.sim.scenario.Autopilot`. It keeps its own boot clock
(truth.ClockMaps: autopilot boot us = offset + tau * 1e6 * (1 + drift)) and streams, on a companion
link and on an optional GCS link:

- HEARTBEAT, SYSTEM_TIME (time_unix_usec 0 until the first GPS fix),
- GPS_RAW_INT (time_usec = boot time of the measurement, or of the receiver's latest fix on a
  `gps_fix_rate_hz` grid; the scenario's noise, fix type, outages with fix_type 1 and garbage lat/lon,
  nothing (or fix_type 0) while GPS-denied),
- GLOBAL_POSITION_INT (the fused estimate at time_boot_ms: truth plus small noise, drifting during
  outages, absent while GPS-denied, lat/lon 0 before the first fix),
- ATTITUDE, ATTITUDE_QUATERNION, LOCAL_POSITION_NED (local position keeps going without GPS, and
  jumps at each EKF origin reset `origin_resets_s`), GPS_GLOBAL_ORIGIN (as a stream, or once when
  the origin is set and at each reset with `origin_on_change`).

Each estimate is stamped on a grid of its stream interval on the boot clock (plus `stamp_jitter_s`,
and `local_position_lag_s` for LOCAL_POSITION_NED) and leaves the autopilot `latency_s` (+- jitter)
after its stamp, paced against time.monotonic_ns and the contract's t0. It answers TIMESYNC (tc1 =
boot time [ns] at microsecond granularity, as ArduPilot and PX4; ts1 echoed) unless
`answer_timesync` is false, and may send its own requests (`own_timesync_hz`, as PX4); COMMAND_LONG
MAV_CMD_SET_MESSAGE_INTERVAL (unless `honour_message_interval` is false: then no ACK) /
GET_MESSAGE_INTERVAL / REQUEST_MESSAGE / REQUEST_AUTOPILOT_CAPABILITIES with COMMAND_ACK, and
UNSUPPORTED for other commands addressed to it. Events: parameter downloads (`param_bursts_s`: a
burst of PARAM_VALUE on both links, the streams slowed down meanwhile), HEARTBEATs of ground stations
forwarded to the companion link (`gcs_heartbeat_systems`), a second camera at component 100 of the
vehicle (`foreign_camera`). Routing as ArduPilot does between its links: a message not addressed to
the autopilot alone (broadcasts, other components such as a camera at component 100, other systems)
is forwarded unchanged to the other link. During the scenario's "autopilot link drops" the companion
link sends nothing and ignores what arrives (the GCS link is unaffected).

The parts, one job each: the links and MAVLink 1 framing (`icgt.sim.autopilot_link`), the clock maps
in force (`icgt.sim.autopilot_clock`), the telemetry messages (`icgt.sim.autopilot_telemetry`), the
streams' schedule and sender thread (`icgt.sim.autopilot_streams`), the receiver with the routing and
the commands (`icgt.sim.autopilot_commands`), the scheduled events (`icgt.sim.autopilot_events`) and the
gimbal device (`icgt.sim.autopilot_gimbal`); `SimAutopilot` here puts them together.
"""

from __future__ import annotations

import threading
from collections.abc import Iterable

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from icgt.geodesy import LocalFrame
from icgt.sim.autopilot_clock import AutopilotClock
from icgt.sim.autopilot_commands import CommandHandler
from icgt.sim.autopilot_events import CAMERA_COMPONENT, GCS_COMPONENT, EventScheduler
from icgt.sim.autopilot_gimbal import GIMBAL_COMPONENT, GimbalDevice
from icgt.sim.autopilot_link import COMPONENT_ID, SYSTEM_ID, AutopilotLink, AutopilotLinks
from icgt.sim.autopilot_streams import STREAM_IDS, StreamScheduler
from icgt.sim.autopilot_telemetry import TelemetryBuilder, gps_condition
from icgt.sim.camera_trigger import CameraTrigger, trigger_due
from icgt.sim.scenario import Scenario, SimError
from icgt.sim.trajectory import Trajectory
from icgt.sim.truth import ClockMaps

__all__ = [
    "CAMERA_COMPONENT",
    "COMPONENT_ID",
    "GCS_COMPONENT",
    "GIMBAL_COMPONENT",
    "STREAM_IDS",
    "SYSTEM_ID",
    "SimAutopilot",
    "gps_condition",
]


class SimAutopilot:
    """A simulated ArduPilot-like autopilot; see the module docstring. start() / stop() (or `with`)."""

    def __init__(
        self,
        scenario: Scenario,
        clocks: ClockMaps,
        companion_url: str,
        gcs_url: str | None = None,
        *,
        trajectory: Trajectory | None = None,
        latency_ms: float | None = None,
        latency_jitter_ms: float | None = None,
        mavlink1_messages: Iterable[str] | None = None,
        baud: int = 921_600,
    ) -> None:
        self.scenario = scenario
        self.clock = AutopilotClock(clocks)
        self.companion_url = companion_url
        self.gcs_url = gcs_url
        self.baud = baud
        self.trajectory = trajectory or Trajectory(scenario)
        ap = scenario.autopilot
        self.latency_ns = round((ap.latency_s * 1e3 if latency_ms is None else latency_ms) * 1e6)
        self.jitter_ns = round((ap.latency_jitter_s * 1e3 if latency_jitter_ms is None else latency_jitter_ms) * 1e6)
        names = ap.mavlink1_messages if mavlink1_messages is None else tuple(mavlink1_messages)
        self.mavlink1_messages = frozenset(n.upper() for n in names)
        self.frame = LocalFrame(scenario.origin.lat_deg, scenario.origin.lon_deg, scenario.origin.ellipsoid_height_m)
        self.system_id = ap.system_id
        self._codec = mavlink2.MAVLink(None, srcSystem=self.system_id, srcComponent=COMPONENT_ID)
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.links = AutopilotLinks(scenario, self.clock)
        self.sent_counts: dict[str, int] = {}
        self.forwarded_counts: dict[str, int] = {"to_companion": 0, "to_gcs": 0}
        self.errors: list[str] = []
        """Unexpected exceptions caught in the worker threads (empty in a healthy run)."""
        self._trigger_lock = threading.Lock()
        self.camera_trigger: CameraTrigger | None = None
        """ArduPilot's camera backend commanding the camera (`[autopilot.camera]`), with its log."""
        if trigger_due(ap.camera):
            self.camera_trigger = CameraTrigger(
                ap.camera,
                self.system_id,
                self._codec,
                self.links.send_companion,
                lambda tau: np.asarray(self.trajectory.state(tau).position_enu_m[0], dtype=float),
            )
        self.telemetry = TelemetryBuilder(scenario, self.clock, self.trajectory, self.frame, self._codec)
        self.streams = StreamScheduler(
            scenario,
            self.clock,
            self.links,
            self.telemetry,
            self._stop,
            latency_ns=self.latency_ns,
            jitter_ns=self.jitter_ns,
            mavlink1_messages=self.mavlink1_messages,
            sent_counts=self.sent_counts,
            errors=self.errors,
        )
        self.commands = CommandHandler(
            scenario,
            self.clock,
            self.links,
            self.streams,
            self.telemetry,
            self._codec,
            self._stop,
            system_id=self.system_id,
            mavlink1_messages=self.mavlink1_messages,
            camera_trigger=self.camera_trigger,
            trigger_lock=self._trigger_lock,
            forwarded_counts=self.forwarded_counts,
            errors=self.errors,
        )
        self.events = EventScheduler(
            scenario,
            self.clock,
            self.links,
            self.streams,
            self.telemetry,
            self._codec,
            self._stop,
            system_id=self.system_id,
            camera_trigger=self.camera_trigger,
            trigger_lock=self._trigger_lock,
            sent_counts=self.sent_counts,
            errors=self.errors,
        )
        self.gimbal = GimbalDevice(
            scenario,
            self.clock,
            self.links,
            self.trajectory,
            self._stop,
            system_id=self.system_id,
            latency_ns=self.latency_ns,
            sent_counts=self.sent_counts,
            errors=self.errors,
        )

    @property
    def clocks(self) -> ClockMaps:
        """The clock maps in force; the session replaces them when it releases a held scenario."""
        return self.clock.maps

    @clocks.setter
    def clocks(self, clocks: ClockMaps) -> None:
        self.clock.maps = clocks

    @property
    def skipped_in_param_bursts(self) -> int:
        """Stream messages not sent because a parameter burst slowed the streams down."""
        return self.streams.skipped_in_param_bursts

    @property
    def stream_resets(self) -> int:
        """Times every stream went back to its profile rate (`stream_reset_s`)."""
        return self.events.stream_resets

    # --- lifecycle ----------------------------------------------------------------------------

    def start(self) -> None:
        if self._threads:
            raise SimError("autopilot already started")
        self._stop.clear()
        self.links.open(self.companion_url, self.gcs_url, self.baud, self.system_id)
        now_ap = self.clock.ap_now_us()
        with self.streams.cond:
            for s in self.streams.streams.values():
                self.streams.restart_stream(s, now_ap)
        self._threads = [
            threading.Thread(target=self.streams.run, name="sim-autopilot-tx", daemon=True),
            threading.Thread(target=self.commands.run, name="sim-autopilot-rx", daemon=True),
            threading.Thread(target=self.events.run, name="sim-autopilot-events", daemon=True),
        ]
        if self.scenario.camera.gimbal is not None:
            self._threads.append(threading.Thread(target=self.gimbal.run, name="sim-gimbal", daemon=True))
        for t in self._threads:
            t.start()

    def stop(self) -> None:
        """Stop the threads and close the links; safe to call more than once."""
        self._stop.set()
        with self.streams.cond:
            self.streams.cond.notify_all()
        for t in self._threads:
            t.join(timeout=5.0)
        alive = [t.name for t in self._threads if t.is_alive()]
        self._threads = []
        self.links.close()
        if alive:
            raise SimError(f"autopilot threads did not stop: {', '.join(alive)}")

    def __enter__(self) -> SimAutopilot:
        self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    @property
    def _companion(self) -> AutopilotLink | None:
        """The companion link (`AutopilotLink`, None unless started); tests reach for its socket."""
        return self.links.companion

    @property
    def companion_address(self) -> tuple[str, int] | None:
        """Local (host, port) of the companion link's socket, once started."""
        return self.links.companion.local_address() if self.links.companion else None

    @property
    def gcs_address(self) -> tuple[str, int] | None:
        """Local (host, port) of the GCS link's socket (e.g. the port udpin:...:0 bound)."""
        return self.links.gcs.local_address() if self.links.gcs else None
