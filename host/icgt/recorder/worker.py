"""The recorder's worker thread: each step reads the links, hands their input to the synchroniser, emits frames.

One thread runs every step (`step()`: under the worker lock, its log writes handed over at its end):
- `drain`: the links it reads itself are pumped (the device's stream, the MAVLink datagrams, which carry the
  kernel's arrival stamps), then every input in the `Inbox` is handled in arrival order (logged, then fed to
  the synchroniser);
- `work_once`: the synchroniser is polled for frames (`emit`: the ground station's CAMERA_IMAGE_CAPTURED
  first, then the log and the live views), its events go out, once a second the health records are written
  (`Health.every_second`) and the native heap trimmed, and the device reader is told when to send the next
  TIME_SYNC.
It steps every 100 ms, and from just before the next frame is due also when input arrives on the links it
watches (`icgt.recorder.step_schedule`, `icgt.recorder.worker_wake`). The readers never wake it otherwise (a
thread switch per message costs as much CPU as handling dozens of them). `flush` is the shutdown's last step:
every input left, every frame still pending.
"""

from __future__ import annotations

import contextlib
import logging
import threading
import time
from collections.abc import Callable, Iterator

from icgt.geotag import FrameRecord
from icgt.recorder import topics
from icgt.recorder.camera_link import CameraImages
from icgt.recorder.health import Health
from icgt.recorder.inbox import Inbox
from icgt.recorder.links import Links
from icgt.recorder.log_file import RecorderLog
from icgt.recorder.mavlink_input import MavlinkInput
from icgt.recorder.native_heap import NativeHeapTrimmer
from icgt.recorder.step_schedule import StepSchedule
from icgt.recorder.worker_wake import WorkerWake
from icgt.recording import layout
from icgt.recording.views import FoxgloveViews
from icgt.sync import Synchroniser

__all__ = ["DRAIN_MAX", "Worker"]

log = logging.getLogger("icgt.recorder")

DRAIN_MAX = 5000  # inputs handled before the worker polls again (bounds frame latency under a flood)


class Worker:
    """The thread that steps the recording. `cadence_hint`: (captures started, the last one's interval [ns]),
    read at each step (a new capture's interval goes to the step schedule); `stopping`: set when the
    recording ends."""

    def __init__(
        self,
        *,
        sync: Synchroniser,
        links: Links,
        inbox: Inbox,
        wake: WorkerWake,
        log_file: RecorderLog,
        views: FoxgloveViews,
        images: CameraImages,
        mavlink_input: MavlinkInput,
        health: Health,
        cadence_hint: Callable[[], tuple[int, int]],
        stopping: threading.Event,
    ) -> None:
        self._sync = sync
        self._links = links
        self._inbox = inbox
        self._wake = wake
        self._log = log_file
        self._views = views
        self._images = images
        self._mavlink_input = mavlink_input
        self._health = health
        self._cadence_hint = cadence_hint
        self._stopping = stopping
        self.schedule = StepSchedule()  # when the worker steps: every 100 ms, and when a frame is due
        self.frames = 0
        self._lock = threading.Lock()  # the worker's step, and the shutdown's final drains
        self._thread: threading.Thread | None = None
        self._next_clock_log_ns = 0
        self._heap_trimmer = NativeHeapTrimmer()  # thread arenas' free pages back to the system (soak)

    # ------------------------------------------------------------ the thread
    def start(self) -> None:
        self._thread = threading.Thread(target=self._work, name="icgt-recorder", daemon=True)
        self._thread.start()

    @property
    def started(self) -> bool:
        return self._thread is not None

    @property
    def alive(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    def join(self, timeout_s: float) -> None:
        """Wait for the thread's end (not from the thread itself)."""
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=timeout_s)

    def _work(self) -> None:
        self._inbox.worker_ident = threading.get_ident()
        # The readers never wake the worker (no switch per message): it steps on its schedule (step_schedule),
        # and while a frame is expected (the schedule is watching) also when input arrives on the links it
        # reads itself (worker_wake), at most once per watch_min_gap_s.
        nudge = self._wake
        timing = self.schedule.timing
        wait_s = timing.period_s
        watch: list[int] = []
        hint_seen = 0
        while True:
            woke_on_input = nudge.wait(wait_s, watch, timing.watch_min_gap_s)
            nudge.clear()
            if self._stopping.is_set():
                break
            try:
                hint = self._cadence_hint()
                if hint[0] != hint_seen:
                    hint_seen = hint[0]
                    self.schedule.expect_interval(hint[1], time.monotonic_ns())
                with self.step():
                    read = self.drain(limit=DRAIN_MAX)
                    now = time.monotonic_ns()
                    self.work_once(now)
                next_ns = self.schedule.next_step_ns(now, self._sync.pending_frames)
                wait_s = max(0.0, (next_ns - time.monotonic_ns()) / 1e9)
                # Input that woke the worker but that its pumps did not take (the device reader holds the port
                # while it awaits a TIME_SYNC answer) would wake it again at once: the timer only, this time.
                # (The thread-input signal cannot: the wait's clear() emptied it.)
                took = read or not woke_on_input or nudge.watch_thread_input
                nudge.watch_thread_input = False  # input_fds sets it again while it watches for it
                watch = self.input_fds(self._sync.pending_frames > 0) if self.schedule.watching and took else []
            except Exception:  # the worker must outlive any bug: frames keep being emitted
                log.exception("recorder worker error (recording continues)")
                wait_s = timing.period_s
                watch = []
                nudge.watch_thread_input = False
        nudge.close()

    def input_fds(self, exposure_in: bool) -> list[int]:
        """The descriptor of the link whose input the expected frame waits for: the device's port until its
        exposure record is in, then the MAVLink socket (a UDP link the worker pumps) for the telemetry after
        mid-exposure. One link at a time: each wake-up costs a step, and the other link's input alone cannot
        complete the frame (whatever it sent is read at that step anyway). A MAVLink link read by its own
        thread (serial, TCP) hands its messages over through the wake's thread-input signal instead."""
        mavlink = self._links.mavlink
        link = mavlink if exposure_in else self._links.device
        threaded = exposure_in and mavlink is not None and mavlink.running and not mavlink.pumped
        self._wake.watch_thread_input = threaded
        if threaded:
            return [self._wake.thread_input_fd]
        fd = link.readable_fd if link is not None else None
        return [] if fd is None else [fd]

    # ------------------------------------------------------------ one step
    @contextlib.contextmanager
    def step(self) -> Iterator[None]:
        """One worker step (or the shutdown's last drains): under the worker lock, its writes handed over at
        its end."""
        with self._lock, self._log.batch():
            yield

    def drain(self, limit: int | None) -> int:
        """What arrived since the last step, into the inbox (the links this thread reads, see the module doc),
        then handled; returns what the pumps read (bytes and datagrams: 0 when nothing)."""
        read = 0
        if self._links.device is not None:
            read += self._links.device.pump()
        if self._links.mavlink is not None:
            read += self._links.mavlink.pump()
        self._inbox.handle(limit)
        return read

    def work_once(self, now: int) -> None:
        self.emit(self._sync.poll(now))
        self._mavlink_input.take_sync_events()
        if now >= self._next_clock_log_ns:
            self._next_clock_log_ns = now + 1_000_000_000
            self._health.every_second(now)
            self._heap_trimmer.maybe_trim(now)
        self.schedule_time_sync()

    def flush(self, *, counters: bool = False) -> None:
        """The shutdown's last step: every input left handled, every pending frame emitted (and the counters)."""
        with self.step():
            self.drain(limit=None)
            self.emit(self._sync.poll(time.monotonic_ns(), flush=True))
            self._mavlink_input.take_sync_events()
            if counters:
                self._health.write_counters(time.monotonic_ns())

    def schedule_time_sync(self) -> None:
        """The device reader sends the TIME_SYNC requests (DeviceLink.time_sync_interval_s: one wake-up per
        exchange) at the rate the clock filter asks for, set again at every step (fast until settled, and
        after a reboot or a gap; dithered)."""
        if self._links.device is not None and not self._stopping.is_set():
            self._links.device.time_sync_interval_s = self._sync.next_exchange_interval_s()

    # ------------------------------------------------------------ frames
    def emit(self, records: list[FrameRecord]) -> None:
        for rec in records:
            self._on_frame(rec)

    def _on_frame(self, rec: FrameRecord) -> None:
        self.frames += 1
        self.schedule.on_frame(rec.mid_host_ns)
        camera = self._links.camera
        # The ground station waits for its CAMERA_IMAGE_CAPTURED: sent before the log's writes and the live views.
        image = self._images.publish(camera, rec) if camera is not None else None
        self._log.write(topics.FRAMES, rec, rec.mid_host_ns)
        self._views.on_frame(rec)
        if image is not None:
            self._log.write(layout.CAMERA_IMAGES, image, rec.mid_host_ns)
