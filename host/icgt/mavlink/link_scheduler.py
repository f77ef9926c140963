"""What the MAVLink link sends on its own, and when: TIMESYNC requests and stream-rate requests.

`LinkScheduler` is driven by time (`due(now_ns)`), by the autopilot's answers (`on_command_ack`, the
COMMAND_ACKs the core believed, and `counted`: how many of each message it sends) and by hints from the
core, which owns the one autopilot state machine (`icgt.mavlink.autopilot_rules.AutopilotPresence`, in the
synchroniser):

* `autopilot_appeared` (seen, back after an outage, rebooted): its streams may be at their defaults and its
  clock may have restarted, so every configured stream rate is asked for again (MAV_CMD_SET_MESSAGE_INTERVAL,
  one command at a time, since a COMMAND_ACK does not say which message it answers; retried until ACKed,
  ``rate_max_attempts`` at most) and TIMESYNC goes fast (``timesync_fast_count`` requests at
  ``timesync_fast_hz``) before settling at ``timesync_slow_hz``;
* `autopilot_lost`: pending rate requests are dropped (they are asked again when it is back).

An ACCEPTED rate whose message then comes at under a fifth of it over ``rate_verify_s`` is asked for again
(ArduPilot ACKs a SET_MESSAGE_INTERVAL taken during its boot, then resets the stream: issue 29), at most
``rate_max_rerequests`` times per message. No I/O, no threads, no locks: the link calls it under its own
lock and does the sending `due` returns.
"""

from __future__ import annotations

import dataclasses
import logging
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.mavlink.link_types import LinkConfig, LinkEventKind, MavlinkEvent, RateRequestResult, StreamRate

__all__ = ["Due", "LinkScheduler", "RateCommand"]

_SET_MESSAGE_INTERVAL = int(mavlink2.MAV_CMD_SET_MESSAGE_INTERVAL)
_IN_PROGRESS = int(mavlink2.MAV_RESULT_IN_PROGRESS)
_VERIFY_FRACTION = 0.2  # an ACCEPTED stream arriving at under this fraction of its rate is asked for again


@dataclasses.dataclass(frozen=True, slots=True)
class RateCommand:
    """One SET_MESSAGE_INTERVAL to send now: the rate, to whom (system, component), its confirmation number."""

    rate: StreamRate
    target: tuple[int, int]
    confirmation: int


@dataclasses.dataclass(slots=True)
class Due:
    """What `LinkScheduler.due` says to do now: a TIMESYNC request, a rate command, events (with log levels)."""

    timesync: bool = False
    rate: RateCommand | None = None
    events: list[tuple[MavlinkEvent, int]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass(slots=True)
class _RateJob:
    rate: StreamRate
    attempts: int = 0
    deadline_ns: int = 0
    ack: int | None = None  # its MAV_RESULT
    acked: bool = False


class LinkScheduler:
    """The link's TIMESYNC and stream-rate jobs over time and the core's hints (see the module docstring)."""

    def __init__(self, config: LinkConfig) -> None:
        self.config = config
        # (system, component) of the autopilot as the core last named it; None until it has
        self.autopilot: tuple[int, int] | None = None
        self.present = False  # between an `autopilot_appeared` and the next `autopilot_lost`
        self._ts_next_ns = 0
        self._ts_fast_left = 0
        self._jobs: list[_RateJob] = []
        self._results: dict[int, RateRequestResult] = {}
        self._rx_count: dict[int, int] = {}  # message id -> messages received from the autopilot
        self._window: dict[int, tuple[int, int]] = {}  # message id -> (verify window start [ns], count then)
        self._rerequests: dict[int, int] = {}  # message id -> re-requests since the autopilot appeared

    # ------------------------------------------------------------------ hints from the core
    def autopilot_appeared(self, system: int, component: int, now_ns: int) -> None:
        """The core says the autopilot is there afresh (seen, back or rebooted): rates again, TIMESYNC fast."""
        self.autopilot = (system, component)
        self.present = True
        self.request_rates()
        self._ts_fast_left = self.config.timesync_fast_count
        self._ts_next_ns = now_ns

    def autopilot_lost(self) -> None:
        """The core says the autopilot is gone: nothing is asked of it until it is back."""
        self.present = False
        self._jobs.clear()
        self._ts_fast_left = 0

    def request_rates(self) -> None:
        """Every configured stream rate asked for (again), from the first, when the autopilot is there."""
        if self.config.request_rates:
            self._jobs = [_RateJob(rate) for rate in self.config.stream_rates]
            self._rerequests.clear()

    # ------------------------------------------------------------------ what the autopilot sends
    def counted(self, msg_id: int) -> None:
        """A message with the autopilot's (system, component), counted per id for the rate checks (on the
        reading thread: a second sender using those ids is counted too, which can only hide a slow stream)."""
        self._rx_count[msg_id] = self._rx_count.get(msg_id, 0) + 1

    def on_command_ack(self, msg: Any, rx_ns: int) -> None:
        """A COMMAND_ACK the core believed to be the autopilot's own (its ids and its stream, signed when signing
        is configured: `Synchroniser.on_mavlink` returned ``believed``): one of SET_MESSAGE_INTERVAL for us
        answers the rate command in flight. An ACK from a second sender with the autopilot's ids never gets here."""
        if int(msg.command) != _SET_MESSAGE_INTERVAL or not self._jobs:
            return
        target = (int(getattr(msg, "target_system", 0)), int(getattr(msg, "target_component", 0)))
        if target not in ((0, 0), (self.config.system_id, self.config.component_id)):
            return  # the answer to another component's request
        job = self._jobs[0]
        if job.attempts == 0:
            return  # not sent yet: a stale ACK
        result = int(msg.result)
        if result == _IN_PROGRESS:
            job.deadline_ns = rx_ns + int(self.config.rate_ack_timeout_s * 1e9)
            return
        job.ack = result
        job.acked = True

    # ------------------------------------------------------------------ time
    def due(self, now_ns: int) -> Due:
        """What to send at ``now_ns`` (a TIMESYNC request, at most one rate command) and what to log."""
        out = Due()
        cfg = self.config
        if cfg.timesync and now_ns >= self._ts_next_ns:
            fast = self._ts_fast_left > 0 and self.present
            hz = cfg.timesync_fast_hz if fast else cfg.timesync_slow_hz
            if fast:
                self._ts_fast_left -= 1
            self._ts_next_ns = now_ns + int(1e9 / max(hz, 1e-3))
            out.timesync = True
        if not self.present or self.autopilot is None:
            return out
        while self._jobs:
            job = self._jobs[0]
            exhausted = job.attempts >= cfg.rate_max_attempts and now_ns >= job.deadline_ns
            if job.acked or exhausted:
                self._jobs.pop(0)
                result = RateRequestResult(
                    job.rate.message_id, job.rate.name, job.rate.rate_hz, job.ack, job.attempts, now_ns
                )
                self._results[job.rate.message_id] = result
                out.events.append(self._result_event(result))
                continue
            if job.attempts < cfg.rate_max_attempts and now_ns >= job.deadline_ns:
                job.attempts += 1
                job.deadline_ns = now_ns + int(cfg.rate_ack_timeout_s * 1e9)
                out.rate = RateCommand(job.rate, self.autopilot, min(job.attempts - 1, 255))
            break
        if not self._jobs:
            out.events.extend(self._rates_not_arriving(now_ns))
        return out

    def rate_results(self) -> list[RateRequestResult]:
        """The latest result per requested message id."""
        return list(self._results.values())

    def _rates_not_arriving(self, now_ns: int) -> list[tuple[MavlinkEvent, int]]:
        """Ask again for streams the autopilot ACCEPTED but sends at under a fifth of the rate asked, over
        each `rate_verify_s` window (ArduPilot resets them at the end of its boot; a parameter download
        slows them only 4 times)."""
        events: list[tuple[MavlinkEvent, int]] = []
        verify_ns = int(self.config.rate_verify_s * 1e9)
        for rate in self.config.stream_rates:
            mid = rate.message_id
            result = self._results.get(mid)
            if result is None or not result.accepted or rate.rate_hz <= 0:
                continue
            count = self._rx_count.get(mid, 0)
            start, count0 = self._window.get(mid, (0, 0))
            if start < result.host_ns:
                self._window[mid] = (now_ns, count)
                continue
            if now_ns - start < verify_ns:
                continue
            self._window[mid] = (now_ns, count)
            expected = rate.rate_hz * (now_ns - start) / 1e9
            tries = self._rerequests.get(mid, 0)
            if count - count0 >= _VERIFY_FRACTION * expected or tries >= self.config.rate_max_rerequests:
                continue
            self._rerequests[mid] = tries + 1
            self._jobs.append(_RateJob(rate))
            detail = (
                f"{rate.name} at {rate.rate_hz:g} Hz: ACCEPTED but {count - count0} came in "
                f"{(now_ns - start) / 1e9:.1f} s; asking again ({tries + 1} of {self.config.rate_max_rerequests})"
            )
            events.append((self._event(now_ns, detail), logging.WARNING))
        return events

    def _result_event(self, result: RateRequestResult) -> tuple[MavlinkEvent, int]:
        if result.result is None:
            detail = f"{result.name} at {result.rate_hz:g} Hz: no COMMAND_ACK after {result.attempts} attempts"
        else:
            entry = mavlink2.enums["MAV_RESULT"].get(result.result)
            outcome = getattr(entry, "name", str(result.result))
            detail = f"{result.name} at {result.rate_hz:g} Hz: {outcome} (attempt {result.attempts})"
        return self._event(result.host_ns, detail), logging.INFO if result.accepted else logging.WARNING

    def _event(self, host_ns: int, detail: str) -> MavlinkEvent:
        system, component = self.autopilot or (self.config.effective_autopilot_system, 0)
        return MavlinkEvent(LinkEventKind.RATE_REQUEST, host_ns, system, component, detail=detail)
