"""One picture per shot when an autopilot sends two commands for it (PX4's camera trigger).

How the autopilots command a MAVLink camera during a mission (facts from their sources, issue 29):

- ArduPilot, CAM1_TYPE = 6 (AP_Camera_MAVLinkCamV2): one COMMAND_LONG MAV_CMD_IMAGE_START_CAPTURE per
  shot to (its system, 100), param3 = 1, param4 = its image number 1, 2, ...; confirmation 0, never
  re-sent. CAM1_TYPE = 5 (AP_Camera_MAVLink): one MAV_CMD_DO_DIGICAM_CONTROL per shot, param5 = 1 and
  every other parameter 0, to (0, 0). Either way one command is one picture: nothing to do here.
- PX4 with TRIG_INTERFACE = 3 (MAVLink; src/modules/mavlink/streams/CAMERA_TRIGGER.hpp): for every
  trigger it sends CAMERA_TRIGGER (its boot time, seq from 0), then MAV_CMD_IMAGE_START_CAPTURE to
  (its system, 100) with param3 = 1 and param4 = its own count from 1 (through MavlinkCommandSender,
  which re-sends it every 0.5 s with confirmation 1, 2, 3 until a COMMAND_ACK comes), then, in the same
  breath, MAV_CMD_DO_DIGICAM_CONTROL to (0, 100) with param5 = 1 and every other parameter NaN, never
  re-sent. Both ask for the same single picture.

`ShotPairing` keeps that to one picture: a single-shot DO_DIGICAM_CONTROL without a command identity
(param6 not > 0) from the sender whose single-shot IMAGE_START_CAPTURE was executed less than
``pair_window_s`` before it is the same shot; it gets COMMAND_ACK ACCEPTED and takes no picture. The
other order (the IMAGE_START_CAPTURE lost, the DO_DIGICAM_CONTROL executed, then the re-sent
IMAGE_START_CAPTURE with confirmation > 0 arriving up to ~1.5 s later) pairs too, within
``resend_window_s``. Pairing is one to one, so a sender that really means two pictures (two
IMAGE_START_CAPTURE, or two DO_DIGICAM_CONTROL) gets two. A DO_DIGICAM_CONTROL with a command identity,
or from another sender, is never paired. Written by hand: no MAVLink library has this rule.
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque

from pymavlink.dialects.v20 import common as mavlink2

IMAGE_START_CAPTURE = mavlink2.MAV_CMD_IMAGE_START_CAPTURE
DO_DIGICAM_CONTROL = mavlink2.MAV_CMD_DO_DIGICAM_CONTROL

Params = tuple[float, float, float, float, float, float, float]


@dataclasses.dataclass(frozen=True, slots=True)
class PairingConfig:
    pair_window_s: float = 0.2
    """DO_DIGICAM_CONTROL this soon after the sender's IMAGE_START_CAPTURE (PX4 sends them together) [s]."""
    resend_window_s: float = 2.0
    """A re-sent IMAGE_START_CAPTURE (confirmation > 0) this soon after an unpaired DO_DIGICAM_CONTROL
    (PX4: 3 re-sends 0.5 s apart) [s]."""


@dataclasses.dataclass(slots=True)
class _Shot:
    rx_ns: int
    sender: tuple[int, int]
    command: int
    sequence: int | None
    paired: bool = False


def single_shot_kind(command: int, params: Params) -> int | None:
    """IMAGE_START_CAPTURE or DO_DIGICAM_CONTROL if the command asks for exactly one picture, else None."""
    if command == IMAGE_START_CAPTURE and params[2] == 1:
        return int(IMAGE_START_CAPTURE)
    if command == DO_DIGICAM_CONTROL and params[4] == 1 and not (math.isfinite(params[5]) and params[5] > 0):
        return int(DO_DIGICAM_CONTROL)
    return None


class ShotPairing:
    """Which single-shot commands are the second half of a shot already taken (worker thread only)."""

    def __init__(self, config: PairingConfig | None = None) -> None:
        self.config = config or PairingConfig()
        self._shots: deque[_Shot] = deque(maxlen=64)
        self.paired = 0
        """Commands answered as the second half of a shot (no picture taken for them)."""

    def match(
        self, rx_ns: int, src_system: int, src_component: int, command: int, confirmation: int, params: Params
    ) -> str | None:
        """Reason for an ACCEPTED without a picture if this command pairs with an earlier shot, else None."""
        kind = single_shot_kind(command, params)
        if kind is None:
            return None
        sender = (src_system, src_component)
        if kind == DO_DIGICAM_CONTROL:
            other, window_s = IMAGE_START_CAPTURE, self.config.pair_window_s
        else:
            other = DO_DIGICAM_CONTROL
            window_s = self.config.resend_window_s if confirmation > 0 else self.config.pair_window_s
        window_ns = round(window_s * 1e9)
        for shot in reversed(self._shots):
            if rx_ns - shot.rx_ns > window_ns:
                break
            if shot.sender == sender and shot.command == other and not shot.paired:
                shot.paired = True
                self.paired += 1
                first = "IMAGE_START_CAPTURE" if other == IMAGE_START_CAPTURE else "DO_DIGICAM_CONTROL"
                number = f" #{shot.sequence}" if shot.sequence is not None else ""
                return f"same shot as {first}{number} {(rx_ns - shot.rx_ns) / 1e6:.0f} ms before (no second picture)"
        return None

    def taken(self, rx_ns: int, src_system: int, src_component: int, command: int, params: Params) -> None:
        """A single-shot command that took a picture (ACCEPTED): a later half may pair with it."""
        kind = single_shot_kind(command, params)
        if kind is None:
            return
        seq = int(params[3]) if kind == IMAGE_START_CAPTURE and math.isfinite(params[3]) and params[3] > 0 else None
        self._shots.append(_Shot(rx_ns, (src_system, src_component), kind, seq))
