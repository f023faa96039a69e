"""The verdict line of a run: does the survey meet its thresholds, and if not, why.

Two sources give a verdict: the relative-accuracy thresholds when a reference trajectory was
evaluated (``metrics["evaluation"]``), and the tolerance table of the track geometry
(``metrics["geometry"]``: exceedances, and checks skipped with their reason). A table whose
checks were all skipped gives no verdict (it is said so); with neither source the line says
``no verdict: no reference and no tolerance table``.
"""

from __future__ import annotations

from typing import Any


def _accuracy(m: dict[str, Any]) -> tuple[bool, str] | None:
    ev, ra = m.get("evaluation"), m.get("relative_accuracy")
    if not ev or not ra:
        return None
    thr = ev["thresholds"]
    what = (f"the relative-accuracy thresholds at {thr['scale_m']:g} m (MSE <= {thr['mse_mm']:g} mm, "
            f"ADEV <= {thr['adev_mm']:g} mm)")
    failed = []
    for c in thr["components"]:
        r = ra[c]
        if not r["mse_pass"]:
            failed.append(f"{c} MSE {r['mse_at_threshold_mm']:.3f} mm")
        if not r["adev_pass"]:
            failed.append(f"{c} ADEV {r['adev_at_threshold_mm']:.3f} mm")
    return (not failed, what + (f": {', '.join(failed)}" if failed else ""))


def _tolerances(m: dict[str, Any]) -> tuple[bool | None, str] | None:
    geo = m.get("geometry") or {}
    table = geo.get("tolerance_table")
    if not table:
        return None
    exceedances, skipped = geo.get("exceedances", []), geo.get("skipped_checks", [])
    note = (f" ({len(skipped)} check{'s' * (len(skipped) != 1)} skipped: "
            + "; ".join(f"{s['check']} {s['reason']}" for s in skipped) + ")") if skipped else ""
    checked = {e["check"].split(":")[0] for e in exceedances}
    if not exceedances and skipped and _all_skipped(geo):
        return None, f"tolerance table {table}: every check skipped{note}"
    if exceedances:
        return False, (f"tolerance table {table}: {len(exceedances)} exceedance{'s' * (len(exceedances) != 1)} "
                       f"({', '.join(sorted(checked))}){note}")
    return True, f"tolerance table {table}: no exceedance{note}"


def _all_skipped(geo: dict[str, Any]) -> bool:
    """True when no check of the table was made: each skipped whole, or on every column it applies to."""
    gone: dict[str, set | None] = {}  # check -> the columns skipped (None: the whole check)
    for s in geo.get("skipped_checks", []):
        cols = s.get("columns")
        gone[s["check"]] = None if cols is None or gone.get(s["check"], set()) is None else gone.get(s["check"], set()) | set(cols)
    for c in geo.get("tolerance_checks", []):
        if c["name"] not in gone or (gone[c["name"]] is not None and not set(c.get("columns", [])) <= gone[c["name"]]):
            return False
    return True


def verdict_line(metrics: dict[str, Any]) -> str:
    """One line: ``verdict: MEETS ...`` / ``verdict: FAILS ...`` (module docstring)."""
    parts = [p for p in (_accuracy(metrics), _tolerances(metrics)) if p is not None]
    given = [p for p in parts if p[0] is not None]
    if not given:
        why = "; ".join(text for _ok, text in parts) or "no reference and no tolerance table"
        return f"no verdict: {why}"
    word = "MEETS" if all(ok for ok, _t in given) else "FAILS"
    if len(parts) == 1:
        return f"verdict: the survey {word} {parts[0][1]}"
    said = {True: "meets ", False: "fails ", None: ""}
    return f"verdict: the survey {word}: " + "; ".join(said[ok] + text for ok, text in parts)
