"""A track design as a table of horizontal curvature and cant against chainage (the track
preprocessor's output the vision run needs): ``design.csv`` with columns ``chainage_m``,
``curvature_per_m`` (positive: curving left) and ``cant_mm`` (over a 1.5 m base, positive: the
right rail raised), linear between rows (straights, clothoid transitions with linear cant ramps,
arcs)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ConfigError

COLUMNS = ("chainage_m", "curvature_per_m", "cant_mm")
CANT_BASE_MM = 1500.0


@dataclass(frozen=True)
class DesignTable:
    """Rows (K,) of chainage [m] (increasing), curvature [1/m] and cant [mm]."""

    chainage_m: np.ndarray
    curvature_per_m: np.ndarray
    cant_mm: np.ndarray

    def at(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Curvature [1/m] and cant angle [rad] (negative with the right rail raised, the roll
        convention of the vision module) at chainages ``s_m``; held constant beyond the ends."""
        s = np.asarray(s_m, float)
        rho = np.interp(s, self.chainage_m, self.curvature_per_m)
        return rho, -np.arcsin(np.interp(s, self.chainage_m, self.cant_mm) / CANT_BASE_MM)


def write_design_csv(path: str | Path, design: DesignTable) -> None:
    """Write ``design`` as ``design.csv`` (module docstring), atomically."""
    from ..sensors.fileio import write_text_atomic
    rows = np.column_stack([design.chainage_m, design.curvature_per_m, design.cant_mm])
    lines = [",".join(COLUMNS)] + [f"{s:.4f},{k:.9g},{c:.3f}" for s, k, c in rows]
    write_text_atomic(path, "\n".join(lines) + "\n")


def read_design_csv(path: str | Path) -> DesignTable:
    """Read ``design.csv``; :class:`ConfigError` naming the file and the row for a wrong header,
    a non-number or chainages not increasing."""
    p = Path(path)
    lines = [ln for ln in p.read_text(encoding="utf-8").splitlines() if ln.strip() and not ln.startswith("#")]
    if not lines or tuple(c.strip() for c in lines[0].split(",")) != COLUMNS:
        raise ConfigError(f"{p}: header must be {','.join(COLUMNS)}")
    rows = []
    for i, ln in enumerate(lines[1:], start=2):
        try:
            vals = [float(v) for v in ln.split(",")]
        except ValueError:
            vals = []
        if len(vals) != 3 or not np.all(np.isfinite(vals)) or abs(vals[2]) >= CANT_BASE_MM:
            raise ConfigError(f"{p}: row {i}: needs three finite numbers (cant below {CANT_BASE_MM:g} mm)")
        rows.append(vals)
    a = np.array(rows)
    if len(a) < 2 or np.any(np.diff(a[:, 0]) <= 0):
        raise ConfigError(f"{p}: chainage_m: needs at least two rows, strictly increasing")
    return DesignTable(a[:, 0], a[:, 1], a[:, 2])
