"""Every limit the ICGT device enforces, per board, with where each number comes from.

The host's mirror of ``firmware/lib/core/limits.hpp`` (tests/device/test_limits.py reads that header
and fails when a number here differs), checked when the recorder's configuration is loaded
(`icgt.recorder.config`), when `icgt start` or a ground station asks for a capture, and before
CONFIGURE is sent: a value the device would refuse is refused here, naming the limit, before
anything is contacted, never later in flight. The device names the limit it applied in ACK.detail
(`icgt.protocol.messages.Limit`); `describe_refusal` turns that into words.

Sources:
- trigger: 50 ms between shots (20 fps: the Sony Alpha 9's fastest burst, electronic shutter; Sony's
  ILCE-9 specifications), at most 3600 s; shutter pulse 1 ms .. 1 s and shorter than the interval
  (the line must be released between shots) (firmware/lib/core/trigger.cpp).
- pairing (firmware/lib/core/exposure_pairing.cpp): feedback timeout 1 ms .. 2 s, the camera's
  shortest shutter lag 0 .. 1 s and below the timeout; a capture is refused unless the window a
  feedback edge may arrive in (shortest lag .. timeout after its trigger) is shorter than the interval,
  because a longer window would let one missed exposure shift the pairing of every later one. Without
  an explicit timeout it is derived per capture: shortest lag + 7/8 of the interval (single shot: + 0.5 s),
  at most 2 s.
- host silence (firmware/lib/core/host_watchdog.hpp): a capture stops by itself once the host has sent no
  frame for its host timeout, 5 s .. 24 h, or never (0). A live host sends one every second at least.
- BNO055: fusion output 100 Hz (Bosch BNO055 datasheet), fusion modes 0x08 (IMUPLUS) .. 0x0C (NDOF).
- LIDAR-Lite: the driver paces at most 500 Hz; what the part delivers with a preset is Garmin's
  acquisition time plus one 200 us poll (v3 manual: 270 Hz typical at the default preset, v3HP manual:
  > 1 kHz; firmware/lib/core/lidar_lite.cpp). The device accepts a faster rate and silently delivers
  less; the host refuses it, so that the rate asked for is the rate recorded.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

from icgt.errors import IcgtError
from icgt.protocol.messages import Board, ErrorCode, LidarModel, Limit

__all__ = [
    "BOARDS",
    "CORE",
    "BoardLimits",
    "LimitError",
    "auto_feedback_timeout_s",
    "check_capture",
    "check_feedback",
    "check_host_timeout",
    "check_sensors",
    "describe_refusal",
    "for_board",
    "lidar_delivered_rate_hz",
]

CaptureModeName = Literal["interval", "focus_burst", "single", "count"]


class LimitError(IcgtError):
    """A value the device would refuse; `limit` is the protocol's name for the limit broken."""

    def __init__(self, limit: Limit, message: str) -> None:
        super().__init__(message if limit == Limit.NONE else f"{message} (limit {limit.name.lower()})")
        self.limit = limit
        self.message = message


@dataclass(frozen=True, kw_only=True)
class BoardLimits:
    """The limits of one board. Every board runs the same core, so the numbers agree; what differs is stated."""

    board: Board
    min_interval_s: float = 0.050
    max_interval_s: float = 3600.0
    min_pulse_s: float = 0.001
    max_pulse_s: float = 1.0
    min_feedback_timeout_s: float = 0.001
    max_feedback_timeout_s: float = 2.0
    max_feedback_min_lag_s: float = 1.0
    auto_window_fraction: float = 7 / 8
    auto_single_window_s: float = 0.5
    imu_max_rate_hz: int = 100
    imu_fusion_modes: tuple[int, ...] = (0x08, 0x09, 0x0A, 0x0B, 0x0C)
    lidar_driver_max_rate_hz: int = 500
    lidar_presets: tuple[tuple[LidarModel, int], ...] = ((LidarModel.V3, 6), (LidarModel.V3HP, 7))
    min_host_timeout_s: float = 5.0  # START_CAPTURE.host_timeout_ms; 0 = never (the camera goes on)
    max_host_timeout_s: float = 86_400.0
    max_count: int = 0xFFFF_FFFF  # START_CAPTURE.count is a u32
    alarm_min_delay_us: float = 1.0  # the shortest alarm delay: far below any limit above
    note: str = ""

    @property
    def max_fps(self) -> float:
        return 1.0 / self.min_interval_s


CORE = BoardLimits(board=Board.UNKNOWN, note="the firmware core's own checks: what every board enforces")
BOARDS: dict[Board, BoardLimits] = {
    Board.TEENSY36: BoardLimits(
        board=Board.TEENSY36, alarm_min_delay_us=4.0, note="IntervalTimer: >= 36 bus cycles (teensy_board.h)"
    ),
    Board.TEENSY41: BoardLimits(board=Board.TEENSY41, alarm_min_delay_us=4.0, note="IntervalTimer (teensy_board.h)"),
    Board.SIMULATOR: BoardLimits(board=Board.SIMULATOR, note="virtual clock, 1 us alarm (hil_sim/board)"),
    Board.QEMU_MPS2: BoardLimits(board=Board.QEMU_MPS2, note="boot check only (firmware/cross)"),
}


def for_board(board: int | None) -> BoardLimits:
    """The limits of the board HELLO named (CORE for one not known)."""
    try:
        return BOARDS.get(Board(board), CORE) if board is not None else CORE
    except ValueError:
        return CORE


# Garmin's acquisition times at SIG_COUNT_VAL 0x80, scaled 1/4 fixed + 3/4 with the count (lidar_lite.cpp).
_CONVERSION_US = {LidarModel.V3: 3_700, LidarModel.V3HP: 950}
_SIG_COUNT = {
    LidarModel.V3: (0x80, 0x1D, 0x80, 0xFF, 0x80, 0x80),
    LidarModel.V3HP: (0x80, 0x1D, 0x80, 0xFF, 0x80, 0x80, 0x04),
}
_POLL_US = 200


def lidar_delivered_rate_hz(model: LidarModel, preset: int, limits: BoardLimits = CORE) -> int:
    """What the LIDAR-Lite delivers with this preset [Hz] (the firmware's LidarLite::max_rate_hz)."""
    base = _CONVERSION_US[model]
    conversion = base // 4 + (base * 3 // 4) * _SIG_COUNT[model][preset] // 0x80
    return min(limits.lidar_driver_max_rate_hz, 1_000_000 // (conversion + _POLL_US))


def auto_feedback_timeout_s(min_lag_s: float, interval_s: float | None, limits: BoardLimits = CORE) -> float:
    """The timeout the device derives for a capture when none is configured (interval None: a single shot)."""
    lag_us, window_us = round(min_lag_s * 1e6), 0
    if interval_s is None:
        window_us = round(limits.auto_single_window_s * 1e6)
    else:
        window_us = round(interval_s * 1e6) * 7 // 8
    return min(lag_us + window_us, round(limits.max_feedback_timeout_s * 1e6)) / 1e6


def _fail(limit: Limit, message: str) -> LimitError:
    return LimitError(limit, message)


def check_feedback(timeout_s: float | None, min_lag_s: float, limits: BoardLimits = CORE) -> None:
    """CONFIGURE's feedback values on their own (the window against an interval: `check_capture`)."""
    if timeout_s is not None and not limits.min_feedback_timeout_s <= timeout_s <= limits.max_feedback_timeout_s:
        raise _fail(
            Limit.FEEDBACK_TIMEOUT,
            f"feedback_timeout_s {timeout_s:g}: allowed {limits.min_feedback_timeout_s:g} .. "
            f"{limits.max_feedback_timeout_s:g} s, or unset (derived from the interval)",
        )
    if not 0.0 <= min_lag_s <= limits.max_feedback_min_lag_s:
        raise _fail(
            Limit.FEEDBACK_MIN_LAG,
            f"feedback_min_lag_s {min_lag_s:g}: allowed 0 .. {limits.max_feedback_min_lag_s:g} s",
        )
    if timeout_s is not None and min_lag_s >= timeout_s:
        raise _fail(
            Limit.FEEDBACK_MIN_LAG,
            f"feedback_min_lag_s {min_lag_s:g}: must be below feedback_timeout_s ({timeout_s:g} s)",
        )


def check_host_timeout(timeout_s: float, limits: BoardLimits = CORE) -> None:
    """START_CAPTURE's host timeout: 0 (never stop by itself) or min_host_timeout_s .. max_host_timeout_s."""
    if timeout_s != 0.0 and not limits.min_host_timeout_s <= timeout_s <= limits.max_host_timeout_s:
        raise _fail(
            Limit.HOST_TIMEOUT,
            f"host_timeout_s {timeout_s:g}: allowed 0 (never: the camera goes on without a host) or "
            f"{limits.min_host_timeout_s:g} .. {limits.max_host_timeout_s:g} s",
        )


def check_capture(
    *,
    mode: CaptureModeName,
    interval_s: float,
    shutter_pulse_s: float,
    count: int = 0,
    burst_s: float = 0.0,
    feedback: bool = True,
    feedback_timeout_s: float | None = None,
    feedback_min_lag_s: float = 0.0,
    limits: BoardLimits = CORE,
) -> None:
    """A START_CAPTURE (with the feedback settings it will be paired with) checked as the device will; LimitError."""
    if not (math.isfinite(shutter_pulse_s) and limits.min_pulse_s <= shutter_pulse_s <= limits.max_pulse_s):
        raise _fail(
            Limit.SHUTTER_PULSE,
            f"shutter_pulse_s {shutter_pulse_s:g}: allowed {limits.min_pulse_s:g} .. {limits.max_pulse_s:g} s",
        )
    if mode == "count" and not 1 <= count <= limits.max_count:
        raise _fail(Limit.COUNT, f"count {count}: allowed 1 .. {limits.max_count} shots in count mode")
    if mode == "single":
        return
    if not (math.isfinite(interval_s) and limits.min_interval_s <= interval_s <= limits.max_interval_s):
        raise _fail(
            Limit.INTERVAL,
            f"interval_s {interval_s:g}: allowed {limits.min_interval_s:g} .. {limits.max_interval_s:g} s "
            f"(at most {limits.max_fps:g} fps)",
        )
    if shutter_pulse_s >= interval_s:
        raise _fail(
            Limit.PULSE_VS_INTERVAL,
            f"interval_s {interval_s:g}: must be longer than the shutter pulse ({shutter_pulse_s:g} s): "
            "the line must be released between shots",
        )
    if mode == "focus_burst" and burst_s < interval_s:
        raise _fail(Limit.BURST, f"burst_s {burst_s:g}: must be at least interval_s ({interval_s:g} s) in focus_burst")
    if not feedback:
        return
    timeout_s = feedback_timeout_s
    if timeout_s is None:
        timeout_s = auto_feedback_timeout_s(feedback_min_lag_s, interval_s, limits)
    if timeout_s - feedback_min_lag_s >= interval_s - 1e-9:
        raise _fail(
            Limit.FEEDBACK_WINDOW,
            f"interval_s {interval_s:g}: the feedback window (feedback_timeout_s {timeout_s:g} less "
            f"feedback_min_lag_s {feedback_min_lag_s:g} = {timeout_s - feedback_min_lag_s:g} s) must be shorter "
            "than the interval, or one missed exposure would shift the pairing of the next; "
            "leave feedback_timeout_s unset to derive it from the interval",
        )


def check_sensors(
    *,
    imu_rate_hz: int,
    imu_mode: int,
    range_rate_hz: int,
    lidar_model: LidarModel,
    lidar_preset: int,
    lidar_bias_every: int,
    limits: BoardLimits = CORE,
) -> None:
    """CONFIGURE's sensor values against the parts' rates and the drivers' checks; LimitError."""
    if not 0 <= imu_rate_hz <= limits.imu_max_rate_hz:
        raise _fail(
            Limit.IMU_RATE,
            f"imu_rate_hz {imu_rate_hz}: allowed 0 (off) .. {limits.imu_max_rate_hz} Hz (the BNO055's fusion rate)",
        )
    if imu_rate_hz and imu_mode not in limits.imu_fusion_modes:
        raise _fail(Limit.IMU_MODE, f"imu_mode 0x{imu_mode:02X}: a BNO055 fusion mode 0x08 .. 0x0C is needed")
    if lidar_model == LidarModel.NONE or range_rate_hz == 0:
        return
    presets = dict(limits.lidar_presets)
    if not 0 <= lidar_preset < presets[lidar_model]:
        raise _fail(
            Limit.LIDAR_PRESET,
            f"lidar_preset {lidar_preset}: the LIDAR-Lite {lidar_model.name.lower()} has presets "
            f"0 .. {presets[lidar_model] - 1}",
        )
    if lidar_bias_every < 1:
        raise _fail(Limit.LIDAR_BIAS_EVERY, f"lidar_bias_every {lidar_bias_every}: at least 1")
    delivered = lidar_delivered_rate_hz(lidar_model, lidar_preset, limits)
    if not 0 <= range_rate_hz <= delivered:
        raise _fail(
            Limit.RANGE_RATE,
            f"range_rate_hz {range_rate_hz}: the LIDAR-Lite {lidar_model.name.lower()} delivers at most "
            f"{delivered} Hz with preset {lidar_preset}",
        )


_SENSOR_MISSING = {
    Limit.IMU_MISSING: "the BNO055 does not answer",
    Limit.LIDAR_MISSING: "the LIDAR-Lite does not answer",
    Limit.FEEDBACK_LINE_MISSING: "this board has no usable feedback line",
}


def describe_refusal(error_code: int, detail: int, limits: BoardLimits = CORE) -> str:
    """A device refusal (ACK error_code and detail) in words, naming the limit and its value."""
    try:
        code = ErrorCode(error_code).name.lower()
    except ValueError:
        code = f"error {error_code}"
    try:
        limit = Limit(detail)
    except ValueError:
        return f"{code} (detail {detail})"
    if limit == Limit.NONE:
        return code
    if limit in _SENSOR_MISSING:
        return f"{code}: {_SENSOR_MISSING[limit]} (limit {limit.name.lower()})"
    ranges = {
        Limit.INTERVAL: f"{limits.min_interval_s:g} .. {limits.max_interval_s:g} s",
        Limit.SHUTTER_PULSE: f"{limits.min_pulse_s:g} .. {limits.max_pulse_s:g} s",
        Limit.PULSE_VS_INTERVAL: "the pulse must be shorter than the interval",
        Limit.FEEDBACK_WINDOW: "feedback timeout less the shortest lag must be shorter than the interval",
        Limit.FEEDBACK_TIMEOUT: f"{limits.min_feedback_timeout_s:g} .. {limits.max_feedback_timeout_s:g} s",
        Limit.FEEDBACK_MIN_LAG: f"0 .. {limits.max_feedback_min_lag_s:g} s and below the timeout",
        Limit.IMU_RATE: f"0 .. {limits.imu_max_rate_hz} Hz",
        Limit.RANGE_RATE: f"0 .. {limits.lidar_driver_max_rate_hz} Hz",
        Limit.HOST_TIMEOUT: f"0 or {limits.min_host_timeout_s:g} .. {limits.max_host_timeout_s:g} s",
    }
    rule = ranges.get(limit)
    return f"{code}: limit {limit.name.lower()}" + (f" ({rule})" if rule else "")
