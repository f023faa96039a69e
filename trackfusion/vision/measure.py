"""Per-frame measurement: stripe -> points -> fitted profiles -> gauge, cross-level and wear.

For each frame and rail: stripe centres per column (:mod:`.stripe`), undistortion and the laser
plane (eq. 24, :class:`~trackfusion.vision.camera.CameraLaserUnit`), the points kept in
continuous runs along the line (:func:`continuous_segments`: glare islands go), the robust profile fit
(:mod:`.profile_fit`). Then, with the roll ``phi`` of the measuring frame relative to the track
(seed 001's ``phi^{t,tgms}``, from the inertial part), for the pair of rails:

* **cross-level** (eq. 37): ``cl = phi (y_l - y_r) + (z_l - z_r)`` of the fitted profile origins
  (the exact rotation rather than its small-angle form);
* **gauge**: the points are rotated into the track frame; each rail's running surface is the top
  of a quadratic fitted to the points within 3 mm of the highest one, its gauge point the gauge
  face (a quadratic ``y(z)`` of the gauge-side points within 1 mm of the level) 14 mm below it,
  and the gauge the distance of the two gauge points;
* **wear** against the unworn profile, in the fitted profile frame: vertical wear is the height
  loss on the profile centreline (a line fitted to the points within 2 mm of it), side wear the
  loss of the gauge face at 14 mm below the unworn top (a quadratic ``q(z)`` within 1 mm).

A frame whose stripe is missing (too few stripe columns), whose fit is poor (inlier rms or
inlier count out of bounds), whose unworn field corner or gauge face is not seen (glare), or
where a gauge point or wear window has too few points is a
**fault**: it is listed with its reason and its figures are NaN, never numbers. A rail whose
stripe points lie near glare columns has its
wear listed as a fault (``glare_near_stripe``) and NaN; its gauge and cross-level stay.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..errors import VisionError
from ..track.rail_profile import GAUGE_POINT_DEPTH_MM, RailHead
from .camera import CameraLaserUnit
from .profile_fit import SIDE_SIGN, fit_profiles, to_profile_frame
from .stripe import StripeSettings, stripe_centres


@dataclass(frozen=True)
class FaultLimits:
    """When a rail's frame is a fault: fewer than ``min_columns`` stripe columns, inlier rms above
    ``max_rms_mm`` or a profile origin less certain than ``max_pose_sd_mm`` (1 sigma, from the
    inliers' geometry), fewer than ``min_inliers`` points on the unworn profile (worn parts of the
    head are not, so this is a count, not a share), fewer than ``min_window_points`` points in a
    gauge-point or wear window, fewer than ``min_side_inliers`` unworn points on the field side
    (q < -10 mm) or on the gauge face (q > 30 mm): those fix the pose of a worn head, and glare
    can hide them; wear (only) is a fault when stripe points lie within
    ``wear_glare_margin_columns`` of the glare columns (the glint's faint tails beyond the glare
    mask shift the points near it: the pose of a worn head, fixed by few unworn points, moves
    by tenths of a millimetre)."""

    min_columns: int = 120
    min_side_inliers: int = 8
    max_pose_sd_mm: float = 0.02
    max_rms_mm: float = 0.12
    min_inliers: int = 40
    min_window_points: int = 5
    wear_glare_margin_columns: int = 60


@dataclass
class FrameMeasurements:
    """Per frame (F,): gauge [m], cross-level [m], per rail (dict by side) vertical and side wear
    [mm], fitted pose (F, 3) (origin [mm] and roll [rad] in the vehicle frame), fit rms [mm];
    ``faults`` lists ``(frame, side, reason)``."""

    gauge_m: np.ndarray
    cross_level_m: np.ndarray
    vertical_wear_mm: dict
    side_wear_mm: dict
    pose: dict
    rms_mm: dict
    faults: list = field(default_factory=list)

    @property
    def fault_frames(self) -> np.ndarray:
        return np.unique(np.array([f for f, _, _ in self.faults], dtype=int))


def rail_points_mm(unit: CameraLaserUnit, images: np.ndarray, stripe: StripeSettings
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Vehicle-frame ``(y, z)`` [mm] (F, W) of the stripe in each column, the valid mask and
    the glare columns (F, W)."""
    rows, glare = stripe_centres(images, stripe, with_glare=True)
    F, W = rows.shape
    cols = np.broadcast_to(np.arange(W, dtype=float), rows.shape)
    valid = np.isfinite(rows)
    uv = np.column_stack([cols[valid], rows[valid]])
    y = np.full(rows.shape, np.nan)
    z = np.full(rows.shape, np.nan)
    if uv.size:
        p_v = unit.pixels_to_vehicle(uv)
        y[valid], z[valid] = p_v[:, 1] * 1e3, p_v[:, 2] * 1e3
    valid = valid & np.isfinite(y)
    return y, z, valid & continuous_segments(y, z, valid), glare


def near_glare(window: np.ndarray, glare: np.ndarray, columns: int) -> np.ndarray:
    """Per frame (F,): whether a window's columns (``window`` (F, W) mask) lie within ``columns``
    of a glare column (``glare`` (F, W)): a glint's faint tails outside the glare mask still
    shift the stripe centres there by a few tenths of a millimetre."""
    if not glare.any():
        return np.zeros(len(window), bool)
    k = np.ones((1, 2 * columns + 1), np.uint8)
    near = cv2.dilate(glare.astype(np.uint8), k) > 0
    return (window & near).any(axis=1)


def continuous_segments(y: np.ndarray, z: np.ndarray, valid: np.ndarray, jump_mm: float = 1.5,
                        min_columns: int = 10) -> np.ndarray:
    """Mask (F, W) of the points in runs of at least ``min_columns`` consecutive columns whose
    neighbours are less than ``jump_mm`` apart: the laser line on the head is continuous, glare
    islands and stray reflections are short runs off it."""
    F, W = y.shape
    step = np.hypot(np.diff(y, axis=1), np.diff(z, axis=1))
    joined = valid[:, 1:] & valid[:, :-1] & (step < jump_mm)
    start = np.concatenate([np.ones((F, 1), bool), ~joined], axis=1)
    label = np.cumsum(start.ravel()).reshape(F, W)
    counts = np.bincount(label[valid], minlength=label.max() + 1)
    return valid & (counts[label] >= min_columns)


def masked_polyfit_at(x: np.ndarray, y: np.ndarray, mask: np.ndarray, x0: np.ndarray, deg: int,
                      sigma: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Per row, the least-squares polynomial of degree ``deg`` through the masked points of
    ``(x, y)`` (F, N) evaluated at ``x0`` (F,); returns the values (F,) and the point counts.
    With ``sigma`` (F,), a second pass drops the points more than 3 sigma from the first fit
    (glare or a stray reflection in the window)."""
    xc = np.where(mask, x - x0[:, None], 0.0)
    yc = np.where(mask, y, 0.0)
    powers = [np.ones_like(xc)]
    for _ in range(2 * deg):
        powers.append(powers[-1] * xc)
    for _ in range(1 if sigma is None else 2):
        m = mask.astype(float)
        moments = [(p * m).sum(axis=1) for p in powers]             # sums of x^k, k <= 2 deg
        A = np.stack([np.stack([moments[i + j] for j in range(deg + 1)], -1) for i in range(deg + 1)], -2)
        b = np.stack([(powers[i] * yc * m).sum(axis=1) for i in range(deg + 1)], -1)
        coef = np.linalg.solve(A + np.eye(deg + 1) * 1e-12, b[..., None])[..., 0]
        if sigma is not None:
            res = yc - sum(coef[:, i:i + 1] * powers[i] for i in range(deg + 1))
            mask = mask & (np.abs(res) <= 3.0 * sigma[:, None])
    n = mask.sum(axis=1)
    return np.where(n > deg, coef[:, 0], np.nan), n


def running_top(y: np.ndarray, z: np.ndarray, mask: np.ndarray, window_mm: float = 3.0
                ) -> tuple[np.ndarray, np.ndarray]:
    """Running-surface height (F,) [mm] of track-frame points: the maximum, within the window, of
    a quadratic fitted to the points within ``window_mm`` of the highest point; and the counts."""
    zi = np.where(mask, z, -np.inf)
    i_top = np.argmax(zi, axis=1)
    y_top = np.take_along_axis(y, i_top[:, None], axis=1)[:, 0]
    win = mask & (np.abs(y - y_top[:, None]) <= window_mm)
    xc = np.where(win, y - y_top[:, None], 0.0)
    m = win.astype(float)
    p = [m, xc * m, xc * xc * m, xc ** 3 * m, xc ** 4 * m]
    mo = [q.sum(axis=1) for q in p]
    A = np.stack([np.stack(mo[i:i + 3], -1) for i in range(3)], -2) + np.eye(3) * 1e-12
    zz = np.where(win, z, 0.0)
    b = np.stack([(p[i] * zz).sum(axis=1) for i in range(3)], -1)
    coef = np.linalg.solve(A, b[..., None])[..., 0]
    c0, c1, c2 = coef.T
    with np.errstate(divide="ignore", invalid="ignore"):
        xv = np.where(c2 < 0, -c1 / (2 * c2), 0.0)
    xv = np.clip(np.nan_to_num(xv), -window_mm, window_mm)
    return c0 + c1 * xv + c2 * xv * xv, win.sum(axis=1)


def gauge_face_y(y_g: np.ndarray, z: np.ndarray, mask: np.ndarray, level: np.ndarray, y_top: np.ndarray,
                 sigma: np.ndarray, window_mm: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Gauge-side coordinate (F,) [mm] at height ``level`` (F,) of points whose ``y_g`` grows
    towards the gauge side, using those beyond ``y_top`` within ``window_mm`` of the level."""
    win = mask & (np.abs(z - level[:, None]) <= window_mm) & (y_g > y_top[:, None])
    return masked_polyfit_at(z, y_g, win, level, 2, sigma)


def measure_rail(unit: CameraLaserUnit, head: RailHead, images: np.ndarray, initial_pose: np.ndarray,
                 stripe: StripeSettings = StripeSettings()) -> dict:
    """Points, fit and wear of one rail over a batch of frames (F, H, W)."""
    y, z, valid, glare = rail_points_mm(unit, images, stripe)
    fit = fit_profiles(head, y, z, valid, unit.side, initial_pose)
    q, zr = to_profile_frame(y, z, fit.pose, unit.side)
    # on the head: not outside the unworn profile beyond the noise (glare, reflections), and
    # inside it by no more than wear can be (the unworn fit's outliers inside are the wear)
    d = fit.residual_mm
    m = valid & (d <= 3.0 * fit.sigma_mm[:, None] + 0.02) & (d > -15.0)
    sig = fit.sigma_mm
    crown = m & (np.abs(q) <= 2.0)
    vw, n_vw = masked_polyfit_at(q, zr, crown, np.zeros(len(q)), 1, sig)
    level = np.full(len(q), -GAUGE_POINT_DEPTH_MM)
    face = m & (q > 20.0) & (np.abs(zr - level[:, None]) <= 1.5)
    q_face, n_sw = masked_polyfit_at(zr, q, face, level, 2, sig)
    inl = fit.inliers
    coverage = np.minimum((inl & (q < -10.0)).sum(axis=1), (inl & (q > 30.0)).sum(axis=1))
    return {"y": y, "z": z, "valid": valid, "on_head": m, "fit": fit, "coverage": coverage, "vertical_wear_mm": -vw,
            "side_wear_mm": head.gauge_point_mm()[0] - q_face, "n_wear": np.minimum(n_vw, n_sw),
            "pose_points": valid, "glare": glare}


def nominal_pose(head: RailHead, side: str, gauge_nominal_m: float, n: int) -> np.ndarray:
    """Initial poses (n, 3): the rail where a nominal track puts it in the measuring frame (the
    design gauge, the 1:40 inclination), the start of every frame's fit."""
    s = SIDE_SIGN[side]
    half_mm = gauge_nominal_m * 500 + head.gauge_point_mm()[0]
    return np.tile([-s * half_mm, 0.0, -s * np.arctan(1 / 40)], (n, 1))


def check_inputs(units: dict, images: dict, roll_rad: np.ndarray) -> None:
    """Raise :class:`~trackfusion.errors.VisionError` naming what is wrong before any computing:
    a side without a unit or images, images that are not (F, H, W) 8-bit grey of the calibrated
    camera's size, or a frame count that differs from the roll series'."""
    for side in SIDE_SIGN:
        if side not in units or side not in images:
            raise VisionError(f"vision: no {side} {'unit' if side not in units else 'images'}")
        img = images[side]
        cam = units[side].camera
        # an array, or frames read and decoded batch by batch when sliced (vision/image_log.py: LogFrames)
        if not (getattr(img, "ndim", 0) == 3 and getattr(img, "dtype", None) == np.uint8):
            raise VisionError(f"vision: {side} images: expected an (F, H, W) uint8 array")
        if img.shape[1:] != (cam.height_px, cam.width_px):
            raise VisionError(f"vision: {side} images: {img.shape[2]} x {img.shape[1]} px, "
                              f"the calibrated camera's are {cam.width_px} x {cam.height_px}")
        if len(img) != len(roll_rad):
            raise VisionError(f"vision: {side} images: {len(img)} frames, roll series has {len(roll_rad)}")


def cross_level_of_poses(pose_left: np.ndarray, pose_right: np.ndarray, roll_rad: np.ndarray) -> np.ndarray:
    """Eq. 37's cross-level [m] (F,): the height difference (left minus right) in the track frame
    of the fitted profile origins (``pose_*[:, :2]``, ``(y, z)`` [mm] in the measuring frame,
    (F, 3) poses), turned by the roll ``roll_rad`` (F,) of the measuring frame relative to the
    track (the exact rotation); NaN poses give NaN."""
    dy = pose_left[:, 0] - pose_right[:, 0]
    dz = pose_left[:, 1] - pose_right[:, 1]
    return (np.sin(roll_rad) * dy + np.cos(roll_rad) * dz) / 1e3


def measure_frames(units: dict, head: RailHead, images: dict, roll_rad: np.ndarray, *,
                   gauge_nominal_m: float = 1.435, limits: FaultLimits = FaultLimits(),
                   stripe: StripeSettings = StripeSettings(), first_frame: int = 0) -> FrameMeasurements:
    """Gauge, cross-level and wear of a batch of frames: ``images[side]`` (F, H, W) of the
    ``units[side]`` (``"left"``, ``"right"``), ``roll_rad`` (F,) the roll of the measuring frame
    relative to the track (module docstring). ``first_frame`` numbers the faults."""
    check_inputs(units, images, roll_rad)
    F = len(roll_rad)
    rails = {side: measure_rail(units[side], head, images[side],
                                nominal_pose(head, side, gauge_nominal_m, F), stripe) for side in SIDE_SIGN}
    c, s = np.cos(roll_rad)[:, None], np.sin(roll_rad)[:, None]
    faults = []
    bad = np.zeros(F, bool)
    wear_bad = {}
    face = {}
    for side, r in rails.items():
        sg = SIDE_SIGN[side]
        yt = c * r["y"] - s * r["z"]
        zt = s * r["y"] + c * r["z"]
        top, n_top = running_top(yt, zt, r["on_head"])
        y_g = sg * yt
        i_top = np.argmax(np.where(r["on_head"], zt, -np.inf), axis=1)
        y_top = np.take_along_axis(y_g, i_top[:, None], axis=1)[:, 0]
        yf, n_face = gauge_face_y(y_g, zt, r["on_head"], top - GAUGE_POINT_DEPTH_MM, y_top, r["fit"].sigma_mm)
        face[side] = sg * yf
        fit = r["fit"]
        reasons = [("missing_stripe", r["valid"].sum(axis=1) < limits.min_columns),
                   ("poor_fit", (fit.rms_mm > limits.max_rms_mm) | (fit.n_inliers < limits.min_inliers)
                    | (fit.pose_sd[:, :2].max(axis=1) > limits.max_pose_sd_mm)),
                   ("unworn_part_unseen", r["coverage"] < limits.min_side_inliers),
                   ("no_gauge_point", (n_face < limits.min_window_points) | (n_top < limits.min_window_points)),
                   ("no_wear_window", r["n_wear"] < limits.min_window_points)]
        taken = np.zeros(F, bool)
        for reason, flag in reasons:
            new = flag & ~taken
            faults += [(first_frame + int(i), side, reason) for i in np.nonzero(new)[0]]
            taken |= flag
        bad |= taken
        # wear only: a glint's tails near the points that fix the pose (and so the unworn
        # profile the wear is measured against); gauge and cross-level stay
        glare_wear = near_glare(r["pose_points"], r["glare"], limits.wear_glare_margin_columns) & ~taken
        faults += [(first_frame + int(i), side, "glare_near_stripe") for i in np.nonzero(glare_wear)[0]]
        wear_bad[side] = glare_wear
    faults.sort()
    o = {side: rails[side]["fit"].pose for side in SIDE_SIGN}
    cross = cross_level_of_poses(o["left"], o["right"], roll_rad)
    gauge = (face["left"] - face["right"]) / 1e3
    nan = lambda x: np.where(bad, np.nan, x)  # noqa: E731
    return FrameMeasurements(
        nan(gauge), nan(cross),
        {k: np.where(wear_bad[k], np.nan, nan(r["vertical_wear_mm"])) for k, r in rails.items()},
        {k: np.where(wear_bad[k], np.nan, nan(r["side_wear_mm"])) for k, r in rails.items()},
        {k: np.where(bad[:, None], np.nan, o[k]) for k in SIDE_SIGN},
        {k: nan(r["fit"].rms_mm) for k, r in rails.items()}, faults)


def concatenate(parts: list[FrameMeasurements]) -> FrameMeasurements:
    """One :class:`FrameMeasurements` of consecutive batches."""
    cat = np.concatenate
    sides = list(SIDE_SIGN)
    return FrameMeasurements(
        cat([p.gauge_m for p in parts]), cat([p.cross_level_m for p in parts]),
        {k: cat([p.vertical_wear_mm[k] for p in parts]) for k in sides},
        {k: cat([p.side_wear_mm[k] for p in parts]) for k in sides},
        {k: cat([p.pose[k] for p in parts]) for k in sides},
        {k: cat([p.rms_mm[k] for p in parts]) for k in sides},
        sorted(f for p in parts for f in p.faults))


def measure_run(units: dict, head: RailHead, images: dict, roll_rad: np.ndarray, *, batch: int = 64,
                workers: int = 1, **kwargs) -> FrameMeasurements:
    """:func:`measure_frames` over a whole run in batches of ``batch`` frames (bounded memory),
    split over ``workers`` forked processes (:class:`trackfusion.forked.ForkedTasks`: each reads
    its frames, from the log (:class:`~trackfusion.vision.image_log.LogFrames`) or the parent's
    arrays; only the figures travel back) when that is possible, with OpenCV on one thread."""
    check_inputs(units, images, roll_rad)
    with one_opencv_thread():
        return _measure_parts(units, head, images, roll_rad, batch, workers, kwargs)


@contextmanager
def one_opencv_thread():
    """OpenCV's own thread pool off while inside (``cv2.setNumThreads(1)``; the forked workers
    inherit it): its calls here are per image and small (threshold, reduce, dilate), so waking
    threads costs CPU rather than saving it (a few per cent, ``benchmarks/vision_stages.py``);
    the frames are split over processes instead. The same results."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _measure_parts(units: dict, head: RailHead, images: dict, roll_rad: np.ndarray, batch: int, workers: int,
                   kwargs: dict) -> FrameMeasurements:
    """:func:`measure_run`'s batches, in this process or on forked ones."""
    from ..forked import ForkedTasks, can_fork
    F = len(roll_rad)

    def part(lo: int, hi: int) -> FrameMeasurements:
        out = [measure_frames(units, head, {k: v[a:min(a + batch, hi)] for k, v in images.items()},
                              roll_rad[a:min(a + batch, hi)], first_frame=a, **kwargs)
               for a in range(lo, hi, batch)]
        return concatenate(out)

    if workers >= 2 and can_fork(workers) and F >= 2 * batch:
        edges = np.linspace(0, F, workers + 1).astype(int)
        with ForkedTasks(always_fork=True) as tasks:
            handles = [tasks.submit(f"vision frames {edges[i]}-{edges[i + 1]}", part, edges[i], edges[i + 1])
                       for i in range(workers)]
            return concatenate([h.result() for h in handles])
    return part(0, F)
