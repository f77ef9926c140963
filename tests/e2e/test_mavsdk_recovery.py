"""MAVSDK ends with every image after a radio drop and after a restart: MAVSDK 4.1's Camera plugin (PyPI
`mavsdk`, its native library) behind a UDP tap (`icgt.sim.udp_tap`) that cuts the link, against `icgt record`
on a simulated flight. One flight shared by the tests (module fixture), in this order:

1. client A starts an interval capture (0.5 s); the tap drops the link for 5 s (both ways) while the camera
   goes on; the link comes back. MAVSDK re-requests what it missed, but always as image 0
   (icgt.mavlink.camera_clients says why); the camera sends the images published while A was away again.
2. A closes; the camera goes on for 6 s; client B (a new MAVSDK instance, the same ids: a restarted ground
   station) connects and lists all photos; then stops the capture.

Every wait is for a result with a generous bound, never a timing assertion.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera, CameraError, PhotosRange
from mcap.reader import make_reader

from icgt.recording import layout
from icgt.sim.live_recorder import LiveRecorder
from icgt.sim.scenario import load_scenario
from icgt.sim.udp_tap import UdpTap

SCENARIO = load_scenario(Path(__file__).with_name("mavsdk_hover.toml"))
CAMERA = 100


def wait_for(predicate: Callable[[], Any], timeout: float, step: float = 0.2) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        time.sleep(step)
    return predicate()


class Client:
    """One MAVSDK instance as a ground station (its default ids, 245/190) through the tap."""

    def __init__(self, url: str) -> None:
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        self.mavsdk.add_any_connection(url)
        system = self.mavsdk.first_autopilot(30.0)
        assert system is not None, "MAVSDK never saw the simulated autopilot"
        self.camera = Camera(system)
        self.callbacks: list[int] = []
        self.camera.subscribe_capture_info(lambda info, *_: self.callbacks.append(int(info.index)))
        assert wait_for(lambda: self.camera.camera_list().cameras, 30.0), "MAVSDK never listed the camera"

    def listed(self, photos: PhotosRange = PhotosRange.ALL) -> set[int]:
        try:
            return {int(p.index) for p in self.camera.list_photos(CAMERA, photos)}
        except CameraError:  # no capture status yet
            return set()

    def close(self) -> None:
        self.mavsdk.destroy()


@dataclass
class Flight:
    live: LiveRecorder
    dropped: dict[str, int] = field(default_factory=dict)
    a_count: int = 0  # images published when A's list was taken (its newest + 1)
    a_listed: set[int] = field(default_factory=set)
    b_first_listed: set[int] = field(default_factory=set)  # B's photos before it asked for any
    b_count: int = 0
    b_listed: set[int] = field(default_factory=set)
    mcap: Path | None = None


@pytest.fixture(scope="module")
def flight(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Flight]:
    live = LiveRecorder(SCENARIO, tmp_path_factory.mktemp("mavsdk_recovery"))
    urls = live.start()
    host, port = urls.gcs.removeprefix("udpout:").rsplit(":", 1)
    tap = UdpTap((host, int(port))).start()
    f = Flight(live)
    a = b = None
    try:
        a = Client(tap.mavsdk_url)
        assert live.session is not None
        live.session.wait_until(5.0)  # telemetry flowing
        a.camera.start_photo_interval(CAMERA, 0.5)
        assert wait_for(lambda: len(a.callbacks) >= 4, 20.0), a.callbacks
        tap.drop(True)
        before = max(a.callbacks)
        time.sleep(5.0)
        tap.drop(False)
        f.dropped = dict(tap.dropped)
        # A hears the camera again: new images come (10 were taken in the 5 s), and the missed ones again
        assert wait_for(lambda: max(a.callbacks) > before + 14, 30.0), a.callbacks
        f.a_count = max(a.callbacks) + 1
        f.a_listed = wait_for(lambda: (got := a.listed()) >= set(range(f.a_count)) and got, 30.0) or a.listed()
        a.close()
        a = None
        time.sleep(6.0)  # the restart: the camera goes on without a ground station
        b = Client(tap.mavsdk_url)
        # its own images come live (3 s of them); what it has by then it was given without asking
        assert wait_for(lambda: len(b.callbacks) >= 6, 30.0), b.callbacks
        f.b_first_listed = b.listed()
        f.b_count = max(b.callbacks) + 1
        # list_photos(ALL) made MAVSDK ask for the older ones
        f.b_listed = wait_for(lambda: (got := b.listed()) >= set(range(f.b_count)) and got, 60.0) or b.listed()
        b.camera.stop_photo_interval(CAMERA)
    finally:
        for client in (a, b):
            if client is not None:
                client.close()
        tap.stop()
        f.mcap = live.stop()
    yield f


def camera_images(mcap: Path) -> list[int]:
    with mcap.open("rb") as fh:
        records = [json.loads(m.data) for _, _, m in make_reader(fh).iter_messages(topics=[layout.CAMERA_IMAGES])]
    return [int(r["image_index"]) for r in records]


def test_the_tap_really_cut_the_link(flight: Flight) -> None:
    assert flight.dropped["to_client"] > 100 and flight.dropped["to_upstream"] > 3, flight.dropped


def test_after_a_radio_drop_mavsdk_lists_every_image(flight: Flight) -> None:
    assert flight.a_count >= 15
    assert flight.a_listed >= set(range(flight.a_count)), sorted(set(range(flight.a_count)) - flight.a_listed)


def test_images_taken_while_the_client_was_away_are_delivered_when_it_comes_back(flight: Flight) -> None:
    """The restarted client holds, before it asked for anything, every image from the first client's last one
    on: those taken while no client was there came with its return."""
    newest = max(flight.b_first_listed)
    away = set(range(flight.a_count, newest + 1))
    assert len(away) >= 12  # 6 s at 0.5 s, and B's first seconds
    assert away <= flight.b_first_listed, sorted(away - flight.b_first_listed)


def test_a_restarted_client_lists_every_image_of_the_recording(flight: Flight) -> None:
    assert flight.mcap is not None
    indices = [i for i in camera_images(flight.mcap) if i >= 0]
    assert indices == list(range(len(indices))) and len(indices) >= flight.b_count
    assert flight.b_listed >= set(range(flight.b_count)), sorted(set(range(flight.b_count)) - flight.b_listed)
