"""A fixed-wing / VTOL survey flight: constant-speed legs, banked coordinated turns, speed changes, climbs.

The inspection scenarios of `icgt.sim.trajectory` are multirotor paths that stop at every waypoint; a VTOL
in forward flight never stops. Here the vehicle flies at 20-25 m/s and turns by banking: heading rate
psi' = g tan(phi) / V, rolled in and out smoothly over ``roll_s`` (smootherstep, so the bank, the heading
rate and the lateral acceleration are continuous). Speed changes ramp the longitudinal acceleration the
same way; climbs ramp the vertical speed. Attitude is that of a coordinated flight: yaw = course, roll =
the bank, pitch = the flight-path angle (no angle of attack or sideslip). Frames as in `icgt.sim.trajectory`:
ENU positions [m], body->NED quaternions (w first), body rates in FRD [rad/s].

A real vehicle does not fly the plan's smooth curves: turbulence pushes it and its autopilot pulls it back.
`Turbulence` adds that as a random, smooth ground-velocity perturbation (`turbulence_offsets`); the
flights of `vtol_survey` and `random_flight` carry light turbulence unless told otherwise. Without it, a
gap in the telemetry hides nothing that a cubic through its ends does not already show.

`SurveyFlight.state(t)` evaluates the flight at any times from a dense integration (``step_s``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from icgt.geodesy import FloatArray, q_from_euler_zyx

__all__ = [
    "LIGHT_TURBULENCE",
    "Leg",
    "SurveyFlight",
    "SurveyState",
    "Turbulence",
    "random_flight",
    "turbulence_offsets",
    "vtol_survey",
]

GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class Turbulence:
    """The vehicle's ground-velocity response to turbulence under its autopilot (1-sigma per axis).

    A sum of ``components`` sinusoids per axis with random phases, their powers drawn from a band-pass
    spectrum: a second-order Gauss-Markov process of correlation time ``correlation_s`` (the gusts as the
    airframe follows them), times a high-pass of ``hold_s`` (the autopilot holding its track and altitude,
    so the position does not wander off). Seeded: the same flight has the same gusts."""

    sigma_h_m_s: float = 0.4
    sigma_v_m_s: float = 0.25
    correlation_s: float = 2.0
    hold_s: float = 10.0
    components: int = 48
    seed: int = 0


# Dryden "light" turbulence at 60 m has gust velocities of about 1 m/s (MIL-F-8785C, W20 = 15 kn); a small
# VTOL under its autopilot follows part of that: ground-velocity deviations of a few decimetres per second,
# accelerations around 0.2 m/s^2 (sigma_v / correlation_s).
LIGHT_TURBULENCE = Turbulence()


def turbulence_offsets(turb: Turbulence, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(position [m], velocity [m/s], acceleration [m/s^2]) perturbations, ENU, shape (len(t), 3).

    Sinusoids rather than a filtered noise sequence: position, velocity and acceleration are exact
    derivatives of one another at any time, with no integration error between the samples' instants."""
    rng = np.random.default_rng([32, turb.seed])
    tau, hold = turb.correlation_s, turb.hold_s
    edges = np.geomspace(0.02 / tau, 20.0 / tau, turb.components + 1)
    pos = np.zeros((len(t), 3))
    vel = np.zeros((len(t), 3))
    acc = np.zeros((len(t), 3))
    for axis, sigma in enumerate((turb.sigma_h_m_s, turb.sigma_h_m_s, turb.sigma_v_m_s)):
        w = rng.uniform(edges[:-1], edges[1:])  # one frequency in each band [rad/s]
        psd = (w * hold) ** 2 / (1.0 + (w * hold) ** 2) / (1.0 + (w * tau) ** 2) ** 2
        power = psd * np.diff(edges)
        amp = sigma * np.sqrt(2.0 * power / power.sum())  # sum of amp^2 / 2 = sigma^2
        phase = rng.uniform(0.0, 2.0 * math.pi, len(w))
        arg = np.outer(t, w) + phase
        pos[:, axis] = (np.sin(arg) - np.sin(phase)) @ (amp / w)
        vel[:, axis] = np.cos(arg) @ amp
        acc[:, axis] = -np.sin(arg) @ (amp * w)
    return pos, vel, acc


@dataclass(frozen=True)
class Leg:
    """One piece of the flight. ``turn_deg`` (turn, + to the right) at ``bank_deg``; ``accel_m_s2`` for
    ``duration_s`` (speed change); ``climb_m_s`` reached and held for ``duration_s`` (climb); else straight."""

    kind: Literal["straight", "turn", "speed", "climb"]
    duration_s: float = 0.0
    turn_deg: float = 0.0
    bank_deg: float = 30.0
    accel_m_s2: float = 0.0
    climb_m_s: float = 0.0


@dataclass(frozen=True)
class SurveyState:
    position_enu_m: FloatArray
    velocity_enu_m_s: FloatArray
    accel_enu_m_s2: FloatArray
    q_body_ned: FloatArray
    omega_body_rad_s: FloatArray


def _ramp(u: FloatArray) -> FloatArray:
    w = np.clip(u, 0.0, 1.0)
    out: FloatArray = w**3 * (10.0 + w * (-15.0 + 6.0 * w))
    return out


def _plateau(t: FloatArray, length_s: float, ramp_s: float) -> FloatArray:
    """0 -> 1 over ramp_s, 1, then 1 -> 0 over the last ramp_s of length_s (t from the piece's start)."""
    up = _ramp(t / ramp_s)
    down = _ramp((length_s - t) / ramp_s)
    out: FloatArray = np.minimum(up, down)
    return out


class SurveyFlight:
    """The legs flown one after another from ``start_enu_m`` at ``speed_m_s`` on ``heading_deg`` (compass)."""

    def __init__(
        self,
        legs: list[Leg],
        *,
        speed_m_s: float = 22.0,
        heading_deg: float = 0.0,
        start_enu_m: tuple[float, float, float] = (0.0, 0.0, 60.0),
        roll_s: float = 1.0,
        step_s: float = 0.002,
        turbulence: Turbulence | None = None,
    ) -> None:
        self.legs = list(legs)
        self.segments: list[tuple[str, float, float]] = []  # (kind, start [s], end [s])
        t0 = 0.0
        pieces: list[tuple[Leg, float, float]] = []
        v = speed_m_s
        for leg in legs:
            if leg.kind == "turn":
                rate = GRAVITY_M_S2 * math.tan(math.radians(leg.bank_deg)) / v
                hold = max(0.0, math.radians(abs(leg.turn_deg)) / rate - roll_s)
                length = hold + 2.0 * roll_s
            else:
                length = max(leg.duration_s, 2.0 * roll_s if leg.kind != "straight" else 0.0)
                if leg.kind == "speed":
                    v += leg.accel_m_s2 * (length - roll_s)
            pieces.append((leg, t0, length))
            self.segments.append((leg.kind, t0, t0 + length))
            t0 += length
        self.duration_s = t0
        n = math.ceil(t0 / step_s) + 1
        t = np.linspace(0.0, t0, n)
        accel_long = np.zeros(n)
        climb = np.zeros(n)
        yaw_rate_scale = np.zeros(n)  # g tan(bank) for the turn pieces (divided by the speed below)
        climb_now = 0.0
        for leg, start, length in pieces:
            inside = (t >= start) & (t <= start + length)
            local = t[inside] - start
            if leg.kind == "turn":
                sign = 1.0 if leg.turn_deg >= 0 else -1.0
                yaw_rate_scale[inside] = (
                    sign * GRAVITY_M_S2 * math.tan(math.radians(leg.bank_deg)) * _plateau(local, length, roll_s)
                )
            elif leg.kind == "speed":
                accel_long[inside] = leg.accel_m_s2 * _plateau(local, length, roll_s / 2.0)
            elif leg.kind == "climb":
                climb[inside] = climb_now + (leg.climb_m_s - climb_now) * _ramp(local / roll_s)
                climb_now = leg.climb_m_s
            after = t > start + length
            if leg.kind == "climb":
                climb[after] = climb_now
        dt = np.diff(t)
        speed = speed_m_s + np.concatenate([[0.0], np.cumsum(0.5 * (accel_long[1:] + accel_long[:-1]) * dt)])
        yaw_rate = yaw_rate_scale / speed
        heading = math.radians(heading_deg) + np.concatenate(
            [[0.0], np.cumsum(0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * dt)]
        )
        vel = np.stack([speed * np.sin(heading), speed * np.cos(heading), climb], axis=-1)
        pos = np.asarray(start_enu_m) + np.concatenate(
            [np.zeros((1, 3)), np.cumsum(0.5 * (vel[1:] + vel[:-1]) * dt[:, None], axis=0)]
        )
        acc = np.gradient(vel, t, axis=0)
        self.turbulence = turbulence
        if turbulence is not None:
            d_pos, d_vel, d_acc = turbulence_offsets(turbulence, t)
            pos, vel, acc = pos + d_pos, vel + d_vel, acc + d_acc
        self._t = t
        self._pos = pos
        self._vel = vel
        self._acc = acc
        self._heading = heading
        self._bank = np.arctan2(yaw_rate * speed, GRAVITY_M_S2)
        self._pitch = np.arctan2(climb, speed)

    def segment_at(self, t_s: float) -> str:
        for kind, a, b in self.segments:
            if a <= t_s <= b:
                return kind
        return "straight"

    def _interp(self, arr: FloatArray, t: FloatArray) -> FloatArray:
        if arr.ndim == 1:
            out: FloatArray = np.interp(t, self._t, arr)
            return out
        return np.stack([np.interp(t, self._t, arr[:, k]) for k in range(arr.shape[1])], axis=-1)

    def state(self, t_s: FloatArray | float) -> SurveyState:
        t = np.atleast_1d(np.asarray(t_s, dtype=float))
        h = 1e-3
        roll, pitch, yaw = (self._interp(a, t) for a in (self._bank, self._pitch, self._heading))
        rates = [self._interp(a, t + h) - self._interp(a, t - h) for a in (self._bank, self._pitch, self._heading)]
        droll, dpitch, dyaw = (r / (2 * h) for r in rates)
        p = droll - dyaw * np.sin(pitch)
        q = dpitch * np.cos(roll) + dyaw * np.cos(pitch) * np.sin(roll)
        r = -dpitch * np.sin(roll) + dyaw * np.cos(pitch) * np.cos(roll)
        return SurveyState(
            self._interp(self._pos, t),
            self._interp(self._vel, t),
            self._interp(self._acc, t),
            np.asarray(q_from_euler_zyx(roll, pitch, yaw)),
            np.stack([p, q, r], axis=-1),
        )


def vtol_survey(turbulence: Turbulence | None = LIGHT_TURBULENCE) -> SurveyFlight:
    """A lawn-mower survey of a long bridge by a VTOL in forward flight (the issue's flight: 24 m/s, a 90 deg
    turn in about 3.4 s at 35 deg of bank): straights, 180 and 90 deg turns, a speed-up, a climb, a slow-down."""
    return SurveyFlight(
        [
            Leg("straight", 12.0),
            Leg("turn", turn_deg=180.0, bank_deg=30.0),
            Leg("straight", 10.0),
            Leg("speed", 3.0, accel_m_s2=1.5),
            Leg("straight", 6.0),
            Leg("turn", turn_deg=-90.0, bank_deg=35.0),
            Leg("climb", 8.0, climb_m_s=2.0),
            Leg("climb", 3.0, climb_m_s=0.0),
            Leg("turn", turn_deg=-180.0, bank_deg=25.0),
            Leg("speed", 3.0, accel_m_s2=-1.5),
            Leg("straight", 12.0),
        ],
        speed_m_s=21.0,
        heading_deg=90.0,
        turbulence=turbulence,
    )


def random_flight(
    rng: np.random.Generator, duration_s: float = 60.0, turbulence: Turbulence | None = LIGHT_TURBULENCE
) -> SurveyFlight:
    """Random legs (turns 30-180 deg at 15-40 deg of bank, speed changes, climbs) for property tests; the
    turbulence's seed is drawn from ``rng`` too."""
    legs: list[Leg] = [Leg("straight", float(rng.uniform(4.0, 8.0)))]
    total = legs[0].duration_s
    while total < duration_s:
        kind = str(rng.choice(["straight", "turn", "speed", "climb"]))
        if kind == "turn":
            leg = Leg(
                "turn",
                turn_deg=float(rng.choice([-1.0, 1.0]) * rng.uniform(30.0, 180.0)),
                bank_deg=float(rng.uniform(15.0, 40.0)),
            )
        elif kind == "speed":
            leg = Leg("speed", float(rng.uniform(2.0, 4.0)), accel_m_s2=float(rng.uniform(-1.5, 1.5)))
        elif kind == "climb":
            leg = Leg("climb", float(rng.uniform(3.0, 6.0)), climb_m_s=float(rng.uniform(-2.0, 2.0)))
        else:
            leg = Leg("straight", float(rng.uniform(3.0, 10.0)))
        legs.append(leg)
        total += max(leg.duration_s, 5.0)
    legs.append(Leg("climb", 3.0, climb_m_s=0.0))
    legs.append(Leg("straight", 6.0))
    speed, heading = float(rng.uniform(20.0, 25.0)), float(rng.uniform(0.0, 360.0))
    if turbulence is not None:
        turbulence = dataclasses.replace(turbulence, seed=int(rng.integers(1 << 31)))
    return SurveyFlight(legs, speed_m_s=speed, heading_deg=heading, turbulence=turbulence)
