"""A command as the camera component's worker handles it: the record, its outcome, and the dedupe.

`Command` is what the link's reader takes from a COMMAND_LONG / COMMAND_INT (`command_params` decodes
the seven parameters and the confirmation); `Outcome` is what executing it gave (the COMMAND_ACK's
fields, and what to do after the ACK). `dedupe_keys` and `RecentCommands` recognise a retransmission of
a command already executed (the rule is in `icgt.mavlink.camera`'s docstring: confirmation > 0, or the
same capture sequence number from the same sender within the retransmit window), so that it gets the
first ACK again and is not executed twice. Split from `icgt.mavlink.camera`.
"""

from __future__ import annotations

import dataclasses
import math
from collections import OrderedDict
from collections.abc import Callable

from icgt.mavlink.link import MavlinkMessage, mavlink2

__all__ = ["Command", "Outcome", "RecentCommands", "command_params", "dedupe_keys"]


@dataclasses.dataclass(frozen=True, slots=True)
class Command:
    rx_ns: int
    src_system: int
    src_component: int
    command: int
    confirmation: int
    params: tuple[float, float, float, float, float, float, float]
    broadcast: bool


@dataclasses.dataclass(frozen=True, slots=True)
class Outcome:
    result: int | None
    progress: int = 0
    result_param2: int = 0
    reason: str = ""
    after: Callable[[], None] | None = None  # runs after the ACK (the requested message follows it)


def command_params(rec: MavlinkMessage) -> tuple[tuple[float, float, float, float, float, float, float], int]:
    msg = rec.msg
    if rec.type == "COMMAND_INT":
        return (
            float(msg.param1),
            float(msg.param2),
            float(msg.param3),
            float(msg.param4),
            float(msg.x),
            float(msg.y),
            float(msg.z),
        ), 0
    return (
        float(msg.param1),
        float(msg.param2),
        float(msg.param3),
        float(msg.param4),
        float(msg.param5),
        float(msg.param6),
        float(msg.param7),
    ), int(msg.confirmation)


def dedupe_keys(cmd: Command) -> tuple[list[tuple[object, ...]], list[tuple[object, ...]]]:
    """(keys that make this command a duplicate, keys to remember it by once executed)."""
    if cmd.command not in (
        mavlink2.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink2.MAV_CMD_IMAGE_STOP_CAPTURE,
        mavlink2.MAV_CMD_DO_DIGICAM_CONTROL,
    ):
        return [], []
    p = cmd.params
    src = (cmd.src_system, cmd.src_component, cmd.command)
    sequence: list[tuple[object, ...]] = []
    if cmd.command == mavlink2.MAV_CMD_IMAGE_START_CAPTURE and p[2] == 1 and math.isfinite(p[3]) and p[3] > 0:
        sequence.append(("sequence", *src, int(p[3])))
    if cmd.command == mavlink2.MAV_CMD_DO_DIGICAM_CONTROL and math.isfinite(p[5]) and p[5] > 0:
        sequence.append(("sequence", *src, int(p[5])))
    retransmission = ("retransmission", *src, p)
    lookup = [*sequence, retransmission] if cmd.confirmation > 0 else sequence
    return lookup, [*sequence, retransmission]


class RecentCommands:
    """The commands executed lately, by dedupe key (the newest 256; worker thread only)."""

    def __init__(self) -> None:
        # executed commands by key: (first receipt, expiry, outcome)
        self._recent: OrderedDict[tuple[object, ...], tuple[int, int, Outcome]] = OrderedDict()

    def expire(self, now: int) -> None:
        for key in [k for k, (_, expires, _) in self._recent.items() if expires <= now]:
            del self._recent[key]

    def duplicate(self, cmd: Command, lookup: list[tuple[object, ...]], retransmit_ns: int) -> Outcome | None:
        """The first transmission's outcome if ``cmd`` (looked up by ``lookup``) repeats it, else None."""
        for key in lookup:
            hit = self._recent.get(key)
            # a repeated sequence number is a retransmission if it says so (confirmation > 0) or comes soon
            if hit is not None and (cmd.confirmation > 0 or cmd.rx_ns - hit[0] <= retransmit_ns):
                return dataclasses.replace(hit[2], reason="duplicate of " + hit[2].reason)
        return None

    def remember(self, keys: list[tuple[object, ...]], rx_ns: int, expires: int, outcome: Outcome) -> None:
        """Keep an executed command's outcome under ``keys`` until ``expires``."""
        for key in keys:
            self._recent[key] = (rx_ns, expires, dataclasses.replace(outcome, after=None))
            self._recent.move_to_end(key)
        while len(self._recent) > 256:
            self._recent.popitem(last=False)
