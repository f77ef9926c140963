"""Geotag every exposure at mid-exposure: time on three clocks, pose interpolated, quality flagged.

The geotagger holds exposures until the autopilot sample that follows mid-exposure has
arrived (position and attitude are interpolated between the samples on either side, not
copied from the latest one as PX4 and ArduPilot do), then emits a FrameRecord. If the later
sample does not come within `max_wait_s` the frame is emitted anyway, held from the earlier
sample and flagged, so nothing is ever dropped.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from icgt.errors import IcgtError
from icgt.geodesy import LocalFrame, q_slerp, q_to_euler_zyx
from icgt.geotag import parts
from icgt.geotag.board_imu import HeadingWindow, board_at, board_in_ned, heading_offset_rad
from icgt.geotag.bounds import MotionAllowance
from icgt.geotag.config import GeotagConfig
from icgt.geotag.gimbal_pose import gimbal_at
from icgt.geotag.position import PoseGap, PositionEstimate, PositionRules, estimate_position
from icgt.geotag.record import FrameFlag, FrameRecord, SensorSource
from icgt.geotag.snapshot import SNAPSHOT_AGE_SATURATED_US, ImuAtMid, snapshot_imu, snapshot_range_valid
from icgt.mavlink.telemetry import (
    AttitudeSample,
    TelemetryBuffer,
    TelemetryStore,
)
from icgt.pose import CameraFields, CameraMounting, camera_fields
from icgt.protocol.messages import Exposure, ExposureFlags, Imu, Range, RangeFlags

GPS_FIX_3D = 3


_NEVER_US = 1 << 62  # a backstep no device clock makes
IMU_SAMPLES_KEPT = 2048  # device IMU samples held (see Geotagger.__init__)
RANGE_SAMPLES_KEPT = 4096  # device range samples held


_RANGE_VALID = int(RangeFlags.VALID)


def _boot_us(s: DeviceSample) -> int:
    return s.boot_us


def _valid_range(s: DeviceSample) -> bool:
    """A RANGE sample flagged valid (the flag tested as an int: IntFlag's & costs a microsecond)."""
    msg = s.msg
    return isinstance(msg, Range) and bool(msg.flags & _RANGE_VALID)


class DeviceClock(Protocol):
    """Device clock [us] -> host CLOCK_MONOTONIC [ns] (icgt.clocks.DeviceClockFilter)."""

    def device_to_host_ns(self, device_us: float) -> int: ...
    def host_to_device_us(self, host_ns: int) -> float: ...
    def uncertainty_ns(self, device_us: float) -> int: ...
    @property
    def settled(self) -> bool: ...


class AutopilotClock(Protocol):
    """Host CLOCK_MONOTONIC [ns] -> autopilot boot clock [us], the method that mapped it and its bound."""

    def host_to_autopilot_us(self, host_ns: int) -> float | None: ...
    def method(self) -> str: ...
    def uncertainty_us(self, boot_us: float) -> float | None: ...


class UtcSource(Protocol):
    """Device clock [us] -> UTC [us] with an uncertainty and the name of the source."""

    def utc_at(self, device_us: float, host_ns: int) -> tuple[int, float, str] | None: ...


@dataclass(frozen=True, slots=True)
class DeviceSample:
    """An IMU or range sample keyed on the device clock (TelemetryBuffer keys on `boot_us`)."""

    boot_us: int  # the device clock counts from the device's boot
    msg: Imu | Range


@dataclass
class _Pending:
    seq: int
    exposure: Exposure
    rx_host_ns: int
    mid_device_us: int
    start_device_us: int
    flags: list[str] = field(default_factory=list)


class Geotagger:
    """Pairs device exposures with autopilot telemetry. Single-threaded: the synchroniser feeds and polls it."""

    def __init__(
        self,
        telemetry: TelemetryStore,
        device_clock: DeviceClock,
        autopilot_clock: AutopilotClock,
        utc: UtcSource,
        config: GeotagConfig,
        emit: Callable[[FrameRecord], None],
    ) -> None:
        self._tm = telemetry
        self._dev = device_clock
        self._ap = autopilot_clock
        self._utc = utc
        self._cfg = config
        # The configuration's seconds in the units the checks below compare with.
        self._max_wait_ms = config.max_wait_s * 1e3
        self._max_clock_uncertainty_ns = round(config.max_clock_uncertainty_s * 1e9)
        self._range_window_us = round(config.range_stale_s * 1e6)
        self._emit = emit
        self._mounting = CameraMounting.of(config)
        self._rules = PositionRules(
            max_gps_gap_s=config.max_gps_gap_s,
            max_accel_m_s2=config.max_accel_m_s2,
            local_drift_m_per_s=config.local_drift_m_per_s,
            max_interpolation_gap_s=config.max_interpolation_gap_s,
            max_extrapolation_m=config.max_extrapolation_m,
            allowance=MotionAllowance(
                config.unseen_accel_h_m_s2, config.unseen_accel_v_m_s2, config.unseen_rate_rad_s2
            ),
        )
        self._lever_m = self._mounting.lever_arm_m
        self._heading_window = HeadingWindow(
            window_s=config.board_imu_heading_window_s,
            points=32,
            max_yaw_rate_rad_s=math.radians(config.board_imu_max_yaw_rate_deg_s),
            min_points=8,
        )
        # Device samples come back late after a gap (RESEND): a sample from before the newest one is
        # inserted in place, never taken for a reboot (the synchroniser clears them on a device reboot).
        # Room for what the device resends (its IMU and range rings: 512 and 1024 samples) beside what came
        # live since the reconnect: 20 s at 100 Hz of IMU, 8 s at 500 Hz of range (about 1.5 MiB in all).
        self._imu: TelemetryBuffer[DeviceSample] = TelemetryBuffer(IMU_SAMPLES_KEPT, reboot_backstep_us=_NEVER_US)
        self._range: TelemetryBuffer[DeviceSample] = TelemetryBuffer(RANGE_SAMPLES_KEPT, reboot_backstep_us=_NEVER_US)
        self._pending: deque[_Pending] = deque()
        self._seq = 0
        self._frame: LocalFrame | None = LocalFrame(*config.origin) if config.origin else None
        self.origin: tuple[float, float, float] | None = config.origin

    # ------------------------------------------------------------------ inputs
    def add_imu(self, imu: Imu) -> None:
        self._imu.push(DeviceSample((imu.read_start_t_us + imu.read_end_t_us) // 2, imu))

    def add_range(self, rng: Range) -> None:
        self._range.push(DeviceSample(rng.acq_start_t_us, rng))

    def clear_device_samples(self) -> None:
        """The device rebooted: its clock restarted, the IMU and range samples held mean nothing now."""
        self._imu.clear()
        self._range.clear()

    def add_exposure(self, exposure: Exposure, rx_host_ns: int, *, resent: bool = False) -> None:
        """An exposure as received; ``resent``: it came through RESEND (the frame carried the retransmit flag)."""
        flags: list[str] = [FrameFlag.RESENT.value] if resent else []
        if exposure.feedback_start_t_us and exposure.feedback_end_t_us:
            start = exposure.feedback_start_t_us
            mid = start + (exposure.feedback_end_t_us - start) // 2
        elif exposure.feedback_start_t_us:
            start = mid = exposure.feedback_start_t_us
        else:
            start = mid = exposure.trigger_t_us
            flags.append(FrameFlag.NO_FEEDBACK.value)
        if exposure.flags & ExposureFlags.FEEDBACK_MISSING:
            flags.append(FrameFlag.FEEDBACK_MISSING.value)
        if exposure.flags & ExposureFlags.UNSOLICITED:
            flags.append(FrameFlag.UNSOLICITED.value)
        self._seq += 1
        self._pending.append(_Pending(self._seq, exposure, rx_host_ns, mid, start, flags))

    # ------------------------------------------------------------------ output
    def poll(self, now_host_ns: int, *, flush: bool = False) -> int:
        """Emit every pending frame whose later pose sample has arrived or whose wait ran out.

        `flush` emits everything (at shutdown). Returns the number emitted."""
        emitted = 0
        while True:
            if not self._pending:
                return emitted
            p = self._pending[0]
            mid_host_ns = self._mid_host_ns(p)
            waited_ms = (now_host_ns - mid_host_ns) / 1e6
            if not (flush or waited_ms >= self._wait_limit_ms(mid_host_ns) or self._later_samples_arrived(mid_host_ns)):
                return emitted
            record = self._build(p, mid_host_ns, now_host_ns)
            self._pending.popleft()
            self._emit(record)
            emitted += 1

    @property
    def pending(self) -> int:
        return len(self._pending)

    # ------------------------------------------------------------------ internals
    def _mid_host_ns(self, p: _Pending) -> int:
        # Before the first accepted exchange there is no mapping at all: the arrival time is the
        # best guess (milliseconds late), and the frame says so (clock_unsynced).
        try:
            return self._dev.device_to_host_ns(p.mid_device_us)
        except IcgtError:
            return p.rx_host_ns

    def _later_samples_arrived(self, mid_host_ns: int) -> bool:
        mid_boot = self._ap.host_to_autopilot_us(mid_host_ns)
        if mid_boot is None:
            return False
        fused = self._tm.fused.latest()
        att = self._attitude_buffer().latest()
        if self._cfg.attitude_source == "gimbal":
            gimbal = self._tm.gimbal.latest()
            if gimbal is None or gimbal.boot_us < mid_boot:
                return False
        if self._cfg.attitude_source == "board_imu":
            imu = self._imu.latest()
            if imu is None or imu.boot_us < self._dev_us(mid_host_ns):
                return False
        return fused is not None and fused.boot_us >= mid_boot and att is not None and att.boot_us >= mid_boot

    def _wait_limit_ms(self, mid_host_ns: int) -> float:
        """How long a frame may wait for the position sample after it: ``max_wait_s``, or longer while the
        last usable GPS sample is recent enough to be interpolated from (a 1-2 Hz stream: its next sample
        is up to ``max_gps_gap_s`` away, and holding the frame beats placing it by the local position)."""
        limit = self._max_wait_ms
        latest = self._tm.fused.latest()
        mid_boot = self._ap.host_to_autopilot_us(mid_host_ns)
        if latest is not None and latest.usable and mid_boot is not None and latest.boot_us <= mid_boot:
            gap_ms = self._cfg.max_gps_gap_s * 1000.0
            if (mid_boot - latest.boot_us) / 1000.0 < gap_ms:
                limit = max(limit, gap_ms + self._max_wait_ms)
        return limit

    def _attitude_buffer(self) -> TelemetryBuffer[AttitudeSample]:
        # ATTITUDE_QUATERNION carries the estimator's quaternion without the Euler round trip.
        return self._tm.attitude_quaternion if len(self._tm.attitude_quaternion) else self._tm.attitude

    def _build(self, p: _Pending, mid_host_ns: int, now_host_ns: int) -> FrameRecord:
        """The frame record, from its parts: timing, position, attitude, IMU, range and the camera rule."""
        e = p.exposure
        flags = list(p.flags)
        unc_ns = self._device_uncertainty_ns(p.mid_device_us, flags)
        utc = self._utc.utc_at(p.mid_device_us, mid_host_ns)
        if utc is None:
            flags.append(FrameFlag.NO_UTC.value)
        mid_boot = self._ap.host_to_autopilot_us(mid_host_ns)
        ap_unc = self._ap.uncertainty_us(mid_boot) if mid_boot is not None else None

        placed = self._position(mid_boot, flags)
        pos = placed if isinstance(placed, PositionEstimate) else None
        if placed is None and mid_boot is not None and self._telemetry_expired(mid_boot):
            flags.append(FrameFlag.TELEMETRY_EXPIRED.value)
        att = self._attitude(mid_boot, flags)
        imu = self._imu_at(p.mid_device_us, e, flags)
        rng = self._range_at(p.mid_device_us, e, flags)
        body_q = att[0] if att else None
        gimbal_q = self._carrier(p.mid_device_us, mid_boot, body_q, flags)
        cam = camera_fields(pos.enu if pos else None, body_q, rng[0] if rng else None, self._mounting, gimbal_q)
        blur = self._blur_px(imu, mid_boot, e.duration_us, cam.scale_mm_per_px)
        if blur is not None and blur > self._cfg.blur_limit_px:
            flags.append(FrameFlag.MOTION_BLUR.value)
        if imu is not None and imu.calib_stat is not None and (imu.calib_stat >> 6) & 3 < 3:
            flags.append(FrameFlag.IMU_UNCALIBRATED.value)
        gps = placed.gps if placed else self._tm.gps.bracket(int(mid_boot) if mid_boot is not None else 0)[0]
        bound_h_v = self._position_bound(pos, att[1] if att else None, unc_ns, ap_unc)
        return FrameRecord(
            **parts.exposure_fields(p.seq, e, p.start_device_us, p.mid_device_us),
            mid_host_ns=mid_host_ns,
            mid_host_uncertainty_ns=unc_ns,
            time_source=utc[2] if utc else "none",
            flags=sorted(set(flags)),
            **parts.utc_fields(utc),
            **parts.position_fields(placed, pos, gps, bound_h_v, self._place(cam), cam),
            attitude_error_bound_deg=att[1] if att else None,
            **parts.attitude_fields(cam),
            **parts.imu_fields(imu),
            **parts.range_fields(rng, cam),
            blur_px=blur,
            **parts.autopilot_clock_fields(self._ap.method() if mid_boot is not None else "none", ap_unc),
            emitted_host_ns=now_host_ns,
        )

    def _device_uncertainty_ns(self, mid_device_us: int, flags: list[str]) -> int:
        """The device -> host mapping's bound at mid [ns] (flags ``clock_unsynced`` above the limit)."""
        try:
            unc_ns = self._dev.uncertainty_ns(mid_device_us)
        except IcgtError:
            unc_ns = 50_000_000  # no exchange yet: USB and scheduling delays of the EXPOSURE itself
        if unc_ns > self._max_clock_uncertainty_ns:
            flags.append(FrameFlag.CLOCK_UNSYNCED.value)
        return unc_ns

    def _place(self, cam: CameraFields) -> tuple[float, float, float] | None:
        """The camera's WGS84 position (lat, lon [deg], alt MSL [m]) from its ENU one."""
        enu = cam.enu
        if enu is None:
            return None
        assert self._frame is not None
        la, lo, al = self._frame.enu_to_geodetic(enu)
        return float(la), float(lo), float(al)

    def _position(self, mid_boot: float | None, flags: list[str]) -> PositionEstimate | PoseGap | None:
        """The position at mid by `icgt.geotag.position` (None: no fix; PoseGap: too far from any sample)."""
        if mid_boot is None:
            flags.append(FrameFlag.NO_FIX.value)
            return None
        if self._frame is None:
            first = next((s for s in self._tm.fused.samples() if s.usable and s.lat_deg is not None), None)
            if first is None:
                flags.append(FrameFlag.NO_FIX.value)
                return None
            assert first.lat_deg is not None and first.lon_deg is not None and first.alt_msl_m is not None
            self.origin = (first.lat_deg, first.lon_deg, first.alt_msl_m)
            self._frame = LocalFrame(*self.origin)
        est = estimate_position(self._tm, self._frame, mid_boot, self._rules)
        if est is None:
            flags.append(FrameFlag.NO_FIX.value)
            return None
        if isinstance(est, PoseGap):
            flags.append(FrameFlag.NO_POSE.value)
            return est
        if est.extrapolated:
            flags.append(FrameFlag.POSE_EXTRAPOLATED.value)
        if est.motion_m > self._cfg.max_position_error_m:
            flags.append(FrameFlag.STALE_POSE.value)
        return est

    def _attitude(self, mid_boot: float | None, flags: list[str]) -> tuple[np.ndarray, float] | None:
        """(body -> NED quaternion at mid, its 95 % bound [deg]): slerp between the samples around mid.

        Bound: the autopilot's own ``attitude_accuracy_deg``, the rate change the ends show |w1 - w0| T u (1-u) / 2
        and an unseen rate change A T^2 u (1-u) / 4 (as `icgt.geotag.bounds.interpolation_bound`); a held
        attitude (one side only) adds |w| dt + A dt^2 / 2."""
        if mid_boot is None:
            flags.append(FrameFlag.NO_ATTITUDE.value)
            return None
        before, after = self._attitude_buffer().bracket(int(mid_boot))
        if before is None and after is None:
            flags.append(FrameFlag.NO_ATTITUDE.value)
            return None
        base = self._cfg.attitude_accuracy_deg
        unseen = self._cfg.unseen_rate_rad_s2
        if before is None or after is None or after.boot_us == before.boot_us:
            only = before or after
            assert only is not None
            dt = abs(mid_boot - only.boot_us) / 1e6
            rate = math.sqrt(only.rollspeed_rps**2 + only.pitchspeed_rps**2 + only.yawspeed_rps**2)
            return np.asarray(only.q_wxyz, dtype=float), base + math.degrees(rate * dt + unseen * dt**2 / 2.0)
        span = (after.boot_us - before.boot_us) / 1e6
        f = (mid_boot - before.boot_us) / (after.boot_us - before.boot_us)
        d_rate = math.sqrt(
            (after.rollspeed_rps - before.rollspeed_rps) ** 2
            + (after.pitchspeed_rps - before.pitchspeed_rps) ** 2
            + (after.yawspeed_rps - before.yawspeed_rps) ** 2
        )
        shape = f * (1.0 - f)
        motion = d_rate * span * shape / 2.0 + unseen * span**2 * shape / 4.0
        return np.asarray(q_slerp(before.q_wxyz, after.q_wxyz, f), dtype=float), base + math.degrees(motion)

    def _carrier(
        self, mid_device_us: int, mid_boot: float | None, body_q: np.ndarray | None, flags: list[str]
    ) -> np.ndarray | None:
        """What carries the camera -> NED at mid, for the attitude sources that measure it (the gimbal's
        report, the board's BNO055); None for "mount", or flagged when it is not known."""
        if self._cfg.attitude_source == "gimbal":
            return self._gimbal(mid_boot, body_q, flags)
        if self._cfg.attitude_source == "board_imu":
            return self._board(mid_device_us, flags)
        return None

    def _board(self, mid_device_us: int, flags: list[str]) -> np.ndarray | None:
        """The board's sensor axes -> NED at mid (`icgt.geotag.board_imu`); None: flag board_imu_stale or
        board_imu_no_heading (never the body's attitude in its place)."""
        gap_us = self._cfg.board_imu_max_gap_s * 1e6
        q_bno = board_at(self._imu, mid_device_us, gap_us)
        if q_bno is None:
            flags.append(FrameFlag.BOARD_IMU_STALE.value)
            return None
        offset: float | None = math.radians(self._cfg.board_imu_heading_offset_deg)
        if self._cfg.board_imu_heading == "autopilot":
            offset = heading_offset_rad(
                self._imu, self._attitude_buffer(), mid_device_us, self._device_to_boot_us,
                self._mounting.q_cam_body, self._heading_window, gap_us,
            )  # fmt: skip
        if offset is None:
            flags.append(FrameFlag.BOARD_IMU_NO_HEADING.value)
            return None
        return board_in_ned(q_bno, offset)

    def _device_to_boot_us(self, device_us: float) -> float | None:
        try:
            return self._ap.host_to_autopilot_us(self._dev.device_to_host_ns(device_us))
        except IcgtError:
            return None

    def _dev_us(self, host_ns: int) -> float:
        """A host instant on the device clock; infinity before the first exchange (the frame waits, up to its
        wait limit)."""
        try:
            return self._dev.host_to_device_us(host_ns)
        except IcgtError:
            return math.inf

    def _gimbal(self, mid_boot: float | None, body_q: np.ndarray | None, flags: list[str]) -> np.ndarray | None:
        """The gimbal's device frame -> NED at mid (`gimbal_pose.gimbal_at`); None: flag gimbal_stale (never the
        body's attitude in its place)."""
        q = None
        if mid_boot is not None:
            yaw = float(q_to_euler_zyx(body_q)[2]) if body_q is not None else None
            q = gimbal_at(self._tm.gimbal, mid_boot, yaw, self._cfg.gimbal_max_gap_s, self._cfg.gimbal_max_hold_s)
        if q is None:
            flags.append(FrameFlag.GIMBAL_STALE.value)
        return q

    def _position_bound(
        self, pos: PositionEstimate | None, attitude_bound_deg: float | None, dev_unc_ns: int, ap_unc_us: float | None
    ) -> tuple[float, float] | None:
        """The camera position's 95 % bound [m] (horizontal, vertical): the estimate's source and motion parts,
        the clock uncertainty at mid times the speed, and the lever arm times the attitude bound (a camera
        without attitude has its lever arm unapplied: the whole arm)."""
        if pos is None:
            return None
        dt_s = (dev_unc_ns / 1e9) + ((ap_unc_us if ap_unc_us is not None else 0.0) / 1e6)
        v = pos.velocity_enu_m_s
        timing_h, timing_v = math.hypot(float(v[0]), float(v[1])) * dt_s, abs(float(v[2])) * dt_s
        # a chord of the arm's sphere: |arm| 2 sin(err / 2) <= |arm| err, and never more than its diameter
        turn = min(math.radians(attitude_bound_deg), 2.0) if attitude_bound_deg is not None else 1.0
        lever = self._lever_m * turn
        return pos.horizontal_m + timing_h + lever, pos.vertical_m + timing_v + lever

    def _telemetry_expired(self, mid_boot: float) -> bool:
        """The fused positions from around ``mid_boot`` were held once and have been trimmed since."""
        oldest = self._tm.fused.oldest()
        return self._tm.fused.expired > 0 and oldest is not None and oldest.boot_us > mid_boot

    def _imu_at(self, mid_device_us: int, e: Exposure, flags: list[str]) -> ImuAtMid | None:
        """The BNO055 at mid: the nearest IMU sample held, unless the exposure's snapshot is nearer mid (the
        samples around it were lost in an outage or left the buffer): then the snapshot, flagged."""
        before, after = self._imu.bracket(mid_device_us)
        s = before if after is None else after if before is None else (
            before if mid_device_us - before.boot_us <= after.boot_us - mid_device_us else after
        )  # fmt: skip
        snap = snapshot_imu(e)
        if s is not None and isinstance(s.msg, Imu):
            age_ms = (mid_device_us - s.boot_us) / 1000.0
            if snap is None or abs(age_ms) <= snap.age_ms:
                m = s.msg
                q = (m.quat_w, m.quat_x, m.quat_y, m.quat_z)
                w = (m.gyro_x_rad_s, m.gyro_y_rad_s, m.gyro_z_rad_s)
                return ImuAtMid(q, w, m.calib_stat, age_ms, SensorSource.SAMPLES)
        if snap is not None:
            flags.append(FrameFlag.IMU_FROM_SNAPSHOT.value)
        return snap

    def _range_at(
        self, mid_device_us: int, e: Exposure, flags: list[str]
    ) -> tuple[float | None, float | None, SensorSource] | None:
        """(range [m] at mid or None, age of the nearest valid acquisition [ms], where it came from).

        The samples held around mid first; with no valid one within ``range_stale_s``, the exposure's own
        snapshot (protocol 2) if it holds a range no older than that (flagged ``range_from_snapshot``)."""
        window_us = self._range_window_us
        window = self._range.between(mid_device_us - window_us, mid_device_us + window_us)
        # The nearest valid acquisitions at or before and at or after mid, searched outwards from mid: the
        # window holds ~100 samples at 500 Hz, of which only the two nearest valid ones are used.
        i_before = bisect_right(window, mid_device_us, key=_boot_us)  # window[:i_before]: at or before mid
        i_after = bisect_left(window, mid_device_us, key=_boot_us)  # window[i_after:]: at or after mid
        a = next((window[i] for i in range(i_before - 1, -1, -1) if _valid_range(window[i])), None)
        b = next((window[i] for i in range(i_after, len(window)) if _valid_range(window[i])), None)
        source = SensorSource.SAMPLES
        if a is None and b is None:
            age_us = e.range_age_us
            if snapshot_range_valid(e) and age_us != SNAPSHOT_AGE_SATURATED_US and age_us <= window_us:
                r, age = e.range_mm / 1000.0, age_us / 1000.0
                flags.append(FrameFlag.RANGE_FROM_SNAPSHOT.value)
                source = SensorSource.SNAPSHOT
            else:
                flags.append(FrameFlag.RANGE_INVALID.value)
                if not window and FrameFlag.RESENT.value in flags:
                    flags.append(FrameFlag.RANGE_SAMPLES_LOST.value)  # not one sample came back from around mid
                return None
        elif a is not None and b is not None:
            ra, rb = a.msg.distance_cm / 100.0, b.msg.distance_cm / 100.0  # type: ignore[union-attr]
            f = 0.0 if b.boot_us == a.boot_us else (mid_device_us - a.boot_us) / (b.boot_us - a.boot_us)
            r = ra + (rb - ra) * f
            age = min(mid_device_us - a.boot_us, b.boot_us - mid_device_us) / 1000.0
        else:
            s = a if a is not None else b
            assert s is not None
            r = s.msg.distance_cm / 100.0  # type: ignore[union-attr]
            age = abs(mid_device_us - s.boot_us) / 1000.0
        if not self._cfg.range_min_m <= r <= self._cfg.range_max_m:
            flags.append(FrameFlag.RANGE_OUT_OF_BAND.value)
        return r, age, source

    def _blur_px(
        self, imu: ImuAtMid | None, mid_boot: float | None, duration_us: int, scale_mm_per_px: float | None
    ) -> float | None:
        """Rotation blur = |omega| x exposure x focal length [px] (plus translation when the speed is known)."""
        if imu is None or duration_us <= 0:
            return None
        omega = math.sqrt(sum(w * w for w in imu.gyro_rad_s))
        blur = omega * duration_us * 1e-6 * self._cfg.focal_length_px
        # The velocity of the fused sample at or before mid-exposure (not the newest one, which
        # would make the figure depend on when the frame happened to be emitted).
        fused = self._tm.fused.bracket(int(mid_boot))[0] if mid_boot is not None else None
        if scale_mm_per_px and fused is not None:
            speed = math.sqrt(fused.vn_mps**2 + fused.ve_mps**2 + fused.vd_mps**2)
            blur += speed * duration_us * 1e-6 * 1000.0 / scale_mm_per_px
        return blur
