"""``trackfusion demo``: the first ten minutes of a new user, end to end on built-in data.

Simulates the seed-002 open-track GNSS survey (43 min, navigation-grade IMU, odometer,
RTK GNSS), checks the raw log it wrote (as ``trackfusion inspect`` does), runs the
pipeline the simulator wrote (``trackfusion run``: fusion, evaluation against the truth,
``report.html``) and closes with a summary: where the results are and whether the survey
meets seed 002's thresholds at 5 m (MSE <= 0.67 mm, ADEV <= 0.16 mm).
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Callable, Sequence

from .pipeline import RunResult, format_summary, load_pipeline, run
from .sensors.mcap_log import inspect_log
from .simulation.scenarios import simulate_to_dir

DEMO_SCENARIO = "open-track-gnss"


def closing_summary(result: RunResult, inputs_dir: Path) -> str:
    """The demo's last lines: verdict per checked component at the threshold scale, and where
    the report, outputs and inputs are."""
    m = result.metrics
    ev, ra = m["evaluation"], m["relative_accuracy"]
    thr = ev["thresholds"]
    verdict = "MEETS" if ev["passed"] else "DOES NOT MEET"
    lines = [f"demo: the survey {verdict} the seed-002 thresholds at {thr['scale_m']:g} m "
             f"(MSE <= {thr['mse_mm']:g} mm, ADEV <= {thr['adev_mm']:g} mm, {' and '.join(thr['components'])}):"]
    for c in thr["components"]:
        r = ra[c]
        ok = "pass" if r["mse_pass"] and r["adev_pass"] else "FAIL"
        lines.append(f"demo:   {c:<9} MSE {r['mse_at_threshold_mm']:.3f} mm, ADEV {r['adev_at_threshold_mm']:.3f} mm"
                     f"  {ok}")
    out = result.out_dir.resolve()
    if "report.html" in result.files:
        lines.append(f"demo: open the report: {out / 'report.html'}")
    lines.append(f"demo: results are in {out}/ ({', '.join(result.files)}); "
                 f"inputs and truth in {inputs_dir.resolve()}/.")
    return "\n".join(lines)


def run_demo(out_dir: str | Path, progress: Callable[[str], None] | None = None, seed: int = 0,
             overrides: Sequence[str] = (), force: bool = False) -> bool:
    """Simulate, fuse, evaluate and report the demo survey in ``out_dir``; True when it passes.

    overrides: scenario ``key=value`` overrides (as ``trackfusion simulate --set``), e.g. a
    shorter survey. ``out_dir`` and its ``out/`` are checked before the simulation
    (:class:`~trackfusion.outdir.OutputFolder`; ``force``: write beside files trackfusion did not write)."""
    from .outdir import OutputFolder, check_all
    say = progress or print
    out = Path(out_dir)
    check_all([OutputFolder(out, force), OutputFolder(out / "out", force)])
    wall = time.perf_counter()
    say(f"demo: step 1/3: simulating scenario {DEMO_SCENARIO!r} (seed {seed}) into {out}/")
    result = simulate_to_dir(DEMO_SCENARIO, out, seed=seed, ideal=False, overrides=list(overrides), progress=say,
                             force=force)
    print(result.format())
    print()
    say("demo: step 2/3: checking the raw log (trackfusion inspect)")
    print(inspect_log(out / "log.mcap").format())
    print()
    say(f"demo: step 3/3: fusing, evaluating against the truth and writing the report "
        f"(trackfusion run {out / 'pipeline.yaml'})")
    fused = run(load_pipeline(out / "pipeline.yaml"), out / "out", progress=say, force=force)
    print(format_summary(fused))
    print()
    print(closing_summary(fused, out))
    print(f"demo: done in {time.perf_counter() - wall:.0f} s.")
    return bool(fused.metrics["evaluation"]["passed"])
