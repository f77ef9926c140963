"""take_over: a device found capturing at start is adopted or stopped as configured, and what no recorder
heard is asked back from the mark the last recorder left (DEVICE_STATE.host_received_seq)."""

from __future__ import annotations

from dataclasses import dataclass, field

import pytest

from icgt.protocol.messages import CaptureMode, CaptureState, DeviceState
from icgt.recorder.resync import take_over


@dataclass
class _Resend:
    asked: list[int] = field(default_factory=list)

    def recover_from(self, seq: int) -> int:
        self.asked.append(seq)
        return 1234


@dataclass
class _Link:
    state: DeviceState | None
    resend: _Resend = field(default_factory=_Resend)

    def wait_device_state(self, timeout_s: float) -> DeviceState | None:
        return self.state


def _capturing(valid: int = 1) -> DeviceState:
    return DeviceState(
        capture_state=CaptureState.CAPTURING,
        mode=CaptureMode.INTERVAL,
        interval_us=200_000,
        host_received_seq=5000,
        host_received_valid=valid,
        imu_rate_hz=100,
    )


@pytest.mark.parametrize("policy", ["adopt", "stop"])
def test_a_running_capture_is_taken_over_and_its_history_asked_back(policy: str) -> None:
    link = _Link(_capturing())
    t = take_over(link, policy)  # type: ignore[arg-type]
    assert t.capturing and t.adopted == (policy == "adopt")
    assert t.interval_s == 0.2
    assert link.resend.asked == [5000] and t.asked_back == 1234


def test_without_a_mark_nothing_is_asked() -> None:
    link = _Link(_capturing(valid=0))
    t = take_over(link, "adopt")  # type: ignore[arg-type]
    assert t.adopted and link.resend.asked == [] and t.asked_back == 0


def test_an_idle_device_or_an_old_firmware_changes_nothing() -> None:
    idle = _Link(DeviceState(capture_state=CaptureState.IDLE, host_received_valid=1, host_received_seq=9))
    assert not take_over(idle, "adopt").capturing  # type: ignore[arg-type]
    assert idle.resend.asked == []
    old = _Link(None)  # no DEVICE_STATE: firmware before the history ring
    t = take_over(old, "stop")  # type: ignore[arg-type]
    assert t.state is None and not t.capturing
