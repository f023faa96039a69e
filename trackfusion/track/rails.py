"""Rails of a track: the design alignment plus irregularities, as points in ``n``.

The reference point of each rail is the top of the rail vertically and its
running edge laterally. Cant follows railway practice: the low (inner) rail
stays on the design gradeline and the running plane is rolled about it by
``cant_rad``, raising the outer rail. Irregularities displace each rail's
point along the canted track frame ``t``: laterally along ``y_t`` and
vertically along ``z_t``.
"""

from __future__ import annotations

import numpy as np

from .design import DesignAlignment
from .irregularity import IrregularityField


class TrackModel:
    """Design + irregularities -> rail reference points, track frame and gauge.

    design: :class:`DesignAlignment`; irregularities: :class:`IrregularityField` covering
    the alignment; gauge_m: design gauge between running edges [m].
    """

    def __init__(self, design: DesignAlignment, irregularities: IrregularityField, gauge_m: float = 1.435):
        self.design = design
        self.irregularities = irregularities
        self.gauge_m_design = gauge_m

    def track_frame(self, s_m) -> np.ndarray:
        """``R_nt`` (N, 3, 3) at chainages ``s_m`` (N,)."""
        return self.design.evaluate(s_m).R_nt

    def rail_points_n(self, s_m, side: str) -> np.ndarray:
        """Reference point of the ``side`` ("left"/"right") rail at chainages ``s_m`` (N,) in ``n`` [m], (N, 3)."""
        s = np.atleast_1d(np.asarray(s_m, dtype=float))
        d = self.design.evaluate(s)
        irr = self.irregularities.evaluate(s)
        half = 0.5 * self.gauge_m_design
        y0 = np.column_stack([-np.sin(d.heading_rad), np.cos(d.heading_rad), np.zeros_like(s)])
        y_t, z_t = d.R_nt[:, :, 1], d.R_nt[:, :, 2]
        # low rail on the gradeline: rotate about it (positive cant: right rail is low)
        low_sign = np.where(d.cant_rad > 0, -1.0, 1.0)[:, None]
        centre = d.pos_n + low_sign * half * (y0 - y_t)
        sign = 1.0 if side == "left" else -1.0
        lateral = sign * half + irr[f"lateral_{side}"]
        return centre + lateral[:, None] * y_t + irr[f"vertical_{side}"][:, None] * z_t

    def gauge_m(self, s_m) -> np.ndarray:
        """Gauge between running edges at ``s_m`` [m] (design gauge plus the gauge irregularity)."""
        irr = self.irregularities.evaluate(np.asarray(s_m, dtype=float))
        return self.gauge_m_design + irr["lateral_left"] - irr["lateral_right"]
