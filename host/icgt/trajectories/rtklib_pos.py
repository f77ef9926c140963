"""An RTKLIB ``.pos`` solution (post-processed kinematic, PPK) as a pose source (position only).

Format (RTKLIB 2.4 manual, "solution file"; written by rnx2rtkp, rtkpost, Emlid Studio and the
demo5 fork alike). Header lines start with ``%``. Two of them matter here:

* ``% (lat/lon/height=WGS84/ellipsoidal,Q=1:fix,2:float,3:sbas,4:dgps,5:single,6:ppp,ns=# of satellites)``:
  the datum and the height: ``ellipsoidal`` (above the WGS84 ellipsoid) or ``geodetic`` (above the
  geoid, i.e. mean sea level, from RTKLIB's geoid model). ``x/y/z-ecef`` and ``e/n/u-baseline``
  files are other solution formats, refused here.
* the column line, ``%  GPST  latitude(deg) longitude(deg)  height(m)   Q  ns   sdn(m) ...``: the time
  system (``GPST``, ``UTC`` or ``JST`` = UTC + 9 h) and the angle format (``latitude(deg)``;
  ``latitude(d'")``, degrees minutes seconds, is refused).

Data lines: the time, either ``yyyy/mm/dd hh:mm:ss.sss`` or GPS week and time of week [s]
(``2404 282401.600``), then latitude and longitude [deg], height [m], Q (1 fix, 2 float, 3 SBAS,
4 DGPS, 5 single, 6 PPP), ns (satellites), sdn sde sdu [m] (standard deviations north, east, up),
sdne sdeu sdun [m] (signed square roots of the covariances), age [s] and ratio (the ambiguity
validation ratio), then velocities if they were output. Fields are separated by spaces (or by
the separator ``out-fieldsep`` chose, e.g. commas). Only the first ten fields are needed here.

Time: GPST is converted to UTC by the GPS - UTC leap seconds (`icgt.clocks.gpstime`, 18 s
since 2017); the frames are then looked up by ``mid_utc_us``. An optional ``time_offset_s`` is
added after the conversion.

Position: the antenna's phase centre (RTKLIB applies the antenna height / ARP offsets it was
given; Emlid recommends leaving them at 0). Give the lever arm from that point to the camera
(`icgt.trajectories.regeotag.RegeotagConfig.lever_arm_body_m`) when it is not the recording's.
Ellipsoidal heights become MSL altitudes with the geoid separation N the caller gives
(MSL = h - N); geodetic heights are used as they are. No attitude: a frame keeps its recorded one.

Error bound of a sample: ``sigma_factor`` (3) times sqrt(sdn^2 + sde^2 + sdu^2); the interpolation
terms of `icgt.trajectories.source` are added. PPK solutions come at 1-20 Hz; ``max_gap_s``
(default 1.5 s) limits what is interpolated.
"""

from __future__ import annotations

import calendar
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from icgt.clocks.gpstime import GpsTimeError, gps_seconds_to_utc_s, week_tow_to_utc_s
from icgt.geodesy import LocalFrame
from icgt.trajectories.source import SampledTrajectory, TrajectoryError

__all__ = ["Q_LABELS", "PosOptions", "PosSolution", "read_pos"]

Q_LABELS: dict[int, str] = {
    1: "ppk_fixed",
    2: "ppk_float",
    3: "ppk_sbas",
    4: "ppk_dgps",
    5: "ppk_single",
    6: "ppk_ppp",
}
"""FrameRecord.position_source of a frame placed from a sample of each RTKLIB Q."""

TimeSystem = Literal["GPST", "UTC", "JST"]
HeightKind = Literal["ellipsoidal", "geodetic"]
_DATE_TIME = re.compile(r"^(\d{4})/(\d{1,2})/(\d{1,2})$")
_JST_OFFSET_S = 9 * 3600.0


@dataclass(frozen=True)
class PosOptions:
    geoid_separation_m: float | None = None
    """Geoid height N [m] for ellipsoidal heights (MSL = h - N); not needed for geodetic heights."""
    time_offset_s: float = 0.0
    time_system: TimeSystem | None = None
    """Override (or supply, for a file without the column header) the time system."""
    height: HeightKind | None = None
    """Override (or supply) the height kind."""
    sigma_factor: float = 3.0
    max_gap_s: float = 1.5
    max_accel_m_s2: float = 3.0
    max_q: int = 6
    """Samples of a worse Q than this are left out (5: no single-point fixes; 1: fixes only)."""


@dataclass(frozen=True)
class PosSolution:
    """What the header said and how many samples of each Q were read."""

    time_system: TimeSystem
    height: HeightKind
    time_format: str
    """"calendar" (yyyy/mm/dd hh:mm:ss.sss) or "week_tow"."""
    q_counts: dict[int, int]
    left_out: int
    """Samples with Q above max_q."""


def _header(lines: list[str]) -> tuple[str | None, str | None, bool | None]:
    """(time system, height kind, degrees?) from the % lines; None where the header does not say."""
    time_system = height = None
    degrees: bool | None = None
    for line in lines:
        body = line.lstrip("%").strip()
        m = re.search(r"lat/lon/height=([^/,)]+)/([^,)]+)", body)
        if m:
            height = m.group(2).strip()
            if m.group(1).strip() != "WGS84":
                raise TrajectoryError(f"datum {m.group(1).strip()!r}: only WGS84 solutions are read")
        elif "x/y/z-ecef" in body or "e/n/u-baseline" in body:
            raise TrajectoryError(
                "an ECEF or baseline solution: output lat/lon/height (rtkpost: solution format Lat/Lon/Height)"
            )
        fields = body.split()
        if fields and fields[0] in ("GPST", "UTC", "JST") and "latitude" in body:
            time_system = fields[0]
            degrees = "latitude(deg)" in body
    return time_system, height, degrees


def _utc_s(date: str, clock: str, where: str) -> float:
    m = _DATE_TIME.match(date)
    parts = clock.split(":")
    if m is None or len(parts) != 3:
        raise TrajectoryError(f"{where}: time {date} {clock!r} is not yyyy/mm/dd hh:mm:ss.sss")
    try:
        h, mi, sec = int(parts[0]), int(parts[1]), float(parts[2])
        whole = calendar.timegm((int(m.group(1)), int(m.group(2)), int(m.group(3)), h, mi, 0))
    except (ValueError, OverflowError):
        raise TrajectoryError(f"{where}: time {date} {clock!r} is not a valid date and time") from None
    if not (0 <= h < 24 and 0 <= mi < 60 and 0.0 <= sec < 61.0):
        raise TrajectoryError(f"{where}: time {date} {clock!r} out of range")
    return whole + sec


def read_pos(
    path: str | Path, origin: tuple[float, float, float], options: PosOptions = PosOptions()
) -> tuple[SampledTrajectory, PosSolution]:
    """An RTKLIB .pos file as a pose source in the recording's ENU frame at `origin` (lat, lon, MSL alt)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8", errors="strict")
    except OSError as exc:
        raise TrajectoryError(f"cannot read {p}: {exc.strerror or exc}") from None
    except UnicodeDecodeError as exc:
        raise TrajectoryError(f"{p}: not a text file ({exc.reason} at byte {exc.start})") from None
    lines = text.splitlines()
    try:
        ts_head, h_head, degrees = _header([ln for ln in lines if ln.startswith("%")])
    except TrajectoryError as exc:
        raise TrajectoryError(f"{p}: {exc}") from None
    if degrees is False:
        raise TrajectoryError(f"{p}: latitude/longitude in degrees-minutes-seconds: output decimal degrees")
    time_system = options.time_system or ts_head
    height = options.height or h_head
    if time_system not in ("GPST", "UTC", "JST"):
        raise TrajectoryError(f"{p}: no time system in the header (GPST/UTC/JST): give it (time_system)")
    if height not in ("ellipsoidal", "geodetic"):
        raise TrajectoryError(f"{p}: no height kind in the header (ellipsoidal/geodetic): give it (height)")
    if height == "ellipsoidal" and options.geoid_separation_m is None:
        raise TrajectoryError(
            f"{p}: heights above the ellipsoid need the geoid separation N to become MSL altitudes "
            "(--geoid-separation METRES, or a log with GPS_RAW_INT.alt_ellipsoid)"
        )
    t_list: list[float] = []
    llh: list[tuple[float, float, float]] = []
    sig: list[float] = []
    qs: list[int] = []
    time_format = ""
    left_out = 0
    for number, raw in enumerate(lines, 1):
        line = raw.strip()
        if not line or line.startswith("%"):
            continue
        where = f"{p}:{number}"
        fields = line.replace(",", " ").split()
        if len(fields) < 10:
            raise TrajectoryError(
                f"{where}: {len(fields)} fields, a solution line has at least 10 "
                f"(time time lat lon height Q ns sdn sde sdu): {line[:80]!r}"
            )
        calendar_time = "/" in fields[0]
        fmt = "calendar" if calendar_time else "week_tow"
        if time_format and fmt != time_format:
            raise TrajectoryError(f"{where}: time format changes from {time_format} to {fmt}")
        time_format = fmt
        try:
            if calendar_time:
                t = _utc_s(fields[0], fields[1], where)
                if time_system == "GPST":
                    t = gps_seconds_to_utc_s(t)
                elif time_system == "JST":
                    t -= _JST_OFFSET_S
            else:
                week, tow = int(fields[0]), float(fields[1])
                if week < 0 or not 0.0 <= tow < 604_800.0:
                    raise TrajectoryError(f"{where}: GPS week {week} / time of week {tow} out of range")
                if time_system != "GPST":
                    raise TrajectoryError(f"{where}: a GPS week and time of week in a {time_system} file")
                t = week_tow_to_utc_s(week, tow)
            lat, lon, h = float(fields[2]), float(fields[3]), float(fields[4])
            q, sdn, sde, sdu = int(fields[5]), float(fields[7]), float(fields[8]), float(fields[9])
            int(fields[6])
        except ValueError:
            raise TrajectoryError(f"{where}: not a number where one belongs: {line[:80]!r}") from None
        except GpsTimeError as exc:
            raise TrajectoryError(f"{where}: {exc}") from None
        if not all(math.isfinite(v) for v in (lat, lon, h, sdn, sde, sdu)):
            raise TrajectoryError(f"{where}: a value is not finite: {line[:80]!r}")
        if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            raise TrajectoryError(f"{where}: latitude/longitude out of range ({lat}, {lon})")
        if q not in Q_LABELS:
            raise TrajectoryError(f"{where}: Q = {q}: RTKLIB's solution quality is 1..6")
        if min(sdn, sde, sdu) < 0.0:
            raise TrajectoryError(f"{where}: a negative standard deviation")
        if q > options.max_q:
            left_out += 1
            continue
        t += options.time_offset_s
        if t_list and t <= t_list[-1]:
            raise TrajectoryError(f"{where}: time does not follow the previous line's: times must increase")
        t_list.append(t)
        msl = (
            h - options.geoid_separation_m if height == "ellipsoidal" and options.geoid_separation_m is not None else h
        )
        llh.append((lat, lon, msl))
        sig.append(math.sqrt(sdn * sdn + sde * sde + sdu * sdu))
        qs.append(q)
    if not t_list:
        raise TrajectoryError(f"{p}: no solution lines" + (f" with Q <= {options.max_q}" if left_out else ""))
    frame = LocalFrame(*origin)
    a = np.asarray(llh, dtype=np.float64)
    enu = np.asarray(frame.geodetic_to_enu(a[:, 0], a[:, 1], a[:, 2]), dtype=np.float64)
    counts: dict[int, int] = {}
    for q in qs:
        counts[q] = counts.get(q, 0) + 1
    traj = SampledTrajectory(
        name=f"{p.name} (RTKLIB .pos)",
        time_base="utc",
        t_s=np.asarray(t_list, dtype=np.float64),
        enu_m=enu,
        frame=frame,
        bound_m=np.asarray(sig, dtype=np.float64) * options.sigma_factor,
        labels=[Q_LABELS[q] for q in qs],
        rank=qs,
        max_gap_s=options.max_gap_s,
        max_accel_m_s2=options.max_accel_m_s2,
    )
    return traj, PosSolution(time_system, height, time_format, counts, left_out)  # type: ignore[arg-type]
