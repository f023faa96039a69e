"""``trackfusion demo``: the first ten minutes of a new user, end to end on built-in data.

Today the demo simulates the seed-002 open-track GNSS survey, checks the raw
log it wrote (as ``trackfusion inspect`` does), and checks the truth files.
The fusion (``trackfusion run``) joins it when the smoother lands.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from .sensors.mcap_log import inspect_log
from .simulation.scenarios import simulate_to_dir

DEMO_SCENARIO = "open-track-gnss"


def run_demo(out_dir: str | Path, progress: Callable[[str], None] | None = None) -> None:
    """Simulate the demo survey into ``out_dir`` and print what was produced."""
    say = progress or print
    out = Path(out_dir)
    say(f"demo: simulating scenario {DEMO_SCENARIO!r} into {out}/")
    result = simulate_to_dir(DEMO_SCENARIO, out, seed=0, ideal=False, overrides=[], progress=say)
    print(result.format())
    print()
    print(inspect_log(out / "log.mcap").format())
    print()
    print(f"demo: results are in {out.resolve()}/ (log.mcap, truth.csv, geometry_truth.csv, pipeline.yaml).")
    print("demo: the fusion step ('trackfusion run pipeline.yaml') is not part of this release yet.")
