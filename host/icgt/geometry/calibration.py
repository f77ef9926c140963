"""Calibration files -> `CameraModel`: ours (TOML), OpenCV FileStorage YAML and JSON (formats: `icgt.geometry`)."""

from __future__ import annotations

import json
import math
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from icgt.geometry.camera import (
    CalibrationError,
    CameraModel,
)

# --- calibration files ----------------------------------------------------------------------


def load_calibration(path: str | Path) -> CameraModel:
    """A CameraModel from a calibration file (formats: module docstring); raises CalibrationError."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"{p}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"{p}: not a text file ({exc.reason})") from exc
    suffix = p.suffix.lower()
    if suffix == ".toml":
        return _from_toml(text, str(p))
    if suffix == ".json":
        try:
            data = json.loads(text)
        except json.JSONDecodeError as exc:
            raise CalibrationError(f"{p}: not valid JSON: {exc}") from exc
        if not isinstance(data, dict):
            raise CalibrationError(f"{p}: expected a JSON object at the top")
        return _from_opencv_mapping(data, str(p))
    if suffix in (".yaml", ".yml"):
        return _from_opencv_mapping(_parse_opencv_yaml(text, str(p)), str(p))
    raise CalibrationError(f"{p}: unknown calibration format {suffix!r}: use .toml, .yaml/.yml (OpenCV) or .json")


def _number(source: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise CalibrationError(f"{source}: {key}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise CalibrationError(f"{source}: {key}: expected a finite number, got {value!r}")
    return v


def _integer(source: str, key: str, value: Any) -> int:
    v = _number(source, key, value)
    if v != int(v) or v <= 0:
        raise CalibrationError(f"{source}: {key}: expected a positive integer, got {value!r}")
    return int(v)


def _from_toml(text: str, source: str) -> CameraModel:
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(f"{source}: not valid TOML: {exc}") from exc
    cam = data.get("camera")
    if not isinstance(cam, dict):
        raise CalibrationError(f"{source}: missing the [camera] table")
    dist = data.get("distortion", {})
    mount = data.get("mounting", {})
    if not isinstance(dist, dict) or not isinstance(mount, dict):
        raise CalibrationError(f"{source}: [distortion] and [mounting] must be tables")
    known = {
        "camera": {"width_px", "height_px", "fx", "fy", "cx", "cy", "skew", "focal_length_mm", "sensor_width_mm"},
        "distortion": {"k1", "k2", "p1", "p2", "k3"},
        "mounting": {"boresight_roll_deg", "boresight_pitch_deg", "boresight_yaw_deg", "lever_arm_camera_m"},
    }
    for section, table in (("camera", cam), ("distortion", dist), ("mounting", mount)):
        unknown = sorted(set(table) - known[section])
        if unknown:
            raise CalibrationError(f"{source}: {section}.{unknown[0]}: unknown key (a typo?)")
    for top in sorted(set(data) - set(known)):
        raise CalibrationError(f"{source}: {top}: unknown table (a typo?)")
    if "width_px" not in cam or "height_px" not in cam:
        raise CalibrationError(f"{source}: camera.width_px and camera.height_px are required")
    w = _integer(source, "camera.width_px", cam["width_px"])
    h = _integer(source, "camera.height_px", cam["height_px"])
    if "fx" in cam:
        fx = _number(source, "camera.fx", cam["fx"])
        fy = _number(source, "camera.fy", cam.get("fy", cam["fx"]))
    elif "focal_length_mm" in cam and "sensor_width_mm" in cam:
        f_mm = _number(source, "camera.focal_length_mm", cam["focal_length_mm"])
        s_mm = _number(source, "camera.sensor_width_mm", cam["sensor_width_mm"])
        if s_mm <= 0:
            raise CalibrationError(f"{source}: camera.sensor_width_mm must be positive")
        fx = fy = f_mm * w / s_mm
    else:
        raise CalibrationError(f"{source}: give camera.fx (and fy) or camera.focal_length_mm and sensor_width_mm")
    lever = mount.get("lever_arm_camera_m", [0.0, 0.0, 0.0])
    if not isinstance(lever, list) or len(lever) != 3:
        raise CalibrationError(f"{source}: mounting.lever_arm_camera_m: expected [x, y, z]")
    return CameraModel(
        width_px=w,
        height_px=h,
        fx=fx,
        fy=fy,
        cx=_number(source, "camera.cx", cam.get("cx", (w - 1) / 2.0)),
        cy=_number(source, "camera.cy", cam.get("cy", (h - 1) / 2.0)),
        skew=_number(source, "camera.skew", cam.get("skew", 0.0)),
        k1=_number(source, "distortion.k1", dist.get("k1", 0.0)),
        k2=_number(source, "distortion.k2", dist.get("k2", 0.0)),
        p1=_number(source, "distortion.p1", dist.get("p1", 0.0)),
        p2=_number(source, "distortion.p2", dist.get("p2", 0.0)),
        k3=_number(source, "distortion.k3", dist.get("k3", 0.0)),
        boresight_rpy_deg=(
            _number(source, "mounting.boresight_roll_deg", mount.get("boresight_roll_deg", 0.0)),
            _number(source, "mounting.boresight_pitch_deg", mount.get("boresight_pitch_deg", 0.0)),
            _number(source, "mounting.boresight_yaw_deg", mount.get("boresight_yaw_deg", 0.0)),
        ),
        lever_arm_camera_m=(
            _number(source, "mounting.lever_arm_camera_m[0]", lever[0]),
            _number(source, "mounting.lever_arm_camera_m[1]", lever[1]),
            _number(source, "mounting.lever_arm_camera_m[2]", lever[2]),
        ),
        source=source,
    )


_YAML_KEY = re.compile(r"^(\s*)([A-Za-z_][\w-]*)\s*:\s*(.*?)\s*$")


def _yaml_scalar(text: str) -> Any:
    t = text.strip().strip('"').strip("'")
    try:
        return int(t)
    except ValueError:
        pass
    try:
        return float(t)
    except ValueError:
        return t


def _parse_opencv_yaml(text: str, source: str) -> dict[str, Any]:
    """The subset of OpenCV FileStorage YAML a calibration uses: scalars and !!opencv-matrix maps."""
    out: dict[str, Any] = {}
    current: dict[str, Any] | None = None
    lines = text.splitlines()
    i = 0
    while i < len(lines):
        raw = lines[i]
        i += 1
        line = raw.split("#", 1)[0].rstrip() if not raw.lstrip().startswith("%") else ""
        if not line.strip() or line.strip() == "---":
            continue
        m = _YAML_KEY.match(line)
        if m is None:
            raise CalibrationError(f"{source}:{i}: cannot read {raw.strip()!r} (expected 'key: value')")
        indent, key, rest = m.groups()
        if not indent:
            if rest.startswith("!!opencv-matrix") or rest == "":
                current = {}
                out[key] = current
            else:
                out[key] = _yaml_scalar(rest)
                current = None
            continue
        if current is None:
            raise CalibrationError(f"{source}:{i}: {key}: indented key outside a matrix")
        if key == "data":
            chunk = rest
            while "]" not in chunk and i < len(lines):
                chunk += " " + lines[i].split("#", 1)[0]
                i += 1
            if not chunk.strip().startswith("[") or "]" not in chunk:
                raise CalibrationError(f"{source}:{i}: data: expected [ ... ]")
            body = chunk.strip()[1 : chunk.strip().index("]")]
            try:
                current["data"] = [float(x) for x in body.replace("\n", " ").split(",") if x.strip()]
            except ValueError as exc:
                raise CalibrationError(f"{source}:{i}: data: {exc}") from exc
        else:
            current[key] = _yaml_scalar(rest)
    return out


def _matrix(source: str, key: str, value: Any) -> list[float]:
    """A flat list of numbers from an OpenCV matrix object, a nested list or a flat list."""
    if isinstance(value, dict):
        data = value.get("data")
        if not isinstance(data, list):
            raise CalibrationError(f"{source}: {key}: matrix without a data list")
        rows, cols = value.get("rows"), value.get("cols")
        if isinstance(rows, int) and isinstance(cols, int) and rows * cols != len(data):
            raise CalibrationError(f"{source}: {key}: {rows}x{cols} matrix with {len(data)} values")
        value = data
    if isinstance(value, list) and value and all(isinstance(r, list) for r in value):
        value = [x for r in value for x in r]
    if not isinstance(value, list):
        raise CalibrationError(f"{source}: {key}: expected a matrix, got {value!r}")
    return [_number(source, key, x) for x in value]


def _first_key(data: Mapping[str, Any], *names: str) -> tuple[str, Any] | None:
    for n in names:
        if n in data:
            return n, data[n]
    return None


def _from_opencv_mapping(data: Mapping[str, Any], source: str) -> CameraModel:
    k_entry = _first_key(data, "camera_matrix", "cameraMatrix", "K")
    if k_entry is None:
        raise CalibrationError(f"{source}: no camera_matrix")
    k = _matrix(source, k_entry[0], k_entry[1])
    if len(k) != 9:
        raise CalibrationError(f"{source}: {k_entry[0]}: expected 9 values (3x3), got {len(k)}")
    if abs(k[3]) > 1e-12 or abs(k[6]) > 1e-12 or abs(k[7]) > 1e-12 or abs(k[8] - 1.0) > 1e-9:
        raise CalibrationError(f"{source}: {k_entry[0]}: not a camera matrix [[fx s cx] [0 fy cy] [0 0 1]]")
    d_entry = _first_key(data, "distortion_coefficients", "dist_coeffs", "distCoeffs", "D")
    d = _matrix(source, d_entry[0], d_entry[1]) if d_entry is not None else []
    if any(abs(c) > 0.0 for c in d[5:]):
        raise CalibrationError(
            f"{source}: {d_entry[0] if d_entry else 'distortion'}: only k1 k2 p1 p2 k3 are supported; "
            f"coefficients 6 and later are not zero"
        )
    d = (d + [0.0] * 5)[:5]
    w_entry = _first_key(data, "image_width", "width", "imageWidth")
    h_entry = _first_key(data, "image_height", "height", "imageHeight")
    if w_entry is None or h_entry is None:
        raise CalibrationError(f"{source}: image_width and image_height are required")
    return CameraModel(
        width_px=_integer(source, w_entry[0], w_entry[1]),
        height_px=_integer(source, h_entry[0], h_entry[1]),
        fx=k[0],
        fy=k[4],
        cx=k[2],
        cy=k[5],
        skew=k[1],
        k1=d[0],
        k2=d[1],
        p1=d[2],
        p2=d[3],
        k3=d[4],
        source=source,
    )
