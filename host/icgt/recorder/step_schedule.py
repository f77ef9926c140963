"""When the recorder's worker steps next: at a base period, and when the next frame is due.

Each step reads both links, feeds the synchroniser and emits the frames that are ready. A step has fixed
costs besides the messages it handles (the wake-up itself, polling the synchroniser, the log hand-off, a
cold interpreter after the pause): on this class of machine about 0.8 ms of CPU, so 20 steps a second were
about 0.8 % of a core more than 10 (measured with deck_pass). So the worker steps rarely, every
``period_s``.

A frame is ready once its exposure record and the telemetry after its mid-exposure have come in, and the
ground station waits for it (CAMERA_IMAGE_CAPTURED): stepping at the base period alone would add up to a
period to each frame. Exposures come at a steady interval while capturing (the device's interval timer; an
autopilot's distance trigger at a steady speed), so the schedule also knows when the next one is due: the
last frame's mid-exposure plus the interval between the last two frames. From ``watch_lead_s`` before that
predicted mid-exposure until ``ready_after_s`` after it (50 Hz telemetry: its sample after mid-exposure
comes at most 20 ms after, plus the links' latency) the schedule is *watching*: the worker also wakes when
input arrives on the links it reads (`icgt.recorder.worker_wake`), so a frame is emitted as soon as its
inputs are in, not at the next timed step. A frame still pending after a step (its telemetry was late) is
watched for, with a timed retry every ``retry_s``, a few times, then only at the base period (a frame that
waits out a GPS gap must not make the worker wake for every message for seconds). A wrong guess costs one
step, never a frame: the base period steps regardless, and after ``max_misses`` due times without a frame
the cadence is forgotten (the capture stopped).

Pure and single-threaded: the worker calls `on_frame` for each frame it emits and asks `next_step_ns`
after each step (and then `watching`). Times are host monotonic ns.
"""

from __future__ import annotations

import dataclasses

__all__ = ["StepSchedule", "StepTiming"]


@dataclasses.dataclass(frozen=True)
class StepTiming:
    """The schedule's settings [s]."""

    # The base period: the longest the worker sleeps. Not longer: the device streams ~25 KB/s at nominal rates
    # and Linux's serial line discipline holds 4 KB (N_TTY_BUF_SIZE) before it throttles the port; at a 10 k
    # msg/s flood 100 ms is ~1000 datagrams, a quarter of the 4 MB UDP receive buffer.
    period_s: float = 0.1
    # A frame pending after a step is tried again this much later if no input woke the worker meanwhile
    # (the watch wakes it when its telemetry arrives; benchmarks/capture_rates.py prints the parts).
    retry_s: float = 0.01
    max_retries: int = 10  # consecutive retries (100 ms), then the base period (a frame waiting out a GPS gap)
    ready_after_s: float = 0.025  # after a due mid-exposure: its exposure record and the telemetry after it
    # The watch opens this long before the predicted mid-exposure: the host's prediction is the last frame's
    # mid plus the interval, off by the shutter's jitter (a few ms) and the clock map's error (< 1 ms).
    watch_lead_s: float = 0.003
    # While watching, the worker wakes on input at most once per this [s]: the device sends a USB transfer
    # every 1-2 ms; a wake-up costs as much as handling dozens of messages (a few wakes per frame, not 20).
    watch_min_gap_s: float = 0.003
    first_frame_s: float = 1.0  # after a capture starts, steps at retry_s until its first frame (shutter lag)
    min_interval_s: float = 0.04  # frames closer (two cameras; 20 fps, the fastest trigger, is 50 ms) set none
    max_interval_s: float = 5.0  # frames farther apart than this: no cadence (single shots)
    max_misses: int = 3  # due times without a frame before the cadence is forgotten

    def __post_init__(self) -> None:
        if not 0.0 < self.retry_s <= self.period_s:
            raise ValueError(f"retry_s must be in (0, period_s], got {self.retry_s} (period_s {self.period_s})")
        if not 0.0 < self.min_interval_s < self.max_interval_s:
            raise ValueError("min_interval_s must be > 0 and below max_interval_s")
        if self.ready_after_s < 0.0 or self.max_retries < 0 or self.max_misses < 1:
            raise ValueError("ready_after_s and max_retries must be >= 0, max_misses >= 1")
        if not 0.0 <= self.watch_lead_s < self.min_interval_s or not 0.0 <= self.watch_min_gap_s <= self.retry_s:
            raise ValueError("watch_lead_s must be in [0, min_interval_s), watch_min_gap_s in [0, retry_s]")


class StepSchedule:
    """The worker's next step time from the frames it emitted (see the module doc)."""

    def __init__(self, timing: StepTiming | None = None) -> None:
        self.timing = timing or StepTiming()
        t = self.timing
        self._period_ns = int(t.period_s * 1e9)
        self._retry_ns = int(t.retry_s * 1e9)
        self._ready_ns = int(t.ready_after_s * 1e9)
        self._min_ns = int(t.min_interval_s * 1e9)
        self._max_ns = int(t.max_interval_s * 1e9)
        self._lead_ns = int(t.watch_lead_s * 1e9)
        self._watching = False
        self._last_mid_ns: int | None = None
        self._interval_ns: int | None = None
        self._retries = 0
        self._first_ns = int(t.first_frame_s * 1e9)
        self._first_until_ns = 0  # a capture started: waiting for its first frame until then [ns]

    @property
    def interval_ns(self) -> int | None:
        """The frame interval the schedule steps at [ns]; None without a cadence."""
        return self._interval_ns

    def expect_interval(self, interval_ns: int, now_ns: int) -> None:
        """A capture at this interval started at ``now_ns``: the worker steps at ``retry_s`` until its first
        frame (for at most ``first_frame_s``: the camera's shutter lag is not known here), and the second
        frame is due one interval after the first (without this the cadence is learnt from two frames, and
        the first two wait for base-period steps)."""
        self._last_mid_ns = None  # the previous capture's last frame says nothing of this one's phase
        self._interval_ns = interval_ns if self._min_ns <= interval_ns <= self._max_ns else None
        self._retries = 0
        self._first_until_ns = now_ns + self._first_ns

    def on_frame(self, mid_host_ns: int) -> None:
        """A frame emitted, with its mid-exposure [host ns]."""
        self._first_until_ns = 0
        last = self._last_mid_ns
        if last is not None:
            gap = mid_host_ns - last
            if gap <= 0:
                return  # an older frame (or the other camera's): neither the cadence nor the last one
            if gap < self._min_ns:
                self._last_mid_ns = mid_host_ns
                return
            self._interval_ns = gap if gap <= self._max_ns else None
        self._last_mid_ns = mid_host_ns

    @property
    def watching(self) -> bool:
        """Whether, until the time the last `next_step_ns` gave, the worker should also wake on the links'
        input (a frame is expected now: see the module doc)."""
        return self._watching

    def next_step_ns(self, now_ns: int, pending_frames: int) -> int:
        """When to step next, after a step at ``now_ns`` that left ``pending_frames`` frames waiting; sets
        `watching`."""
        watching = False
        nxt = now_ns + self._period_ns
        if pending_frames > 0:
            self._retries += 1
            if self._retries <= self.timing.max_retries:
                nxt = min(nxt, now_ns + self._retry_ns)
                watching = True
        else:
            self._retries = 0
        if now_ns < self._first_until_ns:
            nxt = min(nxt, now_ns + self._retry_ns)
            watching = True
        interval, last = self._interval_ns, self._last_mid_ns
        if interval is not None and last is not None:
            # The first due time after now: last + k * interval + ready, k >= 1; its watch opens at the
            # predicted mid-exposure less the lead.
            k = max(1, (now_ns - last - self._ready_ns) // interval + 1)
            if k > self.timing.max_misses:
                self._interval_ns = None  # the capture stopped (or the trigger did)
            else:
                due = last + k * interval + self._ready_ns
                opens = due - self._ready_ns - self._lead_ns
                if now_ns >= opens:
                    nxt = min(nxt, due)
                    watching = True
                else:
                    nxt = min(nxt, opens)
        self._watching = watching
        return nxt
