"""The long-wavelength reference of the cross-level: the design cant (docs/vision.md, "The
cross-level's reference").

The roll of the measuring frame relative to the track (:func:`~trackfusion.vision.relative_motion.
zero_phase_roll` minus the design cant) carries the accelerometer's lateral bias ``b_y`` as a
constant ``b_y / g``: against a constant roll the IMU alone cannot tell it (``a_y - g phi``
cancels it), and eq. 37 turns it into a constant cross-level error of ``b_y / g`` times the
rail-head baseline (0.2 mg: 0.3 mm). The cross-level eq. 37 gives is the deviation from the
design cant (it is measured in the design track frame), and irregularities are deviations
about the design: over a long run their mean tends to zero. So one constant roll offset is estimated from
the run -- the mean of the measured cross-level over the frames without a fault (those more than
5 robust standard deviations from the median left out) divided by the rail-head baseline in the
track frame -- with its uncertainty, the scatter over the run over the square root of the
effective number of independent frames (:func:`effective_samples`). The offset is the roll error
``b_y / g``: the implied lateral accelerometer bias is ``g`` times it. The vision run
(:func:`trackfusion.vision.run.reference_cross_level`) takes it off the frames' roll; eq. 46's
relative trajectory stays as it was (it sees ``a_y - g phi``, where the bias and its roll
offset cancel).

What it cannot tell: a cant error common to the whole run, and the track's own mean
cross-level about the design over the run, are taken off with the bias. Over a short run that
mean is not small: its standard deviation is the irregularity's rms times ``sqrt(integral scale
/ run length)`` (the integral of its autocorrelation over all lags: 8.9 m for the simulated
track's 1.5 mm rms, so 0.32 mm over 200 m and 0.14 mm over 1 km, against 0.30 mm for a 0.2 mg
bias), and the stated uncertainty is that standard deviation (measured about 10 % low over
100 simulated 200 m tracks).

**Weighted by the datasheet** (:func:`prior_weight`): the IMU's datasheet bias ``sigma_b``
(1 sigma, ``vision.accel_bias_mg``) is the roll error's prior, ``N(0, (sigma_b / g)^2)``, and
the estimate's own error (the track's run mean) has the standard deviation ``sd``. The
minimum-variance combination of the two takes off ``w`` times the estimate, ``w = sigma_b^2 /
(sigma_b^2 + sd^2)``, and leaves a roll error of standard deviation ``sigma_b sd / sqrt(sigma_b^2
+ sd^2)``, below both: on a 200 m run (``sd`` about the 0.2 mg bias's) about half is taken off,
on a 3 km run nearly all. Without a datasheet figure, all of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .relative_motion import GRAVITY_MPS2

#: frames further than this many robust standard deviations from the median are left out
CLIP_SIGMAS = 5.0


def effective_samples(x: np.ndarray) -> float:
    """The number of independent samples a uniformly spaced series ``x`` (N,) (NaN gaps allowed)
    is worth for its mean: ``n / tau`` with ``n`` its finite samples and ``tau = 1 + 2 sum
    rho_k`` its integrated autocorrelation, summed up to the first lag where the autocorrelation
    (over the pairs of finite samples, by FFT) is no longer positive; at most ``n``."""
    m = np.isfinite(x)
    n, size = int(m.sum()), x.size
    if n < 3:
        return float(n)
    d = np.where(m, x - x[m].mean(), 0.0)
    fd, fm = np.fft.rfft(d, 2 * size), np.fft.rfft(m.astype(float), 2 * size)
    num = np.fft.irfft(fd * np.conj(fd), 2 * size)[:size]
    pairs = np.rint(np.fft.irfft(fm * np.conj(fm), 2 * size)[:size])
    rho = np.where(pairs > 0, num / np.maximum(pairs, 1.0), 0.0) / (num[0] / n)
    stop = np.nonzero(rho[1:] <= 0)[0]
    k = int(stop[0]) + 1 if stop.size else size
    return float(n / max(1.0, 1.0 + 2.0 * rho[1:k].sum()))


@dataclass(frozen=True)
class RollOffset:
    """A run's constant roll offset of the measuring frame relative to the track [rad] and its
    standard deviation [rad] (NaN with fewer than 3 frames), the frames used and their effective
    number, the used cross-level's mean and standard deviation [mm] and the rail-head baseline
    in the track frame [m]."""

    offset_rad: float
    sd_rad: float
    frames: int
    effective_frames: float
    cross_level_mean_mm: float
    cross_level_sd_mm: float
    baseline_m: float

    def as_metrics(self, reference: str, weight: float = 1.0) -> dict:
        """``metrics.json`` ``vision.cross_level_reference`` of a run with ``reference``
        (``design``: ``weight`` times the offset taken off the roll, ``applied``; ``none``: only
        reported): the offset in urad and deg, the implied lateral accelerometer bias in m/s^2
        and mg (1 mg = 1e-3 g, g = 9.81 m/s^2), each with its standard deviation (``None`` when
        not estimable), the weight and the offset taken off [urad]."""
        sd = self.sd_rad if np.isfinite(self.sd_rad) else None
        scaled = lambda k: None if sd is None else sd * k  # noqa: E731
        finite = lambda x: float(x) if np.isfinite(x) else None  # noqa: E731
        applied = reference == "design"
        return {"reference": reference, "applied": applied, "weight": weight if applied else 0.0,
                "roll_offset_applied_urad": self.offset_rad * 1e6 * weight if applied else 0.0,
                "roll_offset_urad": self.offset_rad * 1e6, "roll_offset_sd_urad": scaled(1e6),
                "roll_offset_deg": float(np.degrees(self.offset_rad)), "roll_offset_sd_deg": scaled(np.degrees(1.0)),
                "lateral_accel_bias_mps2": GRAVITY_MPS2 * self.offset_rad,
                "lateral_accel_bias_sd_mps2": scaled(GRAVITY_MPS2),
                "lateral_accel_bias_mg": self.offset_rad * 1e3, "lateral_accel_bias_sd_mg": scaled(1e3),
                "frames": self.frames, "effective_frames": self.effective_frames,
                "cross_level_mean_mm": finite(self.cross_level_mean_mm),
                "cross_level_sd_mm": finite(self.cross_level_sd_mm), "baseline_m": finite(self.baseline_m)}


def prior_weight(sd_rad: float, accel_bias_mg: float | None) -> float:
    """The share ``w`` (0-1] of the estimated roll offset to take off the roll (module
    docstring): ``sigma_b^2 / (sigma_b^2 + sd^2)`` with ``sigma_b = accel_bias_mg * 1e-3`` [rad]
    (a bias of 1 mg is a roll of 1e-3 rad) and the estimate's standard deviation ``sd_rad``
    [rad]; 1 without a datasheet figure, 0 when the estimate has none."""
    if accel_bias_mg is None:
        return 1.0
    if not np.isfinite(sd_rad):
        return 0.0
    prior = (accel_bias_mg * 1e-3) ** 2
    return float(prior / (prior + sd_rad**2))


def estimate_roll_offset(cross_level_m: np.ndarray, pose_left: np.ndarray, pose_right: np.ndarray,
                         roll_rad: np.ndarray) -> RollOffset:
    """The constant roll offset [rad] (module docstring) of a run's frames: ``cross_level_m``
    (F,) [m], NaN at faults, measured with the roll ``roll_rad`` (F,) [rad] from the fitted
    poses ``pose_left``, ``pose_right`` (F, 3) (origin ``(y, z)`` [mm] in the measuring frame).
    The offset is one Newton step of "mean cross-level = 0": the mean over the frames used
    divided by the mean rail-head baseline in the track frame (``d cl / d phi``), exact to
    second order in the offset. Fewer than 3 usable frames: offset 0, standard deviation NaN."""
    x = np.asarray(cross_level_m, float)
    ok = np.isfinite(x)
    if ok.sum() >= 3:
        med = np.median(x[ok])
        spread = 1.4826 * np.median(np.abs(x[ok] - med))
        if spread > 0:
            ok &= np.abs(x - med) <= CLIP_SIGMAS * spread
    n = int(ok.sum())
    if n < 3:
        return RollOffset(0.0, float("nan"), n, float(n), float("nan"), float("nan"), float("nan"))
    dy = (pose_left[:, 0] - pose_right[:, 0]) / 1e3
    dz = (pose_left[:, 1] - pose_right[:, 1]) / 1e3
    baseline = float(np.mean((np.cos(roll_rad) * dy - np.sin(roll_rad) * dz)[ok]))
    used = np.where(ok, x, np.nan)
    n_eff = effective_samples(used)
    mean, sd = float(x[ok].mean()), float(x[ok].std())
    return RollOffset(mean / baseline, sd / np.sqrt(n_eff) / baseline, n, n_eff, mean * 1e3, sd * 1e3, baseline)


def describe_reference(ref: dict) -> str:
    """One line of text for ``metrics.json`` ``vision.cross_level_reference`` (the run's
    summary and report)."""
    if ref["roll_offset_sd_urad"] is None:
        return f"cross-level reference {ref['reference']}: roll offset not estimable ({ref['frames']} frames)"
    if not ref["applied"]:
        how = "reported, not applied"
    elif ref["weight"] == 1.0:  # no datasheet figure to weigh it against (prior_weight)
        how = "taken off the roll"
    else:
        how = f"{ref['weight']:.2f} of it taken off the roll (the datasheet's bias against the track's run mean)"
    return (f"cross-level reference {ref['reference']}: roll offset {ref['roll_offset_urad']:+.0f} +- "
            f"{ref['roll_offset_sd_urad']:.0f} urad ({ref['roll_offset_deg']:+.4f} deg; lateral accelerometer bias "
            f"{ref['lateral_accel_bias_mg']:+.3f} +- {ref['lateral_accel_bias_sd_mg']:.3f} mg), {how}")
