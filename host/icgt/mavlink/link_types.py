"""The MAVLink link's vocabulary: its configuration, what it reports (events, stats) and what it delivers."""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.errors import IcgtError
from icgt.mavlink.frames import UndecodedBatch

__all__ = [
    "DEFAULT_STREAM_RATES",
    "MAV_COMP_ID_CAMERA",
    "LinkConfig",
    "LinkError",
    "LinkEventKind",
    "LinkStats",
    "MavlinkEvent",
    "MavlinkMessage",
    "RateRequestResult",
    "StreamRate",
    "Subscription",
]

MAV_COMP_ID_CAMERA = 100
_PROTOCOL_MARKER_V1 = 0xFE


class LinkError(IcgtError):
    """The MAVLink connection cannot be opened (bad URL, missing device, refused connection)."""


class LinkEventKind(enum.Enum):
    """What the link itself reports: its transport, its rate requests, its socket. (The autopilot's presence is
    the core's: `icgt.mavlink.autopilot_rules.PresenceChange`.)"""

    TRANSPORT_ERROR = "transport_error"
    TRANSPORT_REOPENED = "transport_reopened"
    RATE_REQUEST = "rate_request"
    KERNEL_DROPS = "kernel_drops"  # the kernel dropped datagrams (UDP receive buffer full): count and buffer size


@dataclasses.dataclass(frozen=True, slots=True)
class MavlinkEvent:
    """A change worth a line in the log."""

    kind: LinkEventKind
    host_ns: int
    system: int
    component: int
    detail: str = ""
    count: int = 0  # KERNEL_DROPS: the datagrams dropped since the last such event


@dataclasses.dataclass(frozen=True, slots=True)
class MavlinkMessage:
    """A message as the reader got it. ``rx_ns`` is time.monotonic_ns() when its last byte arrived."""

    msg: Any
    rx_ns: int

    @property
    def type(self) -> str:
        return str(self.msg.get_type())

    @property
    def src_system(self) -> int:
        return int(self.msg.get_srcSystem())

    @property
    def src_component(self) -> int:
        return int(self.msg.get_srcComponent())

    @property
    def msg_id(self) -> int:
        return int(self.msg.get_msgId())

    @property
    def mavlink_version(self) -> int:
        """1 or 2, from the frame's start marker."""
        buf = self.msg.get_msgbuf()
        return 1 if buf and buf[0] == _PROTOCOL_MARKER_V1 else 2


@dataclasses.dataclass(frozen=True, slots=True)
class StreamRate:
    """A telemetry stream to ask the autopilot for. ``rate_hz <= 0`` asks it to stop the stream."""

    message_id: int
    name: str
    rate_hz: float

    @property
    def interval_us(self) -> int:
        return -1 if self.rate_hz <= 0 else round(1e6 / self.rate_hz)


DEFAULT_STREAM_RATES: tuple[StreamRate, ...] = (
    StreamRate(mavlink2.MAVLINK_MSG_ID_GLOBAL_POSITION_INT, "GLOBAL_POSITION_INT", 50.0),
    StreamRate(mavlink2.MAVLINK_MSG_ID_GPS_RAW_INT, "GPS_RAW_INT", 10.0),
    StreamRate(mavlink2.MAVLINK_MSG_ID_ATTITUDE, "ATTITUDE", 50.0),
    StreamRate(mavlink2.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, "ATTITUDE_QUATERNION", 50.0),
    StreamRate(mavlink2.MAVLINK_MSG_ID_LOCAL_POSITION_NED, "LOCAL_POSITION_NED", 30.0),
    StreamRate(mavlink2.MAVLINK_MSG_ID_SYSTEM_TIME, "SYSTEM_TIME", 2.0),
)


@dataclasses.dataclass(frozen=True, slots=True)
class LinkConfig:
    """How to reach the autopilot and who we are on the link.

    ``system_id`` is the vehicle's system id: the camera component shares it (ground stations only list
    cameras of the vehicle's own system) and it is the autopilot's unless ``autopilot_system`` says
    otherwise. Which component of it is the autopilot is the core's to say (`MavlinkLink.autopilot_hint`,
    from the synchroniser's `AutopilotPresence`; ``SyncConfig.autopilot_component``).
    """

    url: str
    system_id: int = 1
    component_id: int = MAV_COMP_ID_CAMERA
    autopilot_system: int | None = None
    baud: int = 115200  # serial only, when the URL does not say ("/dev/ttyAMA0,921600" does)
    reopen_delay_s: float = 1.0
    request_rates: bool = True
    stream_rates: tuple[StreamRate, ...] = DEFAULT_STREAM_RATES
    rate_ack_timeout_s: float = 0.5
    rate_max_attempts: int = 5
    # An ACCEPTED rate whose message comes at under a fifth of it over this window is asked for again
    # (ArduPilot ACKs a SET_MESSAGE_INTERVAL taken during its boot, then resets the stream to its SRn_
    # rate: issue 29) ...
    rate_verify_s: float = 3.0
    rate_max_rerequests: int = 5  # ... at most this many times per message
    timesync: bool = True
    timesync_fast_hz: float = 5.0  # after the autopilot appears (again) ...
    timesync_fast_count: int = 20  # ... for this many requests, then:
    timesync_slow_hz: float = 1.0
    # Systems whose messages are decoded; frames of any other system on a UDP link are passed on as
    # `UndecodedFrame`s (header only, no CRC check: kept raw, used for nothing). None decodes everything.
    decode_systems: frozenset[int] | None = None
    udp_receive_buffer_bytes: int = 4 * 1024 * 1024  # Linux's default (~208 KB) overflows in a parameter burst
    # MAVLink 2 signing (icgt.mavlink.signing): every frame we send is signed with this 32-byte key and every
    # received message says whether it carried a valid signature (msg.get_signed()). Never in a repr.
    signing_key: bytes | None = dataclasses.field(default=None, repr=False)
    signing_link_id: int = 0
    # UDP with kernel receive timestamps only: after draining the socket the reader sleeps this long [s],
    # so that one wake-up takes many datagrams (their stamps are the kernel's, not the read's). 0: no pause.
    read_batch_s: float = 0.0
    # The service thread (TIMESYNC and stream-rate requests, `icgt.mavlink.link_scheduler`) runs this often [s].
    service_period_s: float = 0.01
    # UDP with kernel receive timestamps only: no reader or service thread, the owner calls `MavlinkLink.pump()`
    # every few tens of ms from its own thread (see icgt.mavlink.link). Other transports ignore it.
    owner_pumps: bool = False

    @property
    def effective_autopilot_system(self) -> int:
        return self.system_id if self.autopilot_system is None else self.autopilot_system


@dataclasses.dataclass(frozen=True, slots=True)
class RateRequestResult:
    """Outcome of one SET_MESSAGE_INTERVAL. ``result`` is the MAV_RESULT, or None when never ACKed."""

    message_id: int
    name: str
    rate_hz: float
    result: int | None
    attempts: int
    host_ns: int

    @property
    def accepted(self) -> bool:
        return self.result is not None and self.result == int(mavlink2.MAV_RESULT_ACCEPTED)


@dataclasses.dataclass(frozen=True, slots=True)
class LinkStats:
    messages_by_type: dict[str, int]
    bad_frames: int
    v1_frames: int
    v2_frames: int
    bytes_received: int
    messages_sent: int
    send_failures: int
    callback_errors: int
    queue_drops: int
    self_echoes: int
    same_id_frames: int
    timesync_sent: int
    undecoded_frames: int
    transport_errors: int
    # UDP datagrams the kernel dropped because the socket's receive buffer was full (SO_MEMINFO / SO_RXQ_OVFL,
    # Linux), and that buffer: what was asked (udp_receive_buffer_bytes) and what the kernel granted [bytes]
    kernel_drops: int = 0
    udp_receive_buffer_bytes: int = 0
    udp_receive_buffer_asked_bytes: int = 0
    # with a signing key only: frames received with a valid signature, an invalid one, none
    signed_ok: int = 0
    signed_bad: int = 0
    unsigned: int = 0


class Subscription:
    """Handle returned by `MavlinkLink.subscribe`; pass it to `unsubscribe`."""

    __slots__ = ("callback", "types", "undecoded")

    def __init__(
        self,
        callback: Callable[[MavlinkMessage], object],
        types: frozenset[str] | None,
        undecoded: Callable[[UndecodedBatch], object] | None = None,
    ) -> None:
        self.callback = callback
        self.types = types
        self.undecoded = undecoded  # takes other systems' undecoded frames in batches instead of `callback`
