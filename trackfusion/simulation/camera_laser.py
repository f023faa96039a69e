"""Synthetic camera-laser units filming the rail heads: geometry, stripe images, calibration images.

Frames as in :mod:`trackfusion.vision.camera` (``v`` the measuring frame on the bogie, ``c`` the
camera) plus ``t``, the track frame at the filmed cross-section (x along the track, y left, z
normal to the design running plane). The measuring frame moves relative to the track:
``p_t = r + R_x(phi) p_v`` with ``r = (0, y_rel, z_rel)`` and ``phi`` the roll of the measuring
frame relative to the track (seed 001's ``phi^{t,tgms}``); yaw relative to the track is left out,
so every plane section of a rail projects onto the vehicle y-z plane as the rail profile itself.

A rail's profile frame (:mod:`trackfusion.track.rail_profile`, mm, q towards the gauge side) sits
in a frame (y-z plane) with ``(y, z) = o + R(theta) (s q, z)`` where ``s = -1`` for the left rail
(its gauge side is towards -y), ``+1`` for the right one, ``o`` the profile origin and ``theta``
the profile roll (rail inclination 1:40 inwards plus the track's cross-level tilt).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import cv2
import numpy as np

from ..errors import SimulationError
from ..track.rail_profile import (RailHead, running_top_and_gauge_point, sample_worn_mm,
                                  segment_normals)
from ..vision.camera import CameraLaserUnit, CameraModel, look_at
from ..vision.profile_fit import SIDE_SIGN

#: rail inclination towards the track centre (1 in 40).
RAIL_INCLINATION_RAD = float(np.arctan(1 / 40))


def rot2(theta: np.ndarray) -> np.ndarray:
    """2-D rotations (..., 2, 2) of angles ``theta`` (...) [rad] (y-z plane, about +x)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def place_profile(points_mm: np.ndarray, side: str, origin_m: np.ndarray, roll_rad: float) -> np.ndarray:
    """Profile points (N, 2) ``(q, z)`` [mm] as (N, 2) ``(y, z)`` [m] of the frame ``origin_m``
    and ``roll_rad`` are given in (module docstring)."""
    local = points_mm * np.array([SIDE_SIGN[side], 1.0]) / 1000.0
    return local @ rot2(roll_rad).T + origin_m


@dataclass(frozen=True)
class SimulatedUnit:
    """A true camera-laser unit and where its laser projector sits (for the illumination)."""

    unit: CameraLaserUnit
    laser_origin_v_m: np.ndarray


def default_camera() -> CameraModel:
    """A 640 x 400 px camera with a 2800 px focal length (about 0.13 mm per pixel at 0.37 m) and
    a barrel distortion (k1 = -0.15: 0.25 % at the image corners)."""
    K = np.array([[2800.0, 0.0, 322.5], [0.0, 2805.0, 198.0], [0.0, 0.0, 1.0]])
    return CameraModel(K, np.array([-0.15, 0.0, 4e-4, -3e-4, 0.0]), 640, 400)


def default_units(half_distance_m: float, camera: CameraModel | None = None) -> dict[str, SimulatedUnit]:
    """Left and right units: the laser above the rail and 0.1 m to its gauge side projecting a
    plane about perpendicular to the track (tilted 2 deg); the camera 0.15 m behind the plane,
    0.2 m to the gauge side and 0.25 m above the rail, looking at the gauge corner, its image
    columns running along the head towards the gauge side and down (so that crown, gauge corner
    and gauge face are one-valued per column)."""
    camera = camera or default_camera()
    units = {}
    for side, sgn in SIDE_SIGN.items():
        rail_y = -sgn * half_distance_m
        laser_origin = np.array([0.0, rail_y + sgn * 0.10, 0.35])
        tilt = np.radians(2.0)
        n = np.array([np.cos(tilt), 0.0, np.sin(tilt)])
        plane_v = np.concatenate([n, [-n @ laser_origin]])
        cam_pos = np.array([-0.15, rail_y + sgn * 0.20, 0.25])
        target = np.array([0.0, rail_y + sgn * 0.014, -0.010])
        beta = np.radians(30.0)
        R_vc = look_at(cam_pos, target, np.array([0.0, sgn * np.cos(beta), -np.sin(beta)]))
        units[side] = SimulatedUnit(CameraLaserUnit(camera, R_vc, cam_pos, plane_v, side), laser_origin)
    return units


@dataclass(frozen=True)
class StripeLook:
    """How the stripe looks: Gaussian half-width ``sigma_px`` across the line, peak [DN] on a
    surface facing the laser, optical blur, speckle contrast and grain, ambient level and sensor
    noise (read noise [DN], shot-noise gain [DN per DN])."""

    sigma_px: float = 1.6
    peak_dn: float = 200.0
    blur_sigma_px: float = 0.7
    speckle_contrast: float = 0.25
    speckle_grain_px: float = 1.5
    ambient_dn: float = 12.0
    read_noise_dn: float = 1.5
    shot_gain: float = 0.05


def section_points_v(sim: SimulatedUnit, boundary_mm: np.ndarray, normals: np.ndarray,
                     origin_v_m: np.ndarray, roll_v_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where the laser plane cuts the rail: vehicle-frame points (N, 3) [m], their surface normals
    (N, 3), and the Lambert factor of the laser light (N,), for a rail whose profile frame is at
    ``origin_v_m`` / ``roll_v_rad`` in the vehicle frame."""
    side = sim.unit.side
    yz = place_profile(boundary_mm, side, origin_v_m, roll_v_rad)
    n_yz = (normals * np.array([SIDE_SIGN[side], 1.0])) @ rot2(roll_v_rad).T
    a, b, c, d = sim.unit.plane_v
    x = -(b * yz[:, 0] + c * yz[:, 1] + d) / a
    pts = np.column_stack([x, yz])
    nrm = np.column_stack([np.zeros(len(yz)), n_yz])
    to_laser = sim.laser_origin_v_m - pts
    lambert = np.einsum("ij,ij->i", nrm, to_laser) / np.linalg.norm(to_laser, axis=1)
    return pts, nrm, lambert


def stripe_curve_px(sim: SimulatedUnit, points_v: np.ndarray, normals_v: np.ndarray,
                    lambert: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Image points (M, 2) and relative brightness (M,) of the lit points the camera sees
    (normal towards the camera and the laser), in profile order; hidden points are NaN."""
    visible = (np.einsum("ij,ij->i", normals_v, sim.unit.t_v_c_m - points_v) > 0) & (lambert > 0)
    uv = sim.unit.camera.project(sim.unit.to_camera(points_v))
    uv[~visible] = np.nan
    return uv, np.where(visible, np.clip(lambert, 0, 1), 0.0)


def _runs(u: np.ndarray) -> list[slice]:
    """Maximal runs of finite ``u`` monotonic in one direction."""
    ok = np.isfinite(u)
    du = np.sign(np.diff(u))
    breaks = np.nonzero(~ok[:-1] | ~ok[1:] | (np.concatenate([[0], du[:-1]]) * du < 0))[0] + 1
    edges = np.concatenate([[0], breaks, [len(u)]])
    return [slice(a, b) for a, b in zip(edges[:-1], edges[1:]) if b - a >= 3 and ok[a:b].all()]


def render_stripe(camera: CameraModel, uv: np.ndarray, brightness: np.ndarray, look: StripeLook,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """Float image (H, W) [DN] of a laser line through the image points ``uv`` (M, 2) with
    relative ``brightness`` (M,): per column, a Gaussian of half-width ``sigma_px * sqrt(1 +
    slope^2)`` centred on the line (the vertical cut of a line of Gaussian cross-section),
    evaluated in a window of rows around the line. With ``rng``, speckle (a blurred log-normal
    field of contrast ``speckle_contrast``) multiplies the stripe."""
    H, W = camera.height_px, camera.width_px
    img = np.zeros((H, W), np.float32)
    for run in _runs(uv[:, 0]):
        u, v, b = uv[run, 0], uv[run, 1], brightness[run]
        if u[-1] < u[0]:
            u, v, b = u[::-1], v[::-1], b[::-1]
        cols = np.arange(max(int(np.ceil(u[0])), 0), min(int(np.floor(u[-1])), W - 1) + 1)
        if cols.size == 0:
            continue
        vc = np.interp(cols, u, v)
        slope = np.interp(cols, u, np.gradient(v, u))
        amp = np.interp(cols, u, b) * look.peak_dn
        w = look.sigma_px * np.sqrt(1 + slope ** 2)
        half = int(min(np.ceil(5 * w.max()), 40))
        rows = np.floor(vc).astype(int)[:, None] + np.arange(-half, half + 1)
        vals = amp[:, None] * np.exp(-0.5 * ((rows - vc[:, None]) / w[:, None]) ** 2)
        if rng is not None and look.speckle_contrast > 0:
            sp = rng.standard_normal(vals.shape).astype(np.float32)
            sp = cv2.GaussianBlur(sp, (0, 0), look.speckle_grain_px)
            sp *= look.speckle_contrast / max(float(sp.std()), 1e-12)
            vals = vals * np.exp(sp - 0.5 * look.speckle_contrast ** 2)
        inside = (rows >= 0) & (rows < H)
        cc = np.broadcast_to(cols[:, None], rows.shape)
        img[rows[inside], cc[inside]] += vals[inside]
    return img


def expose(img: np.ndarray, look: StripeLook, rng: np.random.Generator | None) -> np.ndarray:
    """Optical blur, ambient light, shot and read noise, 8-bit quantisation and saturation."""
    out = cv2.GaussianBlur(img, (0, 0), look.blur_sigma_px) if look.blur_sigma_px > 0 else img.copy()
    out = out + look.ambient_dn
    if rng is not None:
        noise = rng.standard_normal(out.shape, dtype=np.float32)
        out = out + noise * np.sqrt(look.read_noise_dn ** 2 + look.shot_gain * out)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def add_glare(img: np.ndarray, uv: np.ndarray, rng: np.random.Generator) -> None:
    """A saturated sun-glint ellipse next to the stripe (in place on a float image)."""
    ok = np.nonzero(np.isfinite(uv[:, 0]))[0]
    if ok.size == 0:
        return
    u0, v0 = uv[rng.choice(ok)]
    H, W = img.shape
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    a, b = rng.uniform(10, 30), rng.uniform(4, 10)
    v0 += rng.uniform(-25, 25)
    blob = np.exp(-0.5 * (((xx - u0) / a) ** 2 + ((yy - v0) / b) ** 2))
    img += 600.0 * blob


# --------------------------------------------------------------------------- relative motion


def resonant_noise(n: int, rate_hz: float, f0_hz: float, zeta: float, rms: float,
                   rng: np.random.Generator) -> np.ndarray:
    """``n`` samples of white noise through a 2nd-order resonance ``f0_hz`` / damping ``zeta``
    (a suspension mode), scaled to ``rms``; the first 4 resonance periods are run in and dropped."""
    from scipy.signal import bilinear, lfilter

    w0 = 2 * np.pi * f0_hz
    b, a = bilinear([w0 ** 2], [1.0, 2 * zeta * w0, w0 ** 2], rate_hz)
    skip = int(4 * rate_hz / f0_hz)
    n_gen = max(n, int(400 * rate_hz / f0_hz))          # long enough for a stable rms scale
    x = lfilter(b, a, rng.standard_normal(n_gen + skip))[skip:]
    return (x * rms / max(x.std(), 1e-15))[:n]


@dataclass(frozen=True)
class VisionRun:
    """Truth of a simulated run of ``F`` frames: time [s], chainage [m], relative motion of the
    measuring frame to the actual track (lateral, vertical [m], roll [rad]), wear per rail [mm],
    true gauge at 14 mm [m] and cross-level of the profile origins [m] per frame, each rail's
    profile pose in the vehicle frame, and the track centreline's alignment and vertical profile
    [m] (the mean of the two profile origins, relative to the design track frame: eq. 40's
    ``al``, ``vp``). The measuring frame's position relative to the design track frame (eq. 46's
    ``r^{tgms}``) is ``(alignment_m + y_rel_m, vertical_profile_m + z_rel_m)``."""

    t_s: np.ndarray
    s_m: np.ndarray
    y_rel_m: np.ndarray
    z_rel_m: np.ndarray
    roll_rel_rad: np.ndarray
    vertical_wear_mm: dict
    side_wear_mm: dict
    gauge_m: np.ndarray
    cross_level_m: np.ndarray
    origin_v_m: dict
    roll_v_rad: dict
    alignment_m: np.ndarray
    vertical_profile_m: np.ndarray

    def frames(self, first: int, stop: int | None = None) -> "VisionRun":
        """The run's frames ``first`` to ``stop`` (e.g. after an IMU filter's lead-in)."""
        cut = lambda x: {k: v[first:stop] for k, v in x.items()} if isinstance(x, dict) else x[first:stop]  # noqa: E731
        return VisionRun(*(cut(getattr(self, f.name)) for f in fields(self)))


def _track_series(s_m: np.ndarray, rms: float, corr_m: float, rng: np.random.Generator) -> np.ndarray:
    """A smooth random irregularity of ``rms`` along chainage (wavelengths above ~``corr_m``)."""
    step = float(np.median(np.diff(s_m))) if len(s_m) > 1 else 1.0
    n = len(s_m)
    sigma = max(corr_m / step / 2, 0.5)
    n_gen = max(n, int(200 * sigma))                      # long enough for a stable rms scale
    x = rng.standard_normal(n_gen)
    x = cv2.GaussianBlur(x.reshape(1, -1), (0, 0), sigma).ravel()
    return (x * rms / max(x.std(), 1e-15))[:n]


@dataclass(frozen=True)
class TrackAndBogie:
    """What a simulated vision run's track and bogie are like: the track's ``gauge_nominal_m``
    [m] and the rms ``alignment_rms_m`` [m] of its centreline alignment and vertical profile;
    the peaks (about 2.5 rms) of the measuring frame's motion relative to the track,
    ``lateral_peak_m`` [m], ``vertical_peak_m`` [m], ``roll_peak_rad`` [rad]."""

    gauge_nominal_m: float = 1.435
    alignment_rms_m: float = 1.5e-3
    lateral_peak_m: float = 5e-3
    vertical_peak_m: float = 10e-3
    roll_peak_rad: float = np.radians(0.5)


def simulate_run(head: RailHead, *, n_frames: int, speed_mps: float = 30.0, rate_hz: float = 250.0,
                 conditions: TrackAndBogie = TrackAndBogie(), wear: dict | None = None, seed: int = 1,
                 truth_frames: slice = slice(None)) -> VisionRun:
    """Truth of a run: the measuring frame on the bogie moving relative to the track (lateral
    mode at 1.2 Hz, bounce at 3.5 Hz, roll at 1.0 Hz, each with a peak about 2.5 rms, the peaks
    of ``conditions``), a track with gauge variation (rms 1 mm) and cross-level (rms 1.5 mm) of
    wavelengths above ~5 m, a centreline alignment and vertical profile (rms
    ``conditions.alignment_rms_m`` each, wavelengths above ~2 m; the measuring frame follows
    them, the rails carry them), and optional wear:
    ``wear = {"start_m", "end_m", "vertical_mm", "side_mm", "side_rail"}``
    (both rails lose the vertical wear, ``side_rail`` the side wear; 5 m ramps). The true gauge
    is computed for ``truth_frames`` only (NaN elsewhere: an IMU lead-in nobody films)."""
    if n_frames < 2 or speed_mps <= 0 or rate_hz <= 0:
        raise SimulationError("vision run needs n_frames >= 2, speed > 0 and a frame rate > 0")
    rng = np.random.default_rng(seed)
    t = np.arange(n_frames) / rate_hz
    s = speed_mps * t
    y_rel = resonant_noise(n_frames, rate_hz, 1.2, 0.15, conditions.lateral_peak_m / 2.5, rng)
    z_rel = resonant_noise(n_frames, rate_hz, 3.5, 0.2, conditions.vertical_peak_m / 2.5, rng)
    roll_rel = resonant_noise(n_frames, rate_hz, 1.0, 0.2, conditions.roll_peak_rad / 2.5, rng)
    gv = _track_series(s, 1e-3, 5.0, rng)
    cl = _track_series(s, 1.5e-3, 5.0, rng)
    al = _track_series(s, conditions.alignment_rms_m, 2.0, rng)
    vp = _track_series(s, conditions.alignment_rms_m, 2.0, rng)
    q_g = head.gauge_point_mm()[0] / 1000
    half = conditions.gauge_nominal_m / 2 + q_g
    vw = {k: np.zeros(n_frames) for k in SIDE_SIGN}
    sw = {k: np.zeros(n_frames) for k in SIDE_SIGN}
    if wear:
        ramp = np.clip(np.minimum(s - wear["start_m"], wear["end_m"] - s) / 5.0, 0, 1)
        for k in SIDE_SIGN:
            vw[k] = ramp * wear["vertical_mm"]
        sw[wear["side_rail"]] = ramp * wear["side_mm"]
    origin_t = {"left": np.column_stack([half + gv / 2 + al, cl / 2 + vp]),
                "right": np.column_stack([-half - gv / 2 + al, -cl / 2 + vp])}
    tilt = cl / (2 * half)
    roll_t = {k: -sgn * RAIL_INCLINATION_RAD + tilt for k, sgn in SIDE_SIGN.items()}
    r = np.column_stack([al + y_rel, vp + z_rel])
    R_back = rot2(-roll_rel)                      # track -> vehicle
    origin_v = {k: np.einsum("fij,fj->fi", R_back, origin_t[k] - r) for k in SIDE_SIGN}
    roll_v = {k: roll_t[k] - roll_rel for k in SIDE_SIGN}
    cut = lambda x: {k: v[truth_frames] for k, v in x.items()}  # noqa: E731
    gauge = np.full(n_frames, np.nan)
    gauge[truth_frames], _ = true_gauge_and_cross_level(head, cut(origin_t), cut(roll_t), cut(vw), cut(sw))
    cross = origin_t["left"][:, 1] - origin_t["right"][:, 1]
    return VisionRun(t, s, y_rel, z_rel, roll_rel, vw, sw, gauge, cross, origin_v, roll_v, al, vp)


def true_gauge_and_cross_level(head: RailHead, origin_t: dict, roll_t: dict, vw: dict, sw: dict
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Per frame: the gauge [m] between the gauge points 14 mm below each rail's running surface
    (the highest point of the worn head in the track frame), and the cross-level [m] as seed 001
    defines it, the height difference of the profile origins (left minus right)."""
    n = len(origin_t["left"])
    gauge = np.empty(n)
    cache: dict = {}
    for i in range(n):
        gp = {}
        for k, sgn in SIDE_SIGN.items():
            key = (round(float(vw[k][i]), 6), round(float(sw[k][i]), 6))
            if key not in cache:
                cache[key] = sample_worn_mm(head, *key, step_mm=0.01)
            yz = place_profile(cache[key], k, origin_t[k][i], roll_t[k][i])
            _, g = running_top_and_gauge_point(yz * np.array([sgn * 1e3, 1e3]))   # mm, gauge side to +y
            gp[k] = g[0] * sgn / 1e3
        gauge[i] = gp["left"] - gp["right"]
    return gauge, origin_t["left"][:, 1] - origin_t["right"][:, 1]


def frame_images(sim: SimulatedUnit, head: RailHead, run: VisionRun, look: StripeLook, *,
                 seed: int, glare_rate: float = 0.02, missing_rate: float = 0.01,
                 noise: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Images (F, H, W) uint8 of one unit over a run, and the per-frame flags (F,) of frames
    whose stripe was blanked (laser dropout / dirt on the window): 0 ok, 1 missing stripe,
    2 glare. The boundary of the worn head is recomputed when the wear changes."""
    rng = np.random.default_rng(seed)
    side = sim.unit.side
    F = len(run.t_s)
    cam = sim.unit.camera
    out = np.empty((F, cam.height_px, cam.width_px), np.uint8)
    flags = np.zeros(F, np.int8)
    cache: dict = {}
    for i in range(F):
        key = (round(float(run.vertical_wear_mm[side][i]), 3), round(float(run.side_wear_mm[side][i]), 3))
        if key not in cache:
            b = sample_worn_mm(head, *key, step_mm=0.05)
            cache[key] = (b, segment_normals(b))
        b, nrm = cache[key]
        pts, nv, lam = section_points_v(sim, b, nrm, run.origin_v_m[side][i], run.roll_v_rad[side][i])
        uv, bright = stripe_curve_px(sim, pts, nv, lam)
        r = rng if noise else None
        img = render_stripe(cam, uv, bright, look, r)
        if noise and rng.random() < missing_rate:
            img *= 0.0
            flags[i] = 1
        elif noise and rng.random() < glare_rate:
            add_glare(img, uv, rng)
            flags[i] = 2
        out[i] = expose(img, look, r)
    return out, flags
