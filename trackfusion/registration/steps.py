"""Step check of a total station's own readings: mis-locks found before fusion.

A station that locks onto another reflector travelling with the prism (a second prism on the
trolley, a reflective vest beside it) reports a track that is as smooth as the true one but
offset by a few centimetres. The fusion cannot tell the two apart from the readings' residuals:
the first robust solve bends towards the offset track, and the gate then rejects good readings
at the edges. The change of target, though, is a **step** in the station's own track where the
mis-lock starts, and a step back where it ends: 2-10 cm against millimetres of noise at 10 Hz.

**The step statistic.** For every split between two readings of one station with ``K``
readings on each side (``WINDOW_S`` seconds; no tracking gap inside), the positions in ``n``
(N, 3) are fitted in station time by one cubic per axis plus a 3-D step ``S`` after the split,
weighted by each reading's full polar covariance (distance and angle noise differ by orders of
magnitude near the station, and the line of sight turns as the trolley passes it). The step's
significance is ``z2 = S' C_S^-1 S`` (chi-square, 3 dof), divided by the station's noise factor
(the median normalised chi-square of its windows, at least 1: noise above the specification
does not make steps). The track of a trolley is smooth in time at this scale (its acceleration
and jerk are continuous; curvature and braking are low-order in a 3 s window), so a cubic
explains it; a reading-to-reading jump does not fit it.

**Steps.** Splits with ``z2 > Z_MIN**2`` that are the largest within ``K`` splits are steps.

**Mis-locks onto a reflector that moves with the prism.** A step followed, within
``MAX_INTERVAL_S`` and without a tracking gap, by a step back (``S_b ~ -S_a``: their sum within
``PAIR_CHI2`` of its covariance, or within ``PAIR_FRACTION`` of the step) bounds a mis-lock:
the readings from the first after ``S_a`` to the last before ``S_b`` are flagged and left out of
the time synchronisation, the clock-jump search and the fusion. A step without a return is not
a mis-lock by itself: a clock jump below the clock-jump detection (a step ``v J`` along the
track) or a station re-acquiring the prism after locking onto a wrong target first look the
same.

**Mis-locks onto a reflector that does not move** (:func:`motionless_mislocks`, after the time
synchronisation). Between two consecutive steps without a return, the readings are not of the
prism when they did not travel with it: their chord falls short of the odometer's travel over
the same interval by more than ``MOTION_FRACTION`` of it and ``MOTION_MIN_M`` (the track is
one-dimensional and smooth, so the prism's chord is its travel, less centimetres on a curve).
At rest this says nothing; such a mis-lock, and whatever the step check misses, is left to the
gate of the fusion (:mod:`.mislock`).

Not flagged by construction: a hand-over (each station is checked on its own readings; a
station that stops or starts tracking has no split there), curvature, accelerating and
braking (low-order in time), and tracking gaps (no window spans a gap). Not found: a mis-lock
shorter than ``WINDOW_S`` (the gate sees those: the readings of the other side are in the
window), an offset below ``Z_MIN`` sigma of the step (about 2-3 mm across the line of sight at
300 m, 8 mm along it), and a mis-lock that starts or ends at a tracking gap.

Pure maths on arrays, on the station's own clock.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: seconds of readings on each side of a candidate split
WINDOW_S = 1.5
#: fewest readings on each side of a split
MIN_SIDE = 8
#: significance [sigma] of a step (``z2 > Z_MIN**2``, 3 dof)
Z_MIN = 8.0
#: a step and its return agree within this chi-square (3 dof) of their sum ...
PAIR_CHI2 = 25.0
#: ... or within this fraction of the step's length
PAIR_FRACTION = 0.2
#: longest mis-lock bounded by a step and its return [s]
MAX_INTERVAL_S = 300.0
#: between two steps, readings whose chord falls short of the odometer's travel by more than
#: this fraction of it (and ``MOTION_MIN_M`` [m]) are not of the prism (a fixed reflector)
MOTION_FRACTION, MOTION_MIN_M = 0.2, 0.5
#: an interval between readings longer than this [s] (and 3 median intervals) is a tracking gap
GAP_S = 1.0
#: the trolley's short-wave motion that a cubic does not follow [m] per axis (added to each
#: reading's covariance): track irregularities of millimetres over metres, the prism 1 m above
#: the rails rolling with the cross-level; near a station the angles resolve 0.1 mm
MODEL_SIGMA_M = 5e-4
#: candidate splits fitted at once (memory: CHUNK x 2K x 15 x 15 floats)
CHUNK = 1000

_P = 6  # basis functions per axis: 1, x, x^2, x^3, a step of acceleration, the step


def _segments(t_s: np.ndarray) -> list[tuple[int, int]]:
    """[first, end) index ranges of the tracked runs (no interval above the gap limit)."""
    if t_s.size < 2:
        return [(0, t_s.size)]
    dt = np.diff(t_s)
    cut = np.flatnonzero(dt > max(GAP_S, 3.0 * float(np.median(dt))))
    return list(zip(np.r_[0, cut + 1].tolist(), np.r_[cut + 1, t_s.size].tolist()))


def _window_fits(t: np.ndarray, pos: np.ndarray, info: np.ndarray, splits: np.ndarray, k: int
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cubic-plus-step fit (module docstring) for splits (C,) into one tracked run: windows
    ``split - k .. split + k - 1``. ``info`` (N, 3, 3) the readings' inverse covariances [1/m^2].
    Returns the step S (C, 3) [m], its covariance (C, 3, 3) [m^2] and the window's normalised
    chi-square (C,)."""
    win = splits[:, None] + np.arange(-k, k)
    tc = 0.5 * (t[splits - 1] + t[splits])
    tau = t[win] - tc[:, None]
    x = tau / np.abs(tau).max(axis=1, keepdims=True)
    after = (np.arange(2 * k) >= k).astype(float)
    basis = np.stack([np.ones_like(x), x, x * x, x**3, after * x * x, np.broadcast_to(after, x.shape)],
                     axis=-1)                                                                 # (C, M, P)
    W, p = info[win], pos[win]                                                                # (C,M,3,3), (C,M,3)
    C, M = x.shape
    BB = (basis[..., :, None] * basis[..., None, :]).reshape(C, M, _P * _P)
    N = np.matmul(BB.transpose(0, 2, 1), W.reshape(C, M, 9))                                  # (C, P*P, 9)
    N = N.reshape(C, _P, _P, 3, 3).transpose(0, 1, 3, 2, 4).reshape(C, 3 * _P, 3 * _P)
    Wp = np.einsum("cmij,cmj->cmi", W, p)
    rhs = (np.swapaxes(basis, 1, 2) @ Wp).reshape(-1, 3 * _P)  # (C, P, 3): matmul, far faster than einsum here
    unit = np.zeros((3 * _P, 3))
    unit[-3:] = np.eye(3)
    sol = np.linalg.solve(N, np.concatenate([rhs[:, :, None], np.broadcast_to(unit, (C, 3 * _P, 3))], axis=2))
    theta, cov_S = sol[:, :, 0], sol[:, -3:, 1:]          # the estimate, the step's block of N^-1
    chi2 = np.einsum("cmi,cmi->c", p, Wp) - np.einsum("cp,cp->c", theta, rhs)
    dof = 3 * 2 * k - 3 * _P
    return theta[:, -3:], cov_S, np.maximum(chi2, 0.0) / dof


def step_profile(t_s: np.ndarray, pos_n: np.ndarray, cov_n: np.ndarray) -> dict[str, np.ndarray]:
    """The step statistic at every split of one station's readings (module docstring).

    ``t_s`` (N,) [s] increasing (any clock); ``pos_n`` (N, 3) [m]; ``cov_n`` (N, 3, 3) [m^2].
    Returns ``split`` (C,): index of the first reading after each split; ``step_m`` (C, 3);
    ``cov_m2`` (C, 3, 3); ``chi2`` (C,) the window's normalised chi-square; ``z2`` (C,) the
    step's significance divided by the station's noise factor; ``noise_factor`` (1,)."""
    t = np.asarray(t_s, dtype=float)
    pos, cov = np.asarray(pos_n, dtype=float), np.asarray(cov_n, dtype=float)
    period = float(np.median(np.diff(t))) if t.size > 1 else 1.0
    k = max(MIN_SIDE, int(round(WINDOW_S / period)))
    info = np.linalg.inv(cov + MODEL_SIGMA_M**2 * np.eye(3))
    parts = []
    for a, b in _segments(t):
        splits = np.arange(a + k, b - k + 1)
        for c in np.array_split(splits, -(-splits.size // CHUNK)) if splits.size else []:
            parts.append((c, *_window_fits(t, pos, info, c, k)))
    if not parts:
        empty = np.zeros(0)
        return {"split": empty.astype(int), "step_m": np.zeros((0, 3)), "cov_m2": np.zeros((0, 3, 3)),
                "chi2": empty, "z2": empty, "noise_factor": np.ones(1)}
    split, S, C, chi2 = (np.concatenate(v) for v in zip(*parts))
    noise = max(1.0, float(np.median(chi2)))
    z2 = np.einsum("ci,cij,cj->c", S, np.linalg.inv(C), S) / noise
    return {"split": split, "step_m": S, "cov_m2": C * noise, "chi2": chi2, "z2": z2,
            "noise_factor": np.array([noise])}


def _peaks(split: np.ndarray, z2: np.ndarray, k: int) -> np.ndarray:
    """Indices into the profile of the significant steps: above ``Z_MIN**2`` and the largest
    within ``k`` splits, in time order."""
    cand = np.flatnonzero(z2 > Z_MIN**2)
    keep: list[int] = []
    for i in cand[np.argsort(-z2[cand], kind="stable")]:
        if all(abs(int(split[i]) - int(split[j])) > k for j in keep):
            keep.append(int(i))
    return np.array(sorted(keep), dtype=int)


def _returns(S_a: np.ndarray, C_a: np.ndarray, S_b: np.ndarray, C_b: np.ndarray) -> bool:
    """Is step b the return of step a (module docstring)?"""
    d = S_a + S_b
    chi2 = float(d @ np.linalg.solve(C_a + C_b, d))
    return chi2 < PAIR_CHI2 or float(np.linalg.norm(d)) < PAIR_FRACTION * float(np.linalg.norm(S_a))


def _run_index(t: np.ndarray) -> np.ndarray:
    """(N,) index of the tracked run each reading belongs to."""
    run = np.zeros(t.size, dtype=int)
    for j, (a, _b) in enumerate(_segments(t)):
        run[a:] = j
    return run


def _event(ia: int, ib: int, sa: dict, sb: dict, kind: str) -> dict[str, Any]:
    return {"first": ia, "last": ib - 1, "step_m": sa["step_m"].tolist(), "return_m": sb["step_m"].tolist(),
            "z": float(min(sa["z"], sb["z"])), "kind": kind}


def station_mislocks(t_s: np.ndarray, pos_n: np.ndarray, cov_n: np.ndarray
                     ) -> tuple[np.ndarray, list[dict[str, Any]], list[dict[str, Any]]]:
    """Mis-locks of one station found by the step check: a step and its return (module docstring).

    Arguments as :func:`step_profile`. Returns ``flagged`` (N,) bool (the readings inside the
    mis-locks), one ``{"first", "last", "step_m", "return_m", "z", "kind": "step_and_return"}``
    per mis-lock (indices of its first and last reading, the step at its start and at its end
    [m] (3,), the smaller significance of the two [sigma]) and the steps without a return
    (``{"split", "step_m", "cov_m2", "z"}``, for :func:`motionless_mislocks`)."""
    t = np.asarray(t_s, dtype=float)
    flagged = np.zeros(t.size, dtype=bool)
    prof = step_profile(t, pos_n, cov_n)
    if prof["split"].size == 0:
        return flagged, [], []
    period = float(np.median(np.diff(t)))
    k = max(MIN_SIDE, int(round(WINDOW_S / period)))
    found = [{"split": int(prof["split"][i]), "step_m": prof["step_m"][i], "cov_m2": prof["cov_m2"][i],
              "z": float(np.sqrt(prof["z2"][i]))} for i in _peaks(prof["split"], prof["z2"], k)]
    run = _run_index(t)
    out: list[dict[str, Any]] = []
    paired: set[int] = set()
    i = 0
    while i < len(found):
        a = found[i]
        for jb in range(i + 1, len(found)):
            b = found[jb]
            if run[b["split"]] != run[a["split"]] or t[b["split"] - 1] - t[a["split"]] > MAX_INTERVAL_S:
                break
            if _returns(a["step_m"], a["cov_m2"], b["step_m"], b["cov_m2"]):
                flagged[a["split"]:b["split"]] = True
                out.append(_event(a["split"], b["split"], a, b, "step_and_return"))
                paired |= {i, jb}
                i = jb
                break
        i += 1
    return flagged, out, [f for j, f in enumerate(found) if j not in paired]


def motionless_mislocks(t_imu_s: np.ndarray, pos_n: np.ndarray, unpaired: list[dict[str, Any]],
                        odo_t_s: np.ndarray, odo_d_m: np.ndarray) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Mis-locks onto a reflector that does not move with the trolley (module docstring), between
    two consecutive steps without a return (``unpaired`` of :func:`station_mislocks`).

    ``t_imu_s`` (N,) the station's readings on the IMU clock [s]; ``pos_n`` (N, 3) [m];
    ``odo_t_s``, ``odo_d_m`` the odometer. The readings between the steps are flagged when their
    chord ``|p_last - p_first|`` falls short of the odometer's travel over them by more than
    ``MOTION_FRACTION`` of it and ``MOTION_MIN_M``. Returns ``flagged`` (N,) bool and one event
    per mis-lock (as :func:`station_mislocks`, ``kind``: ``"motionless"``)."""
    t = np.asarray(t_imu_s, dtype=float)
    flagged = np.zeros(t.size, dtype=bool)
    run = _run_index(t)
    out: list[dict[str, Any]] = []
    for a, b in zip(unpaired[:-1], unpaired[1:]):
        ia, ib = a["split"], b["split"]
        if run[ia] != run[ib] or t[ib - 1] - t[ia] > MAX_INTERVAL_S:
            continue
        travel = float(abs(np.interp(t[ib - 1], odo_t_s, odo_d_m) - np.interp(t[ia], odo_t_s, odo_d_m)))
        chord = float(np.linalg.norm(pos_n[ib - 1] - pos_n[ia]))
        if travel - chord > max(MOTION_FRACTION * travel, MOTION_MIN_M):
            flagged[ia:ib] = True
            out.append(_event(ia, ib, a, b, "motionless"))
    return flagged, out
