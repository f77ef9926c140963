"""The live links of one recording, in one place: the device link, the MAVLink link and the camera component.

The composition root (`icgt.recorder.recorder`) opens them during start and closes them at stop; the parts
that use them (the worker, capture control, the health report, the shutdown sequence) hold this one object,
so each sees a link the moment it is opened. None: not opened (yet), or no such link in this recording.
"""

from __future__ import annotations

from dataclasses import dataclass

from icgt.device import DeviceLink
from icgt.mavlink.camera import CameraComponent
from icgt.mavlink.link import MavlinkLink

__all__ = ["Links"]


@dataclass
class Links:
    """The recording's links, set by the composition root as it opens them."""

    device: DeviceLink | None = None
    mavlink: MavlinkLink | None = None
    camera: CameraComponent | None = None
