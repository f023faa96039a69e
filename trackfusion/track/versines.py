"""Chord versines of a 3-D rail trace: symmetric and asymmetric chords, any length and spacing.

A chord of length ``a + b`` spans the rail from chainage ``s - a`` to ``s + b``; the versine
at ``s`` is the offset of the rail point ``P(s)`` from the chord point
``Q = P(s-a) + a / (a + b) (P(s+b) - P(s-a))``, resolved

- vertically: ``(P - Q) . up`` (positive: the rail is above the chord, so a crest is positive
  and a dip negative);
- laterally: ``(P - Q) . left``, with ``left`` the horizontal unit normal of the chord to its
  left (positive: the rail bulges to the left of the chord, e.g. the outside of a right-hand
  curve).

Chord ends are placed by chainage (rail length along the trace), so the versine of a circular
arc of radius R with a symmetric chord of length L is ``R (1 - cos(L / 2R))``. A symmetric
chord (``a = b = L/2``) has the transfer function ``1 - cos(pi L / lambda)``
(:func:`chord_transfer`). The 31-ft and 62-ft mid-chord offsets (MCO) of North American
practice are symmetric chords of 9.4488 m and 18.8976 m (:data:`MCO_CHORDS_M`).

Seed 002's evaluation indicator (its eqs. 7-8): on a chord of ``chord_m`` (30 m or 300 m),
versines at monitoring points ``spacing_m`` apart (5 m or 150 m) are compared with the design
(or reference) versines, ``dV = |(V_ref,i - V_meas,i) - (V_ref,j - V_meas,j)|`` for
neighbouring monitoring points i, j; the limits (2 mm and 10 mm) live in the tolerance tables.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import make_interp_spline

from ..errors import TrackGeometryError

FOOT_M = 0.3048
#: North American mid-chord offsets: name -> symmetric chord length [m].
MCO_CHORDS_M = {"mco_31ft": 31 * FOOT_M, "mco_62ft": 62 * FOOT_M}


def _check_trace(s_m: np.ndarray, points_n: np.ndarray) -> None:
    if s_m.ndim != 1 or points_n.shape != (s_m.size, 3):
        raise TrackGeometryError(f"versines need chainage (N,) and points (N, 3), got {s_m.shape} and {points_n.shape}")
    if s_m.size < 4 or np.any(np.diff(s_m) <= 0):
        raise TrackGeometryError("versines need at least 4 points in strictly increasing chainage")


def points_at(s_m: np.ndarray, points_n: np.ndarray, s_query_m: np.ndarray) -> np.ndarray:
    """Trace points (M, 3) at chainages ``s_query_m`` (M,) by a cubic spline through the trace;
    NaN outside the trace's chainage range."""
    spline = make_interp_spline(s_m, points_n, k=3)
    out = spline(np.clip(s_query_m, s_m[0], s_m[-1]))
    out[(s_query_m < s_m[0] - 1e-9) | (s_query_m > s_m[-1] + 1e-9)] = np.nan
    return out


def chord_offsets(s_m, points_n, before_m: float, after_m: float, s_eval_m=None) -> tuple[np.ndarray, np.ndarray]:
    """Vertical and lateral versines [m] of the trace (module docstring) at ``s_eval_m`` (default:
    the trace's own chainages), for a chord from ``s - before_m`` to ``s + after_m``.

    s_m (N,) increasing chainage [m]; points_n (N, 3) rail points in ``n`` [m]. Returns two
    (M,) arrays, NaN where the chord leaves the trace.
    """
    s = np.asarray(s_m, dtype=float)
    p = np.asarray(points_n, dtype=float)
    _check_trace(s, p)
    if before_m < 0 or after_m < 0 or before_m + after_m <= 0:
        raise TrackGeometryError(f"chord needs before_m, after_m >= 0 with a positive sum, got {before_m}, {after_m}")
    se = s if s_eval_m is None else np.asarray(s_eval_m, dtype=float)
    mid = points_at(s, p, se)
    pa = points_at(s, p, se - before_m)
    pb = points_at(s, p, se + after_m)
    chord = pb - pa
    q = pa + (before_m / (before_m + after_m)) * chord
    d = mid - q
    h = np.hypot(chord[:, 0], chord[:, 1])
    with np.errstate(invalid="ignore", divide="ignore"):
        left = np.column_stack([-chord[:, 1] / h, chord[:, 0] / h])
    return d[:, 2], np.sum(d[:, :2] * left, axis=1)


def symmetric_versine(s_m, points_n, chord_m: float, s_eval_m=None) -> tuple[np.ndarray, np.ndarray]:
    """Mid-chord versines (vertical, lateral) [m] for a symmetric chord of ``chord_m``."""
    return chord_offsets(s_m, points_n, 0.5 * chord_m, 0.5 * chord_m, s_eval_m)


def chord_transfer(wavelength_m, before_m: float, after_m: float) -> np.ndarray:
    """Complex transfer function of the versine of a chord (``before_m``, ``after_m``) for a
    sinusoidal irregularity of wavelength ``wavelength_m``: versine = H * irregularity.

    ``H = 1 - (b e^{-i k a} + a e^{i k b}) / (a + b)``, ``k = 2 pi / lambda``; for a symmetric
    chord of length L this is the real ``1 - cos(pi L / lambda)``.
    """
    k = 2 * np.pi / np.asarray(wavelength_m, dtype=float)
    a, b = float(before_m), float(after_m)
    return 1.0 - (b * np.exp(-1j * k * a) + a * np.exp(1j * k * b)) / (a + b)


def symmetric_chord_transfer(wavelength_m, chord_m: float) -> np.ndarray:
    """``1 - cos(pi L / lambda)`` of a symmetric chord of length ``chord_m`` (seed 000)."""
    return 1.0 - np.cos(np.pi * chord_m / np.asarray(wavelength_m, dtype=float))


def two_point_transfer(wavelength_m, wheelbase_m: float) -> np.ndarray:
    """``cos(pi l / lambda)``: the height of the midpoint of two wheels ``l`` apart (seed 000 eq. 6)."""
    return np.cos(np.pi * wheelbase_m / np.asarray(wavelength_m, dtype=float))


@dataclass(frozen=True)
class ChordIndicator:
    """Seed 002's indicator at each chord position: ``chord_start_m`` (K,), ``pair_chainage_m``
    (K, P) the midpoints of the P neighbouring monitoring-point pairs, ``delta_v_m`` (K, P)."""

    chord_start_m: np.ndarray
    pair_chainage_m: np.ndarray
    delta_v_m: np.ndarray


def chord_indicator(s_m, measured_n, reference_n, chord_m: float, spacing_m: float,
                    component: str, step_m: float | None = None) -> ChordIndicator:
    """Seed 002 eqs. 7-8 on one rail: for chords starting every ``step_m`` (default
    ``spacing_m``) the versines of the inner monitoring points ``spacing_m`` apart, measured and
    reference, and ``dV`` of each neighbouring pair (pairs including a chord end, whose versine
    is zero by construction, are included: seed 002's points P1..P49 include the ends).

    measured_n, reference_n: (N, 3) traces at the same chainages s_m (N,); component:
    ``"vertical"`` or ``"lateral"``.
    """
    if component not in ("vertical", "lateral"):
        raise TrackGeometryError(f"component must be 'vertical' or 'lateral', got {component!r}")
    n_seg = chord_m / spacing_m
    if spacing_m <= 0 or abs(n_seg - round(n_seg)) > 1e-9 or round(n_seg) < 2:
        raise TrackGeometryError(f"chord {chord_m:g} m must be a multiple (>= 2) of the spacing {spacing_m:g} m")
    n_seg = int(round(n_seg))
    s = np.asarray(s_m, dtype=float)
    step = spacing_m if step_m is None else step_m
    starts = np.arange(s[0], s[-1] - chord_m + 1e-9, step)
    if starts.size == 0:
        raise TrackGeometryError(f"the trace ({s[-1] - s[0]:.1f} m) is shorter than the chord {chord_m:g} m")
    i = 0 if component == "vertical" else 1
    diff = np.zeros((starts.size, n_seg + 1))
    for j in range(1, n_seg):  # inner monitoring points; a loop over the (few) points per chord
        a = j * spacing_m
        meas = chord_offsets(s, measured_n, a, chord_m - a, starts + a)[i]
        ref = chord_offsets(s, reference_n, a, chord_m - a, starts + a)[i]
        diff[:, j] = ref - meas
    pair_s = starts[:, None] + spacing_m * (np.arange(n_seg) + 0.5)[None, :]
    return ChordIndicator(starts, pair_s, np.abs(np.diff(diff, axis=1)))
