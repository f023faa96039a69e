"""Track quality index: the standard deviation of an irregularity per fixed-length section.

EN 13848-6 describes the quality of a track section by the standard deviation of its D1
longitudinal level and alignment over sections of a fixed length (200 m is the usual one).
:func:`section_std` computes it for one geometry column: sections are aligned on whole
multiples of ``section_m`` of chainage (0-200 m, 200-400 m, ...), so surveys of the same line
report the same sections. NaN samples (not measured, or outside a pass) are left out; a
section whose finite samples cover less than ``min_coverage`` of its grid points gets no
value (its standard deviation would describe a different length of track).

Numpy does it in a few ``bincount`` calls (no per-section loop); the standard deviation is the
population one (``ddof = 0``): over hundreds of samples per section the difference is
negligible and the known answers (a sinusoid's ``A / sqrt(2)``) hold exactly.
"""

from __future__ import annotations

import numpy as np

#: Section length of the quality index [m] (EN 13848-6's usual 200 m).
SECTION_M = 200.0


def section_std(chainage_m: np.ndarray, value: np.ndarray, step_m: float, section_m: float = SECTION_M,
                min_coverage: float = 0.5) -> list[dict]:
    """Standard deviation of ``value`` per section of ``section_m`` of chainage.

    chainage_m (N,) [m] on a uniform grid of ``step_m``; value (N,) in any unit (NaN = no
    sample). Returns one dict per section touched by the grid, in chainage order:
    ``{from_m, to_m, samples, coverage, std}`` where ``coverage`` is the share of the section's
    grid points with a finite value and ``std`` is None below ``min_coverage``.
    """
    s = np.asarray(chainage_m, dtype=float)
    v = np.asarray(value, dtype=float)
    if s.shape != v.shape or s.ndim != 1:
        raise ValueError(f"chainage_m and value must be equal 1-D arrays, got {s.shape} and {v.shape}")
    if step_m <= 0 or section_m < step_m:
        raise ValueError(f"need 0 < step_m <= section_m, got {step_m} and {section_m}")
    if s.size == 0:
        return []
    k = np.floor(s / section_m + 1e-9).astype(np.int64)
    k0 = int(k.min())
    idx = k - k0
    ok = np.isfinite(v)
    n = np.bincount(idx[ok], minlength=idx.max() + 1).astype(float)
    total = np.bincount(idx[ok], weights=v[ok], minlength=n.size)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = total / n
        var = np.bincount(idx[ok], weights=(v[ok] - mean[idx[ok]]) ** 2, minlength=n.size) / n
    per_section = section_m / step_m
    out = []
    for i in np.unique(idx):
        coverage = min(1.0, n[i] / per_section)
        std = float(np.sqrt(var[i])) if n[i] >= 2 and coverage >= min_coverage else None
        start = (k0 + i) * section_m
        out.append({"from_m": float(start), "to_m": float(start + section_m), "samples": int(n[i]),
                    "coverage": round(float(coverage), 3), "std": std})
    return out


def quality_index(table: dict[str, np.ndarray], step_m: float, columns: dict[str, str],
                  section_m: float = SECTION_M) -> dict:
    """The metrics ``geometry.quality_index``: ``section_m``, ``columns`` (quantity -> geometry
    column used, e.g. ``"left longitudinal level": "left_vertical_mm"``) and ``sections``:
    ``[{from_m, to_m, <quantity>: std_mm or None, ...}]``. Columns absent from the table or
    without a finite value are listed under ``not_measured`` instead."""
    used = {q: c for q, c in columns.items() if c in table and np.isfinite(table[c]).any()}
    sections: dict[float, dict] = {}
    for q, c in used.items():
        for sec in section_std(table["chainage_m"], table[c], step_m, section_m):
            row = sections.setdefault(sec["from_m"], {"from_m": sec["from_m"], "to_m": sec["to_m"]})
            row[q] = sec["std"]
    return {"section_m": float(section_m), "columns": used,
            "not_measured": sorted(set(columns) - set(used)),
            "sections": [sections[k] for k in sorted(sections)]}
