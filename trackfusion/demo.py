"""``trackfusion demo``: the first ten minutes of a new user, end to end on built-in data.

Simulates the seed-002 open-track GNSS survey (43 min, navigation-grade IMU, odometer,
RTK GNSS), checks the raw log it wrote (as ``trackfusion inspect`` does), runs the
pipeline the simulator wrote (``trackfusion run``), evaluates the trajectory against the
truth and says whether the survey meets seed 002's thresholds at 5 m. The report, track
geometry and total stations join it with their issues.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from .pipeline import format_summary, load_pipeline, run
from .sensors.mcap_log import inspect_log
from .simulation.scenarios import simulate_to_dir

DEMO_SCENARIO = "open-track-gnss"


def run_demo(out_dir: str | Path, progress: Callable[[str], None] | None = None) -> bool:
    """Simulate, fuse and evaluate the demo survey in ``out_dir``; True when it passes."""
    say = progress or print
    out = Path(out_dir)
    say(f"demo: simulating scenario {DEMO_SCENARIO!r} into {out}/")
    result = simulate_to_dir(DEMO_SCENARIO, out, seed=0, ideal=False, overrides=[], progress=say)
    print(result.format())
    print()
    print(inspect_log(out / "log.mcap").format())
    print()
    say(f"demo: fusing with {out / 'pipeline.yaml'}")
    fused = run(load_pipeline(out / "pipeline.yaml"), out / "out", progress=say)
    print(format_summary(fused))
    evaluation = fused.metrics["evaluation"]
    verdict = "MEETS" if evaluation["passed"] else "DOES NOT MEET"
    thr = evaluation["thresholds"]
    print()
    print(f"demo: the survey {verdict} the seed-002 thresholds at {thr['scale_m']:g} m "
          f"(MSE <= {thr['mse_mm']:g} mm, ADEV <= {thr['adev_mm']:g} mm, {' and '.join(thr['components'])}).")
    print(f"demo: results are in {(out / 'out').resolve()}/ (trajectory.csv, metrics.json, fused.mcap); "
          f"inputs and truth in {out.resolve()}/.")
    return bool(evaluation["passed"])
