"""Camera-laser unit: pinhole camera with OpenCV distortion, laser plane, pose in the vehicle frame.

Frames: ``c`` camera (OpenCV: x right, y down, z along the optical axis), ``v`` the measuring
frame on the bogie (x forward, y left, z up; seed 001's TGMS frame). Lengths in metres.

A laser plane is ``A x + B y + C z + D = 0`` with ``(A, B, C)`` a unit normal (seed 001 eq. 24),
stored as a (4,) array in the frame its name says (``plane_c``, ``plane_v``).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics: ``K`` (3, 3) [px], ``dist`` (5,) OpenCV ``k1 k2 p1 p2 k3``, image size [px]."""

    K: np.ndarray
    dist: np.ndarray
    width_px: int
    height_px: int

    def project(self, points_c: np.ndarray) -> np.ndarray:
        """Pixel coordinates (N, 2) of camera-frame points (N, 3) [m] (``cv2.projectPoints``)."""
        pts = np.ascontiguousarray(points_c, dtype=np.float64).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.K, self.dist)
        return uv.reshape(-1, 2)

    def normalised_rays(self, uv_px: np.ndarray) -> np.ndarray:
        """Undistorted normalised image coordinates (N, 2) of pixels (N, 2)
        (``cv2.undistortPoints`` iterated to 1e-12)."""
        pts = np.ascontiguousarray(uv_px, dtype=np.float64).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 1e-12)
        xy = cv2.undistortPoints(pts, self.K, self.dist, None, None, None, crit)
        return xy.reshape(-1, 2)


def plane_to_frame(plane_a: np.ndarray, R_ba: np.ndarray, t_b_a: np.ndarray) -> np.ndarray:
    """A plane (4,) given in frame a, expressed in frame b where ``p_b = R_ba p_a + t_b_a``."""
    n_b = R_ba @ plane_a[:3]
    return np.concatenate([n_b, [plane_a[3] - n_b @ t_b_a]])


def intersect_rays_with_plane(xy_norm: np.ndarray, plane_c: np.ndarray) -> np.ndarray:
    """Seed 001 eq. 24: camera-frame points (N, 3) [m] where the rays through the normalised
    image points ``xy_norm`` (N, 2) meet the plane ``plane_c`` (4,). Rays parallel to the plane
    give NaN."""
    a, b, c, d = plane_c
    denom = a * xy_norm[:, 0] + b * xy_norm[:, 1] + c
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(np.abs(denom) > 1e-12, -d / denom, np.nan)
    return np.column_stack([xy_norm[:, 0] * z, xy_norm[:, 1] * z, z])


@dataclass(frozen=True)
class CameraLaserUnit:
    """One rail's unit: camera model, camera pose in the vehicle frame (``p_v = R_vc p_c +
    t_v_c``), laser plane in the vehicle frame, and the rail side it films (``"left"`` or
    ``"right"``)."""

    camera: CameraModel
    R_vc: np.ndarray
    t_v_c_m: np.ndarray
    plane_v: np.ndarray
    side: str

    @property
    def plane_c(self) -> np.ndarray:
        """The laser plane in the camera frame."""
        return plane_to_frame(self.plane_v, self.R_vc.T, -self.R_vc.T @ self.t_v_c_m)

    def to_camera(self, points_v: np.ndarray) -> np.ndarray:
        """Camera-frame points (N, 3) of vehicle-frame ones (no BLAS: a 3 x 3 product)."""
        return np.einsum("...i,ij->...j", np.asarray(points_v) - self.t_v_c_m, self.R_vc)

    def to_vehicle(self, points_c: np.ndarray) -> np.ndarray:
        """Vehicle-frame points (N, 3) of camera-frame ones."""
        return np.einsum("ij,...j->...i", self.R_vc, np.asarray(points_c)) + self.t_v_c_m

    def pixels_to_vehicle(self, uv_px: np.ndarray) -> np.ndarray:
        """Vehicle-frame points (N, 3) [m] of stripe pixels (N, 2) on the laser plane: undistortion
        (OpenCV) then eq. 24."""
        return self.to_vehicle(intersect_rays_with_plane(self.camera.normalised_rays(uv_px), self.plane_c))


def look_at(position_v: np.ndarray, target_v: np.ndarray, u_axis_hint_v: np.ndarray) -> np.ndarray:
    """Rotation ``R_vc`` of a camera at ``position_v`` looking at ``target_v`` whose image x axis
    (columns) is as close as possible to ``u_axis_hint_v``."""
    z = np.asarray(target_v, float) - position_v
    z /= np.linalg.norm(z)
    x = np.asarray(u_axis_hint_v, float) - (np.asarray(u_axis_hint_v, float) @ z) * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])
