"""The camera component's capture state, as CAMERA_CAPTURE_STATUS and HEARTBEAT report it.

The image status (idle, interval capture), its interval, the image count an interval capture stops at,
and whether the state changed since the last CAMERA_CAPTURE_STATUS (``dirty``: the worker sends one
then). The component guards it with its lock: the methods named ``*_locked`` expect the caller to hold
it. Split from `icgt.mavlink.camera`.
"""

from __future__ import annotations

__all__ = [
    "IMAGE_STATUS_CAPTURING",
    "IMAGE_STATUS_IDLE",
    "IMAGE_STATUS_INTERVAL_CAPTURING",
    "IMAGE_STATUS_INTERVAL_IDLE",
    "CaptureState",
]

IMAGE_STATUS_IDLE = 0
IMAGE_STATUS_CAPTURING = 1
IMAGE_STATUS_INTERVAL_IDLE = 2
IMAGE_STATUS_INTERVAL_CAPTURING = 3


class CaptureState:
    """What the camera is doing (see the module docstring); the caller holds the component's lock."""

    def __init__(self) -> None:
        self.image_status = IMAGE_STATUS_IDLE
        self.interval_s = 0.0
        self.count_target = 0
        self.images_since_start = 0
        self.dirty = False

    def set_locked(self, status: int, interval_s: float) -> None:
        if (status, interval_s) != (self.image_status, self.interval_s):
            self.image_status = status
            self.interval_s = interval_s
            self.dirty = True
        if status == IMAGE_STATUS_IDLE:
            self.count_target = 0
            self.images_since_start = 0

    def start_interval_locked(self, interval_s: float, count: int) -> None:
        """An interval capture of ``count`` images (0: until stopped) has started."""
        self.count_target = count
        self.images_since_start = 0
        self.set_locked(IMAGE_STATUS_INTERVAL_CAPTURING, interval_s)

    def image_published_locked(self) -> None:
        """One more image: an interval capture that has taken its count is over."""
        if self.image_status == IMAGE_STATUS_INTERVAL_CAPTURING and self.count_target > 0:
            self.images_since_start += 1
            if self.images_since_start >= self.count_target:
                self.set_locked(IMAGE_STATUS_IDLE, 0.0)
