"""Which images each ground station may have missed, so that it ends with every one.

CAMERA_IMAGE_CAPTURED goes out once, over UDP and a radio: a ground station that is away (a radio drop, a
restart) misses what was published meanwhile, and the Camera Protocol leaves recovery to the client
(re-requests by index). Clients that do not ask for the index they miss exist: MAVSDK 4.1
(`MavlinkRequestMessage::send_request_using_new_command` in ``cpp/src/mavsdk/core/mavlink_request_message.cpp``
sets only REQUEST_MESSAGE's param1, the message id; the index it wants is put in param1 of the legacy
REQUEST_CAMERA_IMAGE_CAPTURE, which it sends only on a retry after a failure, and unset params go out as 0
when the autopilot is ArduPilot, NaN otherwise: `MavlinkCommandSender::maybe_reserved`). Every one of its
re-requests therefore asks for image 0 (or for nothing), whatever it misses. So the camera keeps track
itself, per ground station (system id, component id), from the messages it hears from it:

* **Away and back**: a client not heard for ``gap_s`` (its HEARTBEAT comes at 1 Hz) was away. When it is
  heard again, the images published since it was last heard (less ``margin_s``: the drop may have begun
  just after its last HEARTBEAT got through) are sent again, ``push_delay_s`` later.
* **New instance**: a client that asks for CAMERA_INFORMATION is discovering the camera (MAVSDK does it once
  per instance, on the camera's first HEARTBEAT; QGroundControl once per vehicle connection): it holds none
  of the images published before, and they are remembered as not delivered to it. If it came back from
  an absence and its images were pushed before it knew the camera (MAVSDK drops images of a camera it
  has not heard yet), that push, and every image published since, is made again ``push_delay_s`` after
  the discovery.
* **A request that cannot say what it wants** (REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED) with param2 and
  param3 both unset, 0 or NaN: MAVSDK's form): besides the image it names (0; nothing for NaN), every
  image not yet delivered to that client is sent.

Images re-sent are broadcast like the first copy: a client that has them already ignores the duplicate
(MAVSDK and QGroundControl key them by index). All times are host CLOCK_MONOTONIC ns. Thread-safe.
"""

from __future__ import annotations

import array
import bisect
import dataclasses
import math
import threading

__all__ = ["ClientTracker", "IndexSet", "is_unspecified_image_request"]


class IndexSet:
    """A set of image indices as sorted disjoint ranges (an hour at 20 fps is 72 000 indices; a client
    misses them in a few spans). Written by hand: a handful of spans needs no interval-tree library."""

    def __init__(self) -> None:
        self._spans: list[range] = []

    def add(self, span: range) -> None:
        if not span:
            return
        spans = [*self._spans, span]
        spans.sort(key=lambda r: r.start)
        merged: list[range] = []
        for r in spans:
            if merged and r.start <= merged[-1].stop:
                last = merged[-1]
                merged[-1] = range(last.start, max(last.stop, r.stop))
            else:
                merged.append(r)
        self._spans = merged

    def remove(self, span: range) -> None:
        out: list[range] = []
        for r in self._spans:
            if span.stop <= r.start or span.start >= r.stop:
                out.append(r)
                continue
            if r.start < span.start:
                out.append(range(r.start, span.start))
            if span.stop < r.stop:
                out.append(range(span.stop, r.stop))
        self._spans = out

    def spans(self) -> list[range]:
        return list(self._spans)

    def clear(self) -> None:
        self._spans = []

    def __len__(self) -> int:
        return sum(len(r) for r in self._spans)

    def __contains__(self, index: object) -> bool:
        return any(index in r for r in self._spans)


def is_unspecified_image_request(first: float, last: float) -> bool:
    """REQUEST_MESSAGE(CAMERA_IMAGE_CAPTURED) with param2 and param3 both unset (0 or NaN): what MAVSDK sends
    whatever image it misses (module docstring). By the letter of the protocol 0, 0 is image 0."""

    def unset(v: float) -> bool:
        return math.isnan(v) or v == 0

    return unset(first) and unset(last)


@dataclasses.dataclass(slots=True)
class _Client:
    last_heard_ns: int
    undelivered: IndexSet = dataclasses.field(default_factory=IndexSet)
    push: range = range(0)  # images to send again once push_at_ns is reached
    push_at_ns: int = 0
    pushed: range = range(0)  # the last push made, and when
    pushed_ns: int = 0
    returns: int = 0


class ClientTracker:
    """Per ground station: when it was last heard and which images it has not been sent."""

    def __init__(
        self,
        *,
        gap_s: float = 2.5,
        margin_s: float = 0.5,
        push_delay_s: float = 0.3,
        repush_window_s: float = 10.0,
        discovered_delay_s: float = 1.5,
    ) -> None:
        self.gap_ns = int(gap_s * 1e9)
        # After a CAMERA_INFORMATION request the client still has to receive the answer and make its camera
        # (MAVSDK drops images of a camera it has not made yet): the push waits this long after the request.
        self.discovered_delay_ns = int(discovered_delay_s * 1e9)
        self.repush_window_ns = int(repush_window_s * 1e9)
        self.margin_ns = int(margin_s * 1e9)
        self.push_delay_ns = int(push_delay_s * 1e9)
        # by image index: when it was sent the first time (8 bytes an image: as a list of ints it took 40)
        self._published_ns = array.array("q")
        self._clients: dict[tuple[int, int], _Client] = {}
        self._lock = threading.Lock()
        self.counts = {"client_returns": 0, "images_pushed": 0, "images_sent_on_unspecified_request": 0}

    def published(self, index: int, host_ns: int) -> None:
        """Image ``index`` (the next one: indices come in order) was broadcast at ``host_ns``."""
        with self._lock:
            if index == len(self._published_ns):
                self._published_ns.append(host_ns)

    def heard(self, client: tuple[int, int], host_ns: int) -> None:
        """Any message from ``client`` (system, component) arrived at ``host_ns``."""
        with self._lock:
            c = self._clients.get(client)
            if c is None:
                self._clients[client] = _Client(host_ns)
                return
            if host_ns - c.last_heard_ns > self.gap_ns:
                first = bisect.bisect_left(self._published_ns, c.last_heard_ns - self.margin_ns)
                span = range(first, len(self._published_ns))
                c.undelivered.add(span)
                c.push = range(min(c.push.start, span.start), span.stop) if c.push else span
                c.push_at_ns = host_ns + self.push_delay_ns
                c.returns += 1
                self.counts["client_returns"] += 1
            c.last_heard_ns = max(c.last_heard_ns, host_ns)

    def discovered(self, client: tuple[int, int], host_ns: int) -> None:
        """``client`` asked for CAMERA_INFORMATION: a new instance, holding none of the images so far."""
        with self._lock:
            c = self._clients.setdefault(client, _Client(host_ns))
            c.undelivered.clear()
            c.undelivered.add(range(len(self._published_ns)))
            if c.push:  # a push still to come: not before this instance can know the camera
                c.push_at_ns = max(c.push_at_ns, host_ns + self.discovered_delay_ns)
            elif c.pushed and host_ns - c.pushed_ns < self.repush_window_ns:
                # made before this instance knew the camera: again, once it does, with every image
                # published since (those too went to an instance that did not know the camera yet)
                c.push = range(c.pushed.start, len(self._published_ns))
                c.push_at_ns = host_ns + self.discovered_delay_ns

    def due(self, host_ns: int) -> list[range]:
        """The pushes due at ``host_ns`` (taken: each is returned once)."""
        out: list[range] = []
        with self._lock:
            for c in self._clients.values():
                if c.push and host_ns >= c.push_at_ns:
                    # up to the newest: those published since its return went live to a client that may
                    # not have known the camera yet (MAVSDK drops images until its Camera plugin exists)
                    c.push = range(c.push.start, len(self._published_ns))
                    out.append(c.push)
                    c.undelivered.remove(c.push)
                    c.pushed, c.pushed_ns = c.push, host_ns
                    self.counts["images_pushed"] += len(c.push)
                    c.push = range(0)
        return out

    def next_due_ns(self) -> int | None:
        with self._lock:
            times = [c.push_at_ns for c in self._clients.values() if c.push]
        return min(times) if times else None

    def take_undelivered(self, client: tuple[int, int]) -> list[range]:
        """Every image not delivered to ``client`` yet (for its unspecified request), now counted delivered."""
        with self._lock:
            c = self._clients.get(client)
            if c is None:
                return []
            spans = c.undelivered.spans()
            c.undelivered.clear()
            self.counts["images_sent_on_unspecified_request"] += sum(len(r) for r in spans)
            return spans

    def undelivered(self, client: tuple[int, int]) -> list[range]:
        with self._lock:
            c = self._clients.get(client)
            return c.undelivered.spans() if c is not None else []
