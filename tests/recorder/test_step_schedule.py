"""The recorder worker's step schedule: the base period, the watch around a due frame, retries."""

from __future__ import annotations

import pytest

from icgt.recorder.step_schedule import StepSchedule, StepTiming

MS = 1_000_000


def test_without_frames_it_steps_at_the_base_period() -> None:
    s = StepSchedule(StepTiming(period_s=0.1))
    assert s.next_step_ns(5_000 * MS, pending_frames=0) == 5_100 * MS
    s.on_frame(4_000 * MS)  # one frame: no interval yet
    assert s.interval_ns is None
    assert s.next_step_ns(5_000 * MS, pending_frames=0) == 5_100 * MS


def test_at_a_steady_cadence_it_watches_from_the_predicted_mid_exposure_to_the_due_time() -> None:
    s = StepSchedule(StepTiming(period_s=0.1, ready_after_s=0.03, watch_lead_s=0.005))
    s.on_frame(1_000 * MS)
    s.on_frame(1_200 * MS)  # 5 fps
    assert s.interval_ns == 200 * MS
    # The next frame's mid-exposure is predicted at 1400: watched from 1395 (the lead) to 1430 (due).
    assert s.next_step_ns(1_230 * MS, pending_frames=0) == 1_330 * MS  # the base period comes first
    assert not s.watching
    assert s.next_step_ns(1_340 * MS, pending_frames=0) == 1_395 * MS  # the watch opens before the base period
    assert not s.watching
    assert s.next_step_ns(1_395 * MS, pending_frames=0) == 1_430 * MS  # watching: input wakes it, or the due time
    assert s.watching
    assert s.next_step_ns(1_400 * MS, pending_frames=0) == 1_430 * MS
    assert s.watching
    s.on_frame(1_401 * MS)  # the cadence follows the frames: 201 ms now
    assert s.interval_ns == 201 * MS
    assert s.next_step_ns(1_431 * MS, pending_frames=0) == 1_531 * MS
    assert not s.watching
    assert s.next_step_ns(1_600 * MS, pending_frames=0) == (1_401 + 201 + 30) * MS
    assert s.watching


def test_a_missed_exposure_moves_on_to_the_next_due_time_then_the_cadence_is_forgotten() -> None:
    s = StepSchedule(StepTiming(period_s=0.1, ready_after_s=0.03, watch_lead_s=0.01, max_misses=3))
    s.on_frame(1_000 * MS)
    s.on_frame(1_200 * MS)
    assert s.next_step_ns(1_500 * MS, pending_frames=0) == 1_590 * MS  # 1430 passed without a frame: 1630 next
    assert s.next_step_ns(1_590 * MS, pending_frames=0) == 1_630 * MS
    assert s.watching
    assert s.next_step_ns(1_630 * MS, pending_frames=0) == 1_730 * MS  # the third: 1830, watched from 1790
    assert not s.watching
    assert s.next_step_ns(1_790 * MS, pending_frames=0) == 1_830 * MS
    assert s.watching
    assert s.next_step_ns(1_830 * MS, pending_frames=0) == 1_930 * MS  # the fourth due time: forgotten
    assert s.interval_ns is None
    assert not s.watching
    assert s.next_step_ns(1_930 * MS, pending_frames=0) == 2_030 * MS


def test_bursts_and_single_shots_set_no_cadence() -> None:
    s = StepSchedule(StepTiming(min_interval_s=0.05, max_interval_s=5.0))
    s.on_frame(1_000 * MS)
    s.on_frame(1_010 * MS)  # two cameras, or a burst: too close
    assert s.interval_ns is None
    s.on_frame(1_005 * MS)  # an older frame: ignored
    s.on_frame(7_010 * MS)  # a single shot six seconds later
    assert s.interval_ns is None
    s.on_frame(8_010 * MS)
    assert s.interval_ns == 1_000 * MS
    s.on_frame(20_000 * MS)  # a long pause ends the cadence
    assert s.interval_ns is None


def test_a_pending_frame_is_retried_soon_a_few_times_then_at_the_base_period() -> None:
    s = StepSchedule(StepTiming(period_s=0.1, retry_s=0.02, max_retries=2))
    assert s.next_step_ns(0, pending_frames=1) == 20 * MS
    assert s.watching  # its telemetry wakes the worker before the retry
    assert s.next_step_ns(20 * MS, pending_frames=1) == 40 * MS
    assert s.watching
    assert s.next_step_ns(40 * MS, pending_frames=1) == 140 * MS  # waiting out a GPS gap: no 50 Hz stepping
    assert not s.watching  # nor a wake-up for every message meanwhile
    assert s.next_step_ns(140 * MS, pending_frames=0) == 240 * MS
    assert s.next_step_ns(240 * MS, pending_frames=2) == 260 * MS  # a new wait: retried again
    assert s.watching


@pytest.mark.parametrize(
    "kwargs",
    [
        {"retry_s": 0.0},
        {"retry_s": 0.2, "period_s": 0.1},
        {"min_interval_s": 6.0},
        {"max_misses": 0},
        {"watch_lead_s": 0.05},
        {"watch_min_gap_s": 0.02},
    ],
)
def test_settings_out_of_range_are_refused(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError):
        StepTiming(**kwargs)  # type: ignore[arg-type]


def test_a_capture_started_at_an_interval_steps_for_its_first_two_frames_at_once() -> None:
    s = StepSchedule(StepTiming(period_s=0.1, retry_s=0.01, ready_after_s=0.03, first_frame_s=0.5))
    s.on_frame(500 * MS)
    s.on_frame(700 * MS)  # an earlier capture's cadence and phase
    s.expect_interval(1_000 * MS, now_ns=900 * MS)  # a new capture at 1 fps, commanded at 900 ms
    assert s.interval_ns == 1_000 * MS
    # its first frame comes after the camera's shutter lag: stepped for at the retry period meanwhile
    assert s.next_step_ns(900 * MS, pending_frames=0) == 910 * MS
    assert s.watching  # and its exposure record wakes the worker
    assert s.next_step_ns(1_390 * MS, pending_frames=0) == 1_400 * MS
    assert s.next_step_ns(1_400 * MS, pending_frames=0) == 1_500 * MS  # first_frame_s over: the base period
    s.on_frame(1_234 * MS)
    assert s.next_step_ns(1_264 * MS, pending_frames=0) == 1_364 * MS  # the frame came: no more eager steps
    assert s.next_step_ns(2_200 * MS, pending_frames=0) == 2_231 * MS  # the second frame's watch opens
    assert s.next_step_ns(2_231 * MS, pending_frames=0) == 2_264 * MS  # ... until its due time
    assert s.watching
    s.expect_interval(10_000 * MS, now_ns=3_000 * MS)  # slower than the cadence rule allows: single shots
    assert s.interval_ns is None
