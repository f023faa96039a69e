"""Analytic trajectories with known errors, for the evaluation's tests and benchmark.

A trolley runs back and forth on a curve of constant radius with a constant
gradient and a vertical undulation, with static holds at both ends of the
run; every quantity is closed-form, so a reference sampled at any rate is
exact and errors injected in along / lateral / vertical components are known.
"""

from __future__ import annotations

import numpy as np

TRAJECTORY_UNITS: dict[str, str] = {
    "t_s": "s", "e_m": "m", "n_m": "m", "u_m": "m", "qw": "1", "qx": "1", "qy": "1", "qz": "1",
    "ve_mps": "m/s", "vn_mps": "m/s", "vu_mps": "m/s", "chainage_m": "m",
    "sigma_e_m": "m", "sigma_n_m": "m", "sigma_u_m": "m",
}


def track_point(s_m: np.ndarray, radius_m: float = 800.0, gradient: float = 0.003,
                wave_m: float = 0.02, wavelength_m: float = 40.0) -> tuple[np.ndarray, np.ndarray]:
    """Position (N, 3) in ``n`` and its derivative d pos / d s (N, 3) at chainage s_m (N,) m.

    Horizontal: a circle of radius radius_m starting eastwards at the origin,
    turning left. Vertical: ``gradient * s + wave_m * sin(2 pi s / wavelength_m)``.
    """
    s = np.asarray(s_m, dtype=float)
    k = 2 * np.pi / wavelength_m
    psi = s / radius_m
    pos = np.column_stack([radius_m * np.sin(psi), radius_m * (1 - np.cos(psi)),
                           gradient * s + wave_m * np.sin(k * s)])
    d = np.column_stack([np.cos(psi), np.sin(psi), gradient + wave_m * k * np.cos(k * s)])
    return pos, d


def back_and_forth(t_s: np.ndarray, length_m: float, period_s: float, hold_s: float,
                   n_trips: int) -> tuple[np.ndarray, np.ndarray]:
    """Chainage (N,) m and its rate (N,) m/s: hold, then ``n_trips`` smooth round trips
    ``s = L/2 (1 - cos(2 pi t' / period_s))`` (speed zero at each reversal), then hold."""
    t = np.asarray(t_s, dtype=float) - hold_s
    moving = (t > 0) & (t < n_trips * period_s)
    w = 2 * np.pi / period_s
    s = np.where(moving, 0.5 * length_m * (1 - np.cos(w * t)), 0.0)
    sdot = np.where(moving, 0.5 * length_m * w * np.sin(w * t), 0.0)
    return s, sdot


def truth_columns(t_s: np.ndarray, length_m: float = 200.0, period_s: float = 400.0, hold_s: float = 10.0,
                  n_trips: int = 1, **track) -> dict[str, np.ndarray]:
    """Reference trajectory columns (``TRAJECTORY_UNITS`` without sigmas) at times t_s (N,) s."""
    s, sdot = back_and_forth(t_s, length_m, period_s, hold_s, n_trips)
    pos, d = track_point(s, **track)
    vel = d * sdot[:, None]
    psi = np.arctan2(d[:, 1], d[:, 0])
    one = np.ones_like(s)
    return {"t_s": np.asarray(t_s, dtype=float), "e_m": pos[:, 0], "n_m": pos[:, 1], "u_m": pos[:, 2],
            "qw": np.cos(psi / 2), "qx": 0 * one, "qy": 0 * one, "qz": np.sin(psi / 2),
            "ve_mps": vel[:, 0], "vn_mps": vel[:, 1], "vu_mps": vel[:, 2], "chainage_m": s}


def with_errors(truth: dict[str, np.ndarray], error_m: np.ndarray, sigma_m: float = 0.001) -> dict[str, np.ndarray]:
    """Estimate columns: ``truth`` displaced by error_m (N, 3) along / lateral / vertical, where
    along and lateral are horizontal and refer to the direction of increasing chainage of the
    truth track (recomputed from chainage, so valid at rest too), plus constant sigma columns."""
    _, d = track_point(truth["chainage_m"])
    along = d.copy()
    along[:, 2] = 0.0
    along /= np.linalg.norm(along, axis=1)[:, None]
    lateral = np.column_stack([-along[:, 1], along[:, 0], np.zeros(len(along))])
    disp = error_m[:, :1] * along + error_m[:, 1:2] * lateral
    disp[:, 2] += error_m[:, 2]
    est = dict(truth)
    est["e_m"] = truth["e_m"] + disp[:, 0]
    est["n_m"] = truth["n_m"] + disp[:, 1]
    est["u_m"] = truth["u_m"] + disp[:, 2]
    for c in ("sigma_e_m", "sigma_n_m", "sigma_u_m"):
        est[c] = np.full(len(along), sigma_m)
    return est
