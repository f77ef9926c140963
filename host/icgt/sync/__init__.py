"""The synchroniser core: one I/O-free object fed by the live recorder and by the offline recompute."""

from icgt.sync.config import SyncConfig, SyncTuning
from icgt.sync.synchroniser import SyncEvent, Synchroniser
from icgt.sync.timesync import TimesyncPairing, TimesyncReply

__all__ = ["SyncConfig", "SyncEvent", "SyncTuning", "Synchroniser", "TimesyncPairing", "TimesyncReply"]
