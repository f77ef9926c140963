"""Taking over a device that was already running when this recorder started.

A recorder killed in flight (kill -9, a crash, a power cut of the companion computer) leaves the
device capturing: the camera keeps shooting. The device says so in the DEVICE_STATE that follows
every HELLO, with the capture's parameters, the configuration in force and how far the last host
said its log was complete (HOST_RECEIVED). `take_over` decides what to do with it:

* ``[device] running_capture = "adopt"`` (default): the capture goes on as it is, the recorder
  records it as its own (`icgt status` says capturing; a CONFIGURE, which the device would refuse
  while capturing, is not sent; the configuration the device runs is logged);
* ``"stop"``: the capture is stopped first, then the recorder starts as usual.

Either way what the device sent while no recorder listened is asked back from its history, from
the last host's HOST_RECEIVED mark to the first frame this recorder saw (RESEND, through
`icgt.device.resend`); what it no longer holds is counted by kind like any other loss.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

from icgt.device import DeviceLink
from icgt.protocol.messages import CaptureMode, CaptureState, DeviceState

log = logging.getLogger("icgt.recorder")

DEVICE_STATE_WAIT_S = 1.0  # DEVICE_STATE follows HELLO at once; an older firmware never sends one


@dataclass(frozen=True)
class TakeOver:
    """What `take_over` found and did."""

    state: DeviceState | None
    capturing: bool  # the device was capturing when this recorder came up
    adopted: bool  # and the capture goes on as this recorder's
    interval_s: float
    asked_back: int  # device sequence numbers asked again from its history


def describe(state: DeviceState) -> str:
    try:
        mode = CaptureMode(state.mode).name.lower()
    except ValueError:
        mode = f"mode {state.mode}"
    return (
        f"{mode}, interval {state.interval_us / 1e6:.3f} s, count {state.count}, {state.triggers_fired} triggers "
        f"fired; IMU {state.imu_rate_hz} Hz, range {state.range_rate_hz} Hz, feedback "
        f"{'on' if state.feedback_enabled else 'off'} (timeout {state.feedback_timeout_us / 1e3:.0f} ms)"
    )


def take_over(link: DeviceLink, policy: str) -> TakeOver:
    """Read the device's state after the handshake and adopt or stop a running capture (see module doc)."""
    state = link.wait_device_state(DEVICE_STATE_WAIT_S)
    if state is None:
        return TakeOver(None, False, False, 0.0, 0)
    capturing = state.capture_state == CaptureState.CAPTURING
    if not capturing:
        return TakeOver(state, False, False, 0.0, 0)
    asked = 0
    if state.host_received_valid:
        asked = link.resend.recover_from(state.host_received_seq)
    log.warning(
        "the device is already capturing (%s): %s; %d frames sent while no recorder listened asked back",
        describe(state),
        "adopting the capture" if policy == "adopt" else "stopping it ([device] running_capture = stop)",
        asked,
    )
    return TakeOver(state, True, policy == "adopt", state.interval_us / 1e6, asked)
