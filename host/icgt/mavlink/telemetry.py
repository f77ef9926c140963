"""Autopilot telemetry as typed samples in SI units, kept per stream (`TelemetryStore`) to interpolate from.

Every sample carries two times: ``boot_us``, the autopilot's own stamp on its boot clock in microseconds
(GPS_RAW_INT.time_usec is boot time on both ArduPilot and PX4; ``time_boot_ms`` fields are multiplied by
1000), and ``host_rx_ns``, time.monotonic_ns() when the host received the message.

Units: angles in degrees for geodetic coordinates, headings and courses; radians and rad/s for attitude;
metres, m/s; altitudes in metres above mean sea level unless named otherwise.

The rule **never a position without a 3D fix** is enforced here, where positions are produced:

* a GPS_RAW_INT with fix_type < 3 (or with an impossible or 0/0 latitude/longitude) yields a `GpsSample`
  with ``usable=False`` and ``lat_deg``/``lon_deg``/``alt_msl_m`` None; the raw integers stay in ``raw_*``;
* a GLOBAL_POSITION_INT is only usable when the autopilot's latest GPS_RAW_INT (within
  ``gps_fix_max_age_s`` on the boot clock) reports a 3D fix or better; otherwise its position fields are
  None in the same way. Its relative altitude and velocities are kept either way (baro and EKF).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

from icgt.mavlink.gimbal import GimbalSample
from icgt.mavlink.sample_codec import PACKED_SAMPLE_BYTES, SampleCodec
from icgt.mavlink.telemetry_buffer import TelemetryBuffer

if TYPE_CHECKING:
    from icgt.mavlink.link import MavlinkMessage

__all__ = [
    "GPS_FIX_3D",
    "MAX_STREAM_RATE_HZ",
    "SAMPLE_BYTES",
    "TELEMETRY_TYPES",
    "AttitudeSample",
    "FusedPositionSample",
    "GpsSample",
    "LocalPositionSample",
    "Sample",
    "SystemTimeSample",
    "TelemetryBuffer",
    "TelemetryStore",
    "attitude_sample",
    "euler_to_quaternion",
    "fused_position_sample",
    "gps_sample",
    "local_position_sample",
    "quaternion_to_euler",
    "system_time_sample",
]

GPS_FIX_3D = 3
_UINT16_MAX = 0xFFFF
_UINT8_MAX = 0xFF

TELEMETRY_TYPES = frozenset(
    {
        "GPS_RAW_INT",
        "GLOBAL_POSITION_INT",
        "ATTITUDE",
        "ATTITUDE_QUATERNION",
        "LOCAL_POSITION_NED",
        "SYSTEM_TIME",
        "GPS_GLOBAL_ORIGIN",
    }
)
MAX_STREAM_RATE_HZ = 100.0  # per stream: the most samples a second `TelemetryStore.retain` keeps room for
# Memory per buffered sample [bytes]: samples are held packed (`icgt.mavlink.sample_codec`, measured there).
SAMPLE_BYTES = PACKED_SAMPLE_BYTES
LOCAL_RESET_SPEED_MARGIN_MPS = 5.0  # a local position moving faster than its own velocity by this ...
LOCAL_RESET_MIN_JUMP_M = 2.0  # ... and by at least this far between two samples is an origin reset


@dataclasses.dataclass(frozen=True, slots=True)
class GpsSample:
    """GPS_RAW_INT. Position fields are None unless ``usable`` (fix_type >= 3 and a plausible position)."""

    boot_us: int
    host_rx_ns: int
    fix_type: int  # 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    usable: bool
    lat_deg: float | None
    lon_deg: float | None
    alt_msl_m: float | None
    alt_ellipsoid_m: float | None  # None when the autopilot leaves it 0 (MAVLink 1 frames always do)
    raw_lat_e7: int
    raw_lon_e7: int
    raw_alt_mm: int
    h_acc_m: float | None  # None when not reported (0)
    v_acc_m: float | None
    vel_acc_mps: float | None
    eph: float | None  # HDOP (unitless), None when unknown
    epv: float | None  # VDOP (unitless), None when unknown
    vel_mps: float | None  # ground speed
    cog_deg: float | None  # course over ground, 0..360
    satellites: int | None
    yaw_deg: float | None  # dual-antenna yaw, None when not provided


@dataclasses.dataclass(frozen=True, slots=True)
class FusedPositionSample:
    """GLOBAL_POSITION_INT, the autopilot's fused estimate. Position fields are None unless ``usable``."""

    boot_us: int
    host_rx_ns: int
    usable: bool
    lat_deg: float | None
    lon_deg: float | None
    alt_msl_m: float | None
    relative_alt_m: float  # above home
    raw_lat_e7: int
    raw_lon_e7: int
    raw_alt_mm: int
    vn_mps: float  # velocity north, east, down
    ve_mps: float
    vd_mps: float
    heading_deg: float | None  # None when unknown


@dataclasses.dataclass(frozen=True, slots=True)
class AttitudeSample:
    """ATTITUDE or ATTITUDE_QUATERNION: rotation body -> NED as a unit quaternion (w, x, y, z)."""

    boot_us: int
    host_rx_ns: int
    q_wxyz: tuple[float, float, float, float]
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rollspeed_rps: float  # body rates, rad/s
    pitchspeed_rps: float
    yawspeed_rps: float
    source: str  # "ATTITUDE" or "ATTITUDE_QUATERNION"


@dataclasses.dataclass(frozen=True, slots=True)
class LocalPositionSample:
    """LOCAL_POSITION_NED: position (m) and velocity (m/s) in the autopilot's local NED frame."""

    boot_us: int
    host_rx_ns: int
    x_m: float
    y_m: float
    z_m: float
    vx_mps: float
    vy_mps: float
    vz_mps: float
    epoch: int = 0  # counts the local frame's origin resets: positions of different epochs do not compare


@dataclasses.dataclass(frozen=True, slots=True)
class SystemTimeSample:
    """SYSTEM_TIME. ``unix_us`` is None while the autopilot has no UTC (it sends 0 then)."""

    boot_us: int
    host_rx_ns: int
    boot_ms: int
    unix_us: int | None


Sample = GpsSample | FusedPositionSample | AttitudeSample | LocalPositionSample | SystemTimeSample


# ---------------------------------------------------------------------------- conversions
def _finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _plausible_position(lat_e7: int, lon_e7: int) -> bool:
    return (lat_e7, lon_e7) != (0, 0) and abs(lat_e7) <= 900_000_000 and abs(lon_e7) <= 1_800_000_000


def _u16(value: int, scale: float) -> float | None:
    return None if value == _UINT16_MAX else value * scale


def _positive(value: int, scale: float) -> float | None:
    return value * scale if value > 0 else None


def gps_sample(msg: Any, host_rx_ns: int) -> GpsSample:
    """Convert a GPS_RAW_INT (MAVLink 1 or 2; missing MAVLink 2 extensions read as 'not reported')."""
    fix_type = int(msg.fix_type)
    lat, lon, alt = int(msg.lat), int(msg.lon), int(msg.alt)
    usable = fix_type >= GPS_FIX_3D and _plausible_position(lat, lon)
    alt_ell = int(getattr(msg, "alt_ellipsoid", 0))
    yaw = int(getattr(msg, "yaw", 0))
    return GpsSample(
        boot_us=int(msg.time_usec),
        host_rx_ns=host_rx_ns,
        fix_type=fix_type,
        usable=usable,
        lat_deg=lat * 1e-7 if usable else None,
        lon_deg=lon * 1e-7 if usable else None,
        alt_msl_m=alt * 1e-3 if usable else None,
        alt_ellipsoid_m=alt_ell * 1e-3 if usable and alt_ell != 0 else None,
        raw_lat_e7=lat,
        raw_lon_e7=lon,
        raw_alt_mm=alt,
        h_acc_m=_positive(int(getattr(msg, "h_acc", 0)), 1e-3),
        v_acc_m=_positive(int(getattr(msg, "v_acc", 0)), 1e-3),
        vel_acc_mps=_positive(int(getattr(msg, "vel_acc", 0)), 1e-3),
        eph=_u16(int(msg.eph), 0.01),
        epv=_u16(int(msg.epv), 0.01),
        vel_mps=_u16(int(msg.vel), 0.01),
        cog_deg=_u16(int(msg.cog), 0.01),
        satellites=None if int(msg.satellites_visible) == _UINT8_MAX else int(msg.satellites_visible),
        yaw_deg=None if yaw in (0, _UINT16_MAX) else (yaw % 36000) * 0.01,
    )


def fused_position_sample(msg: Any, host_rx_ns: int, gps_fix_ok: bool) -> FusedPositionSample:
    """Convert a GLOBAL_POSITION_INT. ``gps_fix_ok``: the autopilot currently reports a 3D GPS fix."""
    lat, lon, alt = int(msg.lat), int(msg.lon), int(msg.alt)
    usable = gps_fix_ok and _plausible_position(lat, lon)
    return FusedPositionSample(
        boot_us=int(msg.time_boot_ms) * 1000,
        host_rx_ns=host_rx_ns,
        usable=usable,
        lat_deg=lat * 1e-7 if usable else None,
        lon_deg=lon * 1e-7 if usable else None,
        alt_msl_m=alt * 1e-3 if usable else None,
        relative_alt_m=int(msg.relative_alt) * 1e-3,
        raw_lat_e7=lat,
        raw_lon_e7=lon,
        raw_alt_mm=alt,
        vn_mps=int(msg.vx) * 0.01,
        ve_mps=int(msg.vy) * 0.01,
        vd_mps=int(msg.vz) * 0.01,
        heading_deg=_u16(int(msg.hdg), 0.01),
    )


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Aerospace Z-Y-X Euler angles (rad) to the body -> NED quaternion (w, x, y, z)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def quaternion_to_euler(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """The body -> NED quaternion (w, x, y, z) to aerospace Z-Y-X Euler angles (roll, pitch, yaw) in rad."""
    w, x, y, z = q
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def attitude_sample(msg: Any, host_rx_ns: int) -> AttitudeSample | None:
    """Convert an ATTITUDE or ATTITUDE_QUATERNION; None if its values are not finite or not a rotation.

    ATTITUDE_QUATERNION.repr_offset_q (a display offset for tailsitters) is not applied."""
    mtype = str(msg.get_type())
    rates = (float(msg.rollspeed), float(msg.pitchspeed), float(msg.yawspeed))
    if mtype == "ATTITUDE_QUATERNION":
        raw = (float(msg.q1), float(msg.q2), float(msg.q3), float(msg.q4))
        if not _finite(*raw):
            return None
        norm = math.sqrt(sum(c * c for c in raw))
        if not 0.5 < norm < 1.5:
            return None
        q = (raw[0] / norm, raw[1] / norm, raw[2] / norm, raw[3] / norm)
        if q[0] < 0:  # one hemisphere, so neighbouring samples interpolate the short way
            q = (-q[0], -q[1], -q[2], -q[3])
        roll, pitch, yaw = quaternion_to_euler(q)
    elif mtype == "ATTITUDE":
        roll, pitch, yaw = float(msg.roll), float(msg.pitch), float(msg.yaw)
        if not _finite(roll, pitch, yaw):
            return None
        q = euler_to_quaternion(roll, pitch, yaw)
        if q[0] < 0:
            q = (-q[0], -q[1], -q[2], -q[3])
    else:
        raise ValueError(f"not an attitude message: {mtype}")
    if not _finite(*rates):
        return None
    return AttitudeSample(
        boot_us=int(msg.time_boot_ms) * 1000,
        host_rx_ns=host_rx_ns,
        q_wxyz=q,
        roll_rad=roll,
        pitch_rad=pitch,
        yaw_rad=yaw,
        rollspeed_rps=rates[0],
        pitchspeed_rps=rates[1],
        yawspeed_rps=rates[2],
        source=mtype,
    )


def local_position_sample(msg: Any, host_rx_ns: int) -> LocalPositionSample | None:
    """Convert a LOCAL_POSITION_NED; None if a value is not finite."""
    values = (float(msg.x), float(msg.y), float(msg.z), float(msg.vx), float(msg.vy), float(msg.vz))
    if not _finite(*values):
        return None
    return LocalPositionSample(int(msg.time_boot_ms) * 1000, host_rx_ns, *values)


def system_time_sample(msg: Any, host_rx_ns: int) -> SystemTimeSample:
    """Convert a SYSTEM_TIME; ``unix_us`` None when the autopilot sends 0 (no UTC yet)."""
    boot_ms = int(msg.time_boot_ms)
    unix = int(msg.time_unix_usec)
    return SystemTimeSample(boot_ms * 1000, host_rx_ns, boot_ms, unix if unix > 0 else None)


class TelemetryStore:
    """Converts the autopilot's telemetry into samples and keeps one `TelemetryBuffer` per stream.

    Only messages from ``autopilot_system`` (and ``autopilot_component``, unless None) are taken.
    It is fed (`ingest`) and read on one thread, the synchroniser's: it takes no locks.
    ``on_sample`` (optional) sees every sample produced, on the same thread: keep it non-blocking.
    SYSTEM_TIME with time_unix_usec 0 is counted and not stored.

    How long samples are kept: ``retention_s`` on the autopilot's boot clock (a frame that comes back
    that late through the device's RESEND is still posed from the telemetry that arrived on time; the
    synchroniser sets it to the device's history horizon, `icgt.device.history`), and at most
    ``retention_s * MAX_STREAM_RATE_HZ`` samples per stream. Memory: about `SAMPLE_BYTES` per sample
    held, so at most ``6 * MAX_STREAM_RATE_HZ * retention_s * SAMPLE_BYTES * 1.25`` (the 1.25: trimmed
    entries are deleted in batches); `memory_bytes` estimates what is held now. The samples are held packed
    (`icgt.mavlink.sample_codec`, a third of the objects' memory). At 5 fps (retention 742.7 s) that bound is
    119 MiB (all six streams at 100 Hz); the simulated flights send about 180 samples/s in all (the rates the
    recorder asks for): 29-36 MiB once the retention is reached (benchmarks/soak.py). With ``retention_s``
    None, ``capacity`` samples per stream and no time bound (the buffers' own default).
    """

    def __init__(
        self,
        *,
        autopilot_system: int = 1,
        autopilot_component: int | None = 1,
        capacity: int = 4096,
        retention_s: float | None = None,
        gps_fix_max_age_s: float = 2.0,
        on_sample: Callable[[Sample], None] | None = None,
    ) -> None:
        self.autopilot_system = autopilot_system
        self.autopilot_component = autopilot_component
        # Held packed (`icgt.mavlink.sample_codec`): the retention spans the device's history horizon.
        self.gps: TelemetryBuffer[GpsSample] = TelemetryBuffer(capacity, codec=SampleCodec(GpsSample))
        self.fused: TelemetryBuffer[FusedPositionSample] = TelemetryBuffer(
            capacity, codec=SampleCodec(FusedPositionSample)
        )
        attitude_codec = SampleCodec(AttitudeSample)
        self.attitude: TelemetryBuffer[AttitudeSample] = TelemetryBuffer(capacity, codec=attitude_codec)
        self.attitude_quaternion: TelemetryBuffer[AttitudeSample] = TelemetryBuffer(capacity, codec=attitude_codec)
        self.local_position: TelemetryBuffer[LocalPositionSample] = TelemetryBuffer(
            capacity, codec=SampleCodec(LocalPositionSample)
        )
        self.system_time: TelemetryBuffer[SystemTimeSample] = TelemetryBuffer(
            capacity, codec=SampleCodec(SystemTimeSample)
        )
        # GIMBAL_DEVICE_ATTITUDE_STATUS, stamped by the synchroniser (`icgt.mavlink.gimbal`): not by `ingest`
        self.gimbal: TelemetryBuffer[GimbalSample] = TelemetryBuffer(capacity, codec=SampleCodec(GimbalSample))
        self.retention_s: float | None = None
        if retention_s is not None:
            self.retain(retention_s)
        self._gps_fix_max_age_us = int(gps_fix_max_age_s * 1e6)
        self._on_sample = on_sample
        self._last_gps: GpsSample | None = None
        self._counts: dict[str, int] = {
            "samples": 0,
            "invalid": 0,
            "gps_no_fix": 0,
            "fused_unusable": 0,
            "system_time_without_utc": 0,
            "other_source": 0,
            "local_origin_resets": 0,
        }
        self._local_epoch = 0
        self._origin: tuple[int, int, int] | None = None
        self._origin_moved = False

    def buffers(self) -> tuple[TelemetryBuffer[Any], ...]:
        return (
            self.gps,
            self.fused,
            self.attitude,
            self.attitude_quaternion,
            self.local_position,
            self.system_time,
            self.gimbal,
        )

    def retain(self, retention_s: float) -> None:
        """Keep every stream's samples for ``retention_s`` [s] of boot clock (see the class doc for the bound)."""
        if not retention_s > 0:
            raise ValueError(f"retention_s must be positive, not {retention_s}")
        self.retention_s = retention_s
        capacity = max(2, math.ceil(retention_s * MAX_STREAM_RATE_HZ))
        for buf in self.buffers():
            buf.set_bounds(capacity, int(retention_s * 1e6))

    def memory_bytes(self) -> int:
        """An estimate of the memory the samples held take: `SAMPLE_BYTES` per sample (measured, see there)."""
        return sum(buf.held for buf in self.buffers()) * SAMPLE_BYTES

    def counts(self) -> dict[str, int]:
        return dict(self._counts)

    def count_other_source(self, mtype: str) -> None:
        """A message of another system than the autopilot's: counted as `ingest` counts it, nothing stored."""
        if mtype in TELEMETRY_TYPES:
            self._count("other_source")

    def count_other_sources(self, type_counts: Mapping[str, int]) -> None:
        """`count_other_source` for many messages at once: ``type_counts`` maps message type -> how many."""
        n = sum(k for mtype, k in type_counts.items() if mtype in TELEMETRY_TYPES)
        if n:
            self._counts["other_source"] += n

    def _count(self, key: str) -> None:
        self._counts[key] += 1

    @property
    def last_gps(self) -> GpsSample | None:
        return self._last_gps

    def _gps_fix_ok(self, boot_us: int) -> bool:
        gps = self._last_gps
        return gps is not None and gps.fix_type >= GPS_FIX_3D and abs(boot_us - gps.boot_us) <= self._gps_fix_max_age_us

    def _local_jumped(self, s: LocalPositionSample) -> bool:
        """A local position farther from the previous one than its velocity allows: the EKF reset its origin."""
        last = self.local_position.latest()
        if last is None or s.boot_us <= last.boot_us:
            return False
        dt = (s.boot_us - last.boot_us) / 1e6
        moved = math.dist((s.x_m, s.y_m, s.z_m), (last.x_m, last.y_m, last.z_m))
        speed = max(math.hypot(s.vx_mps, s.vy_mps, s.vz_mps), math.hypot(last.vx_mps, last.vy_mps, last.vz_mps))
        return moved > max(LOCAL_RESET_MIN_JUMP_M, (speed + LOCAL_RESET_SPEED_MARGIN_MPS) * dt)

    def ingest(self, rec: MavlinkMessage) -> Sample | None:
        """Convert and store one message; returns the sample (None if not telemetry or not stored)."""
        if rec.src_system != self.autopilot_system or (
            self.autopilot_component is not None and rec.src_component != self.autopilot_component
        ):
            if rec.type in TELEMETRY_TYPES:
                self._count("other_source")
            return None
        msg, rx = rec.msg, rec.rx_ns
        mtype = rec.type
        sample: Sample | None
        if mtype == "GPS_RAW_INT":
            gps = gps_sample(msg, rx)
            self._last_gps = gps
            self.gps.push(gps)
            if not gps.usable:
                self._count("gps_no_fix")
            sample = gps
        elif mtype == "GLOBAL_POSITION_INT":
            fused = fused_position_sample(msg, rx, self._gps_fix_ok(int(msg.time_boot_ms) * 1000))
            self.fused.push(fused)
            if not fused.usable:
                self._count("fused_unusable")
            sample = fused
        elif mtype in ("ATTITUDE", "ATTITUDE_QUATERNION"):
            att = attitude_sample(msg, rx)
            if att is None:
                self._count("invalid")
                return None
            (self.attitude if mtype == "ATTITUDE" else self.attitude_quaternion).push(att)
            sample = att
        elif mtype == "LOCAL_POSITION_NED":
            local = local_position_sample(msg, rx)
            if local is None:
                self._count("invalid")
                return None
            if self._origin_moved:
                self._origin_moved = False  # the jump that follows an announced origin change is that change
            elif self._local_jumped(local):
                self._local_epoch += 1
                self._count("local_origin_resets")
            local = dataclasses.replace(local, epoch=self._local_epoch)
            self.local_position.push(local)
            sample = local
        elif mtype == "GPS_GLOBAL_ORIGIN":
            origin = (int(msg.latitude), int(msg.longitude), int(msg.altitude))
            if self._origin is not None and origin != self._origin:
                self._local_epoch += 1  # the EKF moved its origin: local positions restart from it
                self._origin_moved = True
                self._count("local_origin_resets")
            self._origin = origin
            return None
        elif mtype == "SYSTEM_TIME":
            st = system_time_sample(msg, rx)
            if st.unix_us is None:
                self._count("system_time_without_utc")
                return None
            self.system_time.push(st)
            sample = st
        else:
            return None
        self._count("samples")
        if self._on_sample is not None:
            self._on_sample(sample)
        return sample
