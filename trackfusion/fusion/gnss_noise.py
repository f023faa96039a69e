"""The GNSS white noise estimated from the fixes' residuals, inside the smoother's gating.

Model: the true white covariance of fix ``i`` is ``D C_i D`` with ``C_i`` (3,3) [m^2] the
white part the receiver states (fusion/smoother.py ``white_covariance``) and ``D =
diag(sqrt(f_h), sqrt(f_h), sqrt(f_v))``: one variance factor for the horizontal axes and one
for the vertical (a receiver states the two accuracies apart, and is wrong about them apart).

After a solve with the factors ``f0`` applied, each used fix's residual ``v_i`` (3,) [m] (fix
minus the fitted antenna position and correlated error) gives per group ``g`` a normalised
squared residual: horizontal ``q_h = v_h^T (f0_h C_hh)^-1 v_h`` (2 dof), vertical ``q_v = v_u^2
/ (f0_v C_uu)`` (1 dof). A residual at the optimum is smaller than the noise: ``E[q_g] = dof_g
r_g f_g / f0_g`` with ``r_g`` the group's mean **redundancy** ``r_i = 1 - w_i tr(C'^-1
Cov_fit,i) / dof`` (``Cov_fit,i`` the marginal covariance of the fitted antenna position and
error state ``[J_x I] Cov(X_k, E_i) [J_x I]^T``, from the solve's marginals at an even sample of
the fixes, ``w_i`` the Huber weight, ``C'`` the applied white covariance). The robust estimate:

    f_g = f0_g median(q_g) / (median(chi2(dof_g)) r_g)

taken twice: over every used fix, then over those whose 3-dof normalised residual under the
first estimate passes the gate (the outliers out; the gate's 1e-4 tail is not corrected for).
Its 1-sigma is the median's asymptotic ``1 / (2 sqrt(n) p(m))`` (``p`` the chi-square density
at its median ``m``) relative to ``m``, with the redundancy sample's scatter in quadrature.

The factor the smoother applies (:attr:`GnssNoiseEstimate.applied`) is the estimate when it
differs from 1 by more than :data:`SIGNIFICANCE` sigmas, else 1: an optimistic receiver is
weighted down and a pessimistic one up, but not below ``min_sigma_mm`` (the RMS stated white
sigma scaled to it: a noise-free simulation's estimate is near 0). (Until this release a pessimistic receiver kept its
stated covariance. On the 44 min ``open-track-gnss`` survey whose receiver stated 1.5 times its
white sigma, mismatch benchmark seed 1, the white noise was then weighted at 6 times its true
variance; the error states took the white noise's share, the GNSS correlated part was estimated
at 0.66 of its drawn sigma vertically and the 5 m vertical MSE was 1.57 times the run given the
true noise. Applied: 0.83 and 1.29.)
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from scipy.stats import chi2

from .factors import LinearBlocks

#: fewest used fixes that the estimate is made from
MIN_FIXES = 30
#: fixes at which the redundancy is computed from the marginals (evenly spread)
REDUNDANCY_SAMPLE = 24
#: an estimate is applied when it differs from 1 by more than this many of its sigmas
SIGNIFICANCE = 2.0
#: relative change of an applied variance factor that calls for one more solve
FACTOR_TOLERANCE = 0.1
_DOF = np.array([2, 1])


def per_enu_axis(factor: np.ndarray) -> np.ndarray:
    """(3,) the (horizontal, vertical) variance factors (2,) per ENU axis."""
    return np.asarray(factor, dtype=float)[[0, 0, 1]]


def scaled_white(white_cov: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """``D C D`` (F,3,3) [m^2] of stated white covariances (F,3,3) and the factors (2,)
    (horizontal, vertical)."""
    d = np.sqrt(per_enu_axis(factor))
    return white_cov * d[:, None] * d[None, :]


def nis(residual: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Normalised squared residuals (F,) of residuals (F,3) [m] with covariances (F,3,3),
    whitened as the smoother's factors are (the inverse Cholesky factor: the same bits)."""
    W = np.linalg.inv(np.linalg.cholesky(cov))
    return np.sum(np.einsum("kij,kj->ki", W, residual) ** 2, axis=1)


def _group_nis(residual: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """(F,2): the horizontal (2 dof) and vertical (1 dof) normalised squared residuals."""
    h = residual[:, :2]
    q_h = np.einsum("ki,ki->k", h, np.linalg.solve(cov[:, :2, :2], h[:, :, None])[:, :, 0])
    return np.column_stack([q_h, residual[:, 2] ** 2 / cov[:, 2, 2]])


def _fitted_covariance(tree, blocks: LinearBlocks, i: int) -> np.ndarray:
    """Marginal covariance (3,3) [m^2] of fix ``i``'s fitted value (antenna position plus error
    state) from the solve's marginals ``tree`` (a Bayes tree or fusion/partitioned.py's
    ``PartMarginals``)."""
    J = blocks.jacobians[0][i]
    key_x = int(blocks.keys[0][i])
    if len(blocks.keys) == 1:
        return J @ tree.marginalCovariance(key_x) @ J.T
    key_e = int(blocks.keys[1][i])
    # QR down the tree: the default Cholesky of the shortcuts meets the stiff graphs' conditioning
    A = tree.joint(key_x, key_e, gtsam.EliminateQR).jacobian()[0]  # columns in key order: E ('e') before X ('x')
    cov = np.linalg.inv(A.T @ A)
    M = np.concatenate([np.eye(3), J], axis=1) if key_e < key_x else np.concatenate([J, np.eye(3)], axis=1)
    return M @ cov @ M.T


def redundancy(tree, blocks: LinearBlocks, cov: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """Redundancy (<=S,2) (horizontal, vertical) of the fixes ``sample`` (S,) given their applied
    white covariances ``cov`` (F,3,3) and the Huber weights of ``blocks`` (module docstring);
    a fix whose marginal GTSAM cannot compute is left out."""
    w = blocks.weights()
    out = np.full((sample.size, 2), np.nan)
    for j, i in enumerate(sample):
        try:
            fit = _fitted_covariance(tree, blocks, int(i))
        except RuntimeError:  # GTSAM finds this pair's marginal indeterminate: the other fixes then
            continue
        c = cov[i]
        out[j, 0] = 1.0 - w[i] * np.trace(np.linalg.solve(c[:2, :2], fit[:2, :2])) / 2.0
        out[j, 1] = 1.0 - w[i] * fit[2, 2] / c[2, 2]
    return np.clip(out[np.isfinite(out[:, 0])], 0.05, 1.0)


@dataclass
class GnssNoiseEstimate:
    """The GNSS white-noise variance factors (module docstring): ``factor`` (2,) estimated
    (horizontal, vertical; relative to the stated white variance), ``sigma`` (2,) their
    1-sigma, ``applied`` (2,) what the smoother uses, ``redundancy`` (2,) the mean redundancy,
    ``fixes`` the number of fixes used, ``stated_white_sigma_mm`` (3,) the RMS stated white
    sigma per ENU axis [mm]."""

    factor: np.ndarray
    sigma: np.ndarray
    applied: np.ndarray
    redundancy: np.ndarray
    fixes: int
    stated_white_sigma_mm: np.ndarray

    @property
    def estimated_white_sigma_mm(self) -> np.ndarray:
        """(3,) the stated white sigma per ENU axis times the estimated sigma scale [mm]."""
        return self.stated_white_sigma_mm * np.sqrt(per_enu_axis(self.factor))

    def to_json(self) -> dict:
        scale = np.sqrt(self.factor)
        return {"variance_factor": {"horizontal": float(self.factor[0]), "vertical": float(self.factor[1])},
                "variance_factor_sigma": {"horizontal": float(self.sigma[0]), "vertical": float(self.sigma[1])},
                "sigma_scale": {"horizontal": float(scale[0]), "vertical": float(scale[1])},
                "sigma_scale_sigma": {"horizontal": float(self.sigma[0] / (2 * scale[0])),
                                      "vertical": float(self.sigma[1] / (2 * scale[1]))},
                "applied_variance_factor": {"horizontal": float(self.applied[0]), "vertical": float(self.applied[1])},
                "mean_redundancy": {"horizontal": float(self.redundancy[0]), "vertical": float(self.redundancy[1])},
                "fixes": int(self.fixes),
                "stated_white_sigma_mm": [float(x) for x in self.stated_white_sigma_mm],
                "estimated_white_sigma_mm": [float(x) for x in self.estimated_white_sigma_mm]}

    def summary(self) -> str:
        s, e = self.stated_white_sigma_mm, self.estimated_white_sigma_mm
        return (f"GNSS white noise from {self.fixes} fixes: stated {s[0]:.1f}/{s[1]:.1f}/{s[2]:.1f} mm (E/N/U), "
                f"estimated {e[0]:.1f}/{e[1]:.1f}/{e[2]:.1f} mm; variance factor applied "
                f"{self.applied[0]:.2f} horizontal, {self.applied[1]:.2f} vertical")


def _ratio(q: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Variance ratio (2,) from the group NIS (n,2) and the mean redundancy (2,)."""
    return np.median(q, axis=0) / (chi2.median(_DOF) * r)


def estimate_white_noise(blocks: LinearBlocks, white_cov: np.ndarray, applied: np.ndarray, tree,
                         gate_chi2: float, min_sigma_m: float) -> GnssNoiseEstimate | None:
    """The estimate from one solve (module docstring): ``blocks`` the used fixes' GNSS factors
    at the solution, ``white_cov`` (F,3,3) their stated white covariances [m^2], ``applied``
    (2,) the factors that solve used, ``tree`` its marginals, ``min_sigma_m`` [m] the white
    sigma an applied factor below 1 keeps at the least. None with fewer than
    :data:`MIN_FIXES` fixes."""
    F = blocks.residual.shape[0]
    if F < MIN_FIXES:
        return None
    cov = scaled_white(white_cov, applied)
    q = _group_nis(blocks.residual, cov)
    sample = np.unique(np.linspace(0, F - 1, min(REDUNDANCY_SAMPLE, F)).round().astype(np.int64))
    red = redundancy(tree, blocks, cov, sample)
    if red.shape[0] == 0:
        return None
    r = red.mean(axis=0)
    factor = applied * _ratio(q, r)
    inside = nis(blocks.residual, scaled_white(white_cov, factor)) <= gate_chi2
    factor = applied * _ratio(q[inside], r)
    n = int(inside.sum())
    m = chi2.median(_DOF)
    rel_median = 1.0 / (2.0 * np.sqrt(n) * chi2.pdf(m, _DOF) * m)
    rel_red = red.std(axis=0, ddof=1) / np.sqrt(red.shape[0]) / r if red.shape[0] > 1 else np.zeros(2)
    sigma = factor * np.hypot(rel_median, rel_red)
    use = np.abs(factor - 1.0) > SIGNIFICANCE * sigma
    stated = np.sqrt(np.mean(np.diagonal(white_cov, axis1=1, axis2=2), axis=0)) * 1e3
    floor = np.minimum((min_sigma_m * 1e3) ** 2 / np.array([np.mean(stated[:2] ** 2), stated[2] ** 2]), 1.0)
    return GnssNoiseEstimate(factor, sigma, np.where(use, np.maximum(factor, floor), 1.0), r, n, stated)


def needs_refit(applied_before: np.ndarray, applied_now: np.ndarray) -> bool:
    """Whether the applied factors moved enough (:data:`FACTOR_TOLERANCE`) to solve once more."""
    return bool(np.any(np.abs(applied_now / applied_before - 1.0) > FACTOR_TOLERANCE))
