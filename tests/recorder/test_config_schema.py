"""The recorder's configuration schema: every key refuses bad values with the key, the value and the rule named,
before anything is contacted (parsing is pure); the start-capture request is checked the same way."""

from __future__ import annotations

import math
from pathlib import Path

import msgspec
import pytest

from icgt.recorder.capture import CaptureRequestError, check_capture_request
from icgt.recorder.config import ConfigError, RecorderConfig, load_config, parse_config

BAD: list[tuple[str, str, object]] = [
    ("device", "url", ""),
    ("device", "set_rtc", "yes"),
    ("device", "wait_s", -1.0),
    ("device", "running_capture", "resume"),
    ("mavlink", "url", ""),
    ("mavlink", "system_id", 300),
    ("mavlink", "system_id", 0),
    ("mavlink", "component_id", 256),
    ("mavlink", "ground_station_systems", ["x"]),
    ("mavlink", "ground_station_systems", []),
    ("mavlink", "global_position_hz", 1e9),
    ("mavlink", "global_position_hz", 0),
    ("mavlink", "signing_key_file", ""),
    ("mavlink", "signing_key_file", 7),
    ("capture", "mode", "burst"),
    ("capture", "interval_s", 0.0),
    ("capture", "interval_s", -1.0),
    ("capture", "interval_s", math.inf),
    ("capture", "focus_lead_s", 11.0),
    ("capture", "burst_s", -2.0),
    ("capture", "shutter_pulse_s", 0.0),
    ("capture", "host_timeout_s", 4.9),  # under the device's 5 s (limit host_timeout)
    ("capture", "host_timeout_s", -1.0),
    ("capture", "host_timeout_s", 1e6),
    ("sensors", "imu_rate_hz", 200),
    ("sensors", "imu_rate_hz", 1.5),
    ("sensors", "imu_mode", "amg"),
    ("sensors", "range_rate_hz", 501),
    ("sensors", "lidar_model", "v4"),
    ("sensors", "lidar_preset", 9),
    ("sensors", "lidar_bias_every", 0),
    ("sensors", "feedback", 1),
    ("sensors", "feedback_timeout_s", 0.0),
    ("sensors", "feedback_timeout_s", 5.0),
    ("sensors", "feedback_min_lag_s", -0.01),
    ("sensors", "feedback_min_lag_s", 1.5),
    ("sensors", "feedback_active_high", "no"),
    ("camera", "focal_length_mm", 0),
    ("camera", "sensor_width_mm", -1.0),
    ("camera", "image_width_px", 0),
    ("camera", "image_height_px", 2.5),
    ("camera", "mount_pitch_deg", 400.0),
    ("camera", "lever_arm_body_m", [1.0, 2.0]),
    ("camera", "lever_arm_body_m", [0.0, 0.0, 50.0]),
    ("camera", "gimbal_stabilised", "true"),
    ("camera", "attitude_source", "board"),
    ("camera", "gimbal_max_gap_s", 0.0),
    ("camera", "gimbal_max_hold_s", -0.1),
    ("camera", "board_imu_heading", "compass"),
    ("camera", "board_imu_heading_offset_deg", 400.0),
    ("camera", "board_imu_heading_window_s", 0.0),
    ("camera", "board_imu_heading_window_s", 30.0),
    ("camera", "board_imu_max_yaw_rate_deg_s", 0.0),
    ("camera", "board_imu_max_gap_s", 2.0),
    ("camera", "range_min_m", -1.0),
    ("camera", "range_max_m", 0.0),
    ("camera", "max_wait_s", -5.0),
    ("camera", "max_wait_s", 60.0),
    ("sync", "autopilot_component", 0),
    ("sync", "autopilot_timeout_s", 0.0),
    ("sync", "timesync_timeout_s", -1.0),
    ("sync", "one_way_min_delay_allowance_s", 2.0),  # 2 s: a value in milliseconds written as seconds
    ("sync", "telemetry_retention_s", 0.0),
    ("camera", "surface_normal_enu", [0.0, 0.0]),
    ("camera", "origin", [95.0, 0.0, 0.0]),
    ("mavlink", "udp_receive_buffer_bytes", 1024),
    ("mavlink", "udp_receive_buffer_bytes", 1 << 31),
    ("output", "chunk_interval_s", 1.0),  # with 0.25 s in flight, kill -9 would lose more than 1 s
    ("output", "chunk_interval_s", 5.0),
    ("output", "chunk_interval_s", 0.0),
    ("output", "dir", 5),
    ("output", "file_mode", 0o1777),
]


@pytest.mark.parametrize(("section", "key", "value"), BAD, ids=[f"{s}.{k}={v!r}" for s, k, v in BAD])
def test_every_bad_value_is_refused_naming_the_key(section: str, key: str, value: object) -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({section: {key: value}}, "flight.toml")
    text = str(err.value)
    assert text.startswith("flight.toml: ") and f"[{section}]" in text and key in text, text


def test_every_key_of_every_section_is_in_the_table() -> None:
    cfg = RecorderConfig()
    keys = {(s, k) for s, k, _ in BAD}
    for section in ("device", "mavlink", "capture", "sensors", "sync", "output"):
        for name in msgspec.structs.fields(getattr(cfg, section)):
            assert (section, name.name) in keys, f"no bad-value case for [{section}] {name.name}"
    checked_camera = {k for s, k, _ in BAD if s == "camera"}
    unchecked = {f.name for f in msgspec.structs.fields(cfg.camera)} - checked_camera
    # free-valued camera fields (angles are checked through mount_pitch_deg, limits through max_wait_s)
    assert unchecked <= {
        "mount_roll_deg",
        "mount_yaw_deg",
        "range_stale_s",
        "max_position_error_m",
        "max_gps_gap_s",
        "max_accel_m_s2",
        "local_drift_m_per_s",
        "max_interpolation_gap_s",
        "max_extrapolation_m",
        "unseen_accel_h_m_s2",
        "unseen_accel_v_m_s2",
        "unseen_rate_rad_s2",
        "attitude_accuracy_deg",
        "max_clock_uncertainty_s",
        "blur_limit_px",
    }, unchecked


def test_values_against_each_other() -> None:
    with pytest.raises(ConfigError, match=r"shutter_pulse_s .* shorter than interval_s"):
        parse_config({"capture": {"interval_s": 0.1, "shutter_pulse_s": 0.2}}, "f")
    with pytest.raises(ConfigError, match=r"burst_s .* at least interval_s"):
        parse_config({"capture": {"mode": "focus_burst", "interval_s": 0.5, "burst_s": 0.2}}, "f")
    with pytest.raises(ConfigError, match="range_min_m"):
        parse_config({"camera": {"range_min_m": 10.0, "range_max_m": 5.0}}, "f")
    with pytest.raises(ConfigError, match=r"presets 0 \.\. 5 \(limit lidar_preset\)"):
        parse_config({"sensors": {"lidar_model": "v3", "lidar_preset": 6}}, "f")


def test_unknown_sections_and_keys_are_refused() -> None:
    with pytest.raises(ConfigError, match="unknown key `camra`"):
        parse_config({"camra": {}}, "f")
    with pytest.raises(ConfigError, match=r"\[capture\].*unknown key `intervall_s`"):
        parse_config({"capture": {"intervall_s": 0.2}}, "f")
    with pytest.raises(ConfigError, match=r"\[camera\].*unknown key `focal_mm`"):
        parse_config({"camera": {"focal_mm": 24.0}}, "f")
    with pytest.raises(ConfigError, match=r"\[sync\].*unknown key `autopilot_timeout_ms`"):
        parse_config({"sync": {"autopilot_timeout_ms": 3000}}, "f")


@pytest.mark.parametrize(
    ("section", "old", "value", "new"),
    [
        ("camera", "max_wait_ms", 250, "max_wait_s = 0.25"),
        ("camera", "range_stale_ms", 50.0, "range_stale_s = 0.05"),
        ("camera", "max_clock_uncertainty_us", 1000, "max_clock_uncertainty_s = 0.001"),
        ("sync", "one_way_min_delay_allowance_ms", 5, "one_way_min_delay_allowance_s = 0.005"),
    ],
)
def test_a_renamed_key_is_refused_naming_its_new_name_and_value(section: str, old: str, value: float, new: str) -> None:
    with pytest.raises(ConfigError) as err:
        parse_config({section: {old: value}}, "old.toml")
    text = str(err.value)
    assert text.startswith(f"old.toml: [{section}] {old} was renamed") and new in text, text


def test_a_retired_key_is_refused_saying_so() -> None:
    with pytest.raises(ConfigError, match=r"\[camera\] stale_pose_ms is no longer used"):
        parse_config({"camera": {"stale_pose_ms": 100.0}}, "f")


def test_sync_section_reaches_the_synchroniser() -> None:
    from icgt.sync import SyncConfig

    cfg = parse_config(
        {"sync": {"autopilot_timeout_s": 5.0, "autopilot_component": 2}, "mavlink": {"system_id": 4}}, "f"
    )
    sync = SyncConfig.of(cfg.sync, cfg.camera, autopilot_system=cfg.mavlink.system_id, require_signed_autopilot=False)
    assert (sync.autopilot_timeout_s, sync.autopilot_component, sync.autopilot_system) == (5.0, 2, 4)
    assert sync.timesync_timeout_s == 1.0 and sync.geotag == cfg.camera


def test_a_good_file_loads_and_its_text_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "r.toml"
    path.write_text(
        "[mavlink]\nsystem_id = 3\ncomponent_id = 101\n[camera]\nlever_arm_body_m = [0.25, 0.0, 0.12]\n"
        '[output]\ndir = "out"\nfile_mode = 0o640\n'
    )
    cfg = load_config(path)
    assert (cfg.mavlink.system_id, cfg.mavlink.component_id) == (3, 101)
    assert cfg.camera.lever_arm_body_m == (0.25, 0.0, 0.12) and cfg.output.dir == Path("out")
    import json

    again = parse_config({k: v for k, v in json.loads(cfg.as_text()).items() if k != "source"}, "again")
    assert again == msgspec.structs.replace(cfg, source="again")


def test_unreadable_files_are_clear_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[capture\n")
    with pytest.raises(ConfigError, match=r"bad\.toml"):
        load_config(bad)
    binary = tmp_path / "bin.toml"
    binary.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(ConfigError, match="not UTF-8"):
        load_config(binary)


@pytest.mark.parametrize(
    ("interval", "count"),
    [(math.inf, 0), (math.nan, 0), (-1.0, 0), (0.0, 0), (0.01, 0), (1e6, 0), ("x", 0), (None, -5), (None, 1e400),
     (None, 70_000), (None, 2.5), (None, True), (0.015, 0)],
)  # fmt: skip
def test_capture_requests_out_of_range_are_refused_naming_the_limit(interval: object, count: object) -> None:
    with pytest.raises(CaptureRequestError):
        check_capture_request(interval, count, shutter_pulse_s=0.02)


def test_good_capture_requests_pass() -> None:
    assert check_capture_request(None, 0, 0.02) == (None, 0)
    assert check_capture_request(0.05, 10, 0.02) == (0.05, 10)
    assert check_capture_request(2, 1.0, 0.02) == (2.0, 1)
