"""GPS time (week, time of week) <-> UTC, with the leap seconds between them.

GPS time runs without leap seconds from its epoch 1980-01-06T00:00:00Z; UTC inserts them, so
GPS - UTC grows by one second at each leap second (IERS Bulletin C). The table below holds the
values since 1999; `icgt.clocks.autopilot_clock.GPS_UTC_LEAP_S` (18 s, since 2017-01-01) is the
current one, and no leap second has been announced since. Times before 1999-01-01 are refused
rather than guessed.
"""

from __future__ import annotations

import calendar
import math

from icgt.clocks.autopilot_clock import GPS_EPOCH_UNIX_S, GPS_UTC_LEAP_S
from icgt.errors import IcgtError

__all__ = [
    "SECONDS_PER_WEEK",
    "gps_seconds_to_utc_s",
    "leap_seconds_at_utc",
    "utc_us_to_gps_week_tow_us",
    "week_tow_to_utc_s",
]

SECONDS_PER_WEEK = 604_800

# (UTC instant from which the value holds [s since the Unix epoch], GPS - UTC [s])
_LEAPS: tuple[tuple[int, int], ...] = (
    (calendar.timegm((1999, 1, 1, 0, 0, 0)), 13),
    (calendar.timegm((2006, 1, 1, 0, 0, 0)), 14),
    (calendar.timegm((2009, 1, 1, 0, 0, 0)), 15),
    (calendar.timegm((2012, 7, 1, 0, 0, 0)), 16),
    (calendar.timegm((2015, 7, 1, 0, 0, 0)), 17),
    (calendar.timegm((2017, 1, 1, 0, 0, 0)), GPS_UTC_LEAP_S),
)


class GpsTimeError(IcgtError):
    """A time outside the range whose GPS - UTC leap seconds are known here."""


def leap_seconds_at_utc(utc_s: float) -> int:
    """GPS - UTC [s] at a UTC instant [s since the Unix epoch]."""
    if not math.isfinite(utc_s) or utc_s < _LEAPS[0][0]:
        raise GpsTimeError(f"UTC {utc_s} s is before 1999-01-01 (or not finite): GPS - UTC not tabulated here")
    value = _LEAPS[0][1]
    for start, leap in _LEAPS:
        if utc_s >= start:
            value = leap
    return value


def gps_seconds_to_utc_s(gps_unix_s: float) -> float:
    """GPS time given as seconds on the Unix scale (epoch + week * 604800 + TOW) -> UTC [s since the epoch]."""
    # the leap count is looked up at the UTC instant, which is the GPS instant minus the count itself
    first = leap_seconds_at_utc(gps_unix_s - GPS_UTC_LEAP_S)
    leap = leap_seconds_at_utc(gps_unix_s - first)
    return gps_unix_s - leap


def week_tow_to_utc_s(week: int, tow_s: float) -> float:
    """GPS week and time of week [s] -> UTC [s since the Unix epoch]."""
    return gps_seconds_to_utc_s(GPS_EPOCH_UNIX_S + week * SECONDS_PER_WEEK + tow_s)


def utc_us_to_gps_week_tow_us(utc_us: int) -> tuple[int, int]:
    """UTC [us since the Unix epoch] -> (GPS week, time of week [us]), exact in integers."""
    gps_us = utc_us + (leap_seconds_at_utc(utc_us / 1e6) - GPS_EPOCH_UNIX_S) * 1_000_000
    week, tow_us = divmod(gps_us, SECONDS_PER_WEEK * 1_000_000)
    return int(week), int(tow_us)
