"""The capture settings a ground station may change through the camera's definition file.

They are the `[capture]` section's trigger settings, which the recorder sends to the device in every
START_CAPTURE (`icgt.recorder.capture.start_command`):

* ``ICGT_TRIG_MODE`` (``mode``): 0 interval (a shot every interval), 1 focus_burst (the focus lead, then shots
  for the burst, repeated);
* ``ICGT_INTERVAL`` (``interval_s``): the camera's own interval [s], used when a capture is started without
  one (IMAGE_START_CAPTURE with interval 0, `icgt start`);
* ``ICGT_FOCUS_LEAD`` (``focus_lead_s``): the focus line is asserted this long before each burst [s];
* ``ICGT_BURST`` (``burst_s``): each burst's shooting phase [s] (focus_burst);
* ``ICGT_SHUTTER_PW`` (``shutter_pulse_s``): the shutter pulse's width [s];
* ``CAM_MODE``: the schema's camera mode, photo (0) only, no control shown (MAVSDK and QGroundControl look for
  it when CAMERA_SETTINGS comes; this camera has no video mode).

A new value is checked as the configuration file's would be (`CaptureSection`'s bounds and rules) and
against the board's limits for the capture it makes (`start_command`, nothing sent); it applies from the
next capture start (a running capture keeps the settings it was started with). Values last for the
recorder's run: the configuration file is not rewritten, a restart starts from its values again.
"""

from __future__ import annotations

from collections.abc import Callable

import msgspec

from icgt.device.limits import BoardLimits, LimitError
from icgt.mavlink.camera_definition import CameraParam, ParamError
from icgt.mavlink.camera_settings import CameraSettings
from icgt.recorder import capture
from icgt.recorder.config import CaptureSection, RecorderConfig

__all__ = ["MODES", "PARAM_KEYS", "capture_params", "capture_settings"]

MODES = ("interval", "focus_burst")
PARAM_KEYS = {
    "ICGT_TRIG_MODE": "mode",
    "ICGT_INTERVAL": "interval_s",
    "ICGT_FOCUS_LEAD": "focus_lead_s",
    "ICGT_BURST": "burst_s",
    "ICGT_SHUTTER_PW": "shutter_pulse_s",
}


def capture_params(c: CaptureSection) -> tuple[CameraParam, ...]:
    """The definition file's parameters, their defaults the configured values (bounds: `CaptureSection`'s)."""
    return (
        CameraParam("CAM_MODE", "uint32", "Camera mode", 0, options=(("Photo", 0),), control=False),
        CameraParam("ICGT_TRIG_MODE", "uint32", "Trigger mode", MODES.index(c.mode),
                    options=(("Interval", 0), ("Focus, then burst", 1))),
        CameraParam("ICGT_INTERVAL", "float", "Capture interval when none is given", c.interval_s, "s",
                    0.05, 3600.0, 0.01),
        CameraParam("ICGT_FOCUS_LEAD", "float", "Focus lead before each burst", c.focus_lead_s, "s", 0.0, 10.0, 0.01),
        CameraParam("ICGT_BURST", "float", "Burst length (focus then burst)", c.burst_s, "s", 0.0, 3600.0, 0.01),
        CameraParam("ICGT_SHUTTER_PW", "float", "Shutter pulse width", c.shutter_pulse_s, "s", 0.001, 1.0, 0.001),
    )  # fmt: skip


def _values(c: CaptureSection) -> dict[str, float]:
    return {
        "CAM_MODE": 0.0,
        "ICGT_TRIG_MODE": float(MODES.index(c.mode)),
        "ICGT_INTERVAL": c.interval_s,
        "ICGT_FOCUS_LEAD": c.focus_lead_s,
        "ICGT_BURST": c.burst_s,
        "ICGT_SHUTTER_PW": c.shutter_pulse_s,
    }


def changed(c: CaptureSection, name: str, value: float) -> CaptureSection:
    """The section with one parameter changed (a float rounded to the device's microseconds), checked by the
    section's own rules; ParamError naming the rule otherwise."""
    key = PARAM_KEYS[name]
    new: object = MODES[int(value)] if key == "mode" else round(float(value), 6)
    try:
        return msgspec.convert({**msgspec.structs.asdict(c), key: new}, CaptureSection)
    except msgspec.ValidationError as exc:
        raise ParamError(f"{name} = {value:g}: {exc}") from None


def capture_settings(
    get: Callable[[], CaptureSection],
    put: Callable[[CaptureSection], None],
    config: Callable[[], RecorderConfig],
    limits: Callable[[], BoardLimits],
) -> CameraSettings:
    """The camera's settings over the recorder's capture section (``get``/``put``: the one in force)."""

    def set_one(name: str, value: float) -> None:
        if name not in PARAM_KEYS:  # CAM_MODE: its only value (checked against its options already)
            return
        new = changed(get(), name, value)
        try:  # the capture these settings would start, checked as a ground station's start would be
            capture.start_command(msgspec.structs.replace(config(), capture=new), None, 0, limits())
        except LimitError as exc:
            raise ParamError(f"{name} = {value:g}: {exc}") from None
        put(new)

    return CameraSettings(capture_params(get()), lambda: _values(get()), set_one)
