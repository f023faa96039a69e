"""Benchmark: relative accuracy at 5 m across chunk joins against inside the chunks.

Usage: python benchmarks/chunk_seams.py [--seeds 1 2 3] [--parts]   (after benchmarks/accuracy.py, which
leaves the one-batch run ``out-full_onebatch`` and the run in 600 s chunks ``out-full_600schunks``
of each ``open-track-gnss`` seed under ``$TMPDIR/trackfusion-bench``.)
For every moving sample, the error (estimate minus truth) 5 m of travel further minus the error
there, lateral and vertical; RMS over the pairs straddling a join, over those starting within
30 s of a join, and over the rest, for the chunked and the batch run. A seam shows as a larger
RMS across the joins in the chunked run than in the batch run over the same pairs.
With ``--parts``, the same across the cuts of the exact time parts (fusion/partitioned.py):
benchmarks/parts.py's run in 600 s parts in one worker against its one batch (nothing may show:
the parts give the batch's answer). Writes benchmarks/results/chunk_seams.json (part_seams.json).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results" / "chunk_seams.json"
CACHE = Path(tempfile.gettempdir()) / "trackfusion-bench"
RUNS = {"chunked": "out-full_600schunks", "batch": "out-full_onebatch"}
#: ``--parts``: benchmarks/parts.py's run in 600 s time parts against its one batch
PART_RUNS = {"parts": "out-parts-partsof600s_1workers", "batch": "out-parts-onebatch"}
CHUNK_S, OVERLAP_S, L_M = 600.0, 120.0, 5.0


def errors_of(sim: Path, name: str, truth: dict) -> tuple[np.ndarray, np.ndarray]:
    """Times (N,) [s] of the run ``name``'s trajectory.csv in survey folder ``sim`` and its position
    errors (N,3) e/n/u [m] against ``truth`` (truth.csv's columns), Hermite-interpolated."""
    from trackfusion.evaluation.errors_series import hermite_interpolate
    from trackfusion.sensors.fileio import read_csv_table
    tab = read_csv_table(sim / name / "trajectory.csv")
    pos = np.column_stack([truth[c] for c in ("e_m", "n_m", "u_m")])
    vel = np.column_stack([truth[c] for c in ("ve_mps", "vn_mps", "vu_mps")])
    est = np.column_stack([tab[c] for c in ("e_m", "n_m", "u_m")])
    return tab["t_s"], est - hermite_interpolate(truth["t_s"], pos, vel, tab["t_s"])


def pairs(t_s: np.ndarray, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (i, j): j the first sample L_M further along the same run (faster than 0.5 m/s)."""
    v = np.gradient(s_m, t_s)
    out_i, out_j = [], []
    for sign in (1.0, -1.0):
        edges = np.diff(np.r_[0, (sign * v > 0.5).astype(int), 0])
        for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
            ss = sign * s_m[a:b]
            k = np.searchsorted(ss, ss + L_M)
            ok = k < ss.size
            out_i.append(a + np.flatnonzero(ok))
            out_j.append(a + k[ok])
    return np.concatenate(out_i), np.concatenate(out_j)


def seed_figures(seed: int, runs: dict[str, str] = RUNS) -> dict:
    from trackfusion.fusion.chunks import join_times
    from trackfusion.sensors.fileio import read_csv_table
    sim = CACHE / f"open-track-gnss-{seed}"
    truth = read_csv_table(sim / "truth.csv")
    errs = {k: errors_of(sim, name, truth) for k, name in runs.items()}
    first = next(iter(runs))
    t = errs[first][0]
    i, j = pairs(t, np.interp(t, truth["t_s"], truth["chainage_m"]))
    if first == "parts":
        from trackfusion.fusion.partitioned import cut_times
        joins = cut_times(t[0], t[-1], CHUNK_S)
    else:
        joins = join_times(t[0], t[-1], CHUNK_S, OVERLAP_S)
    masks = join_masks(t, i, j, joins)
    out = {"seed": seed, "joins_s": joins.tolist(), "pairs": {k: int(m.sum()) for k, m in masks.items()}}
    for k, (_, e) in errs.items():
        out.update({f"{k}_{name}": v for name, v in rms_by_mask(e, i, j, masks).items()})
    return out


def join_masks(t_s: np.ndarray, i: np.ndarray, j: np.ndarray, joins: np.ndarray) -> dict[str, np.ndarray]:
    """The pairs (i, j) of samples at times ``t_s`` straddling one of ``joins`` [s], starting within
    30 s of one (straddling ones included), and the rest."""
    straddle, near = np.zeros(i.size, bool), np.zeros(i.size, bool)
    for tj in joins:
        straddle |= (t_s[i] < tj) & (t_s[j] > tj)
        near |= np.abs(t_s[i] - tj) < 30.0
    return {"straddling": straddle, "within_30s": near, "elsewhere": ~near}


def rms_by_mask(err_m: np.ndarray, i: np.ndarray, j: np.ndarray, masks: dict[str, np.ndarray]) -> dict[str, float]:
    """RMS [mm] of the error differences ``err_m[j] - err_m[i]`` (err_m (N,3) e/n/u [m]), lateral
    and vertical (the open-track line runs east: n is lateral), over each mask's pairs."""
    d = (err_m[j] - err_m[i])[:, 1:] * 1e3
    out = {}
    for label, sel in masks.items():
        if sel.any():
            rms = np.sqrt(np.mean(d[sel] ** 2, axis=0))
            out[f"{label}_lateral_mm"], out[f"{label}_vertical_mm"] = float(rms[0]), float(rms[1])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--parts", action="store_true",
                    help="the cuts of the exact time parts (runs of benchmarks/parts.py, 600 s parts)")
    args = ap.parse_args()
    runs = PART_RUNS if args.parts else RUNS
    first = next(iter(runs))
    rows = [seed_figures(s, runs) for s in args.seeds]
    print("RMS of 5 m error differences [mm], lateral / vertical; "
          + (f"exact parts of {CHUNK_S:g} s" if args.parts else f"chunks of {CHUNK_S:g} s, overlap {OVERLAP_S:g} s"))
    for r in rows:
        cells = "  ".join(f"{label}: {first} {r[f'{first}_{label}_lateral_mm']:.3f}/{r[f'{first}_{label}_vertical_mm']:.3f}"
                          f" batch {r[f'batch_{label}_lateral_mm']:.3f}/{r[f'batch_{label}_vertical_mm']:.3f}"
                          for label in ("straddling", "within_30s", "elsewhere"))
        print(f"seed {r['seed']} ({len(r['joins_s'])} joins): {cells}")
    out = RESULTS.with_name("part_seams.json") if args.parts else RESULTS
    out.parent.mkdir(exist_ok=True)
    head = {"part_s": CHUNK_S} if args.parts else {"chunk_s": CHUNK_S, "overlap_s": OVERLAP_S}
    out.write_text(json.dumps({**head, "L_m": L_M, "seeds": rows}, indent=2) + "\n")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
