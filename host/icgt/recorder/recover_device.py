"""`icgt recover-device`: what a device plugged in again still holds of a flight whose recording ended early.

A recording that ends while the device is unreachable (the cable out when the recorder stopped, the companion
computer's power cut) leaves the exposures of the outage in the device's history ring, and only there. Plugged
in again, the device gets asked for them here:

1. connect and read HELLO and DEVICE_STATE (which says why its last capture ended, when, and which recording
   the last host said its frames were in: HOST_RECEIVED.recording_id);
2. check that it is the device of that flight, in the same boot: its serial number, the recording id, its
   sequence numbers and clock not behind the flight log's (`--flight LOG`); otherwise stop, naming what was
   asked and what was found;
3. ask RESEND from where the flight's log stops (the last host's HOST_RECEIVED mark, or the log's last device
   frame + 1, or the oldest frame the ring knows) up to the first frame of this connection, through the same
   `icgt.device.resend` machinery as the recorder: what comes back is kept, what the ring no longer holds is
   counted by kind;
4. merge-check against the flight log: a frame both hold must be the same frame (else the device is not that
   flight's); the ones the log already holds are left out;
5. write the rest to an MCAP log that names the flight (``icgt.flight``: kind "recovered", the flight's
   recording id and file, the device's serial and boot, the sequence range asked, what was lost), read it back
   and count what it holds before saying it is done.

The recovered log holds the device's raw records (``/device/EXPOSURE``, ``/device/PPS``, ``/device/IMU``,
``/device/RANGE``) with their device times, not geotagged frames: the flight log has the telemetry and the
clock mapping those frames need.
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from icgt.device import DeviceAbsentError, DeviceLink, DeviceLinkError, DeviceLinkEvent
from icgt.errors import IcgtError
from icgt.protocol import Received
from icgt.protocol.messages import CaptureState, DeviceState, Exposure, FrameFlags, Hello, StopCause
from icgt.recorder import topics
from icgt.recorder.device_stop import describe_stop, self_stop_of
from icgt.recorder.flight_log import KEPT_TYPES, FlightLog, read_flight_log
from icgt.recorder.log_file import board_name
from icgt.recording import McapRecorder, RecordingError, layout
from icgt.version import __version__

__all__ = ["RecoverDeviceError", "RecoveryResult", "recover_device"]

log = logging.getLogger("icgt.recover_device")

_RETRANSMIT = int(FrameFlags.RETRANSMIT)
STATE_WAIT_S = 2.0
RESEND_WAIT_S = 20.0  # for the device to answer every request (plus 1 s per 10 000 frames asked)


class RecoverDeviceError(IcgtError):
    """The device cannot be reached, is not the flight's, or holds nothing of it."""


@dataclass
class RecoveryResult:
    path: Path
    asked: tuple[int, int]  # device sequence numbers first .. end (exclusive)
    kept: dict[str, int] = field(default_factory=dict)  # by type, written
    already_in_flight: int = 0
    lost: dict[str, int] = field(default_factory=dict)  # by kind, from RESEND_LOST
    image_indexes: tuple[int, int] | None = None
    flight: str = ""

    @property
    def exposures_lost(self) -> int:
        return self.lost.get("exposures", 0) + self.lost.get("unknown", 0)

    def describe(self) -> str:
        kept = ", ".join(f"{n} {t}" for t, n in sorted(self.kept.items())) or "nothing"
        idx = f" (image indexes {self.image_indexes[0]}..{self.image_indexes[1]})" if self.image_indexes else ""
        lost = ", ".join(f"{n} {k}" for k, n in self.lost.items() if n) or "none"
        return (
            f"recovered from the device for {self.flight}: {kept}{idx}, device frames "
            f"{self.asked[0]}..{self.asked[1] - 1} asked; {self.already_in_flight} already in the flight log; "
            f"no longer in the device's history: {lost}; written to {self.path} and read back"
        )


class _Collector:
    """The link's callbacks: what came back by RESEND (kept types), and the handshake's messages."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.resent: list[tuple[Received, int]] = []
        self.events: list[DeviceLinkEvent] = []

    def on_message(self, received: Received, host_rx_ns: int) -> None:
        if received.flags & _RETRANSMIT and received.message.NAME in KEPT_TYPES:
            with self.lock:
                self.resent.append((received, host_rx_ns))

    def on_event(self, event: DeviceLinkEvent) -> None:
        with self.lock:
            self.events.append(event)


def _seq_after(a: int, b: int) -> bool:
    """b comes after a in device sequence arithmetic (mod 2^32)."""
    return 0 < ((b - a) & 0xFFFFFFFF) < (1 << 31)


def _check_flight(flight: FlightLog, hello: Hello, state: DeviceState) -> None:
    """RecoverDeviceError unless this device, in this boot, is the one the flight log recorded."""
    asked = f"the flight of {flight.path.name}"
    if flight.serial_number is not None and hello.serial_number != flight.serial_number:
        raise RecoverDeviceError(
            f"device from another flight: asked for {asked} (device serial {flight.serial_number}), found device "
            f"serial {hello.serial_number}"
        )
    if flight.recording_id is not None and state.recording_id and state.recording_id != flight.recording_id:
        raise RecoverDeviceError(
            f"device from another flight: asked for {asked} (recording 0x{flight.recording_id:08X}), the device's "
            f"last host logged recording 0x{state.recording_id:08X}"
        )
    if flight.last_seq is not None and not _seq_after(flight.last_seq, state.next_seq):
        raise RecoverDeviceError(
            f"the device restarted since {asked}: its sequence is at {state.next_seq}, the log reached "
            f"{flight.last_seq} (and its clock reads {state.t_us / 1e6:.1f} s, the log's {flight.last_t_us / 1e6:.1f}"
            " s): the history of that flight went with the restart"
        )
    if state.t_us < flight.last_t_us:
        raise RecoverDeviceError(
            f"the device restarted since {asked}: its clock reads {state.t_us / 1e6:.1f} s, the log reached "
            f"{flight.last_t_us / 1e6:.1f} s: the history of that flight went with the restart"
        )


def _first_wanted(flight: FlightLog | None, state: DeviceState) -> int:
    """Where the flight's log stops: the last HOST_RECEIVED mark and/or the log's last frame + 1 (the earlier,
    so the frames both hold are checked), else everything the ring knows."""
    candidates: list[int] = []
    if state.host_received_valid:
        candidates.append(state.host_received_seq)
    if flight is not None and flight.last_seq is not None:
        candidates.append((flight.last_seq + 1) & 0xFFFFFFFF)
    if not candidates:
        return state.history_first_seq
    first = candidates[0]
    for c in candidates[1:]:
        if _seq_after(c, first):
            first = c
    if _seq_after(first, state.history_first_seq):  # older than the ring knows: from its oldest
        first = state.history_first_seq
    return first


def _wait_answered(link: DeviceLink, count: int) -> None:
    deadline = time.monotonic() + RESEND_WAIT_S + count / 10_000
    while time.monotonic() < deadline:
        if link.resend.missing_now == 0:
            return
        if not link.connected:
            raise RecoverDeviceError(f"the device went away ({link.url}) while it sent its history again")
        time.sleep(0.05)
    raise RecoverDeviceError(
        f"the device did not answer every RESEND within {RESEND_WAIT_S + count / 10_000:.0f} s "
        f"({link.resend.missing_now} of {count} frames neither came back nor were counted lost)"
    )


def recover_device(url: str, *, flight_path: Path | None, out: Path | None) -> RecoveryResult:
    """Fetch what the device at `url` still holds of a flight and write it to a log (see the module doc)."""
    flight = read_flight_log(flight_path) if flight_path is not None else None
    got = _Collector()
    link = DeviceLink(url, on_message=got.on_message, on_event=got.on_event, on_time_sync=lambda _: None)
    try:
        try:
            hello = link.start()
        except DeviceAbsentError as exc:
            raise RecoverDeviceError(f"no device: {exc}") from None
        state = link.wait_device_state(STATE_WAIT_S)
        if state is None:
            raise RecoverDeviceError(
                f"the device at {url} sent no DEVICE_STATE after its HELLO (firmware {hello.firmware_version}): "
                "it cannot say which flight its history follows"
            )
        if flight is not None:
            _check_flight(flight, hello, state)
        # Its HOST_RECEIVED (if the fetch takes that long) keeps naming the flight's recording to the device.
        link.recording_id = (flight.recording_id if flight is not None else None) or state.recording_id
        stop = self_stop_of(state)
        if stop is not None:
            log.info("%s", describe_stop(stop))
        if state.capture_state == CaptureState.CAPTURING:
            log.warning("the device is capturing now (no host timeout, or a new capture): its ring keeps moving")
        first = _first_wanted(flight, state)
        count = link.resend.recover_from(first)
        end = (first + count) & 0xFFFFFFFF
        what = flight.path.name if flight is not None else f"recording 0x{state.recording_id:08X}"
        if count == 0:
            raise RecoverDeviceError(
                f"nothing to recover for {what}: asked for the device frames from {first}, the device is at "
                f"{state.next_seq}: no frame since the flight log's end"
            )
        log.info("asking the device again for frames %d..%d (%d)", first, end - 1, count)
        _wait_answered(link, count)
        counters = link.resend.counters
        lost = {
            "exposures": counters.lost_exposures,
            "pps": counters.lost_pps,
            "samples": counters.lost_samples,
            "status/replies/logs": counters.lost_other,
            "unknown": counters.lost_unknown,
        }
    except DeviceLinkError as exc:
        raise RecoverDeviceError(f"device {url}: {exc}") from None
    finally:
        link.stop()
    return _write(got, hello, state, flight, (first, first + count), lost, out)


def _write(
    got: _Collector,
    hello: Hello,
    state: DeviceState,
    flight: FlightLog | None,
    asked: tuple[int, int],
    lost: dict[str, int],
    out: Path | None,
) -> RecoveryResult:
    with got.lock:
        resent = sorted(got.resent, key=lambda r: (r[0].seq - asked[0]) & 0xFFFFFFFF)
        events = list(got.events)
    keep: list[tuple[Received, int]] = []
    already = 0
    for received, rx_ns in resent:
        if flight is not None:
            fields = topics.device_payload(received.message, received.seq, received.flags, rx_ns)
            same = flight.same_frame(received.seq, received.message.NAME, _without_header(fields))
            if same is False:
                raise RecoverDeviceError(
                    f"device from another flight: its frame {received.seq} ({received.message.NAME}) is not the "
                    f"one {flight.path.name} holds under that sequence number"
                )
            if same:
                already += 1
                continue
        keep.append((received, rx_ns))
    flight_name = flight.path.name if flight is not None else "the flight of its last host"
    if not keep:
        gone = ", ".join(f"{n} {k}" for k, n in lost.items() if n) or "nothing"
        raise RecoverDeviceError(
            f"nothing left in the device's history for {flight_name}: asked for device frames "
            f"{asked[0]}..{(asked[1] - 1) & 0xFFFFFFFF}, {already} came back that the log already holds; "
            f"no longer held: {gone}"
        )
    path = _output_path(flight, hello, out)
    rid = flight.recording_id if flight is not None and flight.recording_id else state.recording_id
    result = RecoveryResult(path=path, asked=asked, already_in_flight=already, lost=lost, flight=flight_name)
    exposures = [r.message.image_index for r, _ in keep if isinstance(r.message, Exposure)]
    if exposures:
        result.image_indexes = (min(exposures), max(exposures))
    for r, _ in keep:
        result.kept[r.message.NAME] = result.kept.get(r.message.NAME, 0) + 1
    stop = self_stop_of(state)
    note = (
        f"{sum(result.kept.values())} device frames of {flight_name} (recording 0x{rid:08X}) fetched from the "
        f"device's history after the recording ended: {', '.join(f'{n} {t}' for t, n in sorted(result.kept.items()))}"
        f"; lost: {', '.join(f'{n} {k}' for k, n in lost.items() if n) or 'none'}"
        + (f"; {describe_stop(stop)}" if stop is not None else "")
    )
    mono_to_utc = time.time_ns() - time.monotonic_ns()
    try:
        mcap = McapRecorder(path, clock=lambda: time.monotonic_ns() + mono_to_utc)
    except (RecordingError, OSError) as exc:
        raise RecoverDeviceError(f"cannot write {path}: {exc}") from None
    try:
        mcap.add_metadata(
            layout.META_FLIGHT,
            {
                "kind": "recovered",
                "recording_id": f"0x{rid:08X}",
                "flight_file": flight.path.name if flight is not None else "",
                "device_serial": str(hello.serial_number),
                "device_boot_rtc_utc_us": str(hello.rtc_utc_us_at_boot),
                "device_seq_asked": f"{asked[0]}..{(asked[1] - 1) & 0xFFFFFFFF}",
                "stop_cause": _stop_cause_name(state.stop_cause),
                "note": note,
            },
        )
        mcap.add_metadata(
            layout.META_DEVICE,
            {
                "firmware_version": hello.firmware_version,
                "protocol_version": str(hello.protocol_version),
                "board": board_name(hello.board),
                "serial_number": str(hello.serial_number),
                "host_software": f"icgt {__version__} recover-device",
            },
        )
        mcap.add_metadata(layout.META_TIME_BASES, {"monotonic_to_utc_offset_ns": str(mono_to_utc)})
        mcap.register_json(layout.LINK_EVENTS, "icgt.link_event", layout.LINK_EVENT_SCHEMA)
        for name in sorted({r.message.NAME for r, _ in keep} | {"HELLO", "DEVICE_STATE"}):
            cls = layout.DEVICE_TOPIC_TYPES[topics.device_topic(name)]
            mcap.register_json(topics.device_topic(name), f"icgt.device.{name}", topics.device_schema(cls))
        now = time.monotonic_ns()
        mcap.write_encoded(topics.device_topic("HELLO"), topics.device_payload_json(hello, 0, 0, now), now)
        mcap.write_encoded(topics.device_topic("DEVICE_STATE"), topics.device_payload_json(state, 0, 0, now), now)
        for received, rx_ns in keep:
            data = topics.device_payload_json(received.message, received.seq, received.flags, rx_ns)
            mcap.write_encoded(topics.device_topic(received.message.NAME), data, rx_ns)
        for e in events:
            mcap.write(
                layout.LINK_EVENTS,
                {"link": "device", "kind": e.kind, "detail": e.detail, "count": e.count, "outage_ns": e.outage_ns,
                 "host_ns": e.host_ns},
                publish_time_ns=e.host_ns + mono_to_utc,
            )  # fmt: skip
    finally:
        try:
            mcap.close()
        except RecordingError as exc:
            raise RecoverDeviceError(f"cannot write {path}: {exc}") from None
    _read_back(result)
    return result


def _stop_cause_name(value: int) -> str:
    try:
        return StopCause(value).name.lower()
    except ValueError:
        return str(value)


def _without_header(d: dict[str, object]) -> dict[str, object]:
    return {k: v for k, v in d.items() if k not in ("seq", "frame_flags", "host_rx_ns")}


def _output_path(flight: FlightLog | None, hello: Hello, out: Path | None) -> Path:
    if out is not None and out.suffix == ".mcap":
        path = out
    else:
        folder = out if out is not None else (flight.path.parent if flight is not None else Path("."))
        stem = flight.path.stem if flight is not None else f"icgt_device{hello.serial_number}"
        stamp = datetime.now(UTC).strftime("%Y%m%dT%H%M%SZ")
        path = folder / f"{stem}-device-{stamp}.mcap"
    if path.exists():
        raise RecoverDeviceError(f"{path} exists already: not overwritten (give another --out)")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise RecoverDeviceError(f"--out {path.parent}: cannot create the folder: {exc.strerror or exc}") from None
    return path


def _read_back(result: RecoveryResult) -> None:
    """Count what the written file holds, by type, against what was written (never claim a write that did not
    happen)."""
    from icgt.ingest import read

    try:
        counts = read(result.path).topics()
    except IcgtError as exc:
        raise RecoverDeviceError(f"{result.path} was written but does not read back: {exc}") from None
    for name, n in result.kept.items():
        found = counts.get(topics.device_topic(name), 0)
        if found != n:
            raise RecoverDeviceError(f"{result.path} reads back {found} {name} records of the {n} written")
