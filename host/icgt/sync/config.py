"""The synchroniser's settings, declared once with msgspec (stored in each log as JSON, metadata icgt.sync).

`SyncTuning` is what a user may set in the recorder's config file, section [sync]; `SyncConfig` adds what the
recorder derives from its other sections (the camera, the vehicle's system id, whether signing is on). Every
time is in seconds (`_s`). A log written before a setting was renamed is read with the old value converted
(`icgt.geotag.config.RENAMED`); a setting this version does not know is ignored with a warning that names it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Annotated, Any

import msgspec
from msgspec import Meta

from icgt.geotag.config import GeotagConfig, migrate

__all__ = ["RENAMED", "SyncConfig", "SyncTuning"]

log = logging.getLogger(__name__)

RENAMED: dict[str, tuple[str, float]] = {"one_way_min_delay_allowance_ms": ("one_way_min_delay_allowance_s", 1e-3)}
"""Old name -> (new name, factor) of the synchroniser's own settings (the camera's: `icgt.geotag.config`)."""


class SyncTuning(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """The synchroniser's rules a user may tune (the recorder's config file, [sync])."""

    # None: the first HEARTBEAT of a flight controller of the vehicle's system names the autopilot's component.
    autopilot_component: Annotated[int, Meta(ge=1, le=255)] | None = None
    # Silence after which the autopilot counts as gone (and back, or rebooted, when heard again).
    autopilot_timeout_s: Annotated[float, Meta(gt=0.0, le=600.0)] = 3.0
    timesync_timeout_s: Annotated[float, Meta(gt=0.0, le=60.0)] = 1.0  # an unanswered request is forgotten
    # Without TIMESYNC answers the autopilot clock comes from message arrival times; this bounds the
    # link's minimum delay, which one-way timing cannot see (companion UART/UDP: < 1 ms; radios: more).
    one_way_min_delay_allowance_s: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.002
    # How long autopilot telemetry is kept [s of boot clock]; None: the device's history horizon at the rates
    # its DEVICE_STATE reports (at 5 fps before it has, `icgt.device.history`). Never shorter than that.
    telemetry_retention_s: Annotated[float, Meta(gt=0.0, le=86_400.0)] | None = None


class SyncConfig(SyncTuning, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Everything that decides what the synchroniser makes of its inputs."""

    geotag: GeotagConfig = msgspec.field(default_factory=GeotagConfig)
    autopilot_system: Annotated[int, Meta(ge=1, le=255)] = 1  # the vehicle's MAVLink system id
    # With MAVLink signing configured: a message with the autopilot's system id whose signature was not valid
    # (unsigned, another key, replayed) is not believed (counted as autopilot_unsigned_messages).
    require_signed_autopilot: bool = False

    @classmethod
    def of(
        cls, tuning: SyncTuning, geotag: GeotagConfig, *, autopilot_system: int, require_signed_autopilot: bool
    ) -> SyncConfig:
        """The recorder's settings: [sync] as given, with what the other sections decide."""
        return cls(
            **msgspec.structs.asdict(tuning),
            geotag=geotag,
            autopilot_system=autopilot_system,
            require_signed_autopilot=require_signed_autopilot,
        )

    def to_json(self) -> dict[str, Any]:
        """Plain JSON values (tuples as lists), as stored in the log; `from_json` reads them back."""
        out: dict[str, Any] = msgspec.to_builtins(self)
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> SyncConfig:
        """A log's stored settings: old names converted, unknown ones ignored (and named in a warning),
        missing ones at their defaults. ValueError if a value is not of its type or out of its range."""
        top = migrate(data, RENAMED)
        geotag = migrate(dict(top.get("geotag") or {}))
        unknown = [k for k in top if k not in cls.__struct_fields__]
        unknown += [f"geotag.{k}" for k in geotag if k not in GeotagConfig.__struct_fields__]
        if unknown:
            log.warning("stored synchroniser settings not known to this version, ignored: %s", ", ".join(unknown))
        known = {k: v for k, v in top.items() if k in cls.__struct_fields__ and k != "geotag"}
        known["geotag"] = {k: v for k, v in geotag.items() if k in GeotagConfig.__struct_fields__}
        try:
            return msgspec.convert(known, cls)
        except msgspec.ValidationError as exc:
            raise ValueError(str(exc)) from None
