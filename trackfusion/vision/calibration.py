"""Calibration of a camera-laser unit (seed 001 section 10) from a planar-target calibration set.

1. **Intrinsics** by Zhang's method: chessboard corners found with ``cv2.findChessboardCorners``
   and refined with ``cv2.cornerSubPix`` in every board image, then ``cv2.calibrateCamera``
   (distortion ``k1 k2 p1 p2``; ``k3`` is held at zero unless ``fit_k3`` -- a narrow lens does
   not determine it).
2. **Extrinsics in the measuring frame**: the board's pose in the camera frame in the fixture
   view (from the calibration) composed with the fixture's pose in the measuring frame (known:
   the fixture is machined and measured): ``R_vc = R_vb R_cb^T``, ``t_v_c = t_v_b - R_vc t_cb``.
3. **Laser plane**: in every laser image the stripe centres (:mod:`.stripe`), undistorted, are
   intersected with that view's board plane (eq. 24 with the board as the known surface); a
   plane is fitted to all those points by SVD (total least squares): ``A, B, C, D`` in the camera
   frame, then in the measuring frame.

The set is a folder with ``calibration_set.yaml`` (written by
:func:`trackfusion.simulation.vision_calibration.write_calibration_set`, documented in
docs/vision.md). The result is written as YAML with its residuals.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import yaml

from ..errors import VisionError
from ..sensors.fileio import write_text_atomic
from .camera import CameraLaserUnit, CameraModel, intersect_rays_with_plane, plane_to_frame
from .stripe import stripe_centres


@dataclass
class CalibrationResult:
    """A calibrated unit and its residuals: reprojection rms [px] (all corners and per view),
    laser-plane fit rms [mm] and point count, and the number of views used."""

    unit: CameraLaserUnit
    reprojection_rms_px: float
    view_rms_px: list
    laser_plane_rms_mm: float
    laser_points: int
    views: int
    plane_c: np.ndarray

    def to_dict(self) -> dict:
        u = self.unit
        return {"side": u.side,
                "camera": {"image_size_px": [u.camera.width_px, u.camera.height_px],
                           "K": u.camera.K.tolist(), "dist_k1_k2_p1_p2_k3": u.camera.dist.tolist()},
                "extrinsics": {"R_vc": u.R_vc.tolist(), "t_v_c_m": u.t_v_c_m.tolist()},
                "laser_plane_v": {"A": float(u.plane_v[0]), "B": float(u.plane_v[1]),
                                  "C": float(u.plane_v[2]), "D_m": float(u.plane_v[3])},
                "laser_plane_c": [float(x) for x in self.plane_c],
                "residuals": {"reprojection_rms_px": self.reprojection_rms_px,
                              "view_rms_px": [float(x) for x in self.view_rms_px],
                              "laser_plane_rms_mm": self.laser_plane_rms_mm,
                              "laser_points": self.laser_points, "views": self.views}}


def _read_grey(path: Path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise VisionError(f"{path}: not a readable image")
    return img


def _load_set(folder: Path) -> dict:
    path = folder / "calibration_set.yaml"
    if not path.is_file():
        raise VisionError(f"{path}: calibration set description missing")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise VisionError(f"{path}: not YAML ({exc})") from None
    required = {"board": ("inner_corners", "square_m"), "fixture": ("view", "rotation_vector_vb_rad", "position_v_m")}
    for section, keys in required.items():
        for key in keys:
            if not isinstance(doc, dict) or not isinstance(doc.get(section), dict) or key not in doc[section]:
                raise VisionError(f"{path}: {section}.{key}: missing")
    views = doc.get("views")
    if not isinstance(views, list) or not views or not all(isinstance(v, dict) and "board" in v for v in views):
        raise VisionError(f"{path}: views: a list of {{board: FILE, laser: FILE}} is needed")
    if not 0 <= int(doc["fixture"]["view"]) < len(views):
        raise VisionError(f"{path}: fixture.view: {doc['fixture']['view']} is not one of the {len(views)} views")
    if doc.get("side") not in ("left", "right"):
        raise VisionError(f"{path}: side: must be 'left' or 'right'")
    return doc


def find_corners(img: np.ndarray, inner_corners: tuple[int, int]) -> np.ndarray | None:
    """Sub-pixel chessboard corners (N, 2) [px] of a grey image, or None if the board is not
    found."""
    found, corners = cv2.findChessboardCorners(img, inner_corners,
                                               cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 100, 1e-4)
    corners = cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), crit)
    return corners.reshape(-1, 2)


def fit_plane(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Total-least-squares plane (4,) of points (N, 3) (unit normal, ``n . p + D = 0``, normal
    with a positive largest component) and the signed distances (N,)."""
    c = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - c, full_matrices=False)
    n = vt[2] * np.sign(vt[2][np.argmax(np.abs(vt[2]))])
    plane = np.concatenate([n, [-n @ c]])
    return plane, points @ n + plane[3]


def calibrate_unit(folder: str | Path, fit_k3: bool = False) -> CalibrationResult:
    """Calibrate one unit from the calibration set in ``folder`` (module docstring)."""
    folder = Path(folder)
    doc = _load_set(folder)
    inner = tuple(int(x) for x in doc["board"]["inner_corners"])
    obj = board_object_points(inner, float(doc["board"]["square_m"]))
    views = doc["views"]
    fixture_view = int(doc["fixture"]["view"])
    img_pts, obj_pts, used = [], [], []
    size = None
    for i, v in enumerate(views):
        img = _read_grey(folder / v["board"])
        size = img.shape[::-1]
        corners = find_corners(img, inner)
        if corners is None:
            if i == fixture_view:
                raise VisionError(f"{folder / v['board']}: board not found in the fixture view")
            continue
        img_pts.append(corners.astype(np.float32))
        obj_pts.append(obj.astype(np.float32))
        used.append(i)
    if len(used) < 4:
        raise VisionError(f"{folder}: board found in {len(used)} views, calibration needs at least 4")
    flags = 0 if fit_k3 else cv2.CALIB_FIX_K3
    rms, K, dist, rvecs, tvecs = cv2.calibrateCamera(obj_pts, img_pts, size, None, None, flags=flags)
    dist = np.asarray(dist, float).ravel()[:5]
    view_rms = []
    for o, p, r, t in zip(obj_pts, img_pts, rvecs, tvecs):
        proj, _ = cv2.projectPoints(o.astype(np.float64), r, t, K, dist)
        view_rms.append(float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - p) ** 2, axis=1)))))
    camera = CameraModel(K, dist, int(size[0]), int(size[1]))
    pts_c = []
    for k, i in enumerate(used):
        laser_name = views[i].get("laser")
        if not laser_name:
            continue
        rows = stripe_centres(_read_grey(folder / laser_name))
        ok = np.isfinite(rows)
        if ok.sum() < 10:
            continue
        uv = np.column_stack([np.nonzero(ok)[0].astype(float), rows[ok]])
        R_cb = cv2.Rodrigues(rvecs[k])[0]
        t_cb = np.asarray(tvecs[k], float).ravel()
        board_plane_c = np.concatenate([R_cb[:, 2], [-R_cb[:, 2] @ t_cb]])
        pts_c.append(intersect_rays_with_plane(camera.normalised_rays(uv), board_plane_c))
    if len(pts_c) < 2:
        raise VisionError(f"{folder}: laser line found in {len(pts_c)} views, the plane needs at least 2")
    pts = np.concatenate(pts_c)
    plane_c, dists = fit_plane(pts)
    k_fix = used.index(fixture_view)
    R_cb = cv2.Rodrigues(rvecs[k_fix])[0]
    t_cb = np.asarray(tvecs[k_fix], float).ravel()
    R_vb = cv2.Rodrigues(np.asarray(doc["fixture"]["rotation_vector_vb_rad"], float))[0]
    t_v_b = np.asarray(doc["fixture"]["position_v_m"], float)
    R_vc = R_vb @ R_cb.T
    t_v_c = t_v_b - R_vc @ t_cb
    plane_v = plane_to_frame(plane_c, R_vc, t_v_c)
    unit = CameraLaserUnit(camera, R_vc, t_v_c, plane_v, doc["side"])
    return CalibrationResult(unit, float(rms), view_rms, float(np.sqrt(np.mean(dists ** 2)) * 1e3),
                             int(len(pts)), len(used), plane_c)


def board_object_points(inner: tuple[int, int], square_m: float) -> np.ndarray:
    """Inner corners (N, 3) [m] of a chessboard in its own frame (z = 0), OpenCV's row-major order."""
    c, r = inner
    g = np.mgrid[0:c, 0:r].T.reshape(-1, 2).astype(float) * square_m
    return np.column_stack([g, np.zeros(len(g))])


def write_calibration(results: list[CalibrationResult], path: str | Path) -> None:
    """Write the calibrated units (one per side) and their residuals as YAML."""
    write_text_atomic(path, yaml.safe_dump({"units": [r.to_dict() for r in results]}, sort_keys=False))


def load_calibration(path: str | Path) -> dict[str, CameraLaserUnit]:
    """The units of a calibration file written by :func:`write_calibration`, by side."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
        units = {}
        for u in doc["units"]:
            cam = CameraModel(np.array(u["camera"]["K"], float), np.array(u["camera"]["dist_k1_k2_p1_p2_k3"], float),
                              *[int(x) for x in u["camera"]["image_size_px"]])
            p = u["laser_plane_v"]
            units[u["side"]] = CameraLaserUnit(cam, np.array(u["extrinsics"]["R_vc"], float),
                                               np.array(u["extrinsics"]["t_v_c_m"], float),
                                               np.array([p["A"], p["B"], p["C"], p["D_m"]], float), u["side"])
    except (OSError, yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise VisionError(f"{path}: invalid vision calibration ({type(exc).__name__}: {exc})") from None
    return units


def calibrate_folder(folder: str | Path, out: str | Path, fit_k3: bool = False) -> list[CalibrationResult]:
    """Calibrate every unit of ``folder`` -- a calibration set itself, or sub-folders that are
    (e.g. ``left/`` and ``right/``) -- and write them to ``out``. Nothing is written if any set
    fails."""
    folder = Path(folder)
    if not folder.is_dir():
        raise VisionError(f"{folder}: not a folder")
    sets = [folder] if (folder / "calibration_set.yaml").is_file() else \
        sorted(p.parent for p in folder.glob("*/calibration_set.yaml"))
    if not sets:
        raise VisionError(f"{folder}: no calibration_set.yaml in it or in its sub-folders")
    results = [calibrate_unit(s, fit_k3) for s in sets]
    sides = [r.unit.side for r in results]
    if len(set(sides)) != len(sides):
        raise VisionError(f"{folder}: two calibration sets for the same side ({', '.join(sides)})")
    write_calibration(results, out)
    return results
