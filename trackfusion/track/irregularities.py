"""Irregularities from rail traces: vertical profile and alignment per rail, gauge, cross-level, twist.

Against a design alignment (when one is given) an irregularity is the rail point minus the
design rail point at the same design chainage: vertically ``du`` (positive up), laterally the
horizontal offset along the design's left normal (positive left). Without a design the trace
is band-passed into the EN 13848 wavelength ranges D1 (3-25 m), D2 (25-70 m) and D3
(70-150 m) (:data:`EN13848_BANDS`): a Butterworth band-pass run forwards and backwards
(zero phase; the amplitude response is the square of the one-pass filter, 0.5 at the corner
wavelengths and 1 in the pass band), applied to the height ``u`` and to the lateral offset of
the trace from the straight line joining its ends (the band-pass removes what a long curve
adds at wavelengths above the band).

Cross-level is the left rail height minus the right rail height; seed 004's ``H = L sin(theta)``
gives the same from the roll theta over the rail distance L, which is how the rail traces
place the other rail. Twist over a base B is the change of cross-level over B, centred:
``cl(s + B/2) - cl(s - B/2)``. Gauge variation is the gauge minus its nominal value.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import butter, sosfiltfilt

from ..errors import TrackGeometryError
from .design import DesignAlignment
from .irregularity import RAIL_SERIES, IrregularityField
from .rails import TrackModel

#: EN 13848-1 wavelength ranges [m].
EN13848_BANDS = {"D1": (3.0, 25.0), "D2": (25.0, 70.0), "D3": (70.0, 150.0)}


def bandpass(x, step_m: float, wavelength_min_m: float, wavelength_max_m: float, order: int = 2) -> np.ndarray:
    """Zero-phase Butterworth band-pass of a series ``x`` (N,) sampled every ``step_m`` [m],
    passing wavelengths between ``wavelength_min_m`` and ``wavelength_max_m`` (module docstring).
    ``order`` is the one-pass order of the low-pass prototype."""
    x = np.asarray(x, dtype=float)
    if not 0 < wavelength_min_m < wavelength_max_m:
        raise TrackGeometryError(f"band needs 0 < min < max wavelength, got {wavelength_min_m}, {wavelength_max_m}")
    if wavelength_min_m <= 2 * step_m:
        raise TrackGeometryError(f"the shortest wavelength {wavelength_min_m:g} m needs a step below "
                                 f"{wavelength_min_m / 2:g} m (got {step_m:g} m)")
    nyq = 0.5 / step_m  # cycles per metre
    sos = butter(order, [1.0 / wavelength_max_m / nyq, 1.0 / wavelength_min_m / nyq], btype="bandpass",
                 output="sos")
    return sosfiltfilt(sos, x, padtype="odd", padlen=min(x.size - 1, int(3 * wavelength_max_m / step_m)))


def bandpass_response(wavelength_m, step_m: float, wavelength_min_m: float, wavelength_max_m: float,
                      order: int = 2) -> np.ndarray:
    """Amplitude response of :func:`bandpass` at ``wavelength_m`` (forward-backward: |H|^2)."""
    from scipy.signal import sosfreqz
    nyq = 0.5 / step_m
    sos = butter(order, [1.0 / wavelength_max_m / nyq, 1.0 / wavelength_min_m / nyq], btype="bandpass",
                 output="sos")
    f = 1.0 / np.asarray(wavelength_m, dtype=float)
    _, h = sosfreqz(sos, worN=np.atleast_1d(f), fs=1.0 / step_m)
    return np.abs(h) ** 2


def lateral_offset_from_line(points_n: np.ndarray) -> np.ndarray:
    """Horizontal offset [m] (N,) of trace points (N, 3) from the straight line joining its ends,
    positive to the left of the direction of travel along the trace."""
    p = np.asarray(points_n, dtype=float)
    d = p[-1, :2] - p[0, :2]
    d = d / np.linalg.norm(d)
    left = np.array([-d[1], d[0]])
    return (p[:, :2] - p[0, :2]) @ left


def design_track(design: DesignAlignment, gauge_m: float) -> TrackModel:
    """The design track alone (no irregularities): its rails are the reference of the irregularities."""
    s = np.linspace(0.0, design.length_m, 8)
    zero = np.zeros_like(s)
    field = IrregularityField(s, {}, {k: zero for k in RAIL_SERIES})
    return TrackModel(design, field, gauge_m)


def against_design(points_n: np.ndarray, design_s_m: np.ndarray, track: TrackModel, side: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Vertical and lateral irregularity [m] (N,) of rail points (N, 3) at design chainages (N,)
    against the design rail ``side`` of ``track`` (module docstring)."""
    ref = track.rail_points_n(design_s_m, side)
    heading = track.design.evaluate(design_s_m).heading_rad
    left = np.column_stack([-np.sin(heading), np.cos(heading)])
    d = np.asarray(points_n, dtype=float) - ref
    return d[:, 2], np.sum(d[:, :2] * left, axis=1)


def banded(points_n: np.ndarray, step_m: float, band: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Vertical and lateral irregularity [m] (N,) of a trace on a uniform chainage grid in one
    wavelength band (min, max) [m]."""
    lat = lateral_offset_from_line(points_n)
    return (bandpass(points_n[:, 2], step_m, *band), bandpass(lat, step_m, *band))


def cross_level(left_n: np.ndarray, right_n: np.ndarray) -> np.ndarray:
    """Left rail height minus right rail height [m] (N,)."""
    return np.asarray(left_n)[:, 2] - np.asarray(right_n)[:, 2]


def cross_level_from_roll(roll_rad, rail_distance_m) -> np.ndarray:
    """Seed 004: ``H = L sin(theta)`` [m], theta the roll (left side up) of the running plane."""
    return np.asarray(rail_distance_m) * np.sin(np.asarray(roll_rad))


def twist(s_m: np.ndarray, cross_level_m: np.ndarray, base_m: float) -> np.ndarray:
    """Twist [m] (N,) over ``base_m``: ``cl(s + B/2) - cl(s - B/2)`` (linear interpolation),
    NaN where the base leaves the data. ``s_m`` (N,) increasing."""
    s = np.asarray(s_m, dtype=float)
    cl = np.asarray(cross_level_m, dtype=float)
    if base_m <= 0:
        raise TrackGeometryError(f"twist base must be > 0, got {base_m}")
    ahead = np.interp(s + base_m / 2, s, cl, left=np.nan, right=np.nan)
    behind = np.interp(s - base_m / 2, s, cl, left=np.nan, right=np.nan)
    return ahead - behind
