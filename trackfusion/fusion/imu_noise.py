"""IMU white noise and bias instability estimated from the static periods of a survey.

The Allan variance of a rate signal (gyro [rad/s] or specific force [m/s^2]) sampled at
``dt`` is, for the usual error terms (IEEE Std 952 / 1554),

    AVAR(tau) = 3 Q^2 / tau^2  +  N^2 / tau  +  (2 ln 2 / pi) B^2  +  K^2 tau / 3

with ``Q`` the quantisation noise (angle / velocity units), ``N`` the white-noise density
(angle or velocity random walk, [unit/sqrt(s)] of the integrated signal), ``B`` the bias
instability (the flat floor of the Allan deviation divided by 0.664) and ``K`` the rate
random walk. Constant terms of a still sensor (the Earth rate, gravity, a turn-on bias) do
not enter it.

:func:`estimate_imu_noise` computes the overlapping Allan variance of each static period
with ``allantools`` (octave-spaced ``tau``), pools the periods (weighted by the number of
terms each contributes at a ``tau``), and fits the four coefficients by non-negative least
squares weighted by the variance's relative uncertainty (about 1 / sqrt(terms)). ``N`` is
reported with its 1-sigma uncertainty; ``B`` only when the static data reach the
``tau`` at which it rises above the white noise -- a half-minute still period of a
navigation-grade IMU cannot tell its bias instability, and the estimate then says so rather
than reporting a number the data do not hold. Why a hand-written fit: ``allantools`` gives
the Allan deviation, not the noise-term fit.
"""

from __future__ import annotations

from dataclasses import dataclass

import allantools
import numpy as np
from scipy.optimize import nnls

from ..sensors.types import ImuData

DEG = np.pi / 180.0
G0_MPS2 = 9.80665
#: the Allan deviation of bias instability, relative to B, at its flat floor: sqrt(2 ln2 / pi)
BIAS_FLOOR = np.sqrt(2.0 * np.log(2.0) / np.pi)
#: shortest static period used [s] (shorter ones hold too few independent clusters)
MIN_PERIOD_S = 5.0
#: a tau is used when the pooled Allan variance there has at least this many degrees of
#: freedom (about the number of independent clusters of length tau: the static time / tau)
MIN_DOF = 8.0


@dataclass(frozen=True)
class NoiseTerm:
    """One noise coefficient of one triad: ``value`` and ``sigma`` (1-sigma, the same units)
    pooled over the three axes, ``per_axis`` (3,), ``datasheet`` (the pipeline's value, or
    None) and ``unit``. ``value`` is None when the data cannot tell it (``why`` says so)."""

    value: float | None
    sigma: float | None
    per_axis: tuple[float, float, float] | None
    datasheet: float | None
    unit: str
    why: str = ""

    def ratio(self) -> float | None:
        """Estimate over datasheet value (None when either is missing or the datasheet is 0)."""
        if self.value is None or not self.datasheet:
            return None
        return self.value / self.datasheet

    def to_json(self) -> dict:
        out = {"value": self.value, "sigma": self.sigma, "per_axis": list(self.per_axis) if self.per_axis else None,
               "datasheet": self.datasheet, "ratio_to_datasheet": self.ratio(), "unit": self.unit}
        if self.why:
            out["why"] = self.why
        return out


@dataclass(frozen=True)
class AllanFit:
    """Allan-variance model fit of one axis: ``taus_s`` (M,), ``avar`` (M,) pooled observed
    variance, ``terms`` (M,) pooled term counts, ``coef`` (4,) = (Q^2, N^2, B'^2, K^2) with
    B'^2 = (2 ln2/pi) B^2."""

    taus_s: np.ndarray
    avar: np.ndarray
    terms: np.ndarray
    coef: np.ndarray

    @property
    def white(self) -> float:
        """N [unit/sqrt(s)]."""
        return float(np.sqrt(self.coef[1]))

    def bias_instability(self) -> tuple[float, float] | float:
        """B [unit] and its 1-sigma from the floor of the Allan deviation (its minimum / 0.664)
        when that minimum lies inside the taus the data reach (the deviation rises again after
        it); otherwise the data only bound B from above, and that bound [unit] is returned alone."""
        adev, rel = np.sqrt(self.avar), self._rel
        for j in range(1, adev.size - 1):  # the first local minimum the deviation clearly rises from
            # (the deviation's relative 1-sigma is half the variance's)
            if adev[j] <= adev[j - 1] and adev[j + 1:].max() > adev[j] * (1.0 + rel[j]):
                floor = float(adev[j] / BIAS_FLOOR)
                return floor, floor * float(rel[j]) / 2.0
        return float(adev.min() / BIAS_FLOOR)

    @property
    def _rel(self) -> np.ndarray:
        return _relative_sigma(self.taus_s, self.terms)


def _relative_sigma(taus_s: np.ndarray, terms: np.ndarray) -> np.ndarray:
    """Relative 1-sigma uncertainty (M,) of a pooled Allan variance: sqrt(2 / dof), dof the
    overlapping terms over the cluster length in samples (``taus_s[0]`` is one sample)."""
    return np.sqrt(2.0 / np.maximum(terms / np.round(taus_s / taus_s[0]), 1.0))


def _period_avar(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Overlapping Allan variance of one period's samples ``x`` (n,) at octave taus: (taus [s],
    avar, terms)."""
    taus, adev, _err, n = allantools.oadev(x, rate=rate_hz, data_type="freq", taus="octave")
    return np.asarray(taus), np.asarray(adev) ** 2, np.asarray(n, dtype=float)


def _pooled_avar(segments: list[np.ndarray], rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The static periods' Allan variances pooled per tau, weighted by their term counts;
    only taus with at least :data:`MIN_DOF` degrees of freedom."""
    acc: dict[float, list[float]] = {}
    for x in segments:
        taus, avar, n = _period_avar(x, rate_hz)
        for t, a, k in zip(np.round(taus * rate_hz).astype(int), avar, n):
            s = acc.setdefault(int(t), [0.0, 0.0])
            s[0] += a * k
            s[1] += k
    m = np.array(sorted(k for k, (_, n) in acc.items() if k >= 1 and n / k >= MIN_DOF), dtype=int)
    if m.size == 0:
        return np.zeros(0), np.zeros(0), np.zeros(0)
    avar = np.array([acc[k][0] / acc[k][1] for k in m])
    terms = np.array([acc[k][1] for k in m])
    return m / rate_hz, avar, terms


def fit_allan(taus_s: np.ndarray, avar: np.ndarray, terms: np.ndarray) -> AllanFit:
    """Non-negative least-squares fit of the noise model (module docstring) to a pooled Allan
    variance; each tau weighted by 1 / (avar * sqrt(2 / dof)) (:func:`_relative_sigma`)."""
    if taus_s.size == 0 or not np.any(avar > 0):  # a signal without noise (e.g. an ideal or a flat-lined axis)
        return AllanFit(taus_s, avar, terms, np.zeros(4))
    avar = np.maximum(avar, avar.max() * 1e-30)
    rel = _relative_sigma(taus_s, terms)
    A = np.column_stack([3.0 / taus_s**2, 1.0 / taus_s, np.ones_like(taus_s), taus_s / 3.0])
    w = 1.0 / (avar * rel)
    coef, _ = nnls(A * w[:, None], avar * w)
    return AllanFit(taus_s, avar, terms, coef)


def _segments(imu: ImuData, intervals_s: list[tuple[float, float]], column: str) -> list[np.ndarray]:
    """The samples (n, 3) of ``column`` inside each static period of at least :data:`MIN_PERIOD_S`."""
    data = getattr(imu, column)
    out = []
    for a, b in intervals_s:
        i0, i1 = np.searchsorted(imu.t_s, [a, b])
        if i1 - i0 > 2 and imu.t_s[i1 - 1] - imu.t_s[i0] >= MIN_PERIOD_S:
            out.append(np.asarray(data[i0:i1], dtype=float))
    return out


#: the static data are cut into this many blocks for the white noise's uncertainty
WHITE_BLOCKS = 8


def _triad(segments: list[np.ndarray], rate_hz: float) -> list[AllanFit]:
    return [fit_allan(*_pooled_avar([s[:, axis] for s in segments], rate_hz)) for axis in range(3)]


def _white_sigma(segments: list[np.ndarray], rate_hz: float) -> np.ndarray:
    """1-sigma (3,) of each axis's white-noise density N [unit/sqrt(s)] from the scatter of
    :data:`WHITE_BLOCKS` estimates on consecutive blocks of every static period (the fit's own
    covariance is too optimistic: the Allan variances at neighbouring taus share their data)."""
    out = np.zeros(3)
    for axis in range(3):
        est = [fit_allan(*_pooled_avar([s[len(s) * j // WHITE_BLOCKS:len(s) * (j + 1) // WHITE_BLOCKS, axis]
                                        for s in segments], rate_hz)).white for j in range(WHITE_BLOCKS)]
        out[axis] = np.std(est, ddof=1) / np.sqrt(WHITE_BLOCKS)
    return out


def _pool(values: np.ndarray, sigmas: np.ndarray) -> tuple[float, float]:
    """RMS over the axes of a noise density, and its 1-sigma (propagated)."""
    rms = float(np.sqrt(np.mean(values**2)))
    return rms, float(np.sqrt(np.sum((values * sigmas) ** 2)) / (3.0 * rms)) if rms > 0 else 0.0


def _white_term(fits: list[AllanFit], sigma: np.ndarray, scale: float, datasheet: float | None, unit: str
                ) -> NoiseTerm:
    v = np.array([f.white for f in fits]) * scale
    s = sigma * scale
    value, sigma = _pool(v, s)
    return NoiseTerm(value, sigma, tuple(float(x) for x in v), datasheet, unit)


def _bias_term(fits: list[AllanFit], scale: float, datasheet: float | None, unit: str) -> NoiseTerm:
    found = [f.bias_instability() for f in fits]
    if any(not isinstance(b, tuple) for b in found):
        bound = max(b if not isinstance(b, tuple) else b[0] for b in found) * scale
        longest = max(f.taus_s[-1] for f in fits)
        return NoiseTerm(None, None, None, datasheet, unit,
                         why=f"not observable: the Allan deviation still falls at the longest tau the static "
                             f"data reach ({longest:.3g} s); at most {bound:.3g} {unit}")
    v = np.array([b[0] for b in found]) * scale
    s = np.array([b[1] for b in found]) * scale
    value, sigma = _pool(v, s)
    return NoiseTerm(value, sigma, tuple(float(x) for x in v), datasheet, unit)


@dataclass(frozen=True)
class ImuNoiseEstimate:
    """The IMU's noise as its static periods tell it (units in the names, as the pipeline's
    ``sensors.imu``): ``static_s`` the still time used [s], ``periods`` their number."""

    static_s: float
    periods: int
    gyro_arw_deg_per_sqrt_h: NoiseTerm
    gyro_bias_instability_deg_per_h: NoiseTerm
    accel_vrw_mps_per_sqrt_h: NoiseTerm
    accel_bias_instability_ug: NoiseTerm

    def terms(self) -> dict[str, NoiseTerm]:
        return {"gyro_arw_deg_per_sqrt_h": self.gyro_arw_deg_per_sqrt_h,
                "gyro_bias_instability_deg_per_h": self.gyro_bias_instability_deg_per_h,
                "accel_vrw_mps_per_sqrt_h": self.accel_vrw_mps_per_sqrt_h,
                "accel_bias_instability_ug": self.accel_bias_instability_ug}

    def to_json(self) -> dict:
        return {"method": "Allan variance of the static periods (overlapping, octave taus), "
                          "noise-term fit by non-negative least squares",
                "static_s": self.static_s, "periods": self.periods,
                **{k: v.to_json() for k, v in self.terms().items()}}

    def summary(self) -> str:
        """One line for the run's progress: the white-noise terms against the datasheet."""
        def fmt(term: NoiseTerm) -> str:
            ds = f" (datasheet {term.datasheet:.3g})" if term.datasheet is not None else ""
            return f"{term.value:.3g} +- {term.sigma:.2g}{ds}"
        return (f"IMU noise from {self.static_s:.0f} s of static data: gyro ARW "
                f"{fmt(self.gyro_arw_deg_per_sqrt_h)} deg/sqrt(h), accel VRW "
                f"{fmt(self.accel_vrw_mps_per_sqrt_h)} m/s/sqrt(h)")


def estimate_imu_noise(imu: ImuData, static_intervals_s: list[tuple[float, float]], datasheet=None
                       ) -> ImuNoiseEstimate | None:
    """The IMU noise from the samples inside ``static_intervals_s`` ([(start, end)] [s] on the
    IMU clock); ``datasheet``: an object with the pipeline's ``sensors.imu`` fields
    (``gyro_arw_deg_per_sqrt_h``, ...) to compare with, or None. None when no static period
    lasts :data:`MIN_PERIOD_S`."""
    gyro = _segments(imu, static_intervals_s, "gyro_radps")
    if not gyro:
        return None
    accel = _segments(imu, static_intervals_s, "accel_mps2")
    rate_hz = 1.0 / float(np.median(np.diff(imu.t_s)))
    lengths = [s.shape[0] / rate_hz for s in gyro]
    g_fits, a_fits = _triad(gyro, rate_hz), _triad(accel, rate_hz)

    def ds(name: str) -> float | None:
        return None if datasheet is None else float(getattr(datasheet, name))

    rad_to_deg_h = 3600.0 / DEG
    return ImuNoiseEstimate(
        static_s=float(sum(lengths)), periods=len(gyro),
        gyro_arw_deg_per_sqrt_h=_white_term(g_fits, _white_sigma(gyro, rate_hz), 60.0 / DEG,
                                            ds("gyro_arw_deg_per_sqrt_h"), "deg/sqrt(h)"),
        gyro_bias_instability_deg_per_h=_bias_term(g_fits, rad_to_deg_h, ds("gyro_bias_instability_deg_per_h"),
                                                   "deg/h"),
        accel_vrw_mps_per_sqrt_h=_white_term(a_fits, _white_sigma(accel, rate_hz), 60.0,
                                             ds("accel_vrw_mps_per_sqrt_h"), "m/s/sqrt(h)"),
        accel_bias_instability_ug=_bias_term(a_fits, 1e6 / G0_MPS2, ds("accel_bias_instability_ug"), "ug"))
