"""Which MAVLink messages come from the autopilot, and when it (re)appeared or went: the rules, in one place.

The one autopilot state machine (seen / lost / back / rebooted, one timeout): the synchroniser owns it (to
decide which TIMESYNC replies and telemetry it takes, and to say each change once on /icgt/link_events), and
the recorder hands its changes to the MAVLink link as hints (`icgt.mavlink.link_scheduler`: stream rates asked
again, TIMESYNC fast again), so the recorder and the offline recompute apply the same rules to the same
messages and the link keeps no second account. Pure functions and a small state machine over (message,
arrival time): no I/O, no threads.
"""

from __future__ import annotations

import enum
from collections import deque
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

__all__ = [
    "BOOT_CLOCK_TYPES",
    "LATE_TOLERANCE_NS",
    "ORIGIN_TOLERANCE_NS",
    "ORIGIN_WINDOW_NS",
    "REBOOT_BACKSTEP_MS",
    "REBOOT_SILENCE_NS",
    "YOUNG_EARLY_TOLERANCE_NS",
    "YOUNG_STREAM_NS",
    "AutopilotPresence",
    "AutopilotState",
    "Freshness",
    "PresenceChange",
    "boot_clock_ms",
    "is_autopilot_heartbeat",
]

REBOOT_BACKSTEP_MS = 2000  # a boot stamp going back more than this (after a silence) means the autopilot rebooted
REBOOT_SILENCE_NS = 1_000_000_000  # a rebooting autopilot is silent this long at least (it boots): its stream stopped
# The boot origin (arrival minus time_boot_ms) of one autopilot is its boot plus the link's delay: the least
# delayed of the last ORIGIN_WINDOW_NS is the reference (it follows the clocks' drift, 50 ppm: 0.18 s an hour).
# No message of the stream is less delayed than that by more than ORIGIN_TOLERANCE_NS: an earlier origin is
# another sender (booted earlier, or a spoofed clock). A message held back (a radio's buffer, a busy host)
# is later by its delay: believed up to LATE_TOLERANCE_NS, since what tells a late echo or a replay apart is
# its time_boot_ms and sequence number running behind the stream's (`_refusal`), not its delay.
ORIGIN_TOLERANCE_NS = 500_000_000
# Except while the stream is young: its first messages may all have waited (a host busy starting up, a radio
# emptying its buffer at link-up), and the first timely one then is earlier than the origin they gave by
# their delay. Up to YOUNG_EARLY_TOLERANCE_NS earlier is believed in the first YOUNG_STREAM_NS of the stream
# when its sequence number runs on (a flight stack booted 2 s apart is still another sender).
YOUNG_STREAM_NS = 10_000_000_000
YOUNG_EARLY_TOLERANCE_NS = 1_500_000_000
LATE_TOLERANCE_NS = 5_000_000_000
ORIGIN_WINDOW_NS = 60_000_000_000
SEQ_AHEAD_MAX = 64  # packet sequence numbers may jump this far ahead (lost datagrams) within one stream
SEQ_REORDER_MAX = 8  # ... and arrive this far behind (reordered on the way)
BOOT_CLOCK_TYPES = frozenset(
    {"SYSTEM_TIME", "ATTITUDE", "ATTITUDE_QUATERNION", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED"}
)
_NOT_AUTOPILOT_TYPES = frozenset(
    {
        mavlink2.MAV_TYPE_GCS,
        mavlink2.MAV_TYPE_CAMERA,
        mavlink2.MAV_TYPE_GIMBAL,
        mavlink2.MAV_TYPE_ONBOARD_CONTROLLER,
    }
)


def is_autopilot_heartbeat(msg: Any) -> bool:
    """A HEARTBEAT from a flight controller (not a GCS, camera, gimbal or companion computer)."""
    return int(msg.autopilot) != mavlink2.MAV_AUTOPILOT_INVALID and int(msg.type) not in _NOT_AUTOPILOT_TYPES


def boot_clock_ms(msg: Any, mtype: str) -> int | None:
    """The sender's boot clock a message carries [ms]: time_boot_ms, or a TIMESYNC answer's tc1 (its boot clock in
    ns, ArduPilot and PX4); None for messages without one."""
    if mtype in BOOT_CLOCK_TYPES:
        boot = getattr(msg, "time_boot_ms", None)
        return boot if isinstance(boot, int) else None
    if mtype == "TIMESYNC" and int(msg.tc1) > 0:
        return int(msg.tc1) // 1_000_000
    return None


class Freshness(enum.Enum):
    """What one autopilot message says about the autopilot's presence."""

    SAME = "same"  # nothing new
    SEEN = "autopilot_seen"  # the first message ever
    BACK = "autopilot_back"  # the first after a silence longer than the timeout
    REBOOTED = "autopilot_rebooted"  # its boot clock went back, and the stream it replaces had stopped
    SECOND_SENDER = "autopilot_second_sender"  # the autopilot's ids, but not its stream: not believed


class AutopilotState(enum.Enum):
    """What is known of the autopilot now (`AutopilotPresence.state`)."""

    WAITING = "waiting"  # never heard from it
    UP = "up"  # messages arriving
    LOST = "lost"  # nothing for the timeout


class PresenceChange(enum.Enum):
    """A change of the autopilot's presence, as said on /icgt/link_events (each once) and hinted to the link."""

    SEEN = Freshness.SEEN.value
    LOST = "autopilot_lost"  # silent for longer than the timeout (`AutopilotPresence.expire`)
    BACK = Freshness.BACK.value
    REBOOTED = Freshness.REBOOTED.value

    @property
    def appeared(self) -> bool:
        """The autopilot is (again, or afresh) there: its streams may be at defaults, its clock may differ."""
        return self is not PresenceChange.LOST


@dataclass
class AutopilotPresence:
    """Tracks one autopilot (system id given, component learnt from its first HEARTBEAT) over its messages.

    `observe` returns None for messages from anyone else, else how the message changes what is known
    (first seen, back after ``timeout_ns`` of silence, rebooted, or SECOND_SENDER: a message with the
    autopilot's ids that is not of its stream, to be counted and otherwise ignored). ``component`` None
    means: learn it.

    Which stream is the autopilot's: its boot clock's origin (arrival time minus time_boot_ms) stays put
    within ``ORIGIN_TOLERANCE_NS`` and each message type's time_boot_ms never goes back; its MAVLink packet
    sequence numbers (one counter per sender) run on, a few lost or reordered. A message that breaks
    these while the autopilot's stream goes on is another sender (a second flight stack, a router's delayed
    echo, a replay, an attacker). A reboot is believed only when the boot clock went back by more than
    ``REBOOT_BACKSTEP_MS`` after the stream it replaces has been silent for ``REBOOT_SILENCE_NS``: what a
    real reboot gives, and a sender that talks over the running autopilot cannot.
    """

    system: int
    component: int | None = None
    timeout_ns: int = 3_000_000_000
    last_rx_ns: int | None = None
    last_boot_ms: int | None = None
    detail: str = ""
    origin_ns: int | None = None  # host time at the autopilot's boot, as its boot clock says (earliest seen)
    last_seq: int | None = None
    seq_counts: bool = False  # its sequence numbers have been seen to advance (a sender that keeps them at 0 never)
    second_sender_messages: int = 0
    lost: bool = False  # `expire` said so, and no message since
    silence_ns: int = 0
    _boot_by_type: dict[str, int] = field(default_factory=dict)
    _origins: deque[tuple[int, int]] = field(default_factory=deque)  # (rx, origin) rising: the window's minimum
    _gap_ns: int = 0  # the silence before the messages without a boot clock accepted since the last with one
    _first_rx_ns: int | None = None  # when the current stream was first heard (its first message, or a reboot's)

    def observe(self, msg: Any, mtype: str, rx_ns: int) -> Freshness | None:
        if int(msg.get_srcSystem()) != self.system:
            return None
        comp = int(msg.get_srcComponent())
        if self.component is None:
            if mtype != "HEARTBEAT" or not is_autopilot_heartbeat(msg):
                return None
            self.component = comp
        if comp != self.component:
            return None
        boot_ms = boot_clock_ms(msg, mtype)
        seq = int(msg.get_seq())
        if self.last_rx_ns is None:
            self._first_rx_ns = rx_ns
            self._accept(mtype, boot_ms, seq, rx_ns)
            self.detail = f"first {mtype}"
            return Freshness.SEEN
        silent_ns = rx_ns - self.last_rx_ns
        self.silence_ns = silent_ns
        # a reboot's first messages may carry no boot clock (HEARTBEAT): the silence before them still counts
        refusal = self._refusal(mtype, boot_ms, seq, rx_ns, max(silent_ns, self._gap_ns))
        if refusal == "rebooted":
            assert boot_ms is not None and self.last_boot_ms is not None
            self.detail = (
                f"{mtype}.time_boot_ms went from {self.last_boot_ms} to {boot_ms} after "
                f"{silent_ns / 1e9:.3f} s of silence"
            )
            self.origin_ns, self.last_seq, self.seq_counts = None, None, False
            self._first_rx_ns = rx_ns
            self._boot_by_type.clear()
            self._origins.clear()
            self._accept(mtype, boot_ms, seq, rx_ns)
            return Freshness.REBOOTED
        if refusal:
            self.second_sender_messages += 1
            self.detail = f"{mtype} (sequence number {seq}): {refusal}"
            return Freshness.SECOND_SENDER
        fresh = Freshness.SAME
        if silent_ns > self.timeout_ns:
            fresh, self.detail = Freshness.BACK, f"back after {silent_ns / 1e9:.3f} s"
        self._accept(mtype, boot_ms, seq, rx_ns)
        return fresh

    @property
    def state(self) -> AutopilotState:
        if self.last_rx_ns is None:
            return AutopilotState.WAITING
        return AutopilotState.LOST if self.lost else AutopilotState.UP

    def expire(self, now_ns: int) -> int | None:
        """The silence [ns] when the autopilot, heard before, has now been silent for longer than the timeout
        and was not lost yet (said once per outage); None otherwise."""
        if self.lost or self.last_rx_ns is None:
            return None
        silent_ns = now_ns - self.last_rx_ns
        if silent_ns <= self.timeout_ns:
            return None
        self.lost = True
        return silent_ns

    def _refusal(self, mtype: str, boot_ms: int | None, seq: int, rx_ns: int, silent_ns: int) -> str:
        """Why a message is not of the autopilot's stream ("" when it is; "rebooted" when it starts a new one)."""
        if boot_ms is not None and self.origin_ns is not None:
            origin_ns = rx_ns - boot_ms * 1_000_000
            went_back = self.last_boot_ms is not None and boot_ms + REBOOT_BACKSTEP_MS < self.last_boot_ms
            if went_back and silent_ns >= REBOOT_SILENCE_NS:
                return "rebooted"
            off_s = (origin_ns - self.origin_ns) / 1e9
            young = self._first_rx_ns is not None and rx_ns - self._first_rx_ns < YOUNG_STREAM_NS
            early_ns = YOUNG_EARLY_TOLERANCE_NS if young and self._seq_runs_on(seq, reordered=False) else 0
            early_ns = max(early_ns, ORIGIN_TOLERANCE_NS)
            if origin_ns < self.origin_ns - early_ns or origin_ns > self.origin_ns + LATE_TOLERANCE_NS:
                return (
                    f"its boot clock puts the autopilot's boot {off_s:+.3f} s from where the autopilot's own "
                    "stream, still running, puts it"
                )
            last = self._boot_by_type.get(mtype)
            if last is not None and boot_ms < last:
                return f"time_boot_ms {boot_ms} is behind the autopilot's last {mtype} ({last}): an echo or a replay"
            if last is not None and boot_ms == last and not self._seq_runs_on(seq, reordered=False):
                return (
                    f"a repeat of the autopilot's last {mtype} (time_boot_ms {boot_ms}) with sequence number {seq} "
                    f"where its stream is at {self.last_seq}: an echo"
                )
            return ""
        if silent_ns < REBOOT_SILENCE_NS and not self._seq_runs_on(seq):
            return f"the autopilot's stream is at sequence number {self.last_seq}"
        return ""

    def _seq_runs_on(self, seq: int, reordered: bool = True) -> bool:
        """Could `seq` be the stream's next packet (a few lost, or with `reordered` a few behind)? Always, until
        its numbers count. (A message repeating its type's last time_boot_ms is new only if it is ahead.)"""
        if not self.seq_counts or self.last_seq is None:
            return True
        step = (seq - self.last_seq) & 0xFF
        return 1 <= step <= SEQ_AHEAD_MAX or (reordered and step >= 256 - SEQ_REORDER_MAX)

    def _accept(self, mtype: str, boot_ms: int | None, seq: int, rx_ns: int) -> None:
        self.lost = False
        if boot_ms is None and self.last_rx_ns is not None:
            self._gap_ns = max(self._gap_ns, rx_ns - self.last_rx_ns)
        elif boot_ms is not None:
            self._gap_ns = 0
        self.last_rx_ns = rx_ns
        if self.last_seq is not None:
            step = (seq - self.last_seq) & 0xFF
            if 1 <= step <= SEQ_AHEAD_MAX:
                self.seq_counts = True
                self.last_seq = seq
            elif step >= 256 - SEQ_REORDER_MAX and self.seq_counts:
                pass  # a reordered one: the stream is still further on
            else:
                self.last_seq = seq
        else:
            self.last_seq = seq
        if boot_ms is not None:
            origin_ns = rx_ns - boot_ms * 1_000_000
            # the least delayed message of the last ORIGIN_WINDOW_NS (a rising deque: its head is the minimum),
            # so that the origin follows the clocks' drift over hours and one late message does not move it
            window = self._origins
            while window and window[-1][1] >= origin_ns:
                window.pop()
            window.append((rx_ns, origin_ns))
            while len(window) > 1 and window[0][0] < rx_ns - ORIGIN_WINDOW_NS:
                window.popleft()
            self.origin_ns = window[0][1]
            self.last_boot_ms = boot_ms
            self._boot_by_type[mtype] = max(boot_ms, self._boot_by_type.get(mtype, boot_ms))
