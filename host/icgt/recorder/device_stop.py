"""The device's own account of how its last capture ended (DEVICE_STATE.stop_cause, protocol 2).

A device whose host went silent for the capture's host timeout (``[capture] host_timeout_s``) stops the
capture itself (firmware/lib/core/host_watchdog.hpp). It cannot tell anyone then: the cable is out or the
recorder is gone. It says so in the DEVICE_STATE that follows every HELLO, so:

* the recording that reconnects after the outage learns it from the first DEVICE_STATE after the link came
  back: the capture is over (the recorder no longer thinks it captures, and has no stop to deliver at the
  end), and the log says when the device stopped and why (`device_stopped_itself` link event);
* a recording that starts on such a device says so once (a previous flight's capture ended that way; its
  exposures after the outage may still be in the device's history: `icgt recover-device --flight LOG`).
"""

from __future__ import annotations

from dataclasses import dataclass

from icgt.protocol.messages import DeviceState, StopCause

__all__ = ["SelfStop", "SelfStopWatch", "describe_stop"]


@dataclass(frozen=True)
class SelfStop:
    """A capture the device stopped by itself, as one DEVICE_STATE told it."""

    stopped_t_us: int  # device clock
    host_timeout_ms: int
    triggers_fired: int
    recording_id: int  # the host log its last HOST_RECEIVED named (0: none)

    @property
    def detail(self) -> str:
        return describe_stop(self)


def describe_stop(stop: SelfStop) -> str:
    return (
        f"the device stopped the capture by itself at device time {stop.stopped_t_us / 1e6:.3f} s: no frame from "
        f"the host for {stop.host_timeout_ms / 1e3:g} s (host timeout); {stop.triggers_fired} triggers fired "
        "since boot"
    )


def self_stop_of(state: DeviceState) -> SelfStop | None:
    """The self-stop this DEVICE_STATE reports, if the last capture ended that way."""
    if state.stop_cause != StopCause.HOST_SILENT:
        return None
    return SelfStop(state.stopped_t_us, state.host_timeout_ms, state.triggers_fired, state.recording_id)


class SelfStopWatch:
    """Tells which DEVICE_STATE reports a self-stop that is news to this recording (one per stop)."""

    def __init__(self) -> None:
        self._first = True
        self._known: int | None = None  # stopped_t_us of the stop already said

    def observe(self, state: DeviceState) -> tuple[SelfStop, bool] | None:
        """(the stop, whether it happened before this recording's first DEVICE_STATE) once per new stop."""
        first, self._first = self._first, False
        stop = self_stop_of(state)
        if stop is None or stop.stopped_t_us == self._known:
            return None
        self._known = stop.stopped_t_us
        return stop, first
