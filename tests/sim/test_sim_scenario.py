"""Scenario files: the shipped ones load, defaults fill the rest, and mistakes are named precisely."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import pytest

from icgt.errors import IcgtError
from icgt.sim.scenario import (
    SCENARIO_DIR,
    DeckPass,
    Hover,
    PierScan,
    ScenarioError,
    SimError,
    load_scenario,
    parse_scenario,
)

MINIMAL: dict[str, Any] = {
    "name": "t",
    "duration_s": 10.0,
    "origin": {"lat_deg": 37.88, "lon_deg": 127.73, "alt_m": 76.0},
    "structure": {"point_m": [0.0, 10.0, 0.0], "normal": [0.0, -2.0, 0.0]},
    "trajectory": {"kind": "hover"},
}


def with_change(path: str, value: Any) -> dict[str, Any]:
    data = copy.deepcopy(MINIMAL)
    *parents, last = path.split(".")
    node = data
    for p in parents:
        node = node.setdefault(p, {})
    node[last] = value
    return data


def test_shipped_scenarios_load_with_their_kinds() -> None:
    pier = load_scenario(SCENARIO_DIR / "pier_scan.toml")
    deck = load_scenario("deck_pass")  # a bare name is looked up in hil_sim/scenarios
    hover = load_scenario("hover")
    assert isinstance(pier.trajectory, PierScan)
    assert pier.trajectory.speed_m_s == 0.8 and pier.trajectory.side_overlap == 0.6
    assert pier.camera.capture.mode == "focus_burst"
    assert (pier.camera.capture.focus_s, pier.camera.capture.burst_s, pier.camera.capture.burst_fps) == (0.5, 2.0, 5.0)
    assert 60.0 <= pier.duration_s <= 90.0
    assert isinstance(deck.trajectory, DeckPass) and deck.trajectory.speed_m_s == 10.0
    assert deck.camera.capture.mode == "interval" and deck.camera.capture.interval_s == 0.2
    assert deck.autopilot.rates_hz["global_position_int"] == 50.0
    assert isinstance(hover.trajectory, Hover)
    assert hover.gps.outages_s and hover.gps.denied_s and hover.gps.fix_acquired_after_s > 0
    for sc in (pier, deck, hover):
        assert 30.0 <= abs(sc.clocks.device.drift_ppm) <= 50.0
        assert sc.clocks.autopilot.drift_ppm != 0.0
        assert abs(sc.clocks.camera.offset_s) >= 1.0
        assert sc.source.endswith(".toml")


def test_minimal_scenario_gets_defaults_and_a_unit_normal() -> None:
    sc = parse_scenario(MINIMAL, "mem.toml")
    assert sc.structure.normal == (0.0, -1.0, 0.0)
    assert sc.gps.fix_type == 3 and sc.gps.outages_s == ()
    assert sc.autopilot.rates_hz["gps_raw_int"] == 5.0
    assert sc.clocks.camera.exif_resolution == "1s"
    assert sc.sensors.lidar_max_range_m == 40.0
    assert sc.origin.ellipsoid_height_m == 76.0


def test_focus_burst_plan_is_the_papers_cycle() -> None:
    sc = parse_scenario(with_change("camera.capture", {"mode": "focus_burst", "start_s": 1.0, "stop_s": 6.0}))
    taus = sc.camera.capture.nominal_trigger_taus_s(sc.duration_s)
    # cycle of 2.5 s: 0.5 s focus then 10 shots 0.2 s apart
    assert taus[:10] == pytest.approx([1.5 + 0.2 * k for k in range(10)])
    assert taus[10] == pytest.approx(4.0)
    assert len(taus) == 20


@pytest.mark.parametrize(
    ("path", "value", "key", "words"),
    [
        ("trajectory.kind", "orbit", "trajectory.kind", "must be one of 'pier_scan', 'deck_pass', 'hover', 'survey'"),
        ("gps.hdop", float("nan"), "gps.hdop", "finite"),
        ("gps.outages_s", [[1.0, float("inf")]], "gps.outages_s[0][1]", "finite"),
        ("camera.lever_arm_m", [0.1, 0.2], "camera.lever_arm_m", "an array of 3 values"),
        ("camera.capture.interval_s", 0.0, "camera.capture.interval_s", "must be > 0.0, got 0.0"),
        ("autopilot.rates_hz", {"global_position": 5.0}, "autopilot.rates_hz.global_position", "unknown key"),
        ("autopilot.gcs_heartbeat_systems", [245, 256], "autopilot.gcs_heartbeat_systems[1]", "<= 255, got 256"),
        ("surface", {"cracks": [{"points_m": [[0.0, 1.0]], "width_mm": 0.5}]}, "surface.cracks[0].points_m", "least 2"),
        ("surface", {"spalls": [{"points_m": [[0, 0], [1, 1], [2, 2]]}]}, "surface.spalls[0].points_m", "polygon"),
        ("trajectory.speed_m_s", 1.0, "trajectory.speed_m_s", "unknown key"),  # not a hover parameter
        ("gps.noise_m", 1.0, "gps.noise_m", "unknown key"),
        ("gps.outages_s", [[5.0, 2.0]], "gps.outages_s[0]", "after start"),
        ("gps.fix_type", 9, "gps.fix_type", "<= 6"),
        ("clocks.camera.exif_resolution", "1ms", "clocks.camera.exif_resolution", "one of"),
        ("clocks.device.offset_s", "soon", "clocks.device.offset_s", "number"),
        ("duration_s", "long", "duration_s", "number"),
        ("structure.normal", [0.0, 0.0, 0.0], "structure.normal", "zero vector"),
        ("faults.device_unplugs_s", [[3.0, 0.0]], "faults.device_unplugs_s[0]", "duration"),
        ("autopilot.mavlink1_messages", ["CAMERA_INFORMATION"], "autopilot.mavlink1_messages", "not one of"),
        ("camera.capture.stop_s", 0.5, "camera.capture.stop_s", "after start_s"),
    ],
)
def test_errors_name_the_file_and_the_key(path: str, value: Any, key: str, words: str) -> None:
    with pytest.raises(ScenarioError) as info:
        parse_scenario(with_change(path, value), "scenarios/bad.toml")
    message = str(info.value)
    assert message.startswith(f"scenarios/bad.toml: {key}: "), message
    assert words in message


def test_missing_required_key_and_kind_specific_checks() -> None:
    data = copy.deepcopy(MINIMAL)
    del data["origin"]["lat_deg"]
    with pytest.raises(ScenarioError, match=r"x.toml: origin.lat_deg: missing"):
        parse_scenario(data, "x.toml")
    deck = with_change("trajectory", {"kind": "deck_pass", "along_deg": 0.0})  # across the face, not along
    with pytest.raises(ScenarioError, match=r"trajectory\.along_deg: .*not parallel"):
        parse_scenario(deck, "x.toml")
    pier = with_change("structure.normal", [0.0, 0.0, -1.0])
    pier["trajectory"] = {"kind": "pier_scan"}
    with pytest.raises(ScenarioError, match="vertical face"):
        parse_scenario(pier, "x.toml")


def test_file_errors_are_sim_errors(tmp_path: Path) -> None:
    bad = tmp_path / "broken.toml"
    bad.write_text("name = \n")
    with pytest.raises(ScenarioError, match=r"broken\.toml: not valid TOML"):
        load_scenario(bad)
    with pytest.raises(SimError, match="cannot read"):
        load_scenario(tmp_path / "absent.toml")
    assert issubclass(ScenarioError, IcgtError)


@pytest.mark.parametrize(
    ("path", "value", "new"),
    [
        ("camera.capture.focus_ms", 500, "focus_s = 0.5"),
        ("camera.exposure_us", 1000, "exposure_s = 0.001"),
        ("clocks.device.offset_us", 7_351_224, "offset_s = 7.351224"),
        ("autopilot.latency_ms", 2.0, "latency_s = 0.002"),
        ("link.usb_jitter_us", 60, "usb_jitter_s = 6e-05"),
    ],
)
def test_a_key_of_an_older_version_is_refused_with_its_new_name_and_value(path: str, value: Any, new: str) -> None:
    """Times are seconds in every scenario key now; an old file says what to write instead."""
    with pytest.raises(ScenarioError) as info:
        parse_scenario(with_change(path, value), "old.toml")
    message = str(info.value)
    assert message.startswith(f"old.toml: {path}: "), message
    assert f"write {new}" in message, message


def test_a_profile_fills_only_the_keys_the_file_leaves_out() -> None:
    px4 = parse_scenario(with_change("autopilot", {"profile": "px4", "latency_s": 0.009}))
    assert px4.autopilot.latency_s == 0.009  # the file's value
    assert px4.autopilot.latency_jitter_s == 0.004 and px4.autopilot.firmware == "px4"  # the profile's


def test_every_scenario_in_the_repository_loads() -> None:
    """The shipped scenarios and every test flight's file: a renamed key left in one would fail its flight late."""
    root = Path(__file__).resolve().parents[2]
    files = sorted(SCENARIO_DIR.glob("*.toml")) + sorted((root / "tests").rglob("*.toml"))
    loaded = [load_scenario(p) for p in files]
    assert len(loaded) >= 20 and all(sc.duration_s > 0 for sc in loaded)
