"""IMU axis conventions and sample kinds (docs/import.md, "IMU conventions").

trackfusion's body frame ``b`` is x forward, y left, z up (REP-103 "FLU"). A logger's IMU axes
are declared as three letters saying where the sensor's x, y and z point, from F/B (forward,
back), L/R (left, right), U/D (up, down), e.g. ``frd`` (x forward, y right, z down) or
``flu``; or as a signed permutation matrix ``C_b_s`` (3x3, rows: body axes, columns: sensor
axes) with ``v_b = C_b_s @ v_s``. Both must be right-handed (determinant +1).

:func:`check_imu_frame` refuses a log that the declared axes would run upside down (the
median specific force along body z, which is +g on a near-level vehicle, negative or not the
largest) or that holds per-sample increments declared as rates (median specific force
norm near g * dt), each with a hint naming the likely declaration.
"""

from __future__ import annotations

import itertools

import numpy as np

from ..errors import SensorDataError
from .types import ImuData

G0_MPS2 = 9.80665
#: letter -> body direction of a sensor axis pointing that way
_DIRECTIONS = {"f": (1, 0, 0), "b": (-1, 0, 0), "l": (0, 1, 0), "r": (0, -1, 0), "u": (0, 0, 1), "d": (0, 0, -1)}
_LETTERS = {v: k for k, v in _DIRECTIONS.items()}


def axes_matrix(spec) -> np.ndarray:
    """``C_b_s`` (3, 3) of an axes declaration (three letters or a 3x3 signed permutation);
    raises ValueError (one line) for anything else or a left-handed set."""
    if isinstance(spec, str):
        letters = spec.strip().lower()
        if len(letters) != 3 or any(ch not in _DIRECTIONS for ch in letters):
            raise ValueError(f"axes {spec!r}: three letters from F/B, L/R, U/D (e.g. flu, frd)")
        c = np.array([_DIRECTIONS[ch] for ch in letters], dtype=float).T
    else:
        c = np.asarray(spec, dtype=float)
        if c.shape != (3, 3):
            raise ValueError(f"axes: a 3x3 signed permutation matrix, got shape {c.shape}")
    if not (np.isin(c, (-1.0, 0.0, 1.0)).all() and (np.abs(c).sum(axis=0) == 1).all()
            and (np.abs(c).sum(axis=1) == 1).all()):
        raise ValueError(f"axes {axes_name(c) if c.shape == (3, 3) else spec!r}: each sensor axis must point "
                         "along one body axis, each body axis used once")
    if round(np.linalg.det(c)) != 1:
        raise ValueError(f"axes {axes_name(c)}: left-handed (a right-handed IMU's axes give determinant +1)")
    return c


def axes_name(c: np.ndarray) -> str:
    """Three letters of a signed permutation ``C_b_s`` (its columns' body directions)."""
    return "".join(_LETTERS.get(tuple(int(v) for v in col), "?") for col in np.asarray(c).T)


def to_body(imu: ImuData, c_b_s: np.ndarray) -> ImuData:
    """The samples rotated from the sensor axes into ``b``: ``v_b = C_b_s @ v_s`` (a new ImuData)."""
    c = np.asarray(c_b_s, dtype=float)
    if np.array_equal(c, np.eye(3)):
        return imu
    return ImuData(imu.t_s, imu.gyro_radps @ c.T, imu.accel_mps2 @ c.T)


def rates_from_increments(t_s: np.ndarray, increments: np.ndarray) -> np.ndarray:
    """Mean rates (N, 3) over each sample's interval from per-sample increments (N, 3) over
    ``(t[i-1], t[i]]``: divided by ``t[i] - t[i-1]``; the first sample by the median interval."""
    t = np.asarray(t_s, dtype=float)
    dt = np.empty(t.size)
    if t.size > 1:
        dt[1:] = np.diff(t)
        dt[0] = np.median(dt[1:])
    else:
        dt[:] = np.nan
    return np.asarray(increments, dtype=float) / dt[:, None]


def _likely_axes(c_declared: np.ndarray, f_b: np.ndarray) -> str:
    """The right-handed declaration closest to the declared one (most axes kept) under which
    the median specific force ``f_b`` (declared body axes) points up."""
    f_s = c_declared.T @ f_b
    best, best_score = None, -np.inf
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            c = np.zeros((3, 3))
            c[list(perm), range(3)] = signs
            if round(np.linalg.det(c)) != 1:
                continue
            up = c @ f_s
            if up[2] < 0.9 * np.linalg.norm(up):
                continue
            score = float(np.sum(c * c_declared))
            if score > best_score:
                best, best_score = c, score
    return axes_name(best) if best is not None else "?"


#: samples used for the medians (every k-th sample of a long log: the median is robust anyway)
_CHECK_SAMPLES = 200_000


def check_imu_frame(imu: ImuData, source: str, c_b_s: np.ndarray, key: str) -> None:
    """Refuse an IMU log whose samples (already in ``b`` under the declared ``c_b_s``) are
    per-sample increments declared as rates, or whose specific force says the declared axes
    are upside down or on their side. ``source``: the log's name; ``key``: the setting that
    declares the axes (named in the hint). Runs before any computing."""
    n = imu.t_s.size
    if n < 2:
        return
    step = max(1, n // _CHECK_SAMPLES)
    f = np.asarray(imu.accel_mps2[::step], dtype=float)
    dt = float(np.median(np.diff(imu.t_s[::step]))) / step if step > 1 else float(np.median(np.diff(imu.t_s)))
    norm = float(np.median(np.linalg.norm(f, axis=1)))
    if dt > 0 and 0.5 * G0_MPS2 * dt < norm < 2.0 * G0_MPS2 * dt:
        raise SensorDataError(
            f"{source}: /imu: median linear_acceleration norm {norm:.4g} m/s^2 is g * dt ({G0_MPS2 * dt:.4g} at "
            f"{1 / dt:.6g} Hz): the samples look like per-sample increments; declare them as increments "
            "(accel unit m/s, gyro unit rad or deg) instead of rates")
    if not 0.8 * G0_MPS2 < norm < 1.2 * G0_MPS2:
        return  # not gravity-like at all: the units check names it (fusion/input_checks.py)
    f_med = np.median(f, axis=0)
    if f_med[2] > 0.9 * np.linalg.norm(f_med):
        return
    axis = int(np.argmax(np.abs(f_med)))
    says = f"{'xyz'[axis]} {'up' if f_med[axis] > 0 else 'down'}" if axis != 2 else "z down"
    raise SensorDataError(
        f"{source}: /imu: the median specific force ({f_med[0]:.3g}, {f_med[1]:.3g}, {f_med[2]:.3g}) m/s^2 in the "
        f"declared body axes ({key}: {axes_name(c_b_s)}) has gravity's reaction along body {says}, not z up: "
        f"the axes are wrong; likely {key}: {_likely_axes(np.asarray(c_b_s, float), f_med)}")
