"""The synchroniser: device stream + autopilot telemetry in, geotagged frames out. No I/O, one thread.

`Synchroniser` owns every clock filter (device -> host, autopilot -> host, PPS -> UTC, host -> UTC),
the telemetry buffers, the geotagger and every acceptance rule (which autopilot and component to
believe, which TIMESYNC replies are ours, when the autopilot or the device rebooted). It does no
I/O and takes no locks: the recorder (`icgt record`) reads the links on its threads, hands each input
to one worker thread that writes it to the log and then feeds it here, in that order; the offline
recompute (`icgt.ingest.recompute`) reads the same inputs back from the log, in the same order, and
feeds the same object. What one sees, the other sees, so a recomputation with the recorded settings
gives back every frame exactly.

Inputs (each is a logged record; the topic is in `icgt.recording.layout`):

* `on_device(message, rx_ns)`: a device message (EXPOSURE, IMU, RANGE, PPS, HELLO, STATUS, DEVICE_STATE)
  and the host receive time [ns, CLOCK_MONOTONIC]; DEVICE_STATE's rates set how long the autopilot
  telemetry is kept (the device's history horizon: a frame resent that late still finds its pose);
* `on_exchange(...)`: one device TIME_SYNC exchange;
* `on_timesync_request(ts1_ns)`: a MAVLink TIMESYNC request this host sent;
* `on_mavlink(msg, rx_ns)`: any MAVLink message received (pymavlink object), stamped on arrival;
* `on_host_realtime(host_ns, realtime_ns)`: the host's CLOCK_REALTIME next to CLOCK_MONOTONIC.

Output: `poll(now_ns)` returns the frames ready at host time ``now_ns`` (their later pose sample has
arrived, or their wait ran out); each record carries ``emitted_host_ns = now_ns``, which is how the
recompute knows when to poll.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, NamedTuple

from icgt.clocks.autopilot_clock import AutopilotClockFilter, UtcMapper
from icgt.clocks.autopilot_time import AutopilotTimeMap
from icgt.clocks.device_clock import DeviceClockFilter, ExchangeStatus, PpsUtcMapper
from icgt.clocks.one_way import OneWayClock
from icgt.clocks.two_way import ClockNotSyncedError
from icgt.device.history import NOMINAL_RATES, DeviceRates, telemetry_retention_s
from icgt.geotag.clock_views import AutopilotClockView, UtcView, add_pps_edge
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameRecord
from icgt.mavlink.autopilot_rules import BOOT_CLOCK_TYPES, AutopilotPresence, Freshness, PresenceChange
from icgt.mavlink.gimbal import GIMBAL_MESSAGE, gimbal_sample
from icgt.mavlink.link_types import MavlinkMessage
from icgt.mavlink.telemetry import TelemetryStore
from icgt.protocol.messages import DeviceState, Exposure, Hello, Imu, Message, Pps, Range, Status
from icgt.sync.config import SyncConfig
from icgt.sync.timesync import TimesyncPairing, TimesyncReply

__all__ = ["MavlinkVerdict", "SyncEvent", "Synchroniser"]

log = logging.getLogger(__name__)

UNANSWERED_TIMESYNC_WARNING = 10  # requests without any answer before the log says so (once)


@dataclass(frozen=True, slots=True)
class SyncEvent:
    """Something the synchroniser noticed that belongs in the log (kind, host time [ns], detail).

    ``presence``: a change of the autopilot's presence (its kind is ``presence.value``), which the recorder also
    hands to the MAVLink link as a hint. ``outage_ns``: on autopilot_lost the silence so far, on autopilot_back
    (and autopilot_rebooted after a loss) the whole silence [ns]; 0 otherwise."""

    kind: str
    host_ns: int
    detail: str
    outage_ns: int = 0
    presence: PresenceChange | None = None


class MavlinkVerdict(NamedTuple):
    """What `Synchroniser.on_mavlink` made of a message. ``believed``: the followed autopilot's own (its ids and
    its stream, signed when signing is configured); only such a COMMAND_ACK may answer the link's commands (a
    second sender using the autopilot's ids answers nothing). ``timesync``: the round trip when it was a
    TIMESYNC reply to us."""

    believed: bool
    timesync: TimesyncReply | None = None


_BELIEVED = MavlinkVerdict(True)
_NOT_BELIEVED = MavlinkVerdict(False)


class Synchroniser:
    """One flight's synchronisation state. Not thread-safe by design: feed and poll from one thread."""

    def __init__(
        self,
        config: SyncConfig | None = None,
        *,
        device_clock: DeviceClockFilter | None = None,
        autopilot_clock: AutopilotClockFilter | None = None,
    ) -> None:
        self.config = cfg = config or SyncConfig()
        self.device_clock = device_clock or DeviceClockFilter(slow_interval_s=0.1, refit_interval_s=0.5)
        self.autopilot_clock = autopilot_clock or AutopilotClockFilter()
        self.autopilot_one_way = OneWayClock(min_delay_allowance_s=cfg.one_way_min_delay_allowance_s)
        self.autopilot_time = AutopilotTimeMap(self.autopilot_clock, self.autopilot_one_way)
        self.utc = UtcMapper(self.autopilot_time)
        self.pps = PpsUtcMapper()
        # MAV_COMP_ID_AUTOPILOT1 until the autopilot's HEARTBEAT (or the configuration) names its component.
        self._default_component = cfg.autopilot_component if cfg.autopilot_component is not None else 1
        self.telemetry = TelemetryStore(
            autopilot_system=cfg.autopilot_system,
            autopilot_component=self._default_component,
            retention_s=max(cfg.telemetry_retention_s or 0.0, telemetry_retention_s(NOMINAL_RATES)),
        )
        self.autopilot = AutopilotPresence(
            cfg.autopilot_system, cfg.autopilot_component, int(cfg.autopilot_timeout_s * 1e9)
        )
        self.timesync = TimesyncPairing(int(cfg.timesync_timeout_s * 1e9))
        self._ready: list[FrameRecord] = []
        self.geotagger = Geotagger(
            self.telemetry,
            self.device_clock,
            AutopilotClockView(self.autopilot_time),
            UtcView(self.pps, self.utc),
            cfg.geotag,
            self._ready.append,
        )
        self.hello: Hello | None = None
        self.last_status: Status | None = None
        self.events: list[SyncEvent] = []  # drained by the caller (`take_events`)
        self._gimbal_clocks: dict[int, OneWayClock] = {}  # a gimbal device's boot clock -> host, by component
        self.counts: dict[str, int] = {
            "exposures": 0,
            "exchanges": 0,
            "mavlink_messages": 0,
            "device_reboots": 0,
            "autopilot_reboots": 0,
            "autopilot_outages": 0,  # back after a silence longer than autopilot_timeout_s
            "frames": 0,
            "late_pps_skipped": 0,
            "autopilot_second_sender_messages": 0,
            "autopilot_unsigned_messages": 0,
            "gimbal_samples": 0,
            "gimbal_unstamped": 0,  # GIMBAL_DEVICE_ATTITUDE_STATUS before any autopilot clock, or not a rotation
        }
        self._timesync_warned = False
        self._utc_source = ""  # the UTC source the last poll used, to log each change with its jump
        self._device_t_us = 0  # the latest device time seen since the last HELLO
        self._last_pps_t_us = 0  # the latest PPS edge fed to the PPS fit

    # ------------------------------------------------------------------ inputs
    def on_device(self, msg: Message, rx_ns: int, *, retransmitted: bool = False) -> None:
        """A device message as received (any type; those that carry nothing for the frames are kept as state).

        ``retransmitted``: its frame carried the retransmit flag (RESEND brought it back after an outage)."""
        if isinstance(msg, Imu):
            self.geotagger.add_imu(msg)
            self._device_t_us = max(self._device_t_us, msg.read_end_t_us)
        elif isinstance(msg, Range):
            self.geotagger.add_range(msg)
            self._device_t_us = max(self._device_t_us, msg.acq_start_t_us)
        elif isinstance(msg, Exposure):
            self.counts["exposures"] += 1
            self.geotagger.add_exposure(msg, rx_ns, resent=retransmitted)
            self._device_t_us = max(self._device_t_us, msg.trigger_t_us, msg.feedback_start_t_us)
        elif isinstance(msg, Pps):
            if msg.t_us < self._last_pps_t_us:
                # Resent after a gap (RESEND), older than an edge already fitted: the PPS fit takes edges in
                # order only (an older one reads as a reboot); the gap in the edges costs nothing.
                self.counts["late_pps_skipped"] += 1
                return
            self._last_pps_t_us = msg.t_us
            add_pps_edge(self.pps, self.utc, self.device_clock, msg.t_us, msg.pps_count)
            self._device_t_us = max(self._device_t_us, msg.t_us)
        elif isinstance(msg, DeviceState):
            self._retain_for(msg)
        elif isinstance(msg, Status):
            self.last_status = msg
            self._device_t_us = max(self._device_t_us, msg.t_us)
        elif isinstance(msg, Hello):
            if self.hello is not None and msg.t_us < self._device_t_us:
                # Earlier than device time already seen: the device rebooted, its microsecond clock
                # restarted and the old mapping means nothing.
                self.device_clock.reset()
                self.geotagger.clear_device_samples()
                self._last_pps_t_us = 0
                self.counts["device_reboots"] += 1
                self._event("device_rebooted", rx_ns, f"HELLO at device time {msg.t_us} us: its clock restarted")
            self.hello = msg
            self._device_t_us = msg.t_us

    def _retain_for(self, state: DeviceState) -> None:
        """Keep telemetry for the device's history horizon at the rates it reports (only ever longer)."""
        rates = DeviceRates(
            exposure_hz=1e6 / state.interval_us if state.interval_us else 0.0,
            imu_hz=float(state.imu_rate_hz),
            range_hz=float(state.range_rate_hz),
        )
        retention = telemetry_retention_s(rates)
        if retention > (self.telemetry.retention_s or 0.0):
            self.telemetry.retain(retention)

    def on_exchange(self, host_tx_ns: int, device_rx_us: int, device_tx_us: int, host_rx_ns: int) -> ExchangeStatus:
        """One device TIME_SYNC exchange (host send/receive [ns], device receive/transmit [us])."""
        self.counts["exchanges"] += 1
        return self.device_clock.add_exchange(host_tx_ns, device_rx_us, device_tx_us, host_rx_ns)

    def on_timesync_request(self, ts1_ns: int) -> None:
        """A TIMESYNC request this host sent (ts1 = its send time [ns, host clock])."""
        self.timesync.request_sent(ts1_ns)

    def on_host_realtime(self, host_ns: int, realtime_ns: int) -> None:
        """The host's CLOCK_REALTIME [ns] at CLOCK_MONOTONIC ``host_ns``: UTC until the autopilot has GPS time."""
        self.utc.add_host_realtime(host_ns, realtime_ns)

    def on_other_systems(self, type_counts: Mapping[str, int]) -> None:
        """Messages of systems other than the autopilot's, counted per type (what `on_mavlink` does with each
        of them, in bulk: a flood of them must not cost a call each)."""
        self.counts["mavlink_messages"] += sum(type_counts.values())
        self.telemetry.count_other_sources(type_counts)

    def on_mavlink(self, msg: Any, rx_ns: int) -> MavlinkVerdict:
        """Any MAVLink message: whether it was believed to be the followed autopilot's own, and the TIMESYNC
        round trip when it was a reply to us."""
        self.counts["mavlink_messages"] += 1
        if msg.get_srcSystem() != self.autopilot.system:
            # Another system (a ground station, another vehicle, most of a flood): nothing of it reaches the
            # clocks or the poses; only the telemetry store counts it, as ingest() would.
            self.telemetry.count_other_source(str(msg.get_type()))
            return _NOT_BELIEVED
        mtype = str(msg.get_type())
        if self.config.require_signed_autopilot and not msg.get_signed():
            self._unsigned(mtype, rx_ns)
            return _NOT_BELIEVED
        was_lost = self.autopilot.lost
        fresh = self.autopilot.observe(msg, mtype, rx_ns)
        if fresh is Freshness.SECOND_SENDER:
            self._second_sender(rx_ns)
            return _NOT_BELIEVED
        verdict = _BELIEVED if fresh is not None else _NOT_BELIEVED
        if fresh is not None and fresh is not Freshness.SAME:
            self._appeared(PresenceChange(fresh.value), rx_ns, was_lost)
        if fresh is not None and mtype in BOOT_CLOCK_TYPES:
            boot_ms = getattr(msg, "time_boot_ms", None)
            if isinstance(boot_ms, int):
                self.autopilot_one_way.add(boot_ms * 1000.0 + 500.0, rx_ns)  # centre of the truncated ms
        if mtype == "TIMESYNC":
            if fresh is None:
                return verdict  # not from the autopilot we follow
            reply = self.timesync.reply(msg, rx_ns)
            if reply is None:
                return verdict
            self.autopilot_clock.add_timesync(reply.host_tx_ns, reply.autopilot_tc1_ns, reply.host_rx_ns)
            return MavlinkVerdict(True, reply)
        if mtype == "HEARTBEAT":
            return verdict
        if mtype == GIMBAL_MESSAGE:
            self._on_gimbal(msg, rx_ns, own_clock=fresh is not None)
            return verdict
        self.telemetry.autopilot_component = self.autopilot.component or self._default_component
        self.telemetry.ingest(MavlinkMessage(msg, rx_ns))
        if mtype == "SYSTEM_TIME" and fresh is not None:  # the autopilot's own, not a companion's
            self.utc.add_system_time(int(msg.time_unix_usec), int(msg.time_boot_ms))
        return verdict

    def _appeared(self, change: PresenceChange, rx_ns: int, was_lost: bool) -> None:
        """The autopilot seen first, back after its timeout, or rebooted: TIMESYNC requests sent before are not
        answered on the same clock, and a reboot restarts its boot clock."""
        self.timesync.forget()
        outage_ns = self.autopilot.silence_ns if change is PresenceChange.BACK or was_lost else 0
        if change is PresenceChange.BACK:
            self.counts["autopilot_outages"] += 1
        elif change is PresenceChange.REBOOTED:
            self.counts["autopilot_reboots"] += 1
            self.autopilot_one_way.reset()
        level = logging.WARNING if change is PresenceChange.REBOOTED else logging.INFO
        self._event(change.value, rx_ns, self.autopilot.detail, outage_ns=outage_ns, presence=change, level=level)

    def _check_presence(self, now_ns: int) -> None:
        """The autopilot silent for longer than ``autopilot_timeout_s``: said once (its next message is back)."""
        silent_ns = self.autopilot.expire(now_ns)
        if silent_ns is not None:
            detail = f"no message for {silent_ns / 1e9:.3f} s"
            self._event(
                PresenceChange.LOST.value,
                now_ns,
                detail,
                outage_ns=silent_ns,
                presence=PresenceChange.LOST,
                level=logging.WARNING,
            )

    def _unsigned(self, mtype: str, rx_ns: int) -> None:
        """With signing configured, a message of the autopilot's system without a valid signature: counted, said
        once, kept out of everything (whoever can reach the port can send it)."""
        self.counts["autopilot_unsigned_messages"] += 1
        if self.counts["autopilot_unsigned_messages"] == 1:
            detail = (
                f"{mtype} with the autopilot's system id {self.autopilot.system} has no valid signature and signing "
                "is configured: not believed (counted as autopilot_unsigned_messages; give the autopilot the key)"
            )
            log.warning("%s", detail)
            self.events.append(SyncEvent("autopilot_unsigned", rx_ns, detail))

    def _second_sender(self, rx_ns: int) -> None:
        """A message with the autopilot's ids that is not of its stream: counted (`autopilot_second_sender_messages`
        in every counters record), said loudly the first time, and kept out of the clocks, TIMESYNC and poses."""
        self.counts["autopilot_second_sender_messages"] += 1
        if self.counts["autopilot_second_sender_messages"] == 1:
            detail = (
                f"a second sender uses the autopilot's MAVLink id {self.autopilot.system}:{self.autopilot.component}: "
                f"{self.autopilot.detail}; its messages are not believed (counted as autopilot_second_sender_messages)"
            )
            log.warning("%s", detail)
            self.events.append(SyncEvent(Freshness.SECOND_SENDER.value, rx_ns, detail))

    # ------------------------------------------------------------------ output
    def poll(self, now_ns: int, *, flush: bool = False) -> list[FrameRecord]:
        """The frames ready at host time ``now_ns`` (all pending ones with ``flush``), in exposure order."""
        self.timesync.expire(now_ns)
        self._check_presence(now_ns)
        if (
            not self._timesync_warned
            and self.timesync.answered == 0
            and self.timesync.unanswered >= UNANSWERED_TIMESYNC_WARNING
        ):
            self._timesync_warned = True
            self._event(
                "timesync_unanswered",
                now_ns,
                f"the autopilot answered none of {self.timesync.unanswered} TIMESYNC requests: "
                "no autopilot clock mapping",
            )
        self._check_utc_source(now_ns)
        self.geotagger.poll(now_ns, flush=flush)
        ready, self._ready[:] = list(self._ready), []
        self.counts["frames"] += len(ready)
        return ready

    def _check_utc_source(self, now_ns: int) -> None:
        """Log each change of UTC source with how far the new one is from the host clock (a jump of frames' UTC).

        Runs at every poll: the change is seen from the mapper's source alone; the estimate (whose bound
        costs a search over the TIMESYNC hull) is computed only when the source changed."""
        source = self.utc.source.value
        if source == self._utc_source:
            return
        previous, self._utc_source = self._utc_source, source
        if not previous:
            return
        est = self.utc.host_to_utc(now_ns)
        host = self.utc.host_realtime_utc_us(now_ns)
        detail = f"UTC now from {source} (was {previous})"
        if est.valid and host is not None:
            detail += f": {(est.utc_us - host) / 1e6:+.6f} s from the host clock"
        self._event("utc_source_changed", now_ns, detail)

    @property
    def pending_frames(self) -> int:
        return self.geotagger.pending

    def next_exchange_interval_s(self) -> float:
        """Seconds until the next device TIME_SYNC request should go out."""
        return self.device_clock.next_exchange_interval_s()

    def take_events(self) -> list[SyncEvent]:
        events, self.events = self.events, []
        return events

    def _on_gimbal(self, msg: Any, rx_ns: int, *, own_clock: bool) -> None:
        """A gimbal's attitude (any component of the autopilot's system), on the autopilot's boot clock: its own
        ``time_boot_ms`` when the autopilot's component sent it (its mount driver), else the device's own boot
        clock mapped through its arrivals' lower envelope and the autopilot clock."""
        stamp_us = int(msg.time_boot_ms) * 1000 + 500  # the centre of the truncated millisecond
        if own_clock:
            boot_us = stamp_us
        else:
            # Its own boot clock, mapped onto the host's by the lower envelope of its arrivals (as the autopilot's
            # without TIMESYNC): a report that waited in a queue is placed when it was sent, not when it arrived.
            clock = self._gimbal_clocks.setdefault(int(msg.get_srcComponent()), OneWayClock())
            clock.add(stamp_us, rx_ns)
            try:
                boot_us = round(self.autopilot_time.host_to_autopilot_us(clock.autopilot_to_host_ns(stamp_us)))
            except ClockNotSyncedError:
                self.counts["gimbal_unstamped"] += 1
                return
        sample = gimbal_sample(msg, boot_us, rx_ns)
        if sample is None:
            self.counts["gimbal_unstamped"] += 1
            return
        self.telemetry.gimbal.push(sample)
        self.counts["gimbal_samples"] += 1

    def counters(self) -> dict[str, int]:
        """Everything counted, for the log and `icgt status`."""
        t = self.timesync
        return {
            **self.counts,
            "timesync_sent": t.sent,
            "timesync_answered": t.answered,
            "timesync_unanswered": t.unanswered,
            "timesync_foreign": t.foreign,
            "utc_ignored_unset": self.utc.ignored_unset,
            "utc_ignored_implausible": self.utc.ignored_implausible,
            "utc_steps": self.utc.steps,
            "autopilot_clock_resets": self.autopilot_time.resets,
            "pending_frames": self.pending_frames,
            "telemetry_retention_s": round(self.telemetry.retention_s or 0),
            "telemetry_bytes": self.telemetry.memory_bytes(),
            **{f"telemetry_{k}": v for k, v in self.telemetry.counts().items()},
        }

    def _event(
        self,
        kind: str,
        host_ns: int,
        detail: str,
        *,
        outage_ns: int = 0,
        presence: PresenceChange | None = None,
        level: int = logging.INFO,
    ) -> None:
        log.log(level, "%s: %s", kind, detail)
        self.events.append(SyncEvent(kind, host_ns, detail, outage_ns, presence))
