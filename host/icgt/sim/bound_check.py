"""Score the geotagger's error bounds against a flight's truth: telemetry with gaps, live or recomputed.

The flight (`icgt.sim.survey`) is sampled into MAVLink telemetry as an autopilot sends it: GPS_RAW_INT
(with ``h_acc``/``v_acc``), GLOBAL_POSITION_INT and LOCAL_POSITION_NED (the fused estimate with its noise),
ATTITUDE_QUATERNION (with attitude noise), encoded and parsed by pymavlink, then ingested by the real
`TelemetryStore` and placed by the real `Geotagger`. In a gap GLOBAL_POSITION_INT and LOCAL_POSITION_NED
are both silent and attitude goes on (the issue's ArduPilot VTOL log). The clocks are ideal except for a
constant mapping error drawn within the bound they claim.

``mode="live"``: messages arrive in time order and the geotagger is polled as the recorder polls it (a
frame in a gap is emitted when its wait runs out). ``mode="recompute"``: polled 10 s behind the inputs (a
recompute with look-ahead): the sample after a gap is in when the frame is placed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from icgt.geodesy import FloatArray, LocalFrame, q_multiply
from icgt.geotag.config import GeotagConfig
from icgt.geotag.geotagger import Geotagger
from icgt.geotag.record import FrameFlag, FrameRecord
from icgt.mavlink.link_types import MavlinkMessage
from icgt.mavlink.telemetry import TelemetryStore
from icgt.pose import camera_position_enu
from icgt.protocol.messages import Exposure
from icgt.sim.scenario import Scenario
from icgt.sim.survey import SurveyState
from icgt.sim.trajectory import Trajectory, TruthState

__all__ = ["FlightTruth", "FrameScore", "Gap", "ScenarioFlight", "TelemetryPlan", "score_flight"]

_ORIGIN = (47.397742, 8.545594, 488.0)
_BOOT0_US = 5_000_000  # the flight starts 5 s after the autopilot booted


class FlightTruth(Protocol):
    """What is scored: a flight's truth (`icgt.sim.survey.SurveyFlight`, or a scenario's via `ScenarioFlight`)."""

    @property
    def duration_s(self) -> float: ...
    @property
    def segments(self) -> list[tuple[str, float, float]]: ...  # (kind, start [s], end [s])
    def state(self, t_s: FloatArray | float) -> SurveyState | TruthState: ...
    def segment_at(self, t_s: float) -> str: ...


class ScenarioFlight:
    """A simulator scenario's flight (pier scan, deck pass, ...) as a `FlightTruth`: segments ``speed`` where the
    vehicle accelerates by more than 0.1 m/s^2, else ``straight``."""

    def __init__(self, scenario: Scenario) -> None:
        self._traj = Trajectory(scenario)
        self.duration_s = float(min(scenario.duration_s, self._traj.motion_end_s))
        t = np.arange(0.0, self.duration_s, 0.1)
        accel = np.linalg.norm(self._traj.state(t).accel_enu_m_s2, axis=1) > 0.1
        self.segments: list[tuple[str, float, float]] = []
        start = 0
        for k in range(1, len(t) + 1):
            if k == len(t) or accel[k] != accel[start]:
                kind = "speed" if accel[start] else "straight"
                self.segments.append((kind, float(t[start]), float(t[k - 1]) + 0.1))
                start = k

    def state(self, t_s: FloatArray | float) -> TruthState:
        return self._traj.state(t_s)

    def segment_at(self, t_s: float) -> str:
        return next((k for k, a, b in self.segments if a <= t_s < b), "straight")


@dataclass(frozen=True)
class Gap:
    start_s: float
    duration_s: float

    def holds(self, t_s: float) -> bool:
        return self.start_s <= t_s < self.start_s + self.duration_s


@dataclass(frozen=True)
class TelemetryPlan:
    """What the autopilot sends and how good it is (1-sigma noises; h_acc is the radial RMS it reports)."""

    fused_hz: float = 10.0
    gps_hz: float = 5.0
    attitude_hz: float = 50.0
    fix_type: int = 6
    h_acc_m: float = 0.02
    v_acc_m: float = 0.03
    attitude_noise_deg: float = 0.3  # per axis
    # A receiver's error is mostly slow (multipath, atmosphere: correlated over minutes), a little of it white;
    # this fraction of the variance is white, the rest a first-order Gauss-Markov process of position_tau_s.
    position_white_fraction: float = 0.2
    position_tau_s: float = 20.0
    clock_bound_us: float = 300.0  # host -> autopilot bound the clock claims (its error is drawn within it)
    fps: float = 5.0
    lever_arm_body_m: tuple[float, float, float] = (0.30, 0.0, 0.10)


@dataclass(frozen=True)
class FrameScore:
    t_s: float
    segment: str  # straight, turn, speed, climb
    gap_s: float  # duration of the gap the frame's mid-exposure is in (0: none)
    placed: bool
    flags: tuple[str, ...]
    source: str
    h_err_m: float
    v_err_m: float
    att_err_deg: float
    h_bound_m: float
    v_bound_m: float
    att_bound_deg: float
    h_acc_m: float  # the naive bound: the receiver's own accuracy
    v_acc_m: float
    enu_m: tuple[float, float, float] | None  # the camera position the frame gives (None: withheld)

    @property
    def flagged(self) -> bool:
        return bool({FrameFlag.STALE_POSE.value, FrameFlag.POSE_EXTRAPOLATED.value} & set(self.flags))


class _Clock:
    """Device us == host us == autopilot boot us, but host -> autopilot off by ``error_us`` (within bound_us)."""

    def __init__(self, error_us: float, bound_us: float) -> None:
        self.error_us = error_us
        self.bound_us = bound_us

    def device_to_host_ns(self, device_us: float) -> int:
        return round(device_us * 1000)

    def host_to_device_us(self, host_ns: int) -> float:
        return host_ns / 1000

    def uncertainty_ns(self, device_us: float) -> int:
        return 0

    @property
    def settled(self) -> bool:
        return True

    def host_to_autopilot_us(self, host_ns: int) -> float | None:
        return host_ns / 1000 + self.error_us

    def method(self) -> str:
        return "timesync"

    def uncertainty_us(self, boot_us: float) -> float | None:
        return self.bound_us

    def utc_at(self, device_us: float, host_ns: int) -> tuple[int, float, str] | None:
        return int(device_us), 1.0, "pps"


def _angle_deg(qa: np.ndarray, qb: np.ndarray) -> float:
    d = abs(float(np.dot(qa, qb)) / (float(np.linalg.norm(qa)) * float(np.linalg.norm(qb))))
    return math.degrees(2.0 * math.acos(min(1.0, d)))


def _small_rotation(rng: np.random.Generator, sigma_deg: float) -> np.ndarray:
    v = rng.normal(size=3) * math.radians(sigma_deg)
    a = float(np.linalg.norm(v))
    if a < 1e-12:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[math.cos(a / 2)], math.sin(a / 2) * v / a])


def _position_noise(
    duration_s: float, plan: TelemetryPlan, sigma: np.ndarray, rng: np.random.Generator
) -> Callable[[float], np.ndarray]:
    """The receiver's slow error [m] (ENU) at any time: a Gauss-Markov sequence on a 0.1 s grid, interpolated."""
    step = 0.1
    n = math.ceil(duration_s / step) + 2
    rho = math.exp(-step / plan.position_tau_s)
    slow_sigma = sigma * math.sqrt(1.0 - plan.position_white_fraction)
    seq = np.empty((n, 3))
    seq[0] = rng.normal(size=3) * slow_sigma
    kicks = rng.normal(size=(n, 3)) * slow_sigma * math.sqrt(1.0 - rho * rho)
    for k in range(1, n):
        seq[k] = rho * seq[k - 1] + kicks[k]
    grid = np.arange(n) * step

    def at(t_s: float) -> np.ndarray:
        return np.array([np.interp(t_s, grid, seq[:, a]) for a in range(3)])

    return at


def _messages(
    flight: FlightTruth, plan: TelemetryPlan, gaps: list[Gap], rng: np.random.Generator, frame: LocalFrame
) -> list[tuple[float, object]]:
    """(time [s], pymavlink message) of everything the autopilot sends, in time order."""
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    out: list[tuple[float, object]] = []
    sigma_h = plan.h_acc_m / math.sqrt(2.0)  # h_acc read as the radial RMS: each axis h_acc / sqrt(2)

    def stamps(hz: float) -> np.ndarray:
        return np.arange(0.0, flight.duration_s, 1.0 / hz)

    def geodetic(enu: np.ndarray) -> tuple[int, int, int]:
        lat, lon, h = frame.enu_to_geodetic(enu)
        return round(float(lat) * 1e7), round(float(lon) * 1e7), round(float(h) * 1000.0)

    sigma = np.array([sigma_h, sigma_h, plan.v_acc_m])
    noise_at = _position_noise(flight.duration_s, plan, sigma, rng)
    white = math.sqrt(plan.position_white_fraction)

    t_gps = stamps(plan.gps_hz)
    st = flight.state(t_gps)
    for k, t in enumerate(t_gps):
        pos = st.position_enu_m[k] + noise_at(float(t)) + rng.normal(size=3) * sigma * white
        lat, lon, alt = geodetic(pos)
        msg = mav.gps_raw_int_encode(
            int(_BOOT0_US + t * 1e6), plan.fix_type, lat, lon, alt, 60, 90, 0, 0, 22, alt,
            round(plan.h_acc_m * 1000), round(plan.v_acc_m * 1000), 100, 0, 0,
        )  # fmt: skip
        out.append((float(t), msg))
    t_fused = stamps(plan.fused_hz)
    st = flight.state(t_fused)
    for k, t in enumerate(t_fused):
        if any(g.holds(float(t)) for g in gaps):
            continue
        pos = st.position_enu_m[k] + noise_at(float(t)) + rng.normal(size=3) * sigma * white
        vel = st.velocity_enu_m_s[k]
        lat, lon, alt = geodetic(pos)
        boot_ms = int((_BOOT0_US + t * 1e6) // 1000)
        vn, ve, vd = (round(c * 100) for c in (vel[1], vel[0], -vel[2]))
        out.append((float(t), mav.global_position_int_encode(boot_ms, lat, lon, alt, alt - 488_000, vn, ve, vd, 0)))
        out.append(
            (
                float(t),
                mav.local_position_ned_encode(
                    boot_ms, float(pos[1]), float(pos[0]), float(-pos[2]), float(vel[1]), float(vel[0]), float(-vel[2])
                ),
            )
        )
    t_att = stamps(plan.attitude_hz)
    st = flight.state(t_att)
    for k, t in enumerate(t_att):
        q = np.asarray(q_multiply(st.q_body_ned[k], _small_rotation(rng, plan.attitude_noise_deg)))
        w = st.omega_body_rad_s[k]
        boot_ms = int((_BOOT0_US + t * 1e6) // 1000)
        out.append((float(t), mav.attitude_quaternion_encode(boot_ms, *map(float, q), *map(float, w))))
    out.sort(key=lambda m: m[0])
    return out


def _wire(mav: mavlink2.MAVLink, msg: object) -> object:
    parsed = mavlink2.MAVLink(None).parse_buffer(msg.pack(mav))  # type: ignore[attr-defined]
    assert parsed is not None and len(parsed) == 1
    return parsed[0]


def score_flight(
    flight: FlightTruth,
    gaps: list[Gap],
    *,
    plan: TelemetryPlan | None = None,
    mode: Literal["live", "recompute"] = "live",
    seed: int = 0,
    config: GeotagConfig | None = None,
) -> list[FrameScore]:
    """Fly ``flight`` with ``gaps`` in its position telemetry and score every frame against the truth."""
    plan = plan or TelemetryPlan()
    rng = np.random.default_rng(seed)
    frame = LocalFrame(*_ORIGIN)
    cfg = config or GeotagConfig(origin=_ORIGIN, lever_arm_body_m=plan.lever_arm_body_m)
    clock = _Clock(float(rng.uniform(-1.0, 1.0)) * plan.clock_bound_us, plan.clock_bound_us)
    store = TelemetryStore()
    frames: list[FrameRecord] = []
    gt = Geotagger(store, clock, clock, clock, cfg, frames.append)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    messages = _messages(flight, plan, gaps, rng, frame)
    t_frames = np.arange(2.0, flight.duration_s - 2.0, 1.0 / plan.fps)
    exposures = [(float(t), i + 1) for i, t in enumerate(t_frames)]
    duration_us = 1000
    latency_s = 0.005

    def expose(t: float, index: int) -> None:
        start_us = int(_BOOT0_US + t * 1e6) - duration_us // 2
        e = Exposure(
            image_index=index,
            camera_id=0,
            trigger_t_us=start_us - 40_000,
            feedback_start_t_us=start_us,
            feedback_end_t_us=start_us + duration_us,
            duration_us=duration_us,
        )
        gt.add_exposure(e, (start_us + duration_us) * 1000 + 3_000_000)

    def host_ns(t: float) -> int:
        return int((_BOOT0_US + t * 1e6) * 1000)

    # recompute: polled 10 s of host time behind the inputs, as `icgt.ingest.recompute` with look-ahead
    lag_s = 10.0 if mode == "recompute" else 0.0
    events = [(t + latency_s, 0, msg) for t, msg in messages] + [(t + 0.01, 1, i) for t, i in exposures]
    events.sort(key=lambda e: (e[0], e[1]))
    for t, kind, item in events:
        if kind == 0:
            store.ingest(MavlinkMessage(_wire(mav, item), host_ns(t)))
        else:
            assert isinstance(item, int)
            expose(t - 0.01, item)
        gt.poll(host_ns(t - lag_s))
    gt.poll(host_ns(flight.duration_s + 30.0), flush=True)
    return [_score(flight, gaps, plan, f) for f in frames]


def _score(flight: FlightTruth, gaps: list[Gap], plan: TelemetryPlan, f: FrameRecord) -> FrameScore:
    t = (f.mid_device_us - _BOOT0_US) / 1e6
    st = flight.state(t)
    truth = camera_position_enu(st.position_enu_m[0], st.q_body_ned[0], plan.lever_arm_body_m)
    gap = next((g.duration_s for g in gaps if g.holds(t)), 0.0)
    placed = f.east_m is not None and f.north_m is not None and f.up_m is not None
    if placed:
        assert f.east_m is not None and f.north_m is not None and f.up_m is not None
        d = np.array([f.east_m, f.north_m, f.up_m]) - truth
        h_err, v_err = math.hypot(float(d[0]), float(d[1])), abs(float(d[2]))
    else:
        h_err = v_err = math.nan
    att_err = math.nan
    if f.body_qw is not None:
        assert f.body_qx is not None and f.body_qy is not None and f.body_qz is not None
        att_err = _angle_deg(np.array([f.body_qw, f.body_qx, f.body_qy, f.body_qz]), st.q_body_ned[0])
    return FrameScore(
        t_s=t,
        segment=flight.segment_at(t),
        gap_s=gap,
        placed=placed,
        flags=tuple(f.flags),
        source=f.position_source,
        h_err_m=h_err,
        v_err_m=v_err,
        att_err_deg=att_err,
        h_bound_m=f.horizontal_error_bound_m if f.horizontal_error_bound_m is not None else math.nan,
        v_bound_m=f.vertical_error_bound_m if f.vertical_error_bound_m is not None else math.nan,
        att_bound_deg=f.attitude_error_bound_deg if f.attitude_error_bound_deg is not None else math.nan,
        h_acc_m=plan.h_acc_m,
        v_acc_m=plan.v_acc_m,
        enu_m=(f.east_m, f.north_m, f.up_m) if placed else None,  # type: ignore[arg-type]
    )
