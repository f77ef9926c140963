"""The camera component's replies and informational messages, built and not sent.

COMMAND_ACK, HEARTBEAT (MAV_TYPE_CAMERA, MAV_AUTOPILOT_INVALID), CAMERA_INFORMATION, CAMERA_SETTINGS,
STORAGE_INFORMATION (the file system of the output directory) and CAMERA_CAPTURE_STATUS, each from the
component's configuration and the state it is given; `icgt.mavlink.camera` sends them. Split from
`icgt.mavlink.camera`.
"""

from __future__ import annotations

import math
import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

from icgt.mavlink.camera_commands import Command, Outcome
from icgt.mavlink.camera_images import truncate_utf8
from icgt.mavlink.camera_types import CameraConfig
from icgt.mavlink.link import mavlink2

__all__ = ["CameraMessages", "disk_mib", "fixed_bytes"]

_MIB = 1024 * 1024


def fixed_bytes(text: str, size: int) -> list[int]:
    raw = text.encode("utf-8")[:size]
    return list(raw.ljust(size, b"\0"))


def disk_mib(path: Path) -> tuple[float, float, float] | None:
    """(total, used, free) MiB of the file system holding ``path`` (or its nearest existing parent)."""
    probe = path
    while not probe.exists() and probe != probe.parent:
        probe = probe.parent
    try:
        usage = shutil.disk_usage(probe)
    except OSError:
        return None
    return usage.total / _MIB, usage.used / _MIB, usage.free / _MIB


class CameraMessages:
    """The messages of one camera component: ``mav`` encodes them, ``time_boot_ms`` stamps them."""

    def __init__(self, mav: Any, config: CameraConfig, time_boot_ms: Callable[[], int]) -> None:
        self.mav = mav
        self.config = config
        self.time_boot_ms = time_boot_ms

    def ack(self, cmd: Command, outcome: Outcome) -> Any:
        assert outcome.result is not None
        return self.mav.command_ack_encode(
            cmd.command,
            outcome.result,
            outcome.progress & 0xFF,
            outcome.result_param2,
            cmd.src_system,
            cmd.src_component,
        )

    def heartbeat(self, capturing: bool) -> Any:
        state = mavlink2.MAV_STATE_ACTIVE if capturing else mavlink2.MAV_STATE_STANDBY
        return self.mav.heartbeat_encode(mavlink2.MAV_TYPE_CAMERA, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, state, 3)

    def camera_information(self, uri: str, version: int) -> Any:
        """CAMERA_INFORMATION naming the camera definition file at ``uri`` (version ``version``)."""
        info = self.config.info
        major, minor, patch, dev = (v & 0xFF for v in info.firmware_version)
        return self.mav.camera_information_encode(
            self.time_boot_ms(),
            fixed_bytes(info.vendor, 32),
            fixed_bytes(info.model, 32),
            (dev << 24) | (patch << 16) | (minor << 8) | major,
            float(info.focal_length_mm),
            float(info.sensor_size_h_mm),
            float(info.sensor_size_v_mm),
            int(info.resolution_h),
            int(info.resolution_v),
            int(info.lens_id),
            mavlink2.CAMERA_CAP_FLAGS_CAPTURE_IMAGE,
            int(version),
            truncate_utf8(uri, 140),
        )

    def camera_settings(self) -> Any:
        return self.mav.camera_settings_encode(self.time_boot_ms(), mavlink2.CAMERA_MODE_IMAGE, math.nan, math.nan)

    def storage_information(self) -> Any:
        disk = disk_mib(self.config.output_dir)
        if disk is None:
            status, total, used, free = mavlink2.STORAGE_STATUS_NOT_SUPPORTED, 0.0, 0.0, 0.0
        else:
            status, (total, used, free) = mavlink2.STORAGE_STATUS_READY, disk
        return self.mav.storage_information_encode(
            self.time_boot_ms(),
            1,
            1,
            status,
            total,
            used,
            free,
            0.0,
            0.0,
            mavlink2.STORAGE_TYPE_OTHER,
            b"ICGT output",
            mavlink2.STORAGE_USAGE_FLAG_SET | mavlink2.STORAGE_USAGE_FLAG_PHOTO,
        )

    def capture_status(self, status: int, interval: float, count: int) -> Any:
        """CAMERA_CAPTURE_STATUS: image ``status`` (IMAGE_STATUS_*), ``interval`` [s], ``count`` images."""
        disk = disk_mib(self.config.output_dir)
        return self.mav.camera_capture_status_encode(
            self.time_boot_ms(), status, 0, float(interval), 0, disk[2] if disk else 0.0, count
        )
