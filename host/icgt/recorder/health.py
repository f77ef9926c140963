"""What the recorder reports about itself: `icgt status`, the once-a-second log records, the end-of-run summary.

`Health` reads the synchroniser, the links and the log; it changes none of them. On the worker's thread,
once a second (`every_second`): the clock estimates (/icgt/clock/*) and the counters (/icgt/counters) go in
the log, and a snapshot of the synchroniser's state is kept for `status()`, which the control socket's thread
calls (the synchroniser itself runs on the worker only). At the end, `record_summary` logs the device link's
account and stores it, with the ENU origin, as the log's metadata.
"""

from __future__ import annotations

import contextlib
import logging
from dataclasses import asdict, dataclass
from typing import Any

from icgt.recorder.links import Links
from icgt.recorder.log_file import RecorderLog
from icgt.recording import RecordingError, layout
from icgt.sync import Synchroniser

__all__ = ["Health", "RecorderStatus", "timesync_status"]

log = logging.getLogger("icgt.recorder")


@dataclass
class RecorderStatus:
    """What `icgt status` prints."""

    file: str
    capturing: bool
    frames: int
    exposures: int
    device_connected: bool
    autopilot: str
    device_clock_settled: bool
    device_clock_uncertainty_us: float | None
    sequence_gaps: int
    messages_lost: int
    frames_rejected: int
    pending_frames: int
    last_status: dict[str, Any] | None
    timesync: str = ""  # the autopilot's TIMESYNC: answered / unanswered / not asked yet
    waiting_for_device: bool = False  # started, the device not there yet ([device] wait_s)
    frames_recovered: int = 0  # device frames that came back through RESEND
    lost_exposures: int = 0  # exposures the device could no longer send (its history ring had moved on)


class Health:
    """The recorder's reports on itself, from the parts it reads."""

    def __init__(self, sync: Synchroniser, links: Links, log_file: RecorderLog) -> None:
        self._sync = sync
        self._links = links
        self._log = log_file
        self._snapshot: dict[str, Any] = {}

    def every_second(self, now: int) -> None:
        """The worker's once-a-second records: the clock estimates and the counters; the status snapshot."""
        sync = self._sync
        write = self._log.write
        device_est = sync.device_clock.estimate()
        write(layout.CLOCK_DEVICE, device_est.to_dict(), now)
        write(layout.CLOCK_AUTOPILOT, sync.autopilot_clock.estimate().to_dict(), now)
        write(layout.CLOCK_UTC, sync.utc.host_to_utc(now).to_dict() | {"host_ns": now}, now)
        self.write_counters(now)
        self._snapshot = {
            "device_clock_settled": sync.device_clock.settled,
            "device_clock_uncertainty_us": device_est.uncertainty_ns / 1000.0 if device_est.valid else None,
            "pending_frames": sync.pending_frames,
            "sync": sync.counters(),
        }

    def write_counters(self, now: int) -> None:
        links = self._links
        record: dict[str, Any] = {"host_ns": now, "sync": self._sync.counters()}
        if links.device is not None:
            record["device"] = {k: v for k, v in links.device.decoder_stats.items() if v is not None}
            record["device"] |= links.device.resend.counter_dict()
        if links.mavlink is not None:
            stats = asdict(links.mavlink.stats())
            stats.pop("messages_by_type", None)
            record["mavlink"] = stats
        if links.camera is not None:
            record["camera"] = links.camera.counters
        self._log.write(layout.COUNTERS, record, now)

    def record_summary(self) -> None:
        """At the end: the ENU origin and the device link's account, as the log's metadata (and said)."""
        mcap = self._log.mcap
        origin = self._sync.geotagger.origin
        if origin is not None and mcap is not None:
            with contextlib.suppress(RecordingError):
                mcap.add_metadata(
                    layout.META_ENU_ORIGIN,
                    {
                        "lat_deg": repr(origin[0]),
                        "lon_deg": repr(origin[1]),
                        "alt_msl_m": repr(origin[2]),
                        "note": "origin of the frames' east/north/up: the first usable fix (or the configured origin)",
                    },
                )
        device = self._links.device
        if device is None:
            return
        stats = device.decoder_stats | device.resend.counter_dict()
        log.info(
            "device link summary: %s frames, %s rejected, %s messages missing in %s gaps, %s recovered by RESEND; "
            "lost: %s exposures, %s PPS, %s samples, %s status/replies/logs, %s unknown",
            stats.get("frames_ok"),
            device.frames_rejected,
            stats.get("seq_missed"),
            stats.get("seq_gaps"),
            stats.get("resend_recovered"),
            stats.get("lost_exposures"),
            stats.get("lost_pps"),
            stats.get("lost_samples"),
            stats.get("lost_other"),
            stats.get("lost_unknown"),
        )
        if mcap is not None:
            with contextlib.suppress(RecordingError):
                mcap.add_metadata(layout.META_DEVICE_LINK, {k: str(v) for k, v in stats.items()})

    def status(self, *, capturing: bool, frames: int, exposures: int, waiting_for_device: bool) -> RecorderStatus:
        """What the recorder knows now (the synchroniser's part as of its last second: it runs on the worker)."""
        snap = self._snapshot
        device = self._links.device
        mcap = self._log.mcap
        stats = device.decoder_stats if device is not None else {}
        last = self._sync.last_status
        return RecorderStatus(
            file=str(mcap.path) if mcap is not None else "",
            capturing=capturing,
            frames=frames,
            exposures=exposures,
            device_connected=device is not None and device.connected and not waiting_for_device,
            waiting_for_device=waiting_for_device,
            # the synchroniser's account of the autopilot (waiting / up / lost), not a second one of the link's
            autopilot=self._sync.autopilot.state.value if self._links.mavlink is not None else "none",
            device_clock_settled=bool(snap.get("device_clock_settled", False)),
            device_clock_uncertainty_us=snap.get("device_clock_uncertainty_us"),
            sequence_gaps=int(stats.get("seq_gaps") or 0),
            messages_lost=int(stats.get("seq_missed") or 0),
            frames_rejected=device.frames_rejected if device is not None else 0,
            pending_frames=int(snap.get("pending_frames", 0)),
            last_status=asdict(last) if last is not None else None,
            timesync=timesync_status(snap.get("sync", {})),
            frames_recovered=device.resend.counters.recovered if device is not None else 0,
            lost_exposures=device.resend.counters.lost_exposures if device is not None else 0,
        )


def timesync_status(counters: dict[str, int]) -> str:
    """`icgt status`'s word on the autopilot clock: answered, unanswered or not asked yet."""
    sent = counters.get("timesync_sent", 0)
    answered = counters.get("timesync_answered", 0)
    if sent == 0:
        return "not asked yet"
    if answered == 0:
        return f"unanswered ({counters.get('timesync_unanswered', 0)} of {sent} requests)"
    return f"answered ({answered} of {sent} requests)"
