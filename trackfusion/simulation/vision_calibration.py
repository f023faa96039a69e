"""Synthetic calibration set of a camera-laser unit: a planar chessboard in several poses, with the
laser line on it (seed 001 section 10, with Zhang's planar target in place of the trihedral one).

For each pose two images: the board lit (``board_XX.png``) and the laser line on it with the
lights off (``laser_XX.png``). Pose 0 is the board on the calibration fixture, whose pose in the
measuring frame is known (machined and measured with a CMM): it ties the camera to the vehicle
frame. ``calibration_set.yaml`` lists the images, the board and the fixture pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from ..vision.calibration import board_object_points
from ..vision.camera import CameraModel, intersect_rays_with_plane
from .camera_laser import SimulatedUnit, StripeLook, expose, render_stripe


@dataclass(frozen=True)
class BoardSpec:
    """Chessboard: inner corners ``(columns, rows)``, square size [m], white margin [squares]."""

    inner_corners: tuple[int, int] = (11, 8)
    square_m: float = 0.0025
    margin_squares: float = 1.0

    def object_points(self) -> np.ndarray:
        """Inner corners (N, 3) [m] in the board frame (z = 0), OpenCV's row-major order."""
        return board_object_points(self.inner_corners, self.square_m)


def _undistorted_px(camera: CameraModel, supersample: int) -> np.ndarray:
    """Ideal (undistorted) pixel coordinates (H*s, W*s, 2) of the sub-pixel samples of the
    distorted image: where each sample looks in a distortion-free camera of the same ``K``."""
    H, W = camera.height_px, camera.width_px
    o = (np.arange(supersample) + 0.5) / supersample - 0.5
    vs = (np.arange(H)[:, None] + o).ravel()
    us = (np.arange(W)[:, None] + o).ravel()
    uu, vv = np.meshgrid(us, vs)
    xy = camera.normalised_rays(np.column_stack([uu.ravel(), vv.ravel()]))
    K = camera.K
    ideal = np.column_stack([K[0, 0] * xy[:, 0] + K[0, 2], K[1, 1] * xy[:, 1] + K[1, 2]])
    return ideal.reshape(len(vs), len(us), 2)


def _board_texture(board: BoardSpec, px_per_m: float) -> tuple[np.ndarray, float]:
    """High-resolution board image (white 200, black 30) and the board-frame position [m] of its
    pixel (0, 0) (the same in x and y)."""
    c, r = board.inner_corners
    sq = board.square_m
    lo = -sq * (1 + board.margin_squares)
    w = int(round((sq * (c + 1 + 2 * board.margin_squares)) * px_per_m))
    h = int(round((sq * (r + 1 + 2 * board.margin_squares)) * px_per_m))
    yy, xx = np.mgrid[0:h, 0:w]
    bx, by = lo + (xx + 0.5) / px_per_m, lo + (yy + 0.5) / px_per_m
    ix, iy = np.floor(bx / sq + 1.0), np.floor(by / sq + 1.0)
    black = (ix >= 0) & (ix <= c) & (iy >= 0) & (iy <= r) & ((ix + iy) % 2 == 0)
    return np.where(black, 30.0, 200.0).astype(np.float32), lo


def render_board(camera: CameraModel, ideal_px: np.ndarray, supersample: int, R_cb: np.ndarray,
                 t_cb: np.ndarray, board: BoardSpec, px_per_m: float = 40000.0) -> np.ndarray:
    """Float image (H, W) [DN] of the board at pose ``p_c = R_cb p_b + t_cb`` (background 10): the
    board texture mapped through the board-to-image homography onto the ideal pixel positions of
    the distorted image's sub-pixel samples (``cv2.remap``), averaged down (``cv2.resize``,
    area)."""
    tex, lo = _board_texture(board, px_per_m)
    # texture px -> board metres -> ideal image px
    S = np.array([[1 / px_per_m, 0, lo + 0.5 / px_per_m], [0, 1 / px_per_m, lo + 0.5 / px_per_m], [0, 0, 1]])
    Hm = camera.K @ np.column_stack([R_cb[:, 0], R_cb[:, 1], t_cb]) @ S
    Hinv = np.linalg.inv(Hm)
    x, y = ideal_px[..., 0], ideal_px[..., 1]
    w = Hinv[2, 0] * x + Hinv[2, 1] * y + Hinv[2, 2]
    mx = ((Hinv[0, 0] * x + Hinv[0, 1] * y + Hinv[0, 2]) / w).astype(np.float32)
    my = ((Hinv[1, 0] * x + Hinv[1, 1] * y + Hinv[1, 2]) / w).astype(np.float32)
    big = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=10.0)
    return cv2.resize(big, (camera.width_px, camera.height_px), interpolation=cv2.INTER_AREA)


def board_poses(n: int, distance_m: float, rng: np.random.Generator, board: BoardSpec
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` board poses ``(R_cb, t_cb)`` about ``distance_m`` along the optical axis, the board
    centre near the axis, tilted up to 45 deg about both board axes and turned up to 20 deg."""
    c, r = board.inner_corners
    centre_b = np.array([(c - 1) / 2, (r - 1) / 2, 0.0]) * board.square_m
    poses = []
    for i in range(n):
        ax, ay = rng.uniform(-45, 45, 2) if i else (10.0, -15.0)
        az = rng.uniform(-20, 20)
        R, _ = cv2.Rodrigues(np.radians([ax, ay, az]))
        t = np.array([rng.uniform(-0.004, 0.004), rng.uniform(-0.003, 0.003),
                      distance_m + rng.uniform(-0.02, 0.02)]) - R @ centre_b
        poses.append((R, t))
    return poses


def laser_line_px(sim: SimulatedUnit, R_cb: np.ndarray, t_cb: np.ndarray, board: BoardSpec) -> np.ndarray:
    """Image points (M, 2) of the laser line on the board: the intersection of the board plane
    with the laser plane, sampled across the board's extent."""
    plane_c = sim.unit.plane_c
    n_b, d_b = R_cb[:, 2], -R_cb[:, 2] @ t_cb
    direction = np.cross(plane_c[:3], n_b)
    direction /= np.linalg.norm(direction)
    A = np.vstack([plane_c[:3], n_b, direction])
    p0 = np.linalg.solve(A, np.array([-plane_c[3], -d_b, 0.0]))
    c, r = board.inner_corners
    extent = board.square_m * (max(c, r) + 2)
    centre_b = np.array([(c - 1) / 2, (r - 1) / 2, 0.0]) * board.square_m
    centre_c = R_cb @ centre_b + t_cb
    p_mid = p0 + direction * (direction @ (centre_c - p0))
    s = np.linspace(-extent, extent, 600)
    pts = p_mid + s[:, None] * direction
    p_b = (pts - t_cb) @ R_cb
    m = board.margin_squares
    on = (p_b[:, 0] > -board.square_m * (1 + m)) & (p_b[:, 0] < board.square_m * (c + m)) & \
         (p_b[:, 1] > -board.square_m * (1 + m)) & (p_b[:, 1] < board.square_m * (r + m))
    return sim.unit.camera.project(pts[on])


def write_calibration_set(sim: SimulatedUnit, out_dir: str | Path, *, n_poses: int = 30, seed: int = 1,
                          distance_m: float = 0.353,
                          board: BoardSpec = BoardSpec(), supersample: int = 3,
                          look: StripeLook = StripeLook(speckle_contrast=0.1)) -> Path:
    """Render and write the calibration set of one unit into ``out_dir`` (module docstring), the
    boards about ``distance_m`` from the camera (where it sees the rail); returns the path of
    ``calibration_set.yaml``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    cam = sim.unit.camera
    ideal = _undistorted_px(cam, supersample)
    poses = board_poses(n_poses, distance_m, rng, board)
    # the board is set where the laser line crosses it: its centre on the laser plane, seen
    # within the middle of the image
    plane_c = sim.unit.plane_c
    c, r = board.inner_corners
    centre_b = np.array([(c - 1) / 2, (r - 1) / 2, 0.0]) * board.square_m
    for k, (R, t) in enumerate(poses):
        uv = np.array([[cam.width_px * rng.uniform(0.35, 0.65), cam.height_px * rng.uniform(0.4, 0.6)]])
        centre_c = intersect_rays_with_plane(cam.normalised_rays(uv), plane_c)[0]
        poses[k] = (R, centre_c - R @ centre_b)
    board_look = StripeLook(blur_sigma_px=0.6, ambient_dn=0.0, read_noise_dn=1.0, shot_gain=0.02)
    views = []
    for i, (R, t) in enumerate(poses):
        img = expose(render_board(cam, ideal, supersample, R, t, board), board_look, rng)
        cv2.imwrite(str(out / f"board_{i:02d}.png"), img)
        uv = laser_line_px(sim, R, t, board)
        laser = expose(render_stripe(cam, uv, np.ones(len(uv)), look, rng), look, rng)
        cv2.imwrite(str(out / f"laser_{i:02d}.png"), laser)
        views.append({"board": f"board_{i:02d}.png", "laser": f"laser_{i:02d}.png"})
    R_vb = sim.unit.R_vc @ poses[0][0]
    t_v_b = sim.unit.to_vehicle(poses[0][1])
    doc = {"side": sim.unit.side, "image_size_px": [cam.width_px, cam.height_px],
           "board": {"inner_corners": list(board.inner_corners), "square_m": board.square_m},
           "fixture": {"view": 0, "rotation_vector_vb_rad": cv2.Rodrigues(R_vb)[0].ravel().tolist(),
                       "position_v_m": t_v_b.tolist()},
           "views": views}
    path = out / "calibration_set.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path
