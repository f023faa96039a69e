"""Clock jumps of a total station: found from its readings and the odometer, corrected or refused.

A station's clock may step by some milliseconds to seconds in the middle of a survey (a
re-synchronisation, a firmware hiccup). One clock offset per station (:mod:`.timesync`, refined
in the graph) then fits neither side: at 1 m/s, 20 ms is 20 mm along the track, and the gate
would reject everything after the step. The step is found before fusion.

**Detection (odometer).** Around a split between two moving readings, ``K`` moving readings on
each side (``WINDOW_S`` seconds), the prism positions are projected on the window's principal
axis, ``s_i``. The trolley's motion ties them to the odometer distance ``d_i`` at the readings'
times (IMU clock, with the correlation's offset):

    s_i = a + b d_i + c d_i^2 + e0 v_i + e1 v_i H_i

``v_i`` is the odometer speed, ``H_i`` is 1 after the split: ``e0`` absorbs the correlation's
own offset error, and ``J = -e1 / b`` is the clock step (a timing error ``dt`` moves a reading by
``v dt``). Weighted least squares with each reading's polar covariance along the axis. Readings
at rest carry no timing information and are left out, so a step during a stop is found from
the motion on both sides of it. Windows spanning a tracking gap (``registration.readings.PRISM_GAP_MIN_S``)
other than at their split, or whose fit does not explain the readings (a mis-lock: normalised chi-square above
``CHI2_MAX``) are skipped. Every split between moving readings is a candidate; the one of
largest ``|J| / sigma_J`` is refined to the split of smallest chi-square within a quarter
window.

**Attribution (station).** An odometer slip at constant speed moves the ``s - d`` relation by a
step just as a clock jump does. A clock jump, though, is in the station's *time stamps*: its
positions stay continuous in space while the stamps step. Where the trolley moves at the split,
a cubic in station time through the station's own readings (``STATION_WINDOW_S`` on each side)
with a step term gives ``J`` a second time, without the odometer. The two must agree (within 4 sigma and 2 ms); otherwise the
step is not the station's clock (the fusion's odometer slip detection sees it) and is left
alone. At rest (or with fewer than 4 readings on a side of the split) the stamps cannot show it
and the odometer's estimate is taken.

**Decision.** A step with ``|J| / sigma_J > Z_MIN`` is a jump. When ``sigma_J`` is within
``MAX_SIGMA_S`` it is removed from every later time stamp of the station (then the next is
searched, at most ``MAX_JUMPS``); otherwise the run is refused (:class:`RegistrationError`): the
motion around the step does not place the later readings in time well enough.

**Across a tracking gap** (up to ``GAP_MAX_S``, at the split itself; the odometer bridges it)
the same odometer fit shows a step of the ``s - d`` relation, but no reading sees it: a clock
jump while the station was not tracking and an odometer slip in the gap are the same step, and
the station's stamps cannot tell them apart. Correcting the clock for a slip would move every
later reading, ignoring a jump would leave them off by ``v J``: refused
(:class:`RegistrationError`).

Not found: a step inside a gap longer than ``GAP_MAX_S``, and steps below ``Z_MIN`` sigma (a
few milliseconds at walking speed). Pure maths on arrays.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..errors import RegistrationError
from .readings import PRISM_GAP_MIN_S

#: seconds of moving readings on each side of a candidate split
WINDOW_S = 8.0
#: readings slower than this (odometer) [m/s] are at rest: no timing information
MIN_SPEED_MPS = 0.05
#: a window whose jump model leaves a normalised chi-square above this is not explained (mis-lock)
CHI2_MAX = 4.0
#: significance of a step [sigma] to count as a clock jump
Z_MIN = 10.0
#: a jump determined worse than this [s] is refused
MAX_SIGMA_S = 2e-3
#: at most this many jumps per station are corrected
MAX_JUMPS = 10
#: a tracking gap up to this long [s] may lie at a candidate split (the odometer bridges it)
GAP_MAX_S = 30.0
#: seconds of the station's own readings on each side of the split for the attribution
STATION_WINDOW_S = 2.0
#: candidate splits fitted at once (memory: CHUNK x 2 WINDOW_S x rate x 3 x 3 floats)
CHUNK = 2000
#: station-only and odometer estimates agree within this many sigma (and ``AGREE_S``)
AGREE_SIGMA, AGREE_S = 4.0, 2e-3


def _speed(t_s: np.ndarray, odo_t_s: np.ndarray, odo_d_m: np.ndarray, half_s: float = 0.25) -> np.ndarray:
    """Odometer speed [m/s] (N,) at times ``t_s``, central difference over +-``half_s``."""
    return (np.interp(t_s + half_s, odo_t_s, odo_d_m) - np.interp(t_s - half_s, odo_t_s, odo_d_m)) / (2 * half_s)


def _axis_projection(p: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions (C, M, 3) projected on each window's principal axis: s (C, M) [m] about the
    window mean, and their standard deviations (C, M) from ``cov`` (C, M, 3, 3)."""
    centred = p - p.mean(axis=1, keepdims=True)
    _, vec = np.linalg.eigh(np.swapaxes(centred, 1, 2) @ centred)  # (matmul: 15x einsum's speed here)
    u = vec[:, :, -1]
    s = np.einsum("cmi,ci->cm", centred, u)
    sigma = np.sqrt(np.einsum("ci,cmij,cj->cm", u, cov, u))
    return s, sigma


def _wls(A: np.ndarray, y: np.ndarray, sigma: np.ndarray, ridge: np.ndarray
         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Batched weighted least squares: A (C, M, P), y and sigma (C, M), ``ridge`` (P,) added to
    the normal matrix's diagonal. Returns x (C, P), covariance (C, P, P), chi2 per dof (C,)."""
    w = 1.0 / sigma
    Aw, yw = A * w[..., None], y * w
    N = np.swapaxes(Aw, 1, 2) @ Aw + np.diag(ridge)
    cov = np.linalg.inv(N)
    x = np.einsum("cpq,cq->cp", cov, np.einsum("cmp,cm->cp", Aw, yw))
    r = yw - np.einsum("cmp,cp->cm", Aw, x)
    chi2 = np.sum(r * r, axis=1) / max(A.shape[1] - A.shape[2], 1)
    return x, cov, chi2


def _odometer_fit(splits: np.ndarray, k: int, s_idx: np.ndarray, t: np.ndarray, pos: np.ndarray, cov: np.ndarray,
                  d: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The jump model (module docstring) for splits (C,) into the moving readings ``s_idx``:
    windows ``s_idx[split - k : split + k]``. Returns J [s] (C,), sigma_J [s] (C,), chi2 (C,)."""
    win = s_idx[splits[:, None] + np.arange(-k, k)]
    s, sig = _axis_projection(pos[win], cov[win])
    dd = d[win] - d[win].mean(axis=1, keepdims=True)
    scale = np.maximum(np.abs(dd).max(axis=1, keepdims=True), 1e-3)
    x = dd / scale
    vv = v[win]
    after = (np.arange(2 * k) >= k).astype(float)
    A = np.stack([np.ones_like(x), x, x * x, vv, vv * after], axis=-1)
    sol, C, chi2 = _wls(A, s, sig, np.array([0.0, 0.0, 0.0, 1.0, 0.0]))
    b = sol[:, 1] / scale[:, 0]                       # ds/dd, about +-1
    J = -sol[:, 4] / b
    sigma_J = np.sqrt(C[:, 4, 4]) / np.abs(b) * np.sqrt(np.maximum(chi2, 1.0))
    return J, sigma_J, chi2


def _station_only_step(t: np.ndarray, pos: np.ndarray, cov: np.ndarray, i0: int, i1: int, first_after: int,
                       use: np.ndarray) -> tuple[float, float]:
    """The step in time [s] and its sigma from the station's own readings i0..i1-1 (original
    indices; of those, ``use`` (i1 - i0,) bool): a cubic in time of the positions along the
    principal axis plus a step after ``first_after``, divided by the speed at the split."""
    sl = np.arange(i0, i1)[use]
    s, sig = _axis_projection(pos[None, sl], cov[None, sl])
    tau = t[sl] - 0.5 * (t[first_after - 1] + t[first_after])
    span = max(float(np.abs(tau).max()), 1e-3)
    x = tau / span
    after = (sl >= first_after).astype(float)
    A = np.stack([np.ones_like(x), x, x**2, x**3, after], axis=-1)[None]
    sol, C, chi2 = _wls(A, s, sig, np.zeros(5))
    speed = sol[0, 1] / span
    if abs(speed) < MIN_SPEED_MPS:
        return np.nan, np.inf
    return float(-sol[0, 4] / speed), float(np.sqrt(C[0, 4, 4] * max(chi2[0], 1.0)) / abs(speed))


def _best_jump(t: np.ndarray, pos: np.ndarray, cov: np.ndarray, odo_t_s: np.ndarray, odo_d_m: np.ndarray,
               excluded: np.ndarray) -> dict[str, Any] | None:
    """The most significant step of one station's readings, or None (module docstring).
    ``t`` (N,) IMU clock [s]; ``excluded`` (N,) bool: readings near steps judged not a clock."""
    v = _speed(t, odo_t_s, odo_d_m)
    d = np.interp(t, odo_t_s, odo_d_m)
    period = float(np.median(np.diff(t)))
    k = max(8, int(round(WINDOW_S / period)))
    moving = np.flatnonzero((np.abs(v) > MIN_SPEED_MPS) & ~excluded)
    if moving.size < 2 * k + 1:
        return None
    gaps = np.r_[0, np.cumsum(np.diff(t) > max(PRISM_GAP_MIN_S, 3 * period))]
    splits = np.arange(k, moving.size - k + 1)
    gid = gaps[moving]
    inside = gid[splits + k - 1] == gid[splits - k]                              # no tracking gap inside
    at_gap = ((gid[splits - 1] == gid[splits - k]) & (gid[splits + k - 1] == gid[splits])  # one gap, at the split
              & (gid[splits] == gid[splits - 1] + 1) & (t[moving[splits]] - t[moving[splits - 1]] <= GAP_MAX_S))
    splits, across = splits[inside | at_gap], at_gap[inside | at_gap]
    if splits.size == 0:
        return None
    fits = [_odometer_fit(c, k, moving, t, pos, cov, d, v) for c in np.array_split(splits, -(-splits.size // CHUNK))]
    J, sJ, chi2 = (np.concatenate(f) for f in zip(*fits))
    z = np.where(chi2 < CHI2_MAX, np.abs(J) / sJ, 0.0)
    j = int(np.argmax(z))
    if z[j] < Z_MIN:
        return None
    near = np.abs(splits - splits[j]) <= k // 4          # the split that explains the readings best
    j = int(np.flatnonzero(near)[np.argmin(chi2[near])])
    split = int(splits[j])
    first_after = int(moving[split - 1]) + 1
    return {"J": float(J[j]), "sigma": float(sJ[j]), "first_after": first_after,
            "window": (int(moving[split - k]), int(moving[split + k - 1]) + 1), "speed": float(v[first_after]),
            "gap_s": (float(t[moving[split - 1]]), float(t[moving[split]])) if across[j] else None}


def correct_station_clock_jumps(station_id: str, t_station_s: np.ndarray, offset_s: float, pos_n: np.ndarray,
                                cov_n: np.ndarray, odo_t_s: np.ndarray, odo_d_m: np.ndarray,
                                excluded: np.ndarray | None = None) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """Find and remove the clock jumps of one station (module docstring).

    ``t_station_s`` (N,) [s, station clock]; ``offset_s`` the station's clock offset (the
    correlation's or given); ``pos_n`` (N,3) [m], ``cov_n`` (N,3,3) [m^2] its readings in ``n``;
    ``odo_t_s``, ``odo_d_m`` the odometer on the IMU clock. Returns the corrected station times
    (a new array: every stamp after a jump less the step) and one ``{"topic", "index", "t_s",
    "step_s", "sigma_s"}`` per jump (``index`` the first reading after it, ``t_s`` its IMU time
    with the given offset). ``excluded`` (N,) bool: readings that are not of the prism (the step
    check's mis-locks), left out of the search (their stamps are corrected too). Raises
    :class:`RegistrationError` for a jump it cannot determine.
    """
    t_st = np.asarray(t_station_s, dtype=float).copy()
    pos, cov = np.asarray(pos_n, dtype=float), np.asarray(cov_n, dtype=float)
    not_prism = np.zeros(t_st.size, dtype=bool) if excluded is None else np.asarray(excluded, dtype=bool)
    excluded = not_prism.copy()
    jumps: list[dict[str, Any]] = []
    topic = f"/total_station/{station_id}"
    for _ in range(2 * MAX_JUMPS):
        found = _best_jump(t_st - offset_s, pos, cov, odo_t_s, odo_d_m, excluded)
        if found is None:
            break
        J, sigma, i = found["J"], found["sigma"], found["first_after"]
        t_imu = float(t_st[i] - offset_s)
        if found["gap_s"] is not None:  # no reading sees the step: a clock jump or an odometer slip
            a, b = found["gap_s"]
            raise RegistrationError(
                f"{topic}: after its tracking gap {a:.1f}-{b:.1f} s (IMU clock) the readings lie "
                f"{abs(J * found['speed']) * 1e3:.0f} mm along the track from where the odometer puts them "
                f"({J * 1e3:+.0f} ms of the station's clock): a clock jump while the station was not tracking, "
                "or an odometer slip in the gap; no reading sees the step, so the data cannot tell which")
        i0, i1 = (int(x) for x in np.searchsorted(t_st, [t_st[i] - STATION_WINDOW_S, t_st[i - 1] + STATION_WINDOW_S]))
        use = ~not_prism[i0:i1]
        if abs(found["speed"]) > MIN_SPEED_MPS and min(use[:i - i0].sum(), use[i - i0:].sum()) >= 4:
            J_st, s_st = _station_only_step(t_st, pos, cov, i0, i1, i, use)  # the station's stamps must show it
            if not abs(J_st - J) <= max(AGREE_SIGMA * np.hypot(sigma, s_st), AGREE_S):
                excluded[found["window"][0]:found["window"][1]] = True   # not the station's clock
                continue
        if sigma > MAX_SIGMA_S:
            raise RegistrationError(
                f"{topic}: the station's clock jumps by about {J * 1e3:+.0f} ms near t = {t_imu:.1f} s (IMU clock), "
                f"but the motion around it determines the step only to +-{sigma * 1e3:.1f} ms (more than "
                f"{MAX_SIGMA_S * 1e3:g} ms): its later readings cannot be placed in time")
        if len(jumps) == MAX_JUMPS:
            raise RegistrationError(f"{topic}: more than {MAX_JUMPS} clock jumps; the station's clock is unusable")
        t_st[i:] -= J
        jumps.append({"topic": topic, "index": i, "t_s": t_imu, "step_s": J, "sigma_s": sigma})
    return t_st, jumps
