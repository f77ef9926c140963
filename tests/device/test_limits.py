"""The device's limits, one table: every refused value names its limit, before anything is contacted.

The same values are refused when the recorder's configuration is loaded, when `icgt start` asks over
the control socket and when a ground station sends MAV_CMD_IMAGE_START_CAPTURE (COMMAND_ACK DENIED with
the limit's number in result_param2); the device is never sent the command. The host's numbers are
checked against the firmware's own header (firmware/lib/core/limits.hpp).
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import msgspec
import pytest

from icgt.control import ControlError, ControlServer, request
from icgt.device.limits import (
    BOARDS,
    CORE,
    LimitError,
    auto_feedback_timeout_s,
    describe_refusal,
    lidar_delivered_rate_hz,
)
from icgt.mavlink.camera import CommandResult, HandlerResult
from icgt.protocol.messages import Board, LidarModel, Limit
from icgt.recorder.capture_control import CaptureHandler
from icgt.recorder.config import ConfigError, RecorderConfig, parse_config
from icgt.recorder.recorder import Recorder

HEADER = Path(__file__).resolve().parents[2] / "firmware" / "lib" / "core" / "limits.hpp"


def _header_constants() -> dict[str, int]:
    text = HEADER.read_text()
    return {
        m.group(1): int(m.group(2).replace("'", "").rstrip("u"), 0)
        for m in re.finditer(r"inline constexpr \w+ (k\w+) = ([0-9x'A-Fa-f]+u?);", text)
    }


def test_the_host_states_the_firmwares_numbers() -> None:
    c = _header_constants()
    assert c["kMinIntervalUs"] == round(CORE.min_interval_s * 1e6)
    assert c["kMaxIntervalUs"] == round(CORE.max_interval_s * 1e6)
    assert c["kMinPulseUs"] == round(CORE.min_pulse_s * 1e6)
    assert c["kMaxPulseUs"] == round(CORE.max_pulse_s * 1e6)
    assert c["kMinFeedbackTimeoutUs"] == round(CORE.min_feedback_timeout_s * 1e6)
    assert c["kMaxFeedbackTimeoutUs"] == round(CORE.max_feedback_timeout_s * 1e6)
    assert c["kMaxFeedbackMinLagUs"] == round(CORE.max_feedback_min_lag_s * 1e6)
    assert c["kAutoWindowEighths"] / 8 == CORE.auto_window_fraction
    assert c["kAutoSingleWindowUs"] == round(CORE.auto_single_window_s * 1e6)
    assert c["kImuMaxRateHz"] == CORE.imu_max_rate_hz
    assert (c["kImuFirstFusionMode"], c["kImuLastFusionMode"]) == (CORE.imu_fusion_modes[0], CORE.imu_fusion_modes[-1])
    assert c["kLidarMaxRateHz"] == CORE.lidar_driver_max_rate_hz
    assert c["kMinHostTimeoutMs"] == round(CORE.min_host_timeout_s * 1e3)
    assert c["kMaxHostTimeoutMs"] == round(CORE.max_host_timeout_s * 1e3)
    assert (c["kLidarV3Presets"], c["kLidarV3hpPresets"]) == tuple(n for _, n in CORE.lidar_presets)
    for board in (Board.TEENSY36, Board.TEENSY41, Board.SIMULATOR, Board.QEMU_MPS2):
        assert BOARDS[board].min_interval_s == CORE.min_interval_s, board  # one core on every board


def test_derived_values() -> None:
    assert lidar_delivered_rate_hz(LidarModel.V3, 0) == 256  # Garmin: 270 Hz typical
    assert lidar_delivered_rate_hz(LidarModel.V3, 3) == 150  # the long-range preset is slower
    assert lidar_delivered_rate_hz(LidarModel.V3HP, 0) == 500  # the driver's cap
    assert auto_feedback_timeout_s(0.04, 0.05) == pytest.approx(0.08375)
    assert auto_feedback_timeout_s(0.0, None) == 0.5
    assert auto_feedback_timeout_s(0.9, 3600.0) == 2.0
    assert describe_refusal(3, int(Limit.INTERVAL)) == "out_of_range: limit interval (0.05 .. 3600 s)"
    assert describe_refusal(3, int(Limit.HOST_TIMEOUT)) == "out_of_range: limit host_timeout (0 or 5 .. 86400 s)"


# (config overrides, request interval_s, request count, the limit named)
REQUESTS: list[tuple[dict[str, Any], float | None, int, Limit]] = [
    ({}, 0.04, 0, Limit.INTERVAL),  # 25 fps: above the trigger's 20
    ({}, 4000.0, 0, Limit.INTERVAL),
    ({"capture": {"shutter_pulse_s": 0.06}}, 0.05, 0, Limit.PULSE_VS_INTERVAL),
    ({"sensors": {"feedback_timeout_s": 0.15}}, 0.1, 0, Limit.FEEDBACK_WINDOW),  # the old 6.6 fps ceiling
    ({"sensors": {"feedback_timeout_s": 0.15}}, 0.05, 40, Limit.FEEDBACK_WINDOW),  # count mode too
    ({"sensors": {"feedback_timeout_s": 0.15, "feedback_min_lag_s": 0.02}}, 0.12, 0, Limit.FEEDBACK_WINDOW),
    (
        {"capture": {"mode": "focus_burst", "burst_s": 1.0}, "sensors": {"feedback_timeout_s": 0.15}},
        0.1,
        0,
        Limit.FEEDBACK_WINDOW,
    ),
    ({"capture": {"mode": "focus_burst", "burst_s": 0.3}}, 0.5, 0, Limit.BURST),
]
IDS = [f"{r[3].name.lower()}-{i}" for i, r in enumerate(REQUESTS)]


class _NoDevice:
    """Stands where the device link would be: any command sent is a test failure."""

    def __init__(self) -> None:
        self.sent: list[Any] = []

    def command(self, msg: Any) -> None:
        self.sent.append(msg)
        raise AssertionError(f"{msg} reached the device")


def _recorder(overrides: dict[str, Any]) -> tuple[Recorder, _NoDevice]:
    rec = Recorder(parse_config(overrides, "test.toml"))
    device = _NoDevice()
    rec.links.device = device  # type: ignore[assignment]
    return rec, device


@pytest.mark.parametrize(("overrides", "interval_s", "count", "limit"), REQUESTS, ids=IDS)
def test_a_request_over_the_control_socket_names_the_limit(
    tmp_path: Path, overrides: dict[str, Any], interval_s: float | None, count: int, limit: Limit
) -> None:
    rec, device = _recorder(overrides)
    server = ControlServer(tmp_path / "c.sock", rec.control_requests.handle)
    server.start()
    try:
        with pytest.raises(ControlError, match=rf"limit {limit.name.lower()}\b"):
            request(tmp_path / "c.sock", {"command": "start", "interval_s": interval_s, "count": count})
    finally:
        server.stop()
    assert device.sent == []


@pytest.mark.parametrize(("overrides", "interval_s", "count", "limit"), REQUESTS, ids=IDS)
def test_a_ground_station_request_is_denied_with_the_limit(
    overrides: dict[str, Any], interval_s: float | None, count: int, limit: Limit
) -> None:
    rec, device = _recorder(overrides)
    answer = CaptureHandler(rec.capture).start(interval_s or 0.0, count)
    assert isinstance(answer, HandlerResult)
    assert answer.result == CommandResult.DENIED
    assert answer.result_param2 == int(limit)
    assert f"limit {limit.name.lower()}" in answer.reason
    assert device.sent == []


@pytest.mark.parametrize(("overrides", "interval_s", "count", "limit"), REQUESTS, ids=IDS)
def test_the_same_values_in_the_configuration_are_refused_when_it_is_loaded(
    overrides: dict[str, Any], interval_s: float | None, count: int, limit: Limit
) -> None:
    capture = {**overrides.get("capture", {}), "interval_s": interval_s}
    if count == 0:
        with pytest.raises(ConfigError) as err:
            parse_config({**overrides, "capture": capture}, "flight.toml")
        text = str(err.value)
        assert (text.startswith("flight.toml: ") and "interval_s" in text) or "burst_s" in text, text
        assert f"limit {limit.name.lower()}" in text or "<=" in text or ">=" in text, text


# Sensor and feedback settings: refused when the file is loaded, naming the limit.
SENSORS: list[tuple[dict[str, Any], str]] = [
    ({"range_rate_hz": 300}, "limit range_rate"),  # a v3 at preset 0 delivers 256 Hz
    ({"range_rate_hz": 200, "lidar_preset": 3}, "limit range_rate"),  # 150 Hz at the long-range preset
    ({"lidar_preset": 6, "lidar_model": "v3"}, "limit lidar_preset"),
    ({"feedback_timeout_s": 0.05, "feedback_min_lag_s": 0.05}, "limit feedback_min_lag"),
    ({"imu_rate_hz": 200}, "<= 100"),
    ({"feedback_timeout_s": 3.0}, "<= 2.0"),
]


@pytest.mark.parametrize(("sensors", "named"), SENSORS, ids=[n for _, n in SENSORS])
def test_sensor_limits_are_refused_when_the_configuration_is_loaded(sensors: dict[str, Any], named: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({"sensors": sensors}, "flight.toml")
    text = str(err.value)
    assert "[sensors]" in text and named in text, text
    assert next(iter(sensors)) in text, text


def test_twenty_fps_is_accepted_in_every_mode_with_the_derived_timeout() -> None:
    from icgt.recorder.capture import start_command

    cfg = parse_config({"capture": {"interval_s": 0.05}, "sensors": {"feedback_min_lag_s": 0.04}}, "f")
    for count in (0, 1, 40):
        cmd, _ = start_command(cfg, 0.05, count, CORE)
        assert cmd.interval_us == 50_000
    burst = msgspec.structs.replace(
        cfg, capture=msgspec.structs.replace(cfg.capture, mode="focus_burst", burst_s=1.0, focus_lead_s=0.3)
    )
    cmd, _ = start_command(burst, None, 0, CORE)
    assert (cmd.interval_us, cmd.burst_us, cmd.focus_lead_us) == (50_000, 1_000_000, 300_000)
    with pytest.raises(LimitError) as err:
        start_command(cfg, 0.049, 0, CORE)
    assert err.value.limit == Limit.INTERVAL
    assert isinstance(RecorderConfig(), RecorderConfig)  # the defaults pass their own checks


def test_a_refused_configure_is_never_recorded_through_silently() -> None:
    from icgt.protocol.messages import ErrorCode
    from icgt.recorder.capture import ConfigureRefusedError, configure_command, configure_refused

    sensors = RecorderConfig().sensors
    without_imu = configure_refused(sensors, int(ErrorCode.SENSOR_MISSING), int(Limit.IMU_MISSING), "x")
    assert without_imu.imu_rate_hz == 0 and configure_command(without_imu, CORE).imu_rate_hz == 0
    without_lidar = configure_refused(sensors, int(ErrorCode.SENSOR_MISSING), int(Limit.LIDAR_MISSING), "x")
    assert configure_command(without_lidar, CORE).range_rate_hz == 0
    for code, detail in [
        (ErrorCode.OUT_OF_RANGE, Limit.IMU_RATE),
        (ErrorCode.SENSOR_MISSING, Limit.FEEDBACK_LINE_MISSING),
        (ErrorCode.BUSY_CAPTURING, Limit.NONE),
    ]:
        with pytest.raises(ConfigureRefusedError, match="not recording with the device's previous settings"):
            configure_refused(sensors, int(code), int(detail), "device refused CONFIGURE")
    cmd = configure_command(sensors, CORE)
    assert (cmd.feedback_timeout_us, cmd.feedback_min_lag_us) == (0, 0)  # derived per capture by the device


def test_the_ground_station_is_told_why_in_statustext() -> None:
    from pymavlink.dialects.v20 import common as mavlink2

    from icgt.recorder.capture import announce

    class Link:
        def __init__(self) -> None:
            self.mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=100)
            self.sent: list[Any] = []

        def send(self, msg: Any) -> bool:
            self.sent.append(msg)
            return True

    link = Link()
    exc = LimitError(Limit.FEEDBACK_WINDOW, "interval_s 0.1: the feedback window (0.15 s) must be shorter " * 2)
    announce(link, exc)
    head, *chunks = link.sent
    assert head.text == "ICGT refused: limit feedback_window" and head.id == 0
    assert {c.id for c in chunks} == {chunks[0].id} and chunks[0].id != 0
    assert [c.chunk_seq for c in chunks] == list(range(len(chunks)))
    assert "".join(c.text for c in chunks) == str(exc)
