"""Rail-head profile fitted to a frame's point cloud: pose of the unworn profile in the vehicle frame.

Seed 001 (section 5, eqs. 25-32) fits the arc centres by least squares under the constraint that
the arcs stay tangent (Lagrange multipliers). Here the constraint is built in: the unknowns are
the pose of the rigid unworn profile, ``x = (y0, z0, theta)`` (profile origin [mm] and roll [rad]
in the vehicle y-z plane, see :mod:`trackfusion.simulation.camera_laser` for the placement
``(y, z) = o + R(theta) (s q, z)``), so every arc keeps its radius and tangency, and the fit uses
all five arcs and the flanks the laser lights. The residual of a point is its signed distance to
the profile (eq. 27); the sum of squares (eq. 29) is minimised by Gauss-Newton with iteratively
reweighted robust weights (Huber with a shrinking scale, then a one-sided Tukey biweight: 4.685
robust sigmas outside the profile, 3 inside, the sigma from the scatter of neighbouring points,
:func:`noise_sigma_mm`) so that worn
parts of the head (always inside the unworn profile, often most of the points), glare and stray
reflections do not pull the pose. The derivatives: ``dd/do = -n_v`` and ``dd/dtheta = s (n_q z - n_z q)``
with ``n`` the profile normal at the nearest point.

Hand-written rather than ``scipy.optimize.least_squares`` because it solves all frames of a batch
at once (3 x 3 normal equations per frame, numpy-batched): a thousand fits per second.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..track.rail_profile import RailHead, signed_distance_mm

SIDE_SIGN = {"left": -1.0, "right": 1.0}


@dataclass(frozen=True)
class ProfileFit:
    """Per frame (F,): pose ``(y0_mm, z0_mm, roll_rad)`` (F, 3), rms of the inlier residuals [mm],
    number of inliers, number of valid points, the inlier mask (F, N), the signed distances of
    the points to the fitted profile (F, N) [mm] (NaN where none), the point noise (F,) [mm] and
    the standard deviations (F, 3) of the pose (mm, mm, rad) from the inliers' geometry."""

    pose: np.ndarray
    rms_mm: np.ndarray
    n_inliers: np.ndarray
    n_points: np.ndarray
    inliers: np.ndarray
    residual_mm: np.ndarray
    sigma_mm: np.ndarray
    pose_sd: np.ndarray


def to_profile_frame(y_mm, z_mm, pose: np.ndarray, side: str) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle-frame points (F, N) [mm] in the profile frame ``(q, z)`` of poses (F, 3)."""
    s = SIDE_SIGN[side]
    dy, dz = y_mm - pose[:, :1], z_mm - pose[:, 1:2]
    c, sn = np.cos(pose[:, 2:3]), np.sin(pose[:, 2:3])
    return s * (c * dy + sn * dz), -sn * dy + c * dz


def _residuals(head, y, z, pose, side):
    s = SIDE_SIGN[side]
    q, zr = to_profile_frame(y, z, pose, side)
    d, nq, nz = signed_distance_mm(head, q, zr)
    c, sn = np.cos(pose[:, 2:3]), np.sin(pose[:, 2:3])
    nvy = c * s * nq - sn * nz
    nvz = sn * s * nq + c * nz
    J = np.stack([-nvy, -nvz, s * (nq * zr - nz * q)], axis=-1)
    return d, J


def fit_profiles(head: RailHead, y_mm: np.ndarray, z_mm: np.ndarray, valid: np.ndarray, side: str,
                 initial_pose: np.ndarray, noise_floor_mm: float = 0.02, stride: int = 2) -> ProfileFit:
    """Fit the unworn ``head`` to each frame's points ``(y_mm, z_mm)`` (F, N) (vehicle frame,
    ``valid`` (F, N) marks real points) starting from ``initial_pose`` (F, 3) (module
    docstring). ``noise_floor_mm`` bounds the robust sigma from below (a noise-free frame). The
    iterations use every ``stride``-th point (neighbouring columns carry nearly the same
    information), the residuals, inliers and rms returned are of all points."""
    pose = np.array(initial_pose, dtype=float, copy=True)
    valid = np.asarray(valid, bool) & np.isfinite(y_mm) & np.isfinite(z_mm)
    y_all = np.where(valid, y_mm, 0.0)
    z_all = np.where(valid, z_mm, 0.0)
    sigma = noise_sigma_mm(y_mm, z_mm, valid, noise_floor_mm)
    valid_all = valid
    y, z, valid = y_all[:, ::stride], z_all[:, ::stride], valid[:, ::stride]
    scales = [4.0, 2.0, 1.0]
    c_in = 3.0 * sigma[:, None]
    outside_scales = [4.0, 2.0, 1.0, 0.5, 0.25]
    for it in range(len(scales) + len(outside_scales) + 3):
        d, J = _residuals(head, y, z, pose, side)
        ok = valid & np.isfinite(d)
        d = np.where(ok, d, 0.0)
        J = np.where(ok[..., None], J, 0.0)
        a = np.abs(d)
        if it < len(scales):
            c = scales[it]
            w = np.where(a <= c, 1.0, c / np.maximum(a, 1e-12))
        else:
            # worn material is inside the unworn profile, never outside: points inside beyond
            # 3 sigma (wear) are let go, points outside keep pulling with a shrinking scale
            k = it - len(scales)
            c_out = np.maximum(outside_scales[k] if k < len(outside_scales) else 0.0, 4.685 * sigma)[:, None]
            c = np.where(d > 0, c_out, c_in)
            w = np.where(a < c, (1 - (a / c) ** 2) ** 2, 0.0)
        w = np.where(ok, w, 0.0)
        A, g = _normal_equations(w, J, d)
        step = -np.linalg.solve(A, g[..., None])[..., 0]
        step[:, :2] = np.clip(step[:, :2], -5.0, 5.0)
        step[:, 2] = np.clip(step[:, 2], -0.02, 0.02)
        pose += np.where(np.isfinite(step), step, 0.0)
    y, z, valid = y_all, z_all, valid_all
    d, J = _residuals(head, y, z, pose, side)
    ok = valid & np.isfinite(d)
    inl = ok & (np.abs(np.where(ok, d, np.inf)) < 3.0 * sigma[:, None])   # worn points are not
    n_in = inl.sum(axis=1)
    rms = np.sqrt(np.where(inl, d * d, 0.0).sum(axis=1) / np.maximum(n_in, 1))
    # pose standard deviations: sigma^2 (J^T J)^-1 over the inliers, one point per stride
    A, _ = _normal_equations(inl[:, ::stride].astype(float), np.where(inl[..., None], J, 0.0)[:, ::stride],
                             np.zeros(inl[:, ::stride].shape))
    cov = np.linalg.inv(A) * (np.maximum(rms, sigma) ** 2)[:, None, None]
    pose_sd = np.sqrt(np.abs(np.diagonal(cov, axis1=1, axis2=2)))
    return ProfileFit(pose, rms, n_in, valid.sum(axis=1), inl, np.where(ok, d, np.nan), sigma, pose_sd)


def noise_sigma_mm(y_mm: np.ndarray, z_mm: np.ndarray, valid: np.ndarray, floor_mm: float) -> np.ndarray:
    """Point noise (F,) [mm] of each frame, independent of any fit: the robust spread of each
    point's distance from the midpoint of its two neighbouring columns (``1.5 sigma^2`` for
    independent noise; the profile's curvature adds ~0.002 mm at 0.2 mm spacing)."""
    ok = valid[:, 1:-1] & valid[:, :-2] & valid[:, 2:]
    ey = y_mm[:, 1:-1] - 0.5 * (y_mm[:, :-2] + y_mm[:, 2:])
    ez = z_mm[:, 1:-1] - 0.5 * (z_mm[:, :-2] + z_mm[:, 2:])
    e = np.where(ok, np.hypot(ey, ez), 0.0)
    med = _masked_median(e, ok)
    # |e| of a 1-D Gaussian error: median 0.6745 sigma_e
    return np.maximum(1.4826 * med / np.sqrt(1.5), floor_mm)


def _normal_equations(w: np.ndarray, J: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``J^T W J`` (F, 3, 3) and ``J^T W d`` (F, 3) of per-frame weights (F, N), Jacobians
    (F, N, 3) and residuals (F, N), from the six distinct sums."""
    Jw = J * w[..., None]
    A = np.empty((len(w), 3, 3))
    for i in range(3):
        for j in range(i, 3):
            A[:, i, j] = A[:, j, i] = (Jw[..., i] * J[..., j]).sum(axis=1)
    A += np.eye(3) * 1e-9
    return A, (Jw * d[..., None]).sum(axis=1)


def _masked_median(a: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Row medians (F,) of ``a`` (F, N) over ``mask`` (rows without points give 1)."""
    x = np.sort(np.where(mask, a, np.inf), axis=1)
    n = mask.sum(axis=1)
    lo = np.take_along_axis(x, np.maximum((n - 1) // 2, 0)[:, None], axis=1)[:, 0]
    hi = np.take_along_axis(x, np.maximum(n // 2, 0)[:, None], axis=1)[:, 0]
    return np.where(n > 0, 0.5 * (lo + hi), 1.0)
