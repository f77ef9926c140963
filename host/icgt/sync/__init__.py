"""The synchroniser core: one I/O-free object fed by the live recorder and by the offline recompute."""

from icgt.sync.synchroniser import SyncConfig, SyncEvent, Synchroniser
from icgt.sync.timesync import TimesyncPairing, TimesyncReply

__all__ = ["SyncConfig", "SyncEvent", "Synchroniser", "TimesyncPairing", "TimesyncReply"]
