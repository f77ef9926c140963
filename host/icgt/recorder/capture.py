"""The recorder's device commands built from its configuration, checked against the device's limits first.

`configure_command` is the CONFIGURE the recorder sends at start; `start_command` the START_CAPTURE a
ground station, `icgt start` or the configured mode asks for (`check_capture_request` first checks what
such a request gives, `CaptureRequestError`). Both raise `icgt.device.limits.LimitError`
(naming the limit) for anything the device would refuse, before anything is sent. `denied` is the
MAVLink camera's answer to a refused request: COMMAND_ACK DENIED with the limit's number in
result_param2 and the message as its reason; `announce` sends the message to the ground station as
STATUSTEXT. `configure_refused` says what to do when the device
refuses CONFIGURE anyway (a sensor that does not answer): never go on silently with its old settings.
"""

from __future__ import annotations

import math
from typing import Any

import msgspec

from icgt.device.limits import BoardLimits, LimitError, check_capture
from icgt.errors import IcgtError
from icgt.mavlink.camera import CommandResult, HandlerResult
from icgt.protocol.messages import CaptureMode, Configure, ErrorCode, Limit, PinPolarity, StartCapture
from icgt.recorder.config import RecorderConfig, SensorsSection

__all__ = [
    "CaptureRequestError",
    "ConfigureRefusedError",
    "announce",
    "check_capture_request",
    "configure_command",
    "configure_refused",
    "denied",
    "start_command",
]


class ConfigureRefusedError(IcgtError):
    """The device refused the recorder's CONFIGURE for a reason the recorder cannot work around."""


def _us(seconds: float) -> int:
    return round(seconds * 1e6)


def configure_command(sensors: SensorsSection, limits: BoardLimits) -> Configure:
    """CONFIGURE for these sensor settings, checked against the board's limits (LimitError)."""
    s = sensors
    s.check_limits(limits)
    polarity = int(PinPolarity.FOCUS_ACTIVE_HIGH | PinPolarity.SHUTTER_ACTIVE_HIGH | PinPolarity.PPS_RISING)
    if s.feedback_active_high:
        polarity |= int(PinPolarity.FEEDBACK_ACTIVE_HIGH)
    return Configure(
        imu_rate_hz=s.imu_rate_hz,
        imu_mode=s.imu_mode_code,
        imu_ext_crystal=0,
        range_rate_hz=s.range_rate_hz if s.lidar_model != "none" else 0,
        lidar_model=int(s.lidar_model_code),
        lidar_preset=s.lidar_preset,
        lidar_bias_every=s.lidar_bias_every,
        polarity=polarity,
        feedback_enabled=1 if s.feedback else 0,
        feedback_timeout_us=0 if s.feedback_timeout_s is None else _us(s.feedback_timeout_s),
        feedback_min_lag_us=_us(s.feedback_min_lag_s),
    )


def configure_refused(sensors: SensorsSection, code: int, detail: int, message: str) -> SensorsSection:
    """The sensor settings to retry with after the device refused CONFIGURE: the sensor that does not answer
    switched off (the caller logs it loudly). Anything else raises ConfigureRefusedError: the recorder does
    not record with settings other than the ones it was given."""
    if code == ErrorCode.SENSOR_MISSING and detail == Limit.IMU_MISSING and sensors.imu_rate_hz:
        return msgspec.structs.replace(sensors, imu_rate_hz=0)
    if code == ErrorCode.SENSOR_MISSING and detail == Limit.LIDAR_MISSING and sensors.lidar_model != "none":
        return msgspec.structs.replace(sensors, lidar_model="none")
    raise ConfigureRefusedError(f"{message}: not recording with the device's previous settings")


def start_command(
    config: RecorderConfig, interval_s: float | None, count: int, limits: BoardLimits
) -> tuple[StartCapture, CaptureMode]:
    """START_CAPTURE for a request (interval None: the configured one; count 0: until stopped, 1: one shot,
    N: N shots), checked with the configured feedback against the board's limits (LimitError)."""
    c, s = config.capture, config.sensors
    interval = c.interval_s if interval_s is None else interval_s
    if count == 1:
        mode = CaptureMode.SINGLE
    elif count > 1:
        mode = CaptureMode.COUNT
    else:
        mode = CaptureMode.FOCUS_BURST if c.mode == "focus_burst" else CaptureMode.INTERVAL
    name = {
        CaptureMode.SINGLE: "single",
        CaptureMode.COUNT: "count",
        CaptureMode.FOCUS_BURST: "focus_burst",
        CaptureMode.INTERVAL: "interval",
    }[mode]
    check_capture(
        mode=name,  # type: ignore[arg-type]
        interval_s=interval,
        shutter_pulse_s=c.shutter_pulse_s,
        count=count,
        burst_s=c.burst_s,
        feedback=s.feedback,
        feedback_timeout_s=s.feedback_timeout_s,
        feedback_min_lag_s=s.feedback_min_lag_s,
        limits=limits,
    )
    burst = mode == CaptureMode.FOCUS_BURST
    cmd = StartCapture(
        mode=int(mode),
        interval_us=_us(interval),
        count=count if count > 1 else 0,
        focus_lead_us=_us(c.focus_lead_s) if burst else 0,
        burst_us=_us(c.burst_s) if burst else 0,
        shutter_pulse_us=_us(c.shutter_pulse_s),
        host_timeout_ms=round(c.host_timeout_s * 1e3),
    )
    return cmd, mode


def denied(exc: LimitError) -> HandlerResult:
    """A ground station's request refused for a limit: DENIED, the limit's number in result_param2."""
    return HandlerResult(CommandResult.DENIED, reason=str(exc), result_param2=int(exc.limit))


_STATUSTEXT_BYTES = 50
_MAV_SEVERITY_WARNING = 4
_STATUSTEXT_IDS = iter(range(1, 1 << 62))


def announce(link: Any, exc: LimitError) -> None:
    """Tell the ground station why (STATUSTEXT, warning): the whole message in 50-byte chunks that a ground
    station joins by their id (MAVLink 2), the first chunk alone naming the limit."""
    data = str(exc).encode("utf-8")
    msg_id = next(_STATUSTEXT_IDS) % 0xFFFF + 1
    chunks = [data[i : i + _STATUSTEXT_BYTES] for i in range(0, len(data), _STATUSTEXT_BYTES)]
    head = f"ICGT refused: limit {exc.limit.name.lower()}".encode()[:_STATUSTEXT_BYTES]
    link.send(link.mav.statustext_encode(_MAV_SEVERITY_WARNING, head, 0, 0))
    for seq, chunk in enumerate(chunks):
        link.send(link.mav.statustext_encode(_MAV_SEVERITY_WARNING, chunk, msg_id, seq))


class CaptureRequestError(LimitError):
    """A start-capture request (control socket, ground station, command line) with a value out of range."""

    def __init__(self, message: str, limit: Limit = Limit.NONE) -> None:
        super().__init__(limit, message)


MAX_COUNT = 0xFFFF  # START_CAPTURE.count is a u16


def check_capture_request(interval_s: Any, count: Any, shutter_pulse_s: float) -> tuple[float | None, int]:
    """(interval [s] or None for the configured one, count) checked against the device's limits."""
    if interval_s is not None:
        if isinstance(interval_s, bool) or not isinstance(interval_s, int | float) or not math.isfinite(interval_s):
            raise CaptureRequestError(f"interval_s {interval_s!r}: a number of seconds between shots is needed")
        try:
            check_capture(mode="interval", interval_s=interval_s, shutter_pulse_s=shutter_pulse_s, feedback=False)
        except LimitError as exc:
            raise CaptureRequestError(exc.message, exc.limit) from None
    if isinstance(count, bool) or not isinstance(count, int):
        if isinstance(count, float) and count.is_integer() and math.isfinite(count):
            count = int(count)
        else:
            raise CaptureRequestError(f"count {count!r}: a whole number of shots is needed (0: until stopped)")
    if not 0 <= count <= MAX_COUNT:
        raise CaptureRequestError(f"count {count}: allowed 0 (until stopped) .. {MAX_COUNT}")
    return (float(interval_s) if interval_s is not None else None), count
