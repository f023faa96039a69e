"""Sensor pre-processing before fusion: static (zero-velocity) intervals, odometer gross-error
repair, sensor clock to IMU clock.

* :func:`detect_static_intervals` finds where the trolley stands still (for ZUPT / zero angular
  rate factors and the initial alignment) from moving-window standard deviations of the gyro and
  accelerometer norms and, when given, the odometer speed.
* :func:`repair_odometer` detects and repairs isolated gross errors (spikes) of the odometer
  distance by cubic curve fitting and one-step prediction (seed 000, III.C.7).
* :func:`sensor_times_to_imu_clock` maps a sensor's time stamps to the IMU clock.

Everything is vectorised over the samples; only detected candidates are looped over.
"""

from __future__ import annotations

import heapq

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from ..errors import ConfigError, SensorDataError
from ..sensors.types import ImuData, OdometerData, finite_array

__all__ = ["detect_static_intervals", "moving_intervals_by_gnss", "repair_odometer", "sensor_times_to_imu_clock",
           "MAX_CONSECUTIVE_REPAIRS"]

#: at most this many consecutive samples are repaired; a longer run is a real discontinuity
#: (counter jump, data gap, manoeuvre the cubic cannot follow), accepted as measured
MAX_CONSECUTIVE_REPAIRS = 5

#: a moving window spanning more than this many times its nominal duration contains a data gap
_GAP_FACTOR = 1.5


# --- validation -------------------------------------------------------------------------------

def _times_s(t_s, name: str, min_samples: int) -> np.ndarray:
    """Validated time stamps (N,) [s]: 1-D, finite, strictly increasing, at least ``min_samples``."""
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.size < min_samples:
        raise SensorDataError(f"{name}: t_s needs at least {min_samples} samples, got shape {t.shape}")
    if not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
        raise SensorDataError(f"{name}: t_s must be finite and strictly increasing")
    return t


def _samples(x, n: int, name: str, field: str, width: int | None = None) -> np.ndarray:
    """Validated finite float samples of shape (n,) or (n, width)."""
    return finite_array(x, n, name, field, width, SensorDataError)


def _positive(value: float, name: str) -> float:
    """``value`` as float if finite and > 0, else :class:`ConfigError`."""
    v = float(value)
    if not np.isfinite(v) or v <= 0:
        raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")
    return v


# --- static intervals -------------------------------------------------------------------------

def _moving_std(x: np.ndarray, n: int) -> np.ndarray:
    """Standard deviation (N - n + 1,) of ``x`` (N,) over the windows ``x[k:k+n]``, O(N) by
    cumulative sums. ``x`` is centred on its median first, so the sums stay small and the
    difference of cumulative sums keeps its precision over millions of samples."""
    xc = x - np.median(x)
    c = np.zeros(x.size + 1)  # one cumulative-sum buffer, filled in place (long runs: memory)
    np.cumsum(xc, out=c[1:])
    s1 = c[n:] - c[:-n]
    np.multiply(xc, xc, out=xc)
    np.cumsum(xc, out=c[1:])
    del xc
    var = c[n:] - c[:-n]
    del c
    np.multiply(s1, s1, out=s1)
    s1 /= n
    var -= s1
    var /= n - 1
    return np.sqrt(np.maximum(var, 0.0, out=var), out=var)


def _norms(x: np.ndarray) -> np.ndarray:
    """Row norms (N,) of ``x`` (N, 3), in one buffer."""
    sq = np.einsum("ij,ij->i", x, x)
    return np.sqrt(sq, out=sq)


def _odometer_quiet(t_a: np.ndarray, t_b: np.ndarray, odometer: OdometerData,
                    max_speed_mps: float) -> np.ndarray:
    """Windows [t_a, t_b] (K,) [s] whose odometer speed |d(t_b) - d(t_a)| / (t_b - t_a) is below
    ``max_speed_mps``; windows reaching more than one odometer step outside the odometer's time
    span are not quiet."""
    t_odo = _times_s(odometer.t_s, "odometer", 2)
    d_odo = _samples(odometer.distance_m, t_odo.size, "odometer", "distance_m")
    step_s = float(np.median(np.diff(t_odo)))
    quiet = np.empty(t_a.size, dtype=bool)
    for k in range(0, t_a.size, _PREDICTION_BLOCK):  # blocks bound the temporaries (long runs)
        a, b = t_a[k:k + _PREDICTION_BLOCK], t_b[k:k + _PREDICTION_BLOCK]
        speed_mps = np.abs(np.interp(b, t_odo, d_odo) - np.interp(a, t_odo, d_odo)) / (b - a)
        quiet[k:k + _PREDICTION_BLOCK] = (speed_mps < max_speed_mps) & (a >= t_odo[0] - step_s) & (b <= t_odo[-1] + step_s)
    return quiet


def _true_runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First and last index (each (R,)) of every run of True in the boolean ``mask``."""
    edges = np.diff(np.concatenate(([0], mask.astype(np.int8), [0])))
    return np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1


class _CentredCumsum:
    """Rows of the cumulative sums ``c`` (N + 1, k) of ``x - med`` (``x`` (N, k), ``med`` its
    column medians), made on demand for increasing row ranges: the mean over the window
    ``x[j:j+n]`` is ``(c[j+n] - c[j]) / n + med``. The sums are sequential from the previous
    range's rows (the values of one cumulative sum over the whole run, without its buffer:
    long runs' memory); centring keeps the precision over millions of samples."""

    def __init__(self, x: np.ndarray):
        self.x = x
        self.med = np.array([np.median(x[:, i]) for i in range(x.shape[1])])  # a column's copy at a time
        self.lo, self.rows_ = 0, np.zeros((1, x.shape[1]))  # c[lo : lo + len(rows_)]

    def _from(self, start: np.ndarray, a: int, b: int) -> np.ndarray:
        """c[a : b + 1] from c[a] = ``start``."""
        out = np.empty((b - a + 1, self.x.shape[1]))
        out[0] = start
        np.subtract(self.x[a:b], self.med, out=out[1:])
        return np.cumsum(out, axis=0, out=out)

    def rows(self, a: int, b: int) -> np.ndarray:
        """c[a : b] (a at least the previous call's ``a``)."""
        if a >= self.lo + len(self.rows_):  # walk on to row a in blocks
            at, start = self.lo + len(self.rows_) - 1, self.rows_[-1]
            while at < a:
                step = min(a, at + _PREDICTION_BLOCK)
                start, at = self._from(start, at, step)[-1], step
            self.lo, self.rows_ = a, start[None]
        self.rows_ = self._from(self.rows_[a - self.lo], a, b - 1)
        self.lo = a
        return self.rows_


def _locally_steady(m: np.ndarray, half: int, threshold: float) -> np.ndarray:
    """Windows (K,) whose mean ``m`` (K, 3) varies by less than ``threshold`` on every axis over
    the ``half`` windows either side (sliding maximum minus minimum, scipy.ndimage: O(K))."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d
    size = 2 * half + 1
    spread = maximum_filter1d(m, size, axis=0, mode="nearest") - minimum_filter1d(m, size, axis=0, mode="nearest")
    return np.all(spread < threshold, axis=1)


def _steady_means(x: np.ndarray, n: int, quiet: np.ndarray, threshold: float) -> np.ndarray:
    """Windows (K,) of steady mean ``x`` (N, 3) inside the runs of quiet windows (``quiet`` (K,));
    windows outside a run are True.

    A vehicle at rest measures a constant specific force and rate; one that starts or stops
    accelerates, which moves the mean specific force by the acceleration long before the
    vibration of rolling shows in the standard deviation of the norm (a raised-cosine start of
    0.4 m/s^2 reaches 5 mm/s^2 within 0.6 s, at 1 mm/s). Two tests, both needed:

    * locally steady: the window mean varies by less than ``threshold`` over one window length
      either side (:func:`_locally_steady`). This cuts a quiet run at every start and stop,
      however long the motion between them is. A smooth motion without vibration (a
      noise-free log, a good track) stays quiet for minutes; the median of such a run is the
      motion's, not the rest's, and the rest periods at its ends were lost to it.
    * within ``threshold`` (vector norm) of the median window mean of its locally steady piece:
      a slow drift of the mean that no single window sees (a creeping start) is caught as
      long as less than half the piece is motion.

    (Window means only inside the runs.)"""
    c = _CentredCumsum(x)
    steady = np.ones(quiet.size, dtype=bool)
    for a, b in zip(*_true_runs(quiet)):
        rows = c.rows(a, b + n + 1)  # c[a .. b + n]
        m = (rows[n:] - rows[:-n]) / n + c.med
        local = _locally_steady(m, n, threshold)
        ok = np.zeros(m.shape[0], dtype=bool)
        for p, q in zip(*_true_runs(local)):
            piece = m[p:q + 1]
            ok[p:q + 1] = np.linalg.norm(piece - np.median(piece, axis=0), axis=1) < threshold
        steady[a:b + 1] = ok
    return steady


def detect_static_intervals(imu: ImuData, odometer: OdometerData | None = None, *,
                            window_s: float = 0.5, gyro_std_radps: float = 2e-4,
                            accel_std_mps2: float = 5e-3, max_odometer_speed_mps: float = 1e-3,
                            min_duration_s: float = 2.0) -> list[tuple[float, float]]:
    """Intervals on the IMU clock where the trolley stands still.

    A moving window of ``n = round(window_s / dt)`` IMU samples (``dt`` the median sample step)
    is *quiet* when the standard deviation of the gyro norm is below ``gyro_std_radps``, that of
    the accelerometer norm below ``accel_std_mps2``, the window's mean gyro and accelerometer
    vectors vary by less than the same thresholds over a window length either side and lie within
    them of the median window mean of their steady piece (a start or stop is an acceleration:
    :func:`_steady_means`; this needs no odometer and no vibration) and, with an odometer, the odometer speed over
    the window ``|d(t_last) - d(t_first)| / (t_last - t_first)`` below ``max_odometer_speed_mps``.
    A window holding a data gap (spanning more than 1.5 times its nominal duration) or reaching
    more than one odometer step outside the odometer's time span is never quiet. A sample is static when every window that
    contains it is quiet: the run of quiet window centres shrunk by half a window at both ends,
    so a sample whose motion shows anywhere in a window is not included. (At the first and last
    sample of the record the run is not shrunk.) Intervals shorter than ``min_duration_s`` are
    dropped.

    Typical thresholds: the default suits a navigation-grade IMU (gyro white noise ~1e-6 rad/s
    and accel ~1e-4 m/s^2 per sample); a MEMS IMU at 100-500 Hz (~1e-3 rad/s, ~1e-2 m/s^2 per
    sample and axis) needs about ``gyro_std_radps=3e-3, accel_std_mps2=3e-2``. The norm of the
    specific force hardly changes with a horizontal acceleration (by a^2 / 2g) and the gyro norm
    not at all on straight track, so the standard deviations see motion only through the vibration
    of a rolling trolley; the steady-mean test sees the acceleration of every start and stop. An
    IMU cannot tell a constant speed from rest: pass the odometer (after :func:`repair_odometer`,
    a spike would cut a static interval), or check the intervals against GNSS fixes
    (:func:`moving_intervals_by_gnss`). Computation is O(N) by cumulative sums.

    Parameters
    ----------
    imu : ImuData
        ``t_s`` (N,) [s, IMU clock], ``gyro_radps`` (N, 3) [rad/s], ``accel_mps2`` (N, 3) [m/s^2].
    odometer : OdometerData or None
        ``t_s`` (M,) [s, IMU clock], ``distance_m`` (M,) cumulative signed distance [m].
    window_s : float
        Moving-window length [s].
    gyro_std_radps, accel_std_mps2 : float
        Thresholds of the windowed standard deviation of the gyro norm [rad/s] and of the
        accelerometer norm [m/s^2].
    max_odometer_speed_mps : float
        Threshold of the windowed odometer speed [m/s].
    min_duration_s : float
        Shortest interval returned [s].

    Returns
    -------
    list of (start_s, end_s)
        Time stamps [s, IMU clock] of the first and last static sample of each interval,
        in increasing order.

    Raises
    ------
    SensorDataError
        Empty, too short (fewer than two windows of samples) or malformed IMU or odometer data.
    ConfigError
        A non-positive window or threshold.
    """
    window_s = _positive(window_s, "window_s")
    for value, name in ((gyro_std_radps, "gyro_std_radps"), (accel_std_mps2, "accel_std_mps2"),
                        (max_odometer_speed_mps, "max_odometer_speed_mps")):
        _positive(value, name)
    t = _times_s(imu.t_s, "imu", 2)
    dt_s = float(np.median(np.diff(t)))
    n = max(2, int(round(window_s / dt_s)))
    if t.size < 2 * n:
        raise SensorDataError(f"imu: {t.size} samples are fewer than two {window_s} s windows ({2 * n})")
    gyro = _samples(imu.gyro_radps, t.size, "imu", "gyro_radps", 3)
    accel = _samples(imu.accel_mps2, t.size, "imu", "accel_mps2", 3)

    quiet = ((_moving_std(_norms(gyro), n) < gyro_std_radps) & (_moving_std(_norms(accel), n) < accel_std_mps2))
    t_a, t_b = t[: t.size - n + 1], t[n - 1:]
    quiet &= (t_b - t_a) <= _GAP_FACTOR * (n - 1) * dt_s
    if odometer is not None:
        quiet &= _odometer_quiet(t_a, t_b, odometer, max_odometer_speed_mps)

    quiet &= _steady_means(gyro, n, quiet, gyro_std_radps) & _steady_means(accel, n, quiet, accel_std_mps2)

    first_k, last_k = _true_runs(quiet)
    first = np.where(first_k == 0, 0, first_k + n - 1)          # window k covers samples k .. k+n-1
    last = np.where(last_k == quiet.size - 1, t.size - 1, last_k)
    keep = (last > first) & (t[np.maximum(last, first)] - t[first] >= min_duration_s)
    return [(float(t[a]), float(t[b])) for a, b in zip(first[keep], last[keep])]


def moving_intervals_by_gnss(intervals: list[tuple[float, float]], t_s: np.ndarray, pos_m: np.ndarray,
                             sigma_m: np.ndarray, n_sigma: float = 5.0) -> list[int]:
    """Indices of the static intervals during which GNSS fixes show motion.

    intervals: [(start_s, end_s)] on the fixes' clock; t_s (F,) [s], pos_m (F,3) [m] fix
    positions, sigma_m (F,3) [m] their standard deviations per axis. Per interval and axis the
    speed through the fixes inside (Theil-Sen: the median of the pairwise slopes, so outlying
    fixes do not count; at most 300 fixes, evenly chosen) is compared with the least-squares
    speed's standard deviation (from the median fix sigma, as if white); an interval whose speed
    exceeds ``n_sigma`` of it on any axis (or ``n_sigma`` times the median sigma over its span,
    for a correlated fix error) is moving. This is what an IMU cannot see: a constant speed.
    Intervals with fewer than three fixes are not checked.
    """
    moving = []
    for i, (a, b) in enumerate(intervals):
        inside = np.flatnonzero((t_s >= a) & (t_s <= b))
        if inside.size < 3:
            continue
        inside = inside[np.unique(np.linspace(0, inside.size - 1, min(inside.size, 300)).astype(int))]
        t = t_s[inside] - t_s[inside].mean()
        iu, ju = np.triu_indices(inside.size, 1)
        speed = np.median((pos_m[inside][ju] - pos_m[inside][iu]) / (t[ju] - t[iu])[:, None], axis=0)
        sigma = np.median(sigma_m[inside], axis=0)
        bound = n_sigma * np.maximum(sigma / np.sqrt(t @ t), sigma / max(b - a, 1e-9))
        if np.any(np.abs(speed) > bound):
            moving.append(i)
    return moving


# --- odometer gross errors --------------------------------------------------------------------

def _cubic_extrapolate_m(t_hist_s: np.ndarray, d_hist_m: np.ndarray, t_new_s: np.ndarray) -> np.ndarray:
    """Least-squares cubic in time through each history row, evaluated at the new time.

    ``t_hist_s``, ``d_hist_m`` (K, w) [s], [m] with w >= 4; ``t_new_s`` (K,) [s]. Returns (K,) [m].
    Time is centred on ``t_new_s`` and scaled by the history span, distance centred on the
    last history value, so the 4x4 normal equations stay well conditioned."""
    span_s = t_new_s - t_hist_s[:, 0]
    tau = (t_hist_s - t_new_s[:, None]) / span_s[:, None]
    d_ref = d_hist_m[:, -1]
    dd_m = d_hist_m - d_ref[:, None]
    power_sums = np.empty((tau.shape[0], 7))                           # sum over w of tau^p, p = 0..6
    moments = np.empty((tau.shape[0], 4))                              # sum over w of tau^p dd, p = 0..3
    tau_p = np.ones_like(tau)
    for p in range(7):
        power_sums[:, p] = tau_p.sum(axis=1)
        if p < 4:
            moments[:, p] = (tau_p * dd_m).sum(axis=1)
        tau_p = tau_p * tau
    AtA = power_sums[:, np.arange(4)[:, None] + np.arange(4)]         # (K, 4, 4) normal matrix
    return d_ref + np.linalg.solve(AtA, moments[..., None])[:, 0, 0]  # value at tau = 0


def _raw_predictions_m(t_s: np.ndarray, d_m: np.ndarray, window: int) -> np.ndarray:
    """One-step cubic predictions (N,) [m] of every sample from the ``window`` raw samples
    before it; NaN for the first ``window`` samples."""
    pred = np.full(d_m.shape, np.nan)
    t_hist, d_hist = sliding_window_view(t_s[:-1], window), sliding_window_view(d_m[:-1], window)
    for a in range(0, t_hist.shape[0], _PREDICTION_BLOCK):  # blocks bound the (K, window) temporaries
        s = slice(a, a + _PREDICTION_BLOCK)
        pred[window + a:window + a + _PREDICTION_BLOCK] = _cubic_extrapolate_m(t_hist[s], d_hist[s], t_s[window:][s])
    return pred


#: samples per block of :func:`_raw_predictions_m` (each row's fit is independent of the others)
_PREDICTION_BLOCK = 65536


def _predict_one_m(t_s: np.ndarray, d_m: np.ndarray, i: int, window: int) -> float:
    """Cubic prediction [m] of sample ``i`` from the ``window`` samples of ``d_m`` before it."""
    return float(_cubic_extrapolate_m(t_s[None, i - window:i], d_m[None, i - window:i], t_s[i:i + 1])[0])


def _block_outliers(t_s: np.ndarray, d_m: np.ndarray, threshold_m: float) -> dict[int, float]:
    """Gross errors of a short block (B,) without history: robust cubic fit.

    Repeatedly drops the sample of the largest leave-one-out residual (its prediction by the
    cubic through all other kept samples) while that exceeds ``threshold_m``; the dropped
    samples whose residual to the final fit still exceeds it are returned, position in the
    block -> fitted value [m]."""
    tau = (t_s - t_s[0]) / (t_s[-1] - t_s[0])
    A = tau[:, None] ** np.arange(4)
    keep = np.ones(t_s.size, dtype=bool)
    while keep.sum() > 4:
        Ak, dk = A[keep], d_m[keep] - d_m[keep].mean()
        H = Ak @ np.linalg.pinv(Ak)
        loo_m = (dk - H @ dk) / (1.0 - np.diag(H))
        worst = int(np.argmax(np.abs(loo_m)))
        if abs(loo_m[worst]) <= threshold_m:
            break
        keep[np.flatnonzero(keep)[worst]] = False
    coef = np.linalg.lstsq(A[keep], d_m[keep], rcond=None)[0]
    fit_m = A @ coef
    return {int(j): float(fit_m[j]) for j in np.flatnonzero(~keep) if abs(d_m[j] - fit_m[j]) > threshold_m}


class _Repairer:
    """Sequential one-step cubic check of the candidates, on the repaired series ``d``.

    Any change of ``d[j]`` queues samples j+1 .. j+window (their prediction changed), so the
    result equals a full sequential pass over all samples."""

    def __init__(self, t_s: np.ndarray, d_raw_m: np.ndarray, window: int, threshold_m: float):
        self.t, self.raw, self.w, self.thr = t_s, d_raw_m, window, threshold_m
        self.d = d_raw_m.copy()
        self.predicted: dict[int, float] = {}                 # repaired index -> predicted [m]
        self.queue: list[int] = []
        self.checked_from = 0                                  # first index of the forward check
        self.run_first, self.run_last = -2, -2                 # current run of consecutive repairs

    def _set(self, i: int, value_m: float | None) -> None:
        """Repair sample i with ``value_m`` (None: restore the measurement) and queue its successors."""
        if value_m is None:
            self.predicted.pop(i, None)
            self.d[i] = self.raw[i]
        else:
            self.predicted[i] = value_m
            self.d[i] = value_m
        for k in range(i + 1, min(i + self.w + 1, self.d.size)):
            heapq.heappush(self.queue, k)

    def start_segment(self, first: int) -> None:
        """Start checking afresh at ``first``: the first ``window`` samples from a robust block fit."""
        end = min(first + 2 * self.w, self.d.size)
        if end - first > 4:
            for j, value_m in _block_outliers(self.t[first:end], self.d[first:end], self.thr).items():
                if j < self.w:
                    self._set(first + j, value_m)
        self.checked_from = first + self.w

    def check(self, i: int) -> None:
        """One-step check of sample i (histories before i final)."""
        pred_m = _predict_one_m(self.t, self.d, i, self.w)
        if abs(self.raw[i] - pred_m) <= self.thr:
            return
        self._set(i, pred_m)
        self.run_first = self.run_first if i == self.run_last + 1 else i
        self.run_last = i
        if i - self.run_first + 1 > MAX_CONSECUTIVE_REPAIRS:   # not a spike: accept and restart
            for k in range(self.run_first, i + 1):
                self._set(k, None)
            self.run_last = -2
            self.start_segment(self.run_first)

    def run(self, candidates: np.ndarray) -> None:
        """Check the candidate indices (sorted) and everything their repairs affect."""
        self.queue.extend(int(i) for i in candidates)
        heapq.heapify(self.queue)
        self.start_segment(0)
        last = -1
        while self.queue:
            i = heapq.heappop(self.queue)
            if i > last and i >= self.checked_from:
                self.check(i)
                last = i


def _ticks_per_m(d_m: np.ndarray, ticks: np.ndarray, pair: np.ndarray) -> float:
    """The least-squares ratio of tick to distance increments [1/m] over the sample pairs
    ``pair`` (N-1,) bool of ``d_m`` (N,) [m] and ``ticks`` (N,); 0 where the distance does not move."""
    dd_m, dn = np.diff(d_m)[pair], np.diff(ticks.astype(float))[pair]
    if not np.any(dd_m != 0):
        return 0.0
    return float(dd_m @ dn / (dd_m @ dd_m))


def odometer_quantum_m(odometer: OdometerData) -> float:
    """The distance of one encoder tick [m]: the least-squares ratio of the distance to the tick
    increments of the whole log (a log's distance is its ticks times the nominal tick length, so
    this is that length); 0 when the log carries no ticks (all zero) or no motion."""
    if odometer.ticks.size < 2 or not np.any(np.diff(odometer.ticks)):
        return 0.0
    ticks_per_m = _ticks_per_m(odometer.distance_m, odometer.ticks, np.ones(odometer.ticks.size - 1, bool))
    return 1.0 / ticks_per_m if ticks_per_m > 0 else 0.0


def _repaired_ticks(ticks: np.ndarray, d_m: np.ndarray, flagged: np.ndarray, threshold_m: float) -> np.ndarray:
    """Ticks (N,) consistent with the repaired distance ``d_m`` (N,) [m] at the ``flagged`` indices.

    ``ticks_per_m`` is the least-squares ratio of tick to distance increments between unflagged
    neighbours. A flagged sample keeps its ticks when they agree (within ``threshold_m``) with its
    repaired distance counted from the nearest unflagged sample (the spike was in the distance
    output only); otherwise they become that count, rounded. Without motion (no ratio) the ticks
    are kept."""
    out = ticks.copy()
    good = np.ones(d_m.size, dtype=bool)
    good[flagged] = False
    pair = good[1:] & good[:-1]
    ticks_per_m = _ticks_per_m(d_m, ticks, pair) if flagged.size else 0.0
    if ticks_per_m <= 0:
        return out
    unflagged = np.flatnonzero(good)                           # not empty: some pair is unflagged
    ref = unflagged[np.maximum(np.searchsorted(unflagged, flagged) - 1, 0)]  # previous, else first
    expected = ticks[ref] + (d_m[flagged] - d_m[ref]) * ticks_per_m
    bad = np.abs(ticks[flagged] - expected) / ticks_per_m > threshold_m
    out[flagged[bad]] = np.round(expected[bad]).astype(out.dtype)
    return out


def repair_odometer(odometer: OdometerData, *, window: int = 8,
                    threshold_m: float = 0.01) -> tuple[OdometerData, list[dict]]:
    """Detect and repair isolated gross errors (spikes) of the odometer distance (seed 000, III.C.7).

    Every sample i is predicted from the ``window`` accepted (measured or already repaired)
    samples before it by a least-squares cubic polynomial in time, and flagged when
    ``|measured - predicted| > threshold_m``; a flagged sample is replaced by its prediction, and
    later predictions use the repaired value, so an isolated spike does not poison them.

    Method: the seed fits a cubic spline to adjacent outputs and extrapolates one interval. Over
    a window of a few samples a cubic spline's last piece is a single cubic, and the
    least-squares cubic over ``window`` > 4 samples is that fit with redundancy: it smooths the
    tick quantisation instead of amplifying it (at ``window=8`` on uniform sampling the
    prediction is a fixed linear combination of the 8 samples with norm 2.5, against 8.3 for the
    interpolating cubic through 4) and it is a batched 4x4 solve for all samples at once, where
    ``scipy.interpolate.CubicSpline`` would need one spline object per sample. Its one-step error
    on trolley motion (3 m/s, 0.4 m/s^2, smooth jerk, starts, stops, reversals) at 100 Hz is a
    few micrometres, far below the default 1 cm threshold (the seed's 3 x 0.67 cm at 2 m/s and
    300 Hz was 2 cm). Keep ``window / rate`` short (0.1 s or so): a cubic over a long window no
    longer follows the motion. Non-uniform time stamps are handled (the fit is in time).

    Computation: predictions of all samples from the raw series (vectorised); the samples whose
    raw residual exceeds the threshold (spikes and the samples a spike poisons) are re-checked
    in increasing order against the repaired series, and every repair queues the next
    ``window`` samples for a re-check, which equals a full sequential pass. The first
    ``window`` samples have no history: they are checked by a robust cubic fit to the first
    ``2 window`` samples (the sample with the largest leave-one-out residual is dropped while
    that exceeds the threshold; ``predicted_m`` is then the fitted value). More than
    ``MAX_CONSECUTIVE_REPAIRS`` consecutive flags are not a spike but a real discontinuity
    (counter jump, data gap): those samples are kept as measured and the check starts afresh
    there, so a discontinuity does not set off an endless run of extrapolated "repairs".

    Ticks: ``ticks_per_m`` is estimated from the increments of unflagged neighbours; a repaired
    sample keeps its ticks when they agree with its repaired distance counted from the nearest
    unflagged sample (the simulator's spikes are in the distance output only), otherwise its
    ticks become that count, rounded.

    Parameters
    ----------
    odometer : OdometerData
        ``t_s`` (N,) [s], ``distance_m`` (N,) cumulative signed distance [m], ``ticks`` (N,)
        int. Not modified.
    window : int
        Number of preceding samples of each cubic fit (>= 4).
    threshold_m : float
        Largest accepted difference between measurement and prediction [m]; must exceed the
        prediction noise and stay below the smallest spike to be found (0.02 m in the simulator).

    Returns
    -------
    OdometerData
        New arrays: ``t_s`` copied, ``distance_m`` and ``ticks`` repaired.
    list of dict
        One ``{"index": int, "t_s": float, "measured_m": float, "predicted_m": float}`` per
        repaired sample, in index order.

    Raises
    ------
    SensorDataError
        Fewer than ``window + 1`` samples, or malformed arrays.
    ConfigError
        ``window < 4`` or a non-positive threshold.
    """
    if int(window) != window or window < 4:
        raise ConfigError(f"window must be an integer >= 4 (a cubic needs 4 samples), got {window!r}")
    window = int(window)
    threshold_m = _positive(threshold_m, "threshold_m")
    t = _times_s(odometer.t_s, "odometer", window + 1)
    d_raw = _samples(odometer.distance_m, t.size, "odometer", "distance_m")
    ticks = np.asarray(odometer.ticks)
    if ticks.shape != t.shape or not np.issubdtype(ticks.dtype, np.integer):
        raise SensorDataError(f"odometer: ticks must be integers with shape {t.shape}, got {ticks.dtype} {ticks.shape}")

    residual_m = np.abs(d_raw - _raw_predictions_m(t, d_raw, window))
    repairer = _Repairer(t, d_raw, window, threshold_m)
    repairer.run(np.flatnonzero(residual_m > threshold_m))     # NaN residuals compare False

    flagged = np.array(sorted(repairer.predicted), dtype=np.int64)
    report = [{"index": int(i), "t_s": float(t[i]), "measured_m": float(d_raw[i]),
               "predicted_m": float(repairer.predicted[i])} for i in flagged]
    new_ticks = _repaired_ticks(ticks, repairer.d, flagged, threshold_m)
    return OdometerData(t.copy(), repairer.d, new_ticks), report


# --- clocks -----------------------------------------------------------------------------------

def sensor_times_to_imu_clock(t_s: np.ndarray, offset_s: float = 0.0, drift_ppm: float = 0.0) -> np.ndarray:
    """Time stamps of a sensor's own clock mapped to the IMU clock.

    The sensor clock is ``t_sensor = t_imu (1 + drift_ppm 1e-6) + offset_s``: ``offset_s`` [s]
    is the sensor clock's reading when the IMU clock reads 0 (positive: the sensor clock is
    ahead), ``drift_ppm`` [1e-6] its rate error (positive: it runs fast). Hence
    ``t_imu = (t_sensor - offset_s) / (1 + drift_ppm 1e-6)``.

    Parameters
    ----------
    t_s : array (N,) or any shape
        Sensor time stamps [s].
    offset_s : float
        Clock offset [s].
    drift_ppm : float
        Clock rate error [ppm], greater than -1e6.

    Returns
    -------
    ndarray
        Same shape, IMU clock [s]; a new array.

    Raises
    ------
    SensorDataError
        Non-finite time stamps.
    ConfigError
        Non-finite offset or drift, or drift <= -1e6 ppm.
    """
    t = np.asarray(t_s, dtype=float)
    if not np.all(np.isfinite(t)):
        raise SensorDataError("sensor time stamps must be finite")
    rate = 1.0 + float(drift_ppm) * 1e-6
    if not (np.isfinite(offset_s) and np.isfinite(rate) and rate > 0):
        raise ConfigError(f"clock offset_s={offset_s!r} and drift_ppm={drift_ppm!r} must be finite, drift > -1e6 ppm")
    return (t - float(offset_s)) / rate
