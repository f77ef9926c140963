"""The camera driven by MAVSDK's Camera plugin (PyPI `mavsdk`, its native library) through the simulated
autopilot's ground-station port, with `icgt record` running on the simulated flight: client code this
project did not write. Two flights, each shared by its tests (module-scoped fixtures):

* signing off (the defaults): discovery, take_photo, start/stop_photo_interval, capture_info positions
  and relative altitude against the simulator's truth, list_photos after the client reconnects;
* signing on (a passphrase key file): MAVSDK (which has no signing) and a pymavlink client with another
  key are refused without an answer; a pymavlink client with the right passphrase takes a photo and gets
  signed replies; the recording says signing was on and holds neither the passphrase nor the key.
"""

from __future__ import annotations

import json
import math
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from mavsdk import ComponentType, Configuration, Mavsdk
from mavsdk.plugins.camera import Camera, CameraError, PhotosRange
from mcap.reader import make_reader
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.geodesy import LocalFrame
from icgt.mavlink.signing import SigningState, key_from_passphrase
from icgt.recording import layout
from icgt.sim.evaluate import read_frames, read_truth
from icgt.sim.latency import frame_timings
from icgt.sim.live_recorder import LiveRecorder
from icgt.sim.scenario import load_scenario

SCENARIO = load_scenario(Path(__file__).with_name("mavsdk_hover.toml"))
CAMERA = 100
PASSPHRASE = "bridge 12, pier 3 - inspection crew"
M = mavlink2


def wait_for(predicate: Callable[[], Any], timeout: float, step: float = 0.1) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        got = predicate()
        if got:
            return got
        time.sleep(step)
    return predicate()


@dataclass
class Client:
    """One MAVSDK instance as a ground station (system 245), its Camera plugin and the captures it got."""

    url: str
    mavsdk: Mavsdk = field(init=False)
    camera: Camera = field(init=False)
    captures: list[tuple[int, Any]] = field(default_factory=list)  # (host monotonic ns, CaptureInfo)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self) -> None:
        self.mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
        self.mavsdk.add_any_connection(self.url)
        system = self.mavsdk.first_autopilot(20.0)
        assert system is not None, "MAVSDK never saw the simulated autopilot"
        self.camera = Camera(system)
        self.camera.subscribe_capture_info(self._on_capture)

    def _on_capture(self, info: Any, *_: Any) -> None:
        with self.lock:
            self.captures.append((time.monotonic_ns(), info))

    def cameras(self, timeout: float) -> list[Any]:
        return wait_for(lambda: self.camera.camera_list().cameras, timeout) or []

    def captured(self) -> list[Any]:
        with self.lock:
            return [c for _, c in self.captures]

    def close(self) -> None:
        self.mavsdk.destroy()


def camera_images(mcap: Path) -> list[dict[str, Any]]:
    with mcap.open("rb") as f:
        return [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[layout.CAMERA_IMAGES])]


def last_counters(mcap: Path) -> dict[str, Any]:
    with mcap.open("rb") as f:
        records = [json.loads(m.data) for _, _, m in make_reader(f).iter_messages(topics=[layout.COUNTERS])]
    return records[-1]


# ---------------------------------------------------------------------------------------------- signing off
@dataclass
class PlainFlight:
    live: LiveRecorder
    first: list[Any] = field(default_factory=list)  # captures of the first client
    second: list[Any] = field(default_factory=list)  # ... of the one that connected after it
    listed: list[Any] = field(default_factory=list)  # the second client's list_photos(ALL)
    interval_captures: int = 0
    stopped_ns: int = 0
    discovered: list[Any] = field(default_factory=list)
    mcap: Path | None = None


@pytest.fixture(scope="module")
def plain(tmp_path_factory: pytest.TempPathFactory) -> Iterator[PlainFlight]:
    """One flight: the MAVSDK session every signing-off test reads (run once, in this order)."""
    live = LiveRecorder(SCENARIO, tmp_path_factory.mktemp("mavsdk_plain"))
    live.start()
    flight = PlainFlight(live)
    try:
        client = Client(live.mavsdk_url)
        flight.discovered = client.cameras(30.0)
        assert flight.discovered, f"MAVSDK never listed the camera; see {live.recorder_log}"
        assert live.session is not None
        live.session.wait_until(5.0)  # telemetry flowing (a photo before it has no pose: published as poor)
        client.camera.take_photo(CAMERA)
        wait_for(lambda: len(client.captured()) >= 1, 6.0)
        n0 = len(client.captured())
        client.camera.start_photo_interval(CAMERA, 0.5)
        time.sleep(4.1)
        client.camera.stop_photo_interval(CAMERA)
        flight.stopped_ns = time.monotonic_ns()  # the recorder's clock too (CLOCK_MONOTONIC, one machine)
        _settle(client)  # frames are emitted once their pose can be interpolated (a bounded wait)
        flight.interval_captures = len(client.captured()) - n0
        flight.first = client.captured()
        client.close()
        # a ground station that reconnects: it asks for everything taken before it came
        again = Client(live.mavsdk_url)
        assert again.cameras(20.0)
        wait_for(lambda: _status_known(again), 5.0)
        again.camera.take_photo(CAMERA)
        wait_for(lambda: len(again.captured()) >= 1, 6.0)
        total = len(flight.first) + 1
        again.camera.list_photos(CAMERA, PhotosRange.ALL)  # starts MAVSDK's requests for the older ones
        everything = set(range(total))
        flight.listed = wait_for(lambda: _listed(again, everything), 30.0, step=0.5) or _listed_any(again)
        flight.second = again.captured()
        again.close()
    finally:
        flight.mcap = live.stop()
    yield flight


def _settle(client: Client, quiet_s: float = 1.5, timeout_s: float = 6.0) -> None:
    """Wait until no capture_info has come for ``quiet_s`` (at most ``timeout_s``)."""
    deadline = time.monotonic() + timeout_s
    last, since = len(client.captured()), time.monotonic()
    while time.monotonic() < deadline and time.monotonic() - since < quiet_s:
        time.sleep(0.1)
        n = len(client.captured())
        if n != last:
            last, since = n, time.monotonic()


def _status_known(client: Client) -> bool:
    try:
        client.camera.list_photos(CAMERA, PhotosRange.SINCE_CONNECTION)
    except CameraError:
        return False
    return True


def _listed_any(client: Client) -> list[Any]:
    try:
        return list(client.camera.list_photos(CAMERA, PhotosRange.ALL))
    except CameraError:
        return []


def _listed(client: Client, want: set[int]) -> list[Any] | None:
    got = _listed_any(client)
    return got if want <= {p.index for p in got} else None


def test_mavsdk_discovers_the_camera_with_the_default_ground_station_ids(plain: PlainFlight) -> None:
    (info,) = plain.discovered
    assert info.component_id == CAMERA and info.vendor_name == "ICGT"
    cam = SCENARIO.camera
    assert (info.horizontal_resolution_px, info.vertical_resolution_px) == (cam.image_width_px, cam.image_height_px)
    assert info.focal_length_mm == pytest.approx(cam.focal_length_mm)


def test_take_photo_and_interval_give_one_capture_info_per_image(plain: PlainFlight) -> None:
    assert plain.first and plain.first[0].index == 0
    assert 7 <= plain.interval_captures <= 10  # 4.1 s at 0.5 s (the first at once; start/stop ACK timing)
    assert [c.index for c in plain.first] == list(range(len(plain.first)))
    assert plain.mcap is not None
    exposed = [r["host_ns"] for r in camera_images(plain.mcap)][: len(plain.first)]
    assert max(exposed) < plain.stopped_ns  # nothing exposed after stop_photo_interval returned


def test_frames_of_a_steady_interval_are_emitted_once_their_inputs_are_in_not_before(plain: PlainFlight) -> None:
    """Each frame of the interval capture is emitted after its inputs are in (the exposure record ready, the
    telemetry sample after mid-exposure arrived; icgt.sim.latency), never before: the worker's early wake-ups
    (icgt.recorder.step_schedule, worker_wake) must not emit a frame whose pose would be extrapolated. How soon
    after is a timing figure, measured by benchmarks/mavsdk_camera.py and capture_rates.py: under this suite's
    load the recorder's share ranged 6-134 ms (2026-12-07), so no test bounds it."""
    assert plain.mcap is not None
    timings = sorted(frame_timings(plain.mcap), key=lambda t: t.mid_host_ns)
    steady = [
        t.recorder_ms
        for prev, prev2, t in zip(timings, timings[1:], timings[2:], strict=False)
        if abs((prev2.mid_host_ns - prev.mid_host_ns) - (t.mid_host_ns - prev2.mid_host_ns)) < 50_000_000
        and 0.3e9 < t.mid_host_ns - prev2.mid_host_ns < 0.7e9  # the 0.5 s interval
    ]
    assert len(steady) >= 4, steady
    assert all(math.isfinite(x) for x in steady), steady  # every frame's inputs are in the log
    assert min(steady) >= -1.0, steady  # 1 ms: the clock maps' error between the two links


def test_list_photos_after_reconnecting_sees_the_recording_s_indices_and_its_history(plain: PlainFlight) -> None:
    """The new client's photo continues the recording's numbering (index = image_count - 1), and the older
    images come from the history when asked for. MAVSDK 4.1 asks for older images with REQUEST_MESSAGE
    but leaves param2 (the index) unset, 0 (mavlink_request_message.cpp sets only param1): the camera
    sends such a client every image it has not been sent (icgt.mavlink.camera_clients), so the list ends
    complete; re-requests of any index, a range and all images are checked with our own client in
    tests/mavlink/test_mavlink_camera.py, drops and restarts in test_mavsdk_recovery.py."""
    total = len(plain.first) + 1
    listed = {p.index: p for p in plain.listed}
    assert set(listed) == set(range(total))
    assert plain.second[0].index == total - 1  # its own photo came first; then the older ones
    first0 = plain.first[0]
    assert (listed[0].position.latitude_deg, listed[0].time_utc_us) == (
        first0.position.latitude_deg,
        first0.time_utc_us,
    )
    by_index = {c.index: c for c in plain.first}
    for p in plain.listed:
        if p.index in by_index:  # re-sent from the history: the same image
            assert p.position.latitude_deg == by_index[p.index].position.latitude_deg
            assert p.time_utc_us == by_index[p.index].time_utc_us


def test_capture_positions_and_height_above_home_match_the_truth(plain: PlainFlight) -> None:
    assert plain.mcap is not None
    frames = {f["frame_seq"]: f for f in read_frames(plain.mcap)}
    images = {r["image_index"]: r for r in camera_images(plain.mcap)}
    truth = {int(t["start_device_us"]): t for t in read_truth(plain.live.out_dir / "sim" / "truth_exposures.jsonl")}
    origin = SCENARIO.origin
    local = LocalFrame(origin.lat_deg, origin.lon_deg, origin.ellipsoid_height_m)
    captures = {c.index: c for c in plain.first + plain.second}
    assert len(captures) == len(images) == len(frames)
    good = 0
    for index, c in captures.items():
        frame = frames[images[index]["frame_seq"]]
        t = truth[int(frame["start_device_us"])]
        assert images[index]["device_image_index"] == frame["image_index"]
        assert c.is_success == images[index]["capture_result"]  # the log and the ground station agree
        if not images[index]["position_published"]:
            assert (c.position.latitude_deg, c.position.longitude_deg) == (0.0, 0.0) and not c.is_success
            continue
        good += 1
        enu = local.geodetic_to_enu(c.position.latitude_deg, c.position.longitude_deg, origin.ellipsoid_height_m)
        e, n = float(enu[0]), float(enu[1])
        te, tn, tu = t["position_enu_m"]
        assert math.hypot(e - te, n - tn) < 0.25, (index, c.position)
        assert abs(c.position.absolute_altitude_m - t["alt_msl_m"]) < 0.25
        # height above home (the take-off point, the scenario's origin): the camera is ~8.4 m up
        assert abs(c.position.relative_altitude_m - tu) < 0.25, (index, c.position.relative_altitude_m, tu)
        assert c.position.relative_altitude_m > 7.0
    # the others (GPS samples late on a loaded machine: the simulator runs in real time) were published as
    # poor and said so; on a quiet machine nearly all are good
    assert good >= 1
    camera = last_counters(plain.mcap)["camera"]
    assert camera["images"] == len(captures) and camera["rejected_commands"] == 0


# ---------------------------------------------------------------------------------------------- signing on
class SignedGcs:
    """A pymavlink ground station (QGroundControl's ids) that signs with the key of ``passphrase``: its own
    MAVLink 2 packer and parser on a UDP socket (mavutil's dialect is a process-wide MAVLink 1 default)."""

    def __init__(self, url: str, passphrase: str) -> None:
        host, port = url.removeprefix("udpout:").rsplit(":", 1)
        self.target = (host, int(port))
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 * 1024 * 1024)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.1)
        self.mav = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser = mavlink2.MAVLink(None, srcSystem=255, srcComponent=190)
        self.parser.robust_parsing = True
        signing = SigningState(key_from_passphrase(passphrase), link_id=2)
        signing.attach_output(self.mav)
        signing.attach_input(self.parser)  # accepts everything; msg.get_signed() says if it verified

    def send(self, msg: Any) -> None:
        self.sock.sendto(bytes(msg.pack(self.mav)), self.target)
        self.mav.seq = (self.mav.seq + 1) % 256

    def heartbeat(self) -> None:
        self.send(self.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 4))

    def receive(self, want: Callable[[Any], bool], timeout: float) -> Any:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                data = self.sock.recv(65536)
            except TimeoutError:
                continue
            for msg in self.parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA" and want(msg):
                    return msg
        return None

    def shoot(self, sequence: int, timeout: float = 3.0) -> tuple[Any, Any]:
        """(COMMAND_ACK or None, CAMERA_IMAGE_CAPTURED or None) for one IMAGE_START_CAPTURE single shot."""
        self.drain()  # the telemetry that queued up meanwhile: a full socket buffer would drop the answer
        self.send(self.mav.command_long_encode(1, CAMERA, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 0, 1, sequence, 0, 0, 0))
        got: dict[str, Any] = {}

        def want(msg: Any) -> bool:
            kind = msg.get_type()
            if (kind == "COMMAND_ACK" and msg.command == M.MAV_CMD_IMAGE_START_CAPTURE) or (
                kind == "CAMERA_IMAGE_CAPTURED"
            ):
                got[kind] = msg
            return len(got) == 2

        self.receive(want, timeout)
        return got.get("COMMAND_ACK"), got.get("CAMERA_IMAGE_CAPTURED")

    def drain(self) -> None:
        self.sock.setblocking(False)
        try:
            while True:
                data = self.sock.recv(65536)
                self.parser.parse_buffer(data)  # keeps the parser's stream state current
        except (BlockingIOError, InterruptedError):
            pass
        finally:
            self.sock.settimeout(0.1)

    def close(self) -> None:
        self.sock.close()


@dataclass
class SignedFlight:
    live: LiveRecorder
    mavsdk_cameras: list[Any] = field(default_factory=list)
    mavsdk_photo_error: str = ""
    wrong: tuple[Any, Any] = (None, None)
    right: tuple[Any, Any] = (None, None)
    mcap: Path | None = None


@pytest.fixture(scope="module")
def signed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SignedFlight]:
    out = tmp_path_factory.mktemp("mavsdk_signed")
    key_file = out / "mavlink.key"
    key_file.write_text(PASSPHRASE + "\n")
    key_file.chmod(0o600)
    live = LiveRecorder(SCENARIO, out, signing_key_file=key_file)
    live.start()
    flight = SignedFlight(live)
    right = wrong = None
    try:
        assert live.urls is not None
        right = SignedGcs(live.urls.gcs, PASSPHRASE)
        wrong = SignedGcs(live.urls.gcs, PASSPHRASE + "?")
        right.heartbeat()
        wrong.heartbeat()
        # the camera is up once it signs its HEARTBEATs (seen by the client that has the key)
        hb = right.receive(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == CAMERA, 30.0)
        assert hb is not None and hb.get_signed(), f"no signed camera HEARTBEAT; see {live.recorder_log}"
        client = Client(live.mavsdk_url)
        flight.mavsdk_cameras = client.cameras(6.0)  # its CAMERA_INFORMATION requests are not answered
        try:
            client.camera.take_photo(CAMERA)
        except CameraError as exc:
            flight.mavsdk_photo_error = str(exc)
        client.close()
        flight.wrong = wrong.shoot(1, timeout=3.0)
        flight.right = right.shoot(1, timeout=10.0)  # the image follows once its frame is emitted
    finally:
        for gcs in (right, wrong):
            if gcs is not None:
                gcs.close()
        flight.mcap = live.stop()
    yield flight


def test_unsigned_mavsdk_is_refused_when_signing_is_on(signed: SignedFlight) -> None:
    assert signed.mavsdk_cameras == []
    assert signed.mavsdk_photo_error
    assert signed.mcap is not None
    camera = last_counters(signed.mcap)["camera"]
    assert camera["unsigned_commands"] >= 1 and camera["refusal_acks_sent"] == 0


def test_a_client_with_another_key_gets_no_answer_and_no_photo(signed: SignedFlight) -> None:
    assert signed.wrong == (None, None) or signed.wrong[0] is None
    assert signed.mcap is not None
    assert last_counters(signed.mcap)["camera"]["badly_signed_commands"] >= 1


def test_the_right_passphrase_takes_a_photo_with_signed_replies(signed: SignedFlight) -> None:
    ack, image = signed.right
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED and ack.get_signed()
    assert image is not None and image.get_signed() and image.image_index == 0
    assert signed.mcap is not None
    assert [r["image_index"] for r in camera_images(signed.mcap)] == [0]


def test_the_recording_says_signing_was_on_and_holds_no_key(signed: SignedFlight) -> None:
    assert signed.mcap is not None
    with signed.mcap.open("rb") as f:
        reader = make_reader(f)
        meta = {m.name: m.metadata for m in reader.iter_metadata()}
    assert meta[layout.META_MAVLINK_SIGNING]["enabled"] == "true"
    data = signed.mcap.read_bytes()
    key = key_from_passphrase(PASSPHRASE)
    assert PASSPHRASE.encode() not in data and key not in data and key.hex().encode() not in data
