"""Design alignment: horizontal elements, vertical profile and cant, evaluated at chainage s.

This is the "track preprocessor" of seed 001 section 3.2: it turns a design
(as a railway designer writes it) into position, heading, slope, cant and
curvatures at any chainage.

Chainage ``s`` is the horizontal length along the design centreline [m],
starting at 0. Horizontal elements follow each other from a start point and
heading in ``n``:

- ``tangent``: zero curvature;
- ``arc``: constant curvature ``1 / radius_m`` (positive radius curves left)
  with cant ``cant_mm`` raising the outer rail;
- ``clothoid``: curvature and cant change linearly from the previous element's
  values to the next element's (a transition); ``start_radius_m`` /
  ``end_radius_m`` fix its end curvatures instead (``.inf``: straight).

Heading is the integral of curvature (piecewise quadratic, exact) and the
position the integral of (cos, sin) of the heading, by 16-point
Gauss-Legendre quadrature from each element's start: exact to ~1e-12 m and
smooth in s. The vertical profile is a list of vertical points of
intersection (PVIs) joined by constant grades, with a symmetric parabolic
vertical curve of ``curve_length_m`` (or ``radius_m``) at each inner PVI.

Cant ``cant_m`` is signed: height of the left rail minus the right rail over
the cant base (1.5 m for standard gauge). The track frame ``t`` is rolled by
``cant_rad = asin(cant_m / cant_base_m)`` (positive: left side up). Instead of
the arcs' ``cant_mm``, ``cant_stations`` may give the cant at chainages (linear
between them), as a LandXML design does.

The same :class:`AlignmentConfig` comes from a YAML ``alignment:`` section or a
LandXML 1.2 file (``landxml.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from pydantic import Field, ValidationError, model_validator

from ..errors import ConfigError, TrackGeometryError, config_error_from_validation
from ..strict import StrictModel

_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)


class HorizontalElement(StrictModel):
    """One horizontal element (see the module docstring). A clothoid may give its end radii
    explicitly (``start_radius_m``, ``end_radius_m``: signed like ``radius_m``, ``.inf`` for a
    straight end); an end left out follows the neighbouring element."""

    type: Literal["tangent", "clothoid", "arc"]
    length_m: float = Field(gt=0, allow_inf_nan=False)
    radius_m: float | None = Field(None, allow_inf_nan=False)
    cant_mm: float = Field(0.0, ge=0, allow_inf_nan=False)
    start_radius_m: float | None = Field(None, allow_inf_nan=True)  # .inf: a straight end
    end_radius_m: float | None = Field(None, allow_inf_nan=True)

    @model_validator(mode="after")
    def _radius(self) -> "HorizontalElement":
        if self.type == "arc" and (self.radius_m is None or self.radius_m == 0):
            raise ValueError("an arc needs a non-zero radius_m")
        if self.type != "arc" and (self.radius_m is not None or self.cant_mm != 0):
            raise ValueError(f"a {self.type} takes no radius_m or cant_mm (they follow its neighbours)")
        ends = [r for r in (self.start_radius_m, self.end_radius_m) if r is not None]
        if ends and self.type != "clothoid":
            raise ValueError(f"a {self.type} takes no start_radius_m or end_radius_m")
        if any(np.isnan(r) or r == 0 for r in ends):
            raise ValueError("start_radius_m and end_radius_m must be non-zero (.inf for a straight end)")
        return self


class Horizontal(StrictModel):
    """Start point in ``n`` [m], start heading [deg, from east towards north] and the elements."""

    start_e_m: float = 0.0
    start_n_m: float = 0.0
    heading_deg: float = 0.0
    elements: list[HorizontalElement] = Field(min_length=1)


class Pvi(StrictModel):
    """A vertical point of intersection: chainage [m], height [m], vertical curve length or radius [m]."""

    chainage_m: float
    u_m: float
    curve_length_m: float = Field(0.0, ge=0)
    radius_m: float | None = Field(None, gt=0)


class Vertical(StrictModel):
    """PVIs in increasing chainage; the first and last carry no curve."""

    pvis: list[Pvi] = Field(min_length=1)


class CantStation(StrictModel):
    """Applied cant ``cant_mm`` (>= 0) raising ``raised_rail`` at design chainage ``chainage_m``."""

    chainage_m: float = Field(allow_inf_nan=False)
    cant_mm: float = Field(ge=0, allow_inf_nan=False)
    raised_rail: Literal["left", "right"]


class AlignmentConfig(StrictModel):
    """A whole design alignment. Cant comes either from the arcs' ``cant_mm`` (ramped over the
    clothoids) or from ``cant_stations`` (linear between stations in increasing chainage, constant
    before the first and after the last), not both."""

    horizontal: Horizontal
    vertical: Vertical = Vertical(pvis=[Pvi(chainage_m=0.0, u_m=0.0)])
    cant_base_m: float = Field(1.5, gt=0)
    cant_stations: list[CantStation] | None = Field(None, min_length=1)

    @model_validator(mode="after")
    def _one_cant_source(self) -> "AlignmentConfig":
        if self.cant_stations is None:
            return self
        if any(e.cant_mm != 0 for e in self.horizontal.elements):
            raise ValueError("give cant either as the arcs' cant_mm or as cant_stations, not both")
        if any(b.chainage_m <= a.chainage_m for a, b in zip(self.cant_stations, self.cant_stations[1:])):
            raise ValueError("cant_stations: chainages must increase")
        return self


@dataclass
class DesignState:
    """The design at N chainages: ``pos_n`` (N, 3) centreline at grade [m]; ``heading_rad``,
    ``slope_rad`` (positive rising), ``cant_m`` (left minus right rail) and ``cant_rad`` (roll,
    left side up), ``curvature_h_1pm`` (positive left), ``curvature_v_1pm`` (positive sag), all (N,);
    ``R_nt`` (N, 3, 3) the track frame."""

    pos_n: np.ndarray
    heading_rad: np.ndarray
    slope_rad: np.ndarray
    cant_m: np.ndarray
    cant_rad: np.ndarray
    curvature_h_1pm: np.ndarray
    curvature_v_1pm: np.ndarray
    R_nt: np.ndarray


class DesignAlignment:
    """A design alignment compiled for fast vectorised evaluation."""

    def __init__(self, config: AlignmentConfig):
        self.config = config
        h = config.horizontal
        lengths = np.array([e.length_m for e in h.elements])
        self.s_start = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
        self.length_m = float(lengths.sum())
        kappa_end, cant_end = self._element_end_values(h.elements)
        self._k0, self._k1 = kappa_end[:, 0], kappa_end[:, 1]
        self._c0, self._c1 = cant_end[:, 0], cant_end[:, 1]
        self._lengths = lengths
        # heading at each element start: integral of the linear curvature
        dtheta = 0.5 * (self._k0 + self._k1) * lengths
        self._theta0 = np.radians(h.heading_deg) + np.concatenate([[0.0], np.cumsum(dtheta)[:-1]])
        # position at each element start, by quadrature over whole elements
        ends = self._integrate_xy(np.arange(len(lengths)), lengths)
        xy0 = np.array([h.start_e_m, h.start_n_m]) + np.concatenate([[[0.0, 0.0]], np.cumsum(ends, axis=0)[:-1]])
        self._xy0 = xy0
        self._vertical = _VerticalProfile(config.vertical, self.length_m)
        # cant stations: (chainage [m], signed cant [m], left rail minus right)
        self._cant_stations = None if config.cant_stations is None else (
            np.array([c.chainage_m for c in config.cant_stations]),
            np.array([(1.0 if c.raised_rail == "left" else -1.0) * c.cant_mm / 1000.0 for c in config.cant_stations]))

    @staticmethod
    def _element_end_values(elements: list[HorizontalElement]) -> tuple[np.ndarray, np.ndarray]:
        """(M, 2) curvature [1/m] and cant [m] at the start and end of each element."""
        own_k = [1.0 / e.radius_m if e.type == "arc" else 0.0 for e in elements]
        explicit = [(e.start_radius_m, e.end_radius_m) for e in elements]
        # outer rail raised: a left curve (k > 0) raises the right rail -> negative cant
        own_c = [-np.sign(1.0 / e.radius_m) * e.cant_mm / 1000.0 if e.type == "arc" else 0.0 for e in elements]
        k = np.zeros((len(elements), 2))
        c = np.zeros((len(elements), 2))
        for i, e in enumerate(elements):
            if e.type != "clothoid":
                k[i] = own_k[i]
                c[i] = own_c[i]
                continue
            prev_k = own_k[i - 1] if i > 0 and elements[i - 1].type != "clothoid" else 0.0
            next_k = own_k[i + 1] if i + 1 < len(elements) and elements[i + 1].type != "clothoid" else 0.0
            prev_c = own_c[i - 1] if i > 0 and elements[i - 1].type != "clothoid" else 0.0
            next_c = own_c[i + 1] if i + 1 < len(elements) and elements[i + 1].type != "clothoid" else 0.0
            r0, r1 = explicit[i]
            k[i] = prev_k if r0 is None else 1.0 / r0, next_k if r1 is None else 1.0 / r1
            c[i] = prev_c, next_c
        return k, c

    @classmethod
    def from_dict(cls, data: dict[str, Any], source: str = "alignment") -> "DesignAlignment":
        """Validate a dict (as in YAML); raises :class:`ConfigError` naming the field path."""
        try:
            cfg = AlignmentConfig.model_validate(data)
        except ValidationError as exc:
            raise config_error_from_validation(exc, source) from None
        return cls(cfg)

    def _locate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if np.any(~np.isfinite(s)) or np.any(s < -1e-9) or np.any(s > self.length_m + 1e-9):
            raise TrackGeometryError(f"chainage outside the alignment [0, {self.length_m}] m")
        i = np.clip(np.searchsorted(self.s_start, s, side="right") - 1, 0, len(self.s_start) - 1)
        return i, s - self.s_start[i]

    def _heading(self, i: np.ndarray, u: np.ndarray) -> np.ndarray:
        slope = (self._k1[i] - self._k0[i]) / self._lengths[i]
        return self._theta0[i] + self._k0[i] * u + 0.5 * slope * u**2

    def _integrate_xy(self, i: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Integral of (cos, sin)(heading) over [element start, element start + u], (N, 2)."""
        nodes = 0.5 * u[:, None] * (_GL_X[None, :] + 1.0)
        th = self._heading(np.repeat(i[:, None], _GL_X.size, axis=1), nodes)
        w = 0.5 * u[:, None] * _GL_W[None, :]
        return np.column_stack([np.sum(w * np.cos(th), axis=1), np.sum(w * np.sin(th), axis=1)])

    def evaluate(self, s_m) -> DesignState:
        """The design at chainages ``s_m`` (N,) [m] -> :class:`DesignState`."""
        s = np.atleast_1d(np.asarray(s_m, dtype=float))
        i, u = self._locate(s)
        xy = self._xy0[i] + self._integrate_xy(i, u)
        heading = self._heading(i, u)
        frac = u / self._lengths[i]
        kappa = self._k0[i] + (self._k1[i] - self._k0[i]) * frac
        cant = self._c0[i] + (self._c1[i] - self._c0[i]) * frac if self._cant_stations is None else \
            np.interp(s, *self._cant_stations)
        z, dz, ddz = self._vertical.evaluate(s)
        slope = np.arctan(dz)
        cant_rad = np.arcsin(np.clip(cant / self.config.cant_base_m, -1.0, 1.0))
        return DesignState(np.column_stack([xy, z]), heading, slope, cant, cant_rad, kappa,
                           ddz / (1.0 + dz**2) ** 1.5, track_frame(heading, slope, cant_rad))


def track_frame(heading_rad, slope_rad, cant_rad) -> np.ndarray:
    """Track frame ``R_nt`` (N, 3, 3): x along the 3-D tangent, y left in the canted plane, z normal."""
    ch, sh = np.cos(heading_rad), np.sin(heading_rad)
    ca, sa = np.cos(slope_rad), np.sin(slope_rad)
    cc, sc = np.cos(cant_rad), np.sin(cant_rad)
    x = np.stack([ch * ca, sh * ca, sa], -1)
    y0 = np.stack([-sh, ch, np.zeros_like(ch)], -1)
    z0 = np.cross(x, y0)
    y = cc[..., None] * y0 + sc[..., None] * z0
    z = -sc[..., None] * y0 + cc[..., None] * z0
    return np.stack([x, y, z], -1)


class _VerticalProfile:
    """Grades between PVIs with symmetric parabolic vertical curves."""

    def __init__(self, cfg: Vertical, length_m: float):
        p = cfg.pvis
        s = np.array([v.chainage_m for v in p])
        u = np.array([v.u_m for v in p])
        if np.any(np.diff(s) <= 0):
            raise ConfigError("alignment.vertical.pvis: chainages must increase")
        self.s, self.u = s, u
        self.grades = np.diff(u) / np.diff(s) if len(p) > 1 else np.zeros(0)
        lengths = np.zeros(len(p))
        for k in range(1, len(p) - 1):
            dg = self.grades[k] - self.grades[k - 1]
            lengths[k] = p[k].radius_m * abs(dg) if p[k].radius_m is not None else p[k].curve_length_m
            room = min(s[k] - s[k - 1], s[k + 1] - s[k])
            if lengths[k] / 2 > room:
                raise ConfigError(f"alignment.vertical.pvis[{k}]: vertical curve of {lengths[k]:.1f} m "
                                  "overlaps a neighbouring PVI")
        self.curve_len = lengths

    def evaluate(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height [m], grade du/ds and du2/ds2 [1/m] at chainages s."""
        if len(self.s) == 1:
            return np.full_like(s, self.u[0]), np.zeros_like(s), np.zeros_like(s)
        k = np.clip(np.searchsorted(self.s, s, side="right") - 1, 0, len(self.grades) - 1)
        g = self.grades[k]
        z = self.u[k] + g * (s - self.s[k])
        dz = g.copy()
        ddz = np.zeros_like(s)
        for j in range(1, len(self.s) - 1):
            L = self.curve_len[j]
            if L <= 0:
                continue
            x = s - (self.s[j] - L / 2)
            inside = (x > 0) & (x < L)
            g1, g2 = self.grades[j - 1], self.grades[j]
            r = (g2 - g1) / L
            xs = x[inside]
            z[inside] = self.u[j] + g1 * (xs - L / 2) + 0.5 * r * xs**2
            dz[inside] = g1 + r * xs
            ddz[inside] = r
        return z, dz, ddz
