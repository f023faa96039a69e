"""Trolley speed profiles: chainage s(t) with its first two derivatives, analytic and smooth.

A motion plan is a sequence of segments, each either a static period
(``Hold(duration_s)``) or a move to a target chainage (``Move(to_m, speed_mps,
accel_mps2)``, which may go backwards: a reversal). Moves accelerate and brake
with a raised-cosine acceleration ``a(t) = a_peak sin^2(pi t / T_a)``, so the
acceleration and its rate are continuous (s(t) is C^3) and the IMU sees no
jerk spikes; between ramps the speed is constant.

Closed forms for a ramp of duration ``T = 2 v / a_peak`` starting from rest::

    v(t) = a_peak (t/2 - T/(4 pi) sin(2 pi t / T))
    s(t) = a_peak (t^2/4 + T^2/(8 pi^2) (cos(2 pi t / T) - 1))

so a ramp covers ``v T / 2``. A move too short to reach its speed lowers
the speed (keeping the peak acceleration).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SimulationError


@dataclass(frozen=True)
class Hold:
    """Stand still for ``duration_s`` [s]."""

    duration_s: float


@dataclass(frozen=True)
class Move:
    """Move to chainage ``to_m`` [m] at cruise ``speed_mps`` [m/s] with peak acceleration ``accel_mps2``."""

    to_m: float
    speed_mps: float
    accel_mps2: float = 0.3


@dataclass
class MotionProfile:
    """A compiled motion plan: evaluate chainage, speed and acceleration at any time.

    Attributes: ``t0_s`` (M,) segment start times; ``s0_m`` (M,) chainage at
    each start; ``direction`` (M,) +1/-1/0; ``v_mps`` (M,) cruise speed (0 for
    holds); ``T_a_s`` (M,) ramp duration; ``duration_s`` (M,); ``a_peak`` (M,).
    """

    t0_s: np.ndarray
    s0_m: np.ndarray
    direction: np.ndarray
    v_mps: np.ndarray
    T_a_s: np.ndarray
    duration_s: np.ndarray
    a_peak: np.ndarray

    @property
    def end_s(self) -> float:
        """Total duration of the plan [s]."""
        return float(self.t0_s[-1] + self.duration_s[-1])

    @property
    def chainage_range_m(self) -> tuple[float, float]:
        """(min, max) chainage reached [m]."""
        ends = self.s0_m + self.direction * self._distance()
        allv = np.concatenate([self.s0_m, ends])
        return float(allv.min()), float(allv.max())

    def _distance(self) -> np.ndarray:
        cruise = np.maximum(self.duration_s - 2 * self.T_a_s, 0.0)
        return np.where(self.direction != 0, self.v_mps * (self.T_a_s + cruise), 0.0)

    def static_intervals(self) -> list[tuple[float, float]]:
        """(start, end) times [s] of every hold."""
        m = self.direction == 0
        return [(float(a), float(a + d)) for a, d in zip(self.t0_s[m], self.duration_s[m])]

    def evaluate(self, t_s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Chainage [m], speed ds/dt [m/s] and acceleration d2s/dt2 [m/s^2] at times ``t_s`` (any shape).

        Times before the start or after the end are clamped to the plan (standing still).
        """
        t = np.clip(np.asarray(t_s, dtype=float), self.t0_s[0], self.end_s)
        k = np.clip(np.searchsorted(self.t0_s, t, side="right") - 1, 0, len(self.t0_s) - 1)
        tau = t - self.t0_s[k]
        v, T, D, a_pk = self.v_mps[k], self.T_a_s[k], self.duration_s[k], self.a_peak[k]
        sgn = self.direction[k]
        ramp_s, ramp_v, ramp_a = _ramp(np.minimum(tau, T), T, a_pk)
        # braking ramp is the accelerating one mirrored in time
        tb = np.clip(D - tau, 0.0, None)
        brake_s, brake_v, brake_a = _ramp(np.minimum(tb, T), T, a_pk)
        dist_total = self._distance()[k]
        in_acc = tau < T
        in_brake = tau > D - T
        s_rel = np.where(in_acc, ramp_s, np.where(in_brake, dist_total - brake_s, v * T / 2 + v * (tau - T)))
        v_rel = np.where(in_acc, ramp_v, np.where(in_brake, brake_v, v))
        a_rel = np.where(in_acc, ramp_a, np.where(in_brake, -brake_a, 0.0))
        moving = sgn != 0
        s = self.s0_m[k] + np.where(moving, sgn * s_rel, 0.0)
        return s, np.where(moving, sgn * v_rel, 0.0), np.where(moving, sgn * a_rel, 0.0)


def _ramp(tau, T, a_peak):
    """Distance, speed and acceleration ``tau`` seconds into a raised-cosine ramp of duration T."""
    Ts = np.where(T > 0, T, 1.0)
    w = 2 * np.pi / Ts
    s = a_peak * (tau**2 / 4 + Ts**2 / (8 * np.pi**2) * (np.cos(w * tau) - 1))
    v = a_peak * (tau / 2 - np.sin(w * tau) / (2 * w))
    a = a_peak * np.sin(np.pi * tau / Ts) ** 2
    zero = T <= 0
    return np.where(zero, 0.0, s), np.where(zero, 0.0, v), np.where(zero, 0.0, a)


def compile_plan(start_m: float, segments: list[Hold | Move], t0_s: float = 0.0) -> MotionProfile:
    """Compile a list of :class:`Hold` / :class:`Move` segments starting at chainage ``start_m``.

    Raises :class:`SimulationError` for non-positive durations, speeds or accelerations.
    """
    if not segments:
        raise SimulationError("motion plan: no segments")
    rows = []
    t, s = float(t0_s), float(start_m)
    for i, seg in enumerate(segments):
        if isinstance(seg, Hold):
            if not seg.duration_s > 0:
                raise SimulationError(f"motion plan: segment {i}: hold duration must be > 0")
            rows.append((t, s, 0, 0.0, 0.0, seg.duration_s, 0.0))
            t += seg.duration_s
            continue
        if not (seg.speed_mps > 0 and seg.accel_mps2 > 0):
            raise SimulationError(f"motion plan: segment {i}: speed and acceleration must be > 0")
        dist = abs(seg.to_m - s)
        if dist == 0:
            raise SimulationError(f"motion plan: segment {i}: move of zero length")
        # ramp covers v T / 2 = v^2 / a_peak; two ramps must fit into the distance
        v = min(seg.speed_mps, np.sqrt(dist * seg.accel_mps2 / 2))
        T = 2 * v / seg.accel_mps2
        duration = 2 * T + (dist - v * T) / v
        rows.append((t, s, int(np.sign(seg.to_m - s)), v, T, duration, seg.accel_mps2))
        t += duration
        s = float(seg.to_m)
    cols = list(zip(*rows))
    return MotionProfile(*(np.array(c, dtype=float) for c in cols[:2]), np.array(cols[2], dtype=float),
                         *(np.array(c, dtype=float) for c in cols[3:]))
