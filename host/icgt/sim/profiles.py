"""Autopilot profiles of the simulator: what ArduPilot and PX4 really send on a companion link.

A scenario picks one with ``[autopilot] profile = "ideal" | "ardupilot" | "px4"`` (default "ideal");
the profile gives the defaults of every other ``[autopilot]`` key, and the scenario may still set
any of them. Each number below is the firmware's own behaviour where the firmware fixes it, with
its source; where it depends on the installation (which rates a ground station asked for), the
value is the common case and says so.

**ideal** (the simulator before profiles): every estimate stamped on a grid of its stream interval,
sent 2 ms later, TIMESYNC answered, SET_MESSAGE_INTERVAL honoured and ACKed, no origin messages.

**ardupilot** (ArduCopter 4.x, facts from ArduPilot/ardupilot):

- Stream rates: the SRx_ (MAVn_) parameters group messages (POSITION: GLOBAL_POSITION_INT and
  LOCAL_POSITION_NED; EXT_STAT: GPS_RAW_INT; EXTRA1: ATTITUDE; EXTRA3: SYSTEM_TIME;
  ATTITUDE_QUATERNION is in no group) and default to 0 or 1 Hz depending on vehicle and version
  (ArduCopter/GCS_Mavlink.cpp, ArduPlane/GCS_Mavlink.cpp var_info); what a companion port really
  carries is what a ground station requested with REQUEST_DATA_STREAM: MAVProxy asks for every
  stream at 4 Hz (its `streamrate` setting, default 4), hence 4 Hz here; the logs of issue 9 had 2-4 Hz.
- SET_MESSAGE_INTERVAL is honoured and ACKed since ArduPilot 4.0 (ardupilot.org/dev/docs/
  mavlink-requesting-data.html); older firmware and some routers leave it unanswered
  (``honour_message_interval = false``).
- Stamps: GLOBAL_POSITION_INT, LOCAL_POSITION_NED and ATTITUDE carry ``AP_HAL::millis()`` of the
  moment they are written (the AHRS state then), so stamps fall wherever the 400 Hz main loop
  (2.5 ms) sends them: ``stamp_jitter_s = 0.0025``. LOCAL_POSITION_NED is written after
  GLOBAL_POSITION_INT in the same stream and, when the port's buffer is short, a loop or more
  later: up to 20 ms later in real logs (issue 9): ``local_position_lag_s = 0.02``.
- GPS_RAW_INT.time_usec is ``last_fix_time_ms * 1000``: the boot time of the receiver's latest
  fix in whole milliseconds (libraries/AP_GPS/AP_GPS.cpp send_mavlink_gps_raw), not the send time;
  the receiver runs at 5 Hz (``gps_fix_rate_hz = 5``), the message at the stream's rate.
- TIMESYNC: answered with ``tc1`` = the boot time in ns at microsecond resolution
  (GCS_Common.cpp handle_timesync; newer versions take the request's receive time).
- GPS_GLOBAL_ORIGIN is sent when the EKF origin is set and when it changes (``origin_on_change``).
- While parameters are being sent, streams run "4 or more times slower than requested"
  (mavlink-requesting-data.html): ``param_burst_stream_divisor = 4``.
- HEARTBEAT 1 Hz, MAV_AUTOPILOT_ARDUPILOTMEGA.
- Measured on ArduCopter 4.7.0-dev SITL (issue 29, docs/sitl.md): it sends its own TIMESYNC request
  every 10 s on each link (first ~10 s after boot, ts1 = boot ns + its system id):
  ``own_timesync_hz = 0.1``; a SET_MESSAGE_INTERVAL taken before its boot ends (~2.4 s) is ACKed
  ACCEPTED and then undone by the SRn_ rates (`stream_reset_s`, off by default: a scenario sets it);
  GPS_GLOBAL_ORIGIN and HOME_POSITION come once each when the EKF origin is set (~20 s after boot in
  SITL, well before the EKF uses GPS, ~41 s); the MAVLinkCamV2 camera backend is icgt.sim.camera_trigger.
  TIMESYNC's tc1 is the request's receive time less its transfer time at the port's baud rate (and the
  bytes waiting): on a real UART the frame's true start; on SITL's TCP ports, where the baud rate is
  nominal, up to ~2.5 ms early at 115200 (not simulated: the simulator answers with the receive time).

**px4** (PX4-Autopilot, src/modules/mavlink/mavlink_main.cpp, configure_streams_to_default,
MAVLINK_MODE_ONBOARD, the mode of a companion link):

- GLOBAL_POSITION_INT 50 Hz, LOCAL_POSITION_NED 30 Hz, ATTITUDE 100 Hz, ATTITUDE_QUATERNION
  50 Hz, GPS_RAW_INT "unlimited" (every receiver update: 5 Hz here), SYSTEM_TIME 1 Hz,
  GPS_GLOBAL_ORIGIN 1 Hz, TIMESYNC 10 Hz (PX4 sends its own TIMESYNC requests on that link:
  ``own_timesync_hz = 10``), HEARTBEAT 1 Hz with MAV_AUTOPILOT_PX4.
- Stamps are the uORB sample's timestamp (the estimator's output time), on its own grid, sent
  with the next stream tick: a few ms later (``latency_s = 0.005``, +-4 ms: an estimate, not a
  documented figure). GPS_RAW_INT.time_usec is the sample's boot time in us.
- TIMESYNC answered (tc1 = boot time in ns), SET_MESSAGE_INTERVAL honoured and ACKed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

PROFILE_NAMES = ("ideal", "ardupilot", "px4")

IDEAL_RATES_HZ: Mapping[str, float] = {
    "heartbeat": 1.0,
    "gps_raw_int": 5.0,
    "global_position_int": 10.0,
    "attitude": 10.0,
    "attitude_quaternion": 10.0,
    "local_position_ned": 10.0,
    "system_time": 1.0,
    "gps_global_origin": 0.0,
}

PROFILES: Mapping[str, Mapping[str, Any]] = {
    "ideal": {
        "rates_hz": IDEAL_RATES_HZ,
        "latency_s": 0.002,
        "latency_jitter_s": 0.0005,
        "answer_timesync": True,
        "honour_message_interval": True,
        "firmware": "ardupilot",
        "stamp_jitter_s": 0.0,
        "local_position_lag_s": 0.0,
        "gps_fix_rate_hz": 0.0,
        "own_timesync_hz": 0.0,
        "origin_on_change": False,
        "param_burst_stream_divisor": 1,
    },
    "ardupilot": {
        "rates_hz": {
            "heartbeat": 1.0,
            "gps_raw_int": 4.0,
            "global_position_int": 4.0,
            "attitude": 4.0,
            "attitude_quaternion": 0.0,
            "local_position_ned": 4.0,
            "system_time": 4.0,
            "gps_global_origin": 0.0,
        },
        "latency_s": 0.001,
        "latency_jitter_s": 0.0005,
        "answer_timesync": True,
        "honour_message_interval": True,
        "firmware": "ardupilot",
        "stamp_jitter_s": 0.0025,
        "local_position_lag_s": 0.02,
        "gps_fix_rate_hz": 5.0,
        "own_timesync_hz": 0.1,
        "origin_on_change": True,
        "param_burst_stream_divisor": 4,
    },
    "px4": {
        "rates_hz": {
            "heartbeat": 1.0,
            "gps_raw_int": 5.0,
            "global_position_int": 50.0,
            "attitude": 100.0,
            "attitude_quaternion": 50.0,
            "local_position_ned": 30.0,
            "system_time": 1.0,
            "gps_global_origin": 1.0,
        },
        "latency_s": 0.005,
        "latency_jitter_s": 0.004,
        "answer_timesync": True,
        "honour_message_interval": True,
        "firmware": "px4",
        "stamp_jitter_s": 0.0,
        "local_position_lag_s": 0.0,
        "gps_fix_rate_hz": 0.0,
        "own_timesync_hz": 10.0,
        "origin_on_change": False,
        "param_burst_stream_divisor": 1,
    },
}
"""Defaults of the ``[autopilot]`` keys per profile (see the module docstring for the sources)."""
