"""What an earlier log says about the flight it recorded, for `icgt recover-device --flight LOG`.

The device's frames that log holds (by device sequence number, with their bodies, to check the ones the
device sends again against them), the recording id the recorder named to the device (HOST_RECEIVED), the
device's serial number and boot (HELLO), and how far its sequence and clock had got: enough to tell whether
a device plugged in later is the one of that flight, still in the same boot, and which of its frames the log
lacks.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from icgt.errors import IcgtError
from icgt.recording import layout

__all__ = ["KEPT_TYPES", "FlightLog", "FlightLogError", "read_flight_log"]

KEPT_TYPES = ("EXPOSURE", "PPS", "IMU", "RANGE")
"""The device messages its history keeps (SPEC.md §3), the only ones RESEND can bring back."""
_HEADER = ("seq", "frame_flags", "host_rx_ns")


class FlightLogError(IcgtError):
    """The --flight log cannot be read, or is not an ICGT recording."""


@dataclass
class FlightLog:
    path: Path
    recording_id: int | None  # None: a log from before recording ids (protocol 1)
    serial_number: int | None
    rtc_utc_us_at_boot: int | None  # the device's boot as its HELLO told it
    last_seq: int | None  # the highest device sequence number in the log (unwrapped from the first)
    last_t_us: int  # the latest device clock reading in the log
    frames: dict[int, tuple[str, dict[str, Any]]] = field(default_factory=dict)  # seq -> (type, fields), kept types

    def same_frame(self, seq: int, name: str, fields: dict[str, Any]) -> bool | None:
        """Whether the log holds this very frame (None: the log does not have that sequence number)."""
        held = self.frames.get(seq)
        if held is None:
            return None
        return held[0] == name and all(held[1].get(k) == v for k, v in fields.items())


def _fields(data: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in data.items() if k not in _HEADER}


def read_flight_log(path: Path) -> FlightLog:
    """The flight that `path` (an `icgt record` log, finished or not) recorded, as far as the device goes."""
    from icgt.ingest import read
    from icgt.ingest.reader import IngestError

    if not path.is_file():
        raise FlightLogError(f"--flight {path}: no such file")
    try:
        rec = read(path, allow_unfinished=True)
        meta = rec.metadata
        flight = meta.get(layout.META_FLIGHT, {})
        device = meta.get(layout.META_DEVICE, {})
        if not device:
            raise FlightLogError(f"--flight {path}: not an ICGT recording (no icgt.device metadata)")
        rid = flight.get("recording_id")
        serial = device.get("serial_number")
        out = FlightLog(
            path=path,
            recording_id=int(rid, 0) if rid else None,
            serial_number=int(serial) if serial and serial.isdigit() else None,
            rtc_utc_us_at_boot=None,
            last_seq=None,
            last_t_us=0,
        )
        topics = [t for t in rec.topics() if t.startswith(layout.DEVICE_PREFIX)]
        for msg in rec.records(topics):
            d = msg.data
            cls = layout.DEVICE_TOPIC_TYPES.get(msg.topic)
            if cls is None:
                continue
            name = cls.NAME
            seq = d.get("seq")
            if not isinstance(seq, int):
                continue
            if name == "HELLO" and out.rtc_utc_us_at_boot is None and d.get("rtc_utc_us_at_boot"):
                out.rtc_utc_us_at_boot = int(d["rtc_utc_us_at_boot"])
            for key in ("t_us", "read_end_t_us", "read_t_us", "trigger_t_us"):
                if isinstance(d.get(key), int):
                    out.last_t_us = max(out.last_t_us, d[key])
            out.last_seq = seq if out.last_seq is None else _later(out.last_seq, seq)
            if name in KEPT_TYPES:
                out.frames[seq] = (name, _fields(d))
    except IngestError as exc:
        raise FlightLogError(f"--flight {path}: {exc}") from None
    return out


def _later(a: int, b: int) -> int:
    """The later of two device sequence numbers (mod 2^32)."""
    return b if 0 < ((b - a) & 0xFFFFFFFF) < (1 << 31) else a
