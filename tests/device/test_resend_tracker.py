"""The host's ResendTracker against a model device with a bounded history, over a lossy link (hypothesis).

The model device numbers every frame, keeps the last N events and the last M samples (as the firmware's
rings do), answers RESEND with what it holds (flagged retransmit) and a RESEND_LOST counting the rest by
kind. The link between them drops live and resent frames at random. Whatever happens, once the tracker
has settled: every frame the device sent is either delivered exactly once or counted lost, and the
counts by kind are exactly the kinds of the frames that were not delivered."""

from __future__ import annotations

import random
from collections import Counter

from hypothesis import Phase, given, settings
from hypothesis import strategies as st

from icgt.device.resend import ResendTracker
from icgt.protocol import Received
from icgt.protocol.messages import Exposure, FrameFlags, Imu, Message, Pps, Resend, ResendLost, Status

KINDS = ("exposure", "pps", "sample", "other")


def _message(kind: str, seq: int) -> Message:
    if kind == "exposure":
        return Exposure(image_index=seq)
    if kind == "pps":
        return Pps(t_us=seq, pps_count=seq)
    if kind == "sample":
        return Imu(read_start_t_us=seq)
    return Status(t_us=seq)


class ModelDevice:
    def __init__(self, events_kept: int, samples_kept: int, start_seq: int) -> None:
        self.events_kept = events_kept
        self.samples_kept = samples_kept
        self.kinds: dict[int, str] = {}
        self.next_seq = start_seq
        self.requests: list[Resend] = []

    def emit(self, kind: str) -> Received:
        seq = self.next_seq & 0xFFFFFFFF
        self.kinds[seq] = kind
        self.next_seq += 1
        return Received(seq, 0, _message(kind, seq))

    def kept(self) -> set[int]:
        order = list(self.kinds)  # insertion order = sequence order
        events = [s for s in order if self.kinds[s] in ("exposure", "pps")][-self.events_kept :]
        samples = [s for s in order if self.kinds[s] == "sample"][-self.samples_kept :]
        return set(events) | set(samples)

    def answer(self, req: Resend) -> list[Received]:
        kept = self.kept()
        out: list[Received] = []
        tally: Counter[str] = Counter()
        resent = 0
        for i in range(req.count):
            s = (req.first_seq + i) & 0xFFFFFFFF
            if s in kept:
                out.append(Received(s, FrameFlags.RETRANSMIT, _message(self.kinds[s], s)))
                resent += 1
            elif s in self.kinds:
                tally[self.kinds[s]] += 1
            else:
                tally["unknown"] += 1
        lost = ResendLost(
            first_seq=req.first_seq,
            count=req.count,
            resent=resent,
            exposures=tally["exposure"],
            pps=tally["pps"],
            samples=tally["sample"],
            other=tally["other"],
            unknown=tally["unknown"],
        )
        out.append(self.emit_message(lost))
        return out

    def emit_message(self, msg: Message) -> Received:
        seq = self.next_seq & 0xFFFFFFFF
        self.kinds[seq] = "other"
        self.next_seq += 1
        return Received(seq, 0, msg)


@settings(max_examples=60, deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate])
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(50, 1500),
    live_loss=st.sampled_from([0.0, 0.01, 0.2]),
    resend_loss=st.sampled_from([0.0, 0.05]),
    outage=st.tuples(st.integers(0, 1000), st.integers(0, 900)),
    kept=st.tuples(st.integers(5, 400), st.integers(5, 200)),
    start_seq=st.sampled_from([0, 2**32 - 300]),
)
def test_every_frame_is_delivered_once_or_counted_lost_by_kind(
    seed: int,
    n: int,
    live_loss: float,
    resend_loss: float,
    outage: tuple[int, int],
    kept: tuple[int, int],
    start_seq: int,
) -> None:
    rng = random.Random(seed)
    lossless = live_loss == 0.0 and resend_loss == 0.0
    device = ModelDevice(kept[0], kept[1], start_seq)
    clock = [0]
    sent: list[Resend] = []
    tracker = ResendTracker(lambda m: sent.append(m), clock=lambda: clock[0])  # type: ignore[arg-type, func-returns-value]
    delivered: Counter[int] = Counter()

    def deliver(r: Received, lossy: float) -> None:
        if rng.random() < lossy:
            return
        if tracker.observe(r):
            delivered[r.seq] += 1

    def pump() -> None:  # the reader thread ticks many times a second: here until nothing more goes out
        for _ in range(1000):
            tracker.tick()
            if not sent:
                return
            while sent:
                for r in device.answer(sent.pop(0)):
                    deliver(r, resend_loss if r.flags & FrameFlags.RETRANSMIT else live_loss)

    deliver(device.emit("other"), 0.0)
    for i in range(n):
        r = rng.random()
        kind = "exposure" if r < 0.05 else "pps" if r < 0.07 else "other" if r < 0.12 else "sample"
        frame = device.emit(kind)
        down = outage[0] <= i < outage[0] + outage[1]
        if not down:
            deliver(frame, live_loss)
        if i % 25 == 0:
            clock[0] += 100_000_000
            pump()
    deliver(device.emit("other"), 0.0)  # a last live frame shows any trailing gap
    for _ in range(10):  # settle on the lossy link: timeouts and retries
        clock[0] += 3_000_000_000
        pump()
    live_loss = resend_loss = 0.0  # then the link is clean again: everything open must close
    for _ in range(10):
        clock[0] += 3_000_000_000
        pump()
        deliver(device.emit("other"), 0.0)
    assert tracker.missing_now == 0
    c = tracker.counters
    assert max(delivered.values()) == 1, "a frame was delivered twice"
    not_delivered = Counter(kind for s, kind in device.kinds.items() if s not in delivered)
    if c.lost_unknown == 0:
        assert (c.lost_exposures, c.lost_pps, c.lost_samples, c.lost_other) == (
            not_delivered["exposure"],
            not_delivered["pps"],
            not_delivered["sample"],
            not_delivered["other"],
        )
    else:  # retries ran out while resent frames kept being lost: still every frame accounted for
        assert c.lost_exposures + c.lost_pps + c.lost_samples + c.lost_other + c.lost_unknown == sum(
            not_delivered.values()
        )
    if lossless:
        assert c.lost_unknown == 0


def test_a_restarted_host_asks_from_the_last_mark() -> None:
    device = ModelDevice(1000, 1000, 0)
    for _ in range(300):
        device.emit("exposure")
    sent: list[Resend] = []
    tracker = ResendTracker(lambda m: sent.append(m), clock=lambda: 0)  # type: ignore[arg-type, func-returns-value]
    assert tracker.observe(device.emit("other"))  # the first frame this host sees
    assert tracker.recover_from(120) == 180
    tracker.tick()
    assert [(r.first_seq, r.count) for r in sent] == [(120, 180)]
    for r in device.answer(sent.pop()):
        tracker.observe(r)
    assert tracker.counters.recovered == 180
    assert tracker.missing_now == 0
    assert tracker.received_through() == device.next_seq


def test_a_device_reboot_ends_open_gaps_as_unknown() -> None:
    sent: list[Resend] = []
    tracker = ResendTracker(lambda m: sent.append(m), clock=lambda: 0)  # type: ignore[arg-type, func-returns-value]
    tracker.observe(Received(1000, 0, Status()))
    tracker.observe(Received(1010, 0, Status()))  # 9 missing
    tracker.observe(Received(0, 0, Status()))  # rebooted before answering
    assert tracker.counters.lost_unknown == 9
    assert tracker.missing_now == 0
