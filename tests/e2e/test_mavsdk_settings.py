"""The camera's settings through MAVSDK's Camera settings API (PyPI `mavsdk` 4.1, its native library), against
`icgt record` on a simulated flight (issue 33): MAVSDK fetches the camera definition file named by
CAMERA_INFORMATION.cam_definition_uri over MAVLink FTP (`mftp://icgt_camera.xml`), parses it, reads every
parameter with PARAM_EXT, and a setting it changes changes what the device does.

One flight (module fixture), in this order: the client lists the settings and their options, reads the
current values (the recorder's configuration), sets trigger mode focus_burst with a 0.6 s burst and a 0.4 s
focus lead, has a setting refused (a shutter pulse longer than the interval), then runs a 0.2 s photo
interval for 3 s. The device's own EXPOSURE records say the capture was a focus-then-burst one (focus_cycle
flag) and its trigger times come in bursts of 3 shots 0.2 s apart, a 0.6 s gap between bursts (the focus
lead before each burst's first shot). MAVSDK caches definition files by model, vendor and version in
$HOME/.cache/mavsdk/camera, read when its Camera plugin is made: the plugin is made with HOME set to an empty
folder of this test's (other tests' MAVSDK clients, perhaps running at the same time, fill the user's), so the
file really comes over FTP.
"""

from __future__ import annotations

import itertools
import json
import os
import time
import tomllib
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera, CameraError, Option, Setting
from mcap.reader import make_reader

from icgt.ingest import read
from icgt.protocol.messages import ExposureFlags
from icgt.recording import layout
from icgt.sim.live_recorder import LiveRecorder
from icgt.sim.scenario import load_scenario

SCENARIO = load_scenario(Path(__file__).with_name("mavsdk_hover.toml"))
CAMERA = 100
NAMES = {"ICGT_TRIG_MODE", "ICGT_INTERVAL", "ICGT_FOCUS_LEAD", "ICGT_BURST", "ICGT_SHUTTER_PW"}


def wait_for(predicate: Callable[[], Any], timeout: float, step: float = 0.2) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        time.sleep(step)
    return predicate()


def _try(fn: Callable[[], Any]) -> Any:
    try:
        return fn()
    except CameraError:
        return None


def _current(camera: Camera) -> dict[str, str]:
    got = _try(lambda: camera.get_current_settings(CAMERA)) or []
    return {s.setting_id: s.option.option_id for s in got}


@dataclass
class Session:
    live: LiveRecorder
    cache: Path = Path()  # MAVSDK's definition cache of this test's client
    options: dict[str, Any] = field(default_factory=dict)  # setting id -> SettingOptions
    initial: dict[str, str] = field(default_factory=dict)
    after_set: dict[str, str] = field(default_factory=dict)
    refused: str = ""
    after_refusal: dict[str, str] = field(default_factory=dict)
    started_ns: int = 0
    cached_after: list[Path] = field(default_factory=list)
    mcap: Path | None = None


def _cached(cache: Path) -> list[Path]:
    return sorted(cache.glob("camera_definition-ICGT*.cache")) if cache.is_dir() else []


def _camera_with_home(system: Any, home: Path) -> Camera:
    """MAVSDK's Camera plugin made while HOME is ``home`` (where it puts its definition cache), HOME restored."""
    old = os.environ.get("HOME")
    os.environ["HOME"] = str(home)
    try:
        return Camera(system)
    finally:
        if old is None:
            del os.environ["HOME"]
        else:
            os.environ["HOME"] = old


@pytest.fixture(scope="module")
def session(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Session]:
    home = tmp_path_factory.mktemp("mavsdk_home")
    live = LiveRecorder(SCENARIO, tmp_path_factory.mktemp("mavsdk_settings"))
    live.start()
    s = Session(live, cache=home / ".cache" / "mavsdk" / "camera")
    client = None
    try:
        client = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        client.add_any_connection(live.mavsdk_url)
        system = client.first_autopilot(30.0)
        assert system is not None, "MAVSDK never saw the simulated autopilot"
        camera = _camera_with_home(system, home)
        assert wait_for(lambda: camera.camera_list().cameras, 30.0), "MAVSDK never listed the camera"
        options = wait_for(lambda: _try(lambda: camera.get_possible_setting_options(CAMERA)), 30.0)
        assert options, f"the settings never became available; see {live.recorder_log}"
        s.options = {o.setting_id: o for o in options}
        s.initial = wait_for(lambda: c if set(c := _current(camera)) == NAMES else None, 20.0) or _current(camera)
        for name, value in (("ICGT_TRIG_MODE", "1"), ("ICGT_BURST", "0.6"), ("ICGT_FOCUS_LEAD", "0.4")):
            camera.set_setting(CAMERA, Setting(setting_id=name, option=Option(option_id=value)))
        s.after_set = _current(camera)
        try:  # 0.9 s pulse: not shorter than the 0.5 s interval, the device would refuse it
            camera.set_setting(CAMERA, Setting(setting_id="ICGT_SHUTTER_PW", option=Option(option_id="0.9")))
        except CameraError as exc:
            s.refused = str(exc)
        s.after_refusal = _current(camera)
        assert live.session is not None
        live.session.wait_until(5.0)  # telemetry flowing
        s.started_ns = time.monotonic_ns()
        camera.start_photo_interval(CAMERA, 0.2)
        time.sleep(3.0)
        camera.stop_photo_interval(CAMERA)
        time.sleep(1.0)
        s.cached_after = _cached(s.cache)
    finally:
        if client is not None:
            client.destroy()
        s.mcap = live.stop()
    yield s


def _counters(mcap: Path) -> dict[str, Any]:
    with mcap.open("rb") as fh:
        records = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(topics=[layout.COUNTERS])]
    return records[-1]


def _find(counters: dict[str, Any], key: str) -> int | None:
    """A counter anywhere in the nested /icgt/counters record."""
    for k, v in counters.items():
        if k == key and isinstance(v, int):
            return v
        if isinstance(v, dict) and (got := _find(v, key)) is not None:
            return got
    return None


def test_mavsdk_fetches_the_definition_over_mavlink_ftp_and_lists_the_settings(session: Session) -> None:
    assert len(session.cached_after) == 1  # downloaded (the cache was empty), then cached by MAVSDK
    assert session.mcap is not None
    counters = _counters(session.mcap)
    assert (_find(counters, "ftp_files_opened") or 0) >= 1 and (_find(counters, "ftp_bytes_read") or 0) > 0
    # what MAVSDK cached is the file the recorder served, a camera definition of the schema
    root = ET.parse(session.cached_after[0]).getroot()
    assert root.tag == "mavlinkcamera" and root.findtext("definition/vendor") == "ICGT"
    assert {p.get("name") for p in root.iter("parameter")} == NAMES | {"CAM_MODE"}
    assert set(session.options) == NAMES  # CAM_MODE (photo only) shows no control
    mode = session.options["ICGT_TRIG_MODE"]
    assert not mode.is_range and [o.option_id for o in mode.options] == ["0", "1"]
    assert [o.option_description for o in mode.options] == ["Interval", "Focus, then burst"]
    pulse = session.options["ICGT_SHUTTER_PW"]
    assert pulse.is_range and [float(o.option_id) for o in pulse.options[:2]] == pytest.approx([0.001, 1.0])


def test_current_settings_are_the_recorders_configuration(session: Session) -> None:
    capture = tomllib.loads((session.live.out_dir / "recorder.toml").read_text()).get("capture", {})
    got = session.initial
    assert got["ICGT_TRIG_MODE"] == ("1" if capture.get("mode") == "focus_burst" else "0")
    assert float(got["ICGT_INTERVAL"]) == pytest.approx(capture.get("interval_s", 0.2), abs=1e-6)
    assert float(got["ICGT_SHUTTER_PW"]) == pytest.approx(capture.get("shutter_pulse_s", 0.02), abs=1e-6)


def test_settings_set_through_mavsdk_are_read_back_and_a_refused_one_is_kept(session: Session) -> None:
    assert session.after_set["ICGT_TRIG_MODE"] == "1"
    assert float(session.after_set["ICGT_BURST"]) == pytest.approx(0.6, abs=1e-6)
    assert float(session.after_set["ICGT_FOCUS_LEAD"]) == pytest.approx(0.4, abs=1e-6)
    assert session.refused  # MAVSDK got PARAM_EXT_ACK FAILED
    assert session.after_refusal["ICGT_SHUTTER_PW"] == session.initial["ICGT_SHUTTER_PW"]
    assert session.mcap is not None  # the flight's log says who set what, and why one was refused
    said = [d["message"] for _, d in read(session.mcap).messages(layout.LOG) if "camera setting" in d["message"]]
    assert [m.split(" (")[0] for m in said[:3]] == [
        "camera setting ICGT_TRIG_MODE = 1 from 245:190",
        "camera setting ICGT_BURST = 0.6 s from 245:190",
        "camera setting ICGT_FOCUS_LEAD = 0.4 s from 245:190",
    ]
    assert "ICGT_SHUTTER_PW = 0.9" in said[3] and "pulse_vs_interval" in said[3]


def test_the_device_shoots_as_the_settings_say(session: Session) -> None:
    """Focus then burst: 3 shots 0.2 s apart (a 0.6 s burst), the next burst 0.4 s (focus lead) + 0.2 s later.
    A gap is told short (0.2 s) or long (0.6 s) by a 0.4 s threshold: a shot a loaded machine fires late moves
    a gap by far less than that."""
    assert session.mcap is not None
    rec = read(session.mcap)
    triggers = [d for _, d in rec.messages(layout.device_topic("EXPOSURE")) if d["trigger_t_us"]]
    assert len(triggers) >= 6, len(triggers)
    assert all(d["flags"] & int(ExposureFlags.FOCUS_CYCLE) for d in triggers)
    gaps = [(b["trigger_t_us"] - a["trigger_t_us"]) / 1e6 for a, b in itertools.pairwise(triggers)]
    runs = "".join("s" if g < 0.4 else "L" for g in gaps)
    assert "L" in runs and "sss" not in runs and "LL" not in runs, gaps  # bursts of 3 shots, never 4 or 1
    assert all(0.1 < g < 1.0 for g in gaps), gaps
