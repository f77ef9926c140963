"""The MAVLink side of a recording: what the link hands over, logged and fed to the synchroniser in order.

`MavlinkInput` takes each input of the MAVLink link from the worker's inbox (`icgt.recorder.inbox`): a
message of the vehicle or of a ground station is written to its own topic, fed to the synchroniser, to the
camera's image history and to the live views; other systems' frames (a shared network, a flood) are kept raw
and written in batches, one record per drain of the inbox. TIMESYNC requests sent and the link's own events go
on their topics too, and the synchroniser's account of the autopilot's presence goes back to the link as a hint.
"""

from __future__ import annotations

import contextlib
from typing import Any

from icgt.mavlink.frames import UndecodedBatch
from icgt.mavlink.link import MavlinkEvent, MavlinkLink, MavlinkMessage
from icgt.recorder import topics
from icgt.recorder.camera_link import CameraImages
from icgt.recorder.log_file import RecorderLog
from icgt.recording import RecordingError, layout
from icgt.recording.views import FoxgloveViews
from icgt.sync import SyncEvent, Synchroniser

__all__ = ["OTHER_SYSTEMS_BATCH", "MavlinkInput"]

OTHER_SYSTEMS_BATCH = 500  # other systems' MAVLink frames per /mavlink/other_systems record, at most


class MavlinkInput:
    """Every MAVLink input of one recording, on the worker's thread. ``link``: the recorder's link once it runs
    (it takes the autopilot's believed COMMAND_ACKs and the presence hints)."""

    def __init__(
        self,
        sync: Synchroniser,
        log_file: RecorderLog,
        views: FoxgloveViews,
        images: CameraImages,
        expanded_systems: frozenset[int],
    ) -> None:
        self._sync = sync
        self._log = log_file
        self._views = views
        self._images = images
        # MAVLink systems whose messages are logged field by field: the vehicle and its ground stations.
        self.expanded_systems = expanded_systems
        self.link: MavlinkLink | None = None
        self._other_systems: list[dict[str, Any]] = []  # their raw frames, written once per inbox drain
        self._registered: set[str] = set()

    def on_message(self, rec: MavlinkMessage | UndecodedBatch) -> None:
        sync = self._sync
        if isinstance(rec, UndecodedBatch):  # other systems' frames (all of a flood): logged and counted in bulk
            self._other_systems += topics.mavlink_raw_payloads(rec)
            sync.on_other_systems(rec.type_counts())
            if len(self._other_systems) >= OTHER_SYSTEMS_BATCH:
                self.flush_other_systems()
            return
        name = rec.type
        if name == "BAD_DATA":
            return
        if rec.src_system not in self.expanded_systems:
            # Other vehicles and clients on a shared network: kept raw, batched into one record per drain
            # of the inbox (a flood of them must not cost a JSON record each); the synchroniser still sees
            # each one (and ignores it), in order.
            self._other_systems.append(topics.mavlink_raw_payload(rec.msg, rec.rx_ns))
            sync.on_mavlink(rec.msg, rec.rx_ns)
            if len(self._other_systems) >= OTHER_SYSTEMS_BATCH:
                self.flush_other_systems()
            return
        if self._other_systems:
            self.flush_other_systems()
        topic = topics.mavlink_topic(name)
        mcap = self._log.mcap
        if topic not in self._registered and mcap is not None:
            with contextlib.suppress(RecordingError):
                mcap.register_json(topic, f"mavlink.{name}", topics.mavlink_schema(rec.msg))
            self._registered.add(topic)
        self._log.write(topic, topics.mavlink_payload(rec.msg, rec.rx_ns), rec.rx_ns)
        verdict = sync.on_mavlink(rec.msg, rec.rx_ns)
        if name == "COMMAND_ACK" and verdict.believed and self.link is not None:
            self.link.autopilot_answered(rec.msg, rec.rx_ns)  # a second sender's ACK answers nothing
        self._images.on_mavlink(rec.msg, rec.src_system, rec.rx_ns)
        self._views.on_mavlink(rec.msg, rec.rx_ns)

    def flush_other_systems(self) -> None:
        """Other systems' frames kept since the last flush, as /mavlink/other_systems records."""
        frames, self._other_systems = self._other_systems, []
        for i in range(0, len(frames), OTHER_SYSTEMS_BATCH):
            batch = frames[i : i + OTHER_SYSTEMS_BATCH]
            self._log.write(layout.MAVLINK_OTHER_SYSTEMS, {"frames": batch}, batch[0]["host_rx_ns"])

    @property
    def holds_other_systems(self) -> bool:
        return bool(self._other_systems)

    def on_timesync_sent(self, tx_ns: int) -> None:
        self._log.write(layout.CLOCK_AUTOPILOT_REQUESTS, {"host_tx_ns": tx_ns}, tx_ns)
        self._sync.on_timesync_request(tx_ns)

    def on_event(self, event: MavlinkEvent) -> None:
        # MavlinkLink logs the event itself (icgt.mavlink.link, also on /icgt/log); here it only goes on the topic.
        self._log.link_event("mavlink", event.kind.value, event.detail, event.host_ns, event.count)

    def take_sync_events(self) -> None:
        """The synchroniser's events since the last step, each on its way (`on_sync_event`)."""
        for event in self._sync.take_events():
            self.on_sync_event(event)

    def on_sync_event(self, event: SyncEvent) -> None:
        """A synchroniser event on /icgt/link_events, once. The autopilot's presence (seen / lost / back /
        rebooted: the one state machine, the synchroniser's) goes under link "mavlink", and to the MAVLink link as
        a hint (its stream rates asked again, TIMESYNC fast again); the rest under "sync"."""
        if event.presence is None:
            self._log.link_event("sync", event.kind, event.detail, event.host_ns, outage_ns=event.outage_ns)
            return
        self._log.link_event("mavlink", event.kind, event.detail, event.host_ns, outage_ns=event.outage_ns)
        if self.link is not None:
            ap = self._sync.autopilot
            self.link.autopilot_hint(event.presence, ap.system, ap.component, event.host_ns)
