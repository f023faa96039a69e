"""Rail-head profiles (EN 13674-1 60E1 and 54E1) built from their published arcs, worn variants.

Profile frame ``r`` (a cross-section of one rail): ``q`` across the head, positive towards the
**gauge side** (the inside of the track), ``z`` up; the origin is the top of the unworn head on
the profile centreline. All lengths in this module are **millimetres** (the unit of the rail
drawings).

The unworn head is convex and symmetric: a crown arc R1 (centre on the centreline), then on each
side an arc R2 and a corner arc R3, each tangent to the previous one, then a straight flank
inclined 1 in ``flank_slope`` (widening downwards). The arcs are given by the drawing's radii and
the widths between tangent points: ``crown_width_mm`` (R1/R2 tangent points) and
``r2_width_mm`` (R2/R3 tangent points); the R3/flank tangent point follows from tangency, so the
head width at the top of the flank is a check on the data (72.0 mm for 60E1).

Seed 001's eq. 25 parametrises each arc by the angle of its normal; here ``a`` is that angle
measured from the vertical towards +q, a point of arc k is ``c_k + R_k (sin a, cos a)``.

Wear is material removed by two cuts of the unworn head: a horizontal cut ``vertical_wear_mm``
below the unworn top (vertical wear, measured on the centreline) and a cut at the gauge corner
whose normal makes ``side_wear_angle_deg`` with the vertical, through the point ``side_wear_mm``
inside the unworn gauge face at 14 mm below the unworn top (side wear as EN 13674 measures it).

The gauge point is the point of the gauge face 14 mm below the running surface (EN 13848-1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import TrackGeometryError

#: depth of the gauge point below the running surface [mm] (EN 13848-1).
GAUGE_POINT_DEPTH_MM = 14.0


@dataclass(frozen=True)
class RailHeadSpec:
    """Drawing data of one rail head (mm). ``flank_depth_mm`` is how far below the top the flank
    is modelled (the head's lower corners are out of a rail-profile camera's view)."""

    name: str
    crown_radius_mm: float
    side_radius_mm: float
    corner_radius_mm: float
    crown_width_mm: float
    r2_width_mm: float
    flank_slope: float
    flank_depth_mm: float = 30.0


#: 60E1 (ex UIC 60), EN 13674-1: R300 / R80 / R13, tangent points 20.456 and 52.053 mm apart,
#: flanks 1:20; the derived head width at the top of the flanks is 72.0 mm.
RAIL_60E1 = RailHeadSpec("60E1", 300.0, 80.0, 13.0, 20.456, 52.053, 20.0)
#: 54E1 (ex UIC 54): R300 / R80 / R13 and 1:20 flanks like 60E1, head width 70 mm. The R80/R13
#: tangent width here is derived from the 70 mm head width with 60E1's crown width.
RAIL_54E1 = RailHeadSpec("54E1", 300.0, 80.0, 13.0, 20.456, 49.6652, 20.0)
RAIL_SPECS = {s.name: s for s in (RAIL_60E1, RAIL_54E1)}


@dataclass(frozen=True)
class Arc:
    """Circular arc: centre ``(q, z)`` [mm], radius [mm], normal angles ``a0 < a1`` [rad]."""

    centre_mm: tuple[float, float]
    radius_mm: float
    a0_rad: float
    a1_rad: float


@dataclass(frozen=True)
class RailHead:
    """The unworn head of one rail as 5 arcs (field R3, field R2, R1, gauge R2, gauge R3) and two
    flank segments, ordered from the field flank to the gauge flank."""

    spec: RailHeadSpec
    arcs: tuple[Arc, ...]
    flank_top_mm: tuple[float, float]   # gauge-side R3/flank tangent point (q, z)
    flank_normal_rad: float             # normal angle of the gauge flank from the vertical

    @property
    def half_width_mm(self) -> float:
        return self.flank_top_mm[0]

    def gauge_point_mm(self) -> tuple[float, float]:
        """Unworn gauge point ``(q, z)`` [mm], ``z = -14``."""
        return gauge_face_q_mm(self, -GAUGE_POINT_DEPTH_MM), -GAUGE_POINT_DEPTH_MM


def rail_head(spec: RailHeadSpec | str) -> RailHead:
    """The :class:`RailHead` of a spec or of its name (``"60E1"``, ``"54E1"``)."""
    if isinstance(spec, str):
        if spec not in RAIL_SPECS:
            raise TrackGeometryError(f"rail profile {spec!r}: unknown (known: {', '.join(RAIL_SPECS)})")
        spec = RAIL_SPECS[spec]
    r1, r2, r3 = spec.crown_radius_mm, spec.side_radius_mm, spec.corner_radius_mm
    if not r1 > r2 > r3 > 0:
        raise TrackGeometryError(f"rail profile {spec.name}: radii must decrease outwards")
    c1 = np.array([0.0, -r1])
    a1 = np.arcsin(spec.crown_width_mm / 2 / r1)
    c2 = c1 + (r1 - r2) * np.array([np.sin(a1), np.cos(a1)])
    a2 = np.arcsin((spec.r2_width_mm / 2 - c2[0]) / r2)
    c3 = c2 + (r2 - r3) * np.array([np.sin(a2), np.cos(a2)])
    a3 = np.arctan2(1.0, 1.0 / spec.flank_slope)
    flank_top = c3 + r3 * np.array([np.sin(a3), np.cos(a3)])
    mirror = np.array([-1.0, 1.0])
    arcs = (Arc(tuple(c3 * mirror), r3, -a3, -a2), Arc(tuple(c2 * mirror), r2, -a2, -a1),
            Arc(tuple(c1), r1, -a1, a1), Arc(tuple(c2), r2, a1, a2), Arc(tuple(c3), r3, a2, a3))
    return RailHead(spec, arcs, (float(flank_top[0]), float(flank_top[1])), float(a3))


def gauge_face_q_mm(head: RailHead, z_mm: float) -> float:
    """Gauge-side ``q`` [mm] of the unworn head at height ``z_mm`` (below the corner arc's
    centre the flank or the lower part of the corner arc)."""
    (cq, cz), r = head.arcs[4].centre_mm, head.arcs[4].radius_mm
    if z_mm <= head.flank_top_mm[1]:
        return head.flank_top_mm[0] + (head.flank_top_mm[1] - z_mm) / head.spec.flank_slope
    return cq + float(np.sqrt(r * r - (z_mm - cz) ** 2))


def sample_unworn_mm(head: RailHead, step_mm: float = 0.02) -> np.ndarray:
    """Boundary of the unworn head from the bottom of the field flank to the bottom of the gauge
    flank, points about ``step_mm`` apart: (N, 2) ``(q, z)`` [mm]."""
    parts = []
    tq, tz = head.flank_top_mm
    depth = head.spec.flank_depth_mm
    flank_len = np.hypot((depth + tz) / head.spec.flank_slope, depth + tz)
    n_f = max(int(flank_len / step_mm), 2)
    zf = np.linspace(-depth, tz, n_f, endpoint=False)
    qf = tq + (tz - zf) / head.spec.flank_slope
    parts.append(np.column_stack([-qf, zf]))
    for arc in head.arcs:
        n = max(int(arc.radius_mm * (arc.a1_rad - arc.a0_rad) / step_mm), 2)
        a = np.linspace(arc.a0_rad, arc.a1_rad, n, endpoint=False)
        parts.append(np.column_stack([arc.centre_mm[0] + arc.radius_mm * np.sin(a),
                                      arc.centre_mm[1] + arc.radius_mm * np.cos(a)]))
    parts.append(np.column_stack([qf[::-1], zf[::-1]]))
    return np.concatenate(parts)


def _cut(points: np.ndarray, point_on_line: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """Replace the points beyond the line (``(p - p0) . n > 0``) by their orthogonal projection on
    it: on a convex boundary that is the chord of the cut-off cap, points kept in order."""
    beyond = (points - point_on_line) @ normal
    out = points.copy()
    mask = beyond > 0
    out[mask] -= beyond[mask, None] * normal
    return out


def _resample(points: np.ndarray, step_mm: float) -> np.ndarray:
    """The polyline ``points`` (N, 2) resampled every ``step_mm`` of arc length."""
    seg = np.hypot(*np.diff(points, axis=0).T)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    s_new = np.arange(0.0, s[-1], step_mm)
    return np.column_stack([np.interp(s_new, s, points[:, 0]), np.interp(s_new, s, points[:, 1])])


def sample_worn_mm(head: RailHead, vertical_wear_mm: float = 0.0, side_wear_mm: float = 0.0,
                   side_wear_angle_deg: float = 60.0, step_mm: float = 0.02) -> np.ndarray:
    """Boundary of the worn head (module docstring), (N, 2) ``(q, z)`` [mm], field flank to gauge
    flank, resampled every ``step_mm``. Zero wear gives the unworn boundary."""
    if not (0 <= vertical_wear_mm < GAUGE_POINT_DEPTH_MM and 0 <= side_wear_mm < 15):
        raise TrackGeometryError(f"wear out of range: vertical {vertical_wear_mm} mm, side {side_wear_mm} mm")
    pts = sample_unworn_mm(head, step_mm / 2)
    if vertical_wear_mm > 0:
        pts = _cut(pts, np.array([0.0, -vertical_wear_mm]), np.array([0.0, 1.0]))
    if side_wear_mm > 0:
        q_g, z_g = head.gauge_point_mm()
        g = np.radians(side_wear_angle_deg)
        pts = _cut(pts, np.array([q_g - side_wear_mm, z_g]), np.array([np.sin(g), np.cos(g)]))
    return _resample(pts, step_mm)


def segment_normals(points: np.ndarray) -> np.ndarray:
    """Outward unit normals (N, 2) of a boundary polyline ordered field flank -> gauge flank
    (the tangent rotated by -90 deg), from central differences."""
    t = np.gradient(points, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    return np.column_stack([-t[:, 1], t[:, 0]])


def signed_distance_mm(head: RailHead, q_mm: np.ndarray, z_mm: np.ndarray
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Signed distance of points to the unworn head (positive outside), any shape ``S``.

    Returns ``(d, nq, nz)``: distance [mm] and the outward unit normal of the head at the nearest
    point (the gradient of ``d``). Each arc counts where the point's direction from its centre lies
    within the arc's normals (two cross products with the end normals: every arc spans less than
    180 deg), the flanks where the projection lies along them; the nearest of those wins (on a
    convex head every outside or slightly inside point has one); NaN where none does."""
    q = np.asarray(q_mm, dtype=float)
    z = np.asarray(z_mm, dtype=float)
    best = np.full(q.shape, np.inf)
    d_out = np.full(q.shape, np.nan)
    nq_out = np.zeros(q.shape)
    nz_out = np.zeros(q.shape)
    for arc in head.arcs:
        vq, vz = q - arc.centre_mm[0], z - arc.centre_mm[1]
        # direction (sin a, cos a): within [a0, a1] iff cross(n0, v) >= 0 and cross(v, n1) >= 0
        s0, c0, s1, c1 = np.sin(arc.a0_rad), np.cos(arc.a0_rad), np.sin(arc.a1_rad), np.cos(arc.a1_rad)
        inside = (c0 * vq - s0 * vz >= 0) & (s1 * vz - c1 * vq >= 0)
        rho = np.sqrt(vq * vq + vz * vz)
        d = rho - arc.radius_mm
        ok = inside & (np.abs(d) < best)
        best = np.where(ok, np.abs(d), best)
        d_out = np.where(ok, d, d_out)
        inv = 1.0 / np.maximum(rho, 1e-12)
        nq_out = np.where(ok, vq * inv, nq_out)
        nz_out = np.where(ok, vz * inv, nz_out)
    tq, tz = head.flank_top_mm
    a3 = head.flank_normal_rad
    n = np.array([np.sin(a3), np.cos(a3)])
    for side in (1.0, -1.0):
        pq, pz = side * q - tq, z - tz
        along = -pq * n[1] + pz * n[0]        # minus the distance along the downward tangent
        d = pq * n[0] + pz * n[1]
        ok = (along <= 0) & (np.abs(d) < best)
        best = np.where(ok, np.abs(d), best)
        d_out = np.where(ok, d, d_out)
        nq_out = np.where(ok, side * n[0], nq_out)
        nz_out = np.where(ok, n[1], nz_out)
    return d_out, nq_out, nz_out


def running_top_and_gauge_point(points: np.ndarray) -> tuple[float, np.ndarray]:
    """Height of the running surface (the highest point) and the gauge point 14 mm below it of a
    dense boundary ``points`` (N, 2) ``(q, z)`` in any frame with z up and the gauge side at +q:
    the gauge point is interpolated on the part of the boundary beyond the highest point."""
    i_top = int(np.argmax(points[:, 1]))
    z_top = float(points[i_top, 1])
    gauge_side = points[i_top:]
    below = np.nonzero(gauge_side[:, 1] <= z_top - GAUGE_POINT_DEPTH_MM)[0]
    if below.size == 0:
        raise TrackGeometryError("rail boundary does not reach 14 mm below its running surface")
    j = int(below[0])
    p0, p1 = gauge_side[j - 1], gauge_side[j]
    w = (z_top - GAUGE_POINT_DEPTH_MM - p0[1]) / (p1[1] - p0[1])
    return z_top, p0 + w * (p1 - p0)
