"""``trackfusion batch``: many surveys, each with its own pipeline YAML, in parallel.

Engines: ``local`` (default) runs the surveys in a process pool on this machine; ``dask``
submits them to a Dask cluster — a ``LocalCluster`` of ``workers`` processes, or the scheduler
at ``address`` (``tcp://host:8786``), whose workers must see the same paths (shared
filesystem) and have trackfusion installed (extra ``[distributed]``).

Each survey runs exactly as ``trackfusion run`` would (outputs staged, nothing written for a
failed survey). A failing survey is reported with its one-line error and does not stop the
others. :class:`BatchResult` holds one :class:`SurveyOutcome` per pipeline, in the order given;
the command prints the summary table and exits 0 when every survey succeeded, 3 when at least
one failed (docs/batch.md).
"""

from __future__ import annotations

import os
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Callable, Literal, Sequence

from .errors import ConfigError, TrackfusionError

Engine = Literal["local", "dask"]
EXIT_SOME_FAILED = 3


@dataclass
class SurveyOutcome:
    """One survey of a batch: ``ok``; ``out_dir`` when it succeeded; ``error`` (one line) and
    ``error_kind`` (``input``: a trackfusion error, bad data or config; ``internal``: a bug or
    a crashed worker) when it failed; ``figures``: headline metrics (accuracy verdict, MSE /
    ADEV at the threshold scale [mm] when a reference was given)."""

    pipeline: str
    name: str
    ok: bool
    wall_s: float
    out_dir: str | None = None
    error: str | None = None
    error_kind: str | None = None
    figures: dict[str, Any] = field(default_factory=dict)


def _figures(metrics: dict) -> dict[str, Any]:
    out: dict[str, Any] = {"duration_s": metrics.get("duration_s"), "keyframes": metrics.get("keyframes")}
    ev = metrics.get("evaluation")
    if ev:
        out["passed"] = ev["passed"]
        for c in ev["thresholds"]["components"]:
            ra = metrics["relative_accuracy"][c]
            out[f"{c}_mse_mm"] = ra["mse_at_threshold_mm"]
            out[f"{c}_adev_mm"] = ra["adev_at_threshold_mm"]
    if "geometry" in metrics:
        out["exceedances"] = len(metrics["geometry"].get("exceedances", []))
    return out


def run_one(pipeline_path: str, out_dir: str | None = None, force: bool = False) -> SurveyOutcome:
    """Run one survey; never raises (a failure is returned in the outcome). Runs in workers."""
    from .pipeline import load_pipeline, run

    tic = time.perf_counter()
    name = Path(pipeline_path).stem
    try:
        pipeline = load_pipeline(pipeline_path)
        name = pipeline.config.name
        result = run(pipeline, out_dir, force=force)
        return SurveyOutcome(pipeline_path, name, True, time.perf_counter() - tic, str(result.out_dir),
                             figures=_figures(result.metrics))
    except TrackfusionError as exc:
        return SurveyOutcome(pipeline_path, name, False, time.perf_counter() - tic, error=str(exc),
                             error_kind="input")
    except Exception as exc:  # noqa: BLE001 - a batch reports every failure and carries on
        where = traceback.extract_tb(exc.__traceback__)[-1]
        return SurveyOutcome(pipeline_path, name, False, time.perf_counter() - tic,
                             error=f"{type(exc).__name__}: {exc} ({Path(where.filename).name}:{where.lineno})",
                             error_kind="internal")


@dataclass
class BatchResult:
    engine: str
    outcomes: list[SurveyOutcome]
    wall_s: float

    @property
    def failed(self) -> list[SurveyOutcome]:
        return [o for o in self.outcomes if not o.ok]

    @property
    def exit_code(self) -> int:
        return EXIT_SOME_FAILED if self.failed else 0

    def to_json(self) -> dict:
        return {"engine": self.engine, "wall_s": self.wall_s, "surveys": len(self.outcomes),
                "failed": len(self.failed), "outcomes": [asdict(o) for o in self.outcomes]}

    def format_table(self) -> str:
        """The summary table: one row per survey, then the totals."""
        comps = sorted({k[:-7] for o in self.outcomes for k in o.figures if k.endswith("_mse_mm")})
        head = ["#", "survey", "status", "time s", "accuracy"] + [f"{c} MSE/ADEV mm" for c in comps] + ["output / error"]
        rows = []
        for i, o in enumerate(self.outcomes, 1):
            f = o.figures
            verdict = {True: "pass", False: "FAIL", None: "-"}[f.get("passed")] if o.ok else "-"
            cells = [str(i), o.name, "ok" if o.ok else f"FAILED ({o.error_kind})", f"{o.wall_s:.1f}", verdict]
            cells += [f"{f[c + '_mse_mm']:.3f}/{f[c + '_adev_mm']:.3f}" if f.get(c + "_mse_mm") is not None else "-"
                      for c in comps]
            cells.append(o.out_dir if o.ok else f"{o.pipeline}: {o.error}")
            rows.append(cells)
        widths = [max(len(r[j]) for r in [head] + rows) for j in range(len(head) - 1)]
        fmt = lambda r: "  ".join(c.ljust(w) for c, w in zip(r, widths)) + "  " + r[-1]  # noqa: E731
        lines = [fmt(head), fmt(["-" * w for w in widths] + ["-" * 14])] + [fmt(r) for r in rows]
        lines.append(f"{len(self.outcomes) - len(self.failed)} of {len(self.outcomes)} surveys succeeded "
                     f"({self.engine} engine, {self.wall_s:.1f} s)"
                     + (f"; {len(self.failed)} failed, exit code {EXIT_SOME_FAILED}" if self.failed else ""))
        return "\n".join(lines)


def _out_dirs(paths: Sequence[str], out_root: str | None) -> list[str | None]:
    if out_root is None:
        return [None] * len(paths)  # out/ beside each YAML, as 'trackfusion run'
    stems = [Path(p).stem for p in paths]
    dup = next((s for s in stems if stems.count(s) > 1), None)
    if dup is not None:
        raise ConfigError(f"--out-root: two pipelines are named {dup!r}; give them distinct file names")
    return [str(Path(out_root) / s) for s in stems]


def _check_out_dirs(paths: Sequence[str], out_dirs: Sequence[str | None], force: bool) -> None:
    """Every survey's output folder checked before any survey starts
    (:class:`~trackfusion.outdir.OutputFolder`); two surveys writing one folder are refused."""
    from .outdir import OutputFolder
    seen: dict[Path, str] = {}
    for p, o in zip(paths, out_dirs):
        folder = Path(o) if o is not None else Path(p).resolve().parent / "out"
        key = folder.resolve()
        if key in seen:
            raise ConfigError(f"{p}: writes into {folder}/ as {seen[key]} does; give them distinct folders "
                              "(--out-root, or one folder per pipeline YAML)")
        seen[key] = p
        OutputFolder(folder, force).check()


def _collect(jobs, completed, failure: Callable[[Exception], str], say) -> list[SurveyOutcome]:
    """The outcomes of ``jobs`` in their order, taken from ``completed`` (the
    :data:`~trackfusion.parallel.Completed` of each :func:`run_one` as it ends, each said); a
    call that raised (its worker died, its task was lost) is an internal failure with the error
    ``failure(exc)``."""
    outcomes: dict[int, SurveyOutcome] = {}
    for i, outcome, exc in completed:
        if exc is not None:
            p = jobs[i][0]
            outcome = SurveyOutcome(p, Path(p).stem, False, 0.0, error=failure(exc), error_kind="internal")
        outcomes[i] = outcome
        say(_line(outcomes[i], len(outcomes), len(jobs)))
    return [outcomes[i] for i in range(len(jobs))]


def _local(jobs, workers: int, say, force: bool = False) -> list[SurveyOutcome]:
    from .parallel import completed_in_spawned_pool
    completed = completed_in_spawned_pool(run_one, [(p, o, force) for p, o in jobs], workers)
    return _collect(jobs, completed, lambda exc: f"worker died: {exc}", say)


def _dask(jobs, workers: int, address: str | None, say, force: bool = False) -> list[SurveyOutcome]:
    from .parallel import completed_on_dask, open_dask
    with open_dask(address, workers, "--engine dask", "--address") as client:
        say(f"batch: dask scheduler {client.scheduler.address}, {len(client.scheduler_info()['workers'])} workers")
        keys = [f"survey-{i}-{Path(p).stem}" for i, (p, _o) in enumerate(jobs)]
        completed = completed_on_dask(client, run_one, [(p, o, force) for p, o in jobs], keys)
        return _collect(jobs, completed, lambda exc: f"dask task failed: {type(exc).__name__}: {exc}", say)


def _line(o: SurveyOutcome, done: int, total: int) -> str:
    status = f"done in {o.wall_s:.1f} s" if o.ok else f"FAILED: {o.error}"
    return f"batch: [{done}/{total}] {o.name} ({o.pipeline}): {status}"


def run_batch(pipelines: Sequence[str | os.PathLike], engine: Engine = "local", address: str | None = None,
              workers: int | None = None, out_root: str | None = None,
              progress: Callable[[str], None] | None = None, force: bool = False) -> BatchResult:
    """Run every pipeline YAML (module docstring); ``workers`` defaults to the CPU count (local)
    or 2 (LocalCluster); ``out_root``: write survey ``X.yaml`` to ``out_root/X/`` instead of
    ``out/`` beside the YAML. Every output folder is checked first (``force``: write beside
    files trackfusion did not write; docs/robustness.md)."""
    say = progress or (lambda _m: None)
    paths = [str(Path(p)) for p in pipelines]
    if not paths:
        raise ConfigError("batch: no pipeline given")
    if engine not in ("local", "dask"):
        raise ConfigError(f"--engine: unknown engine {engine!r} (use local or dask)")
    if address is not None and engine != "dask":
        raise ConfigError("--address: only with --engine dask")
    if workers is not None and workers < 1:
        raise ConfigError(f"--workers: must be at least 1, got {workers}")
    jobs = list(zip(paths, _out_dirs(paths, out_root)))
    _check_out_dirs(paths, [o for _p, o in jobs], force)
    tic = time.perf_counter()
    say(f"batch: {len(jobs)} surveys on the {engine} engine")
    if engine == "local":
        outcomes = _local(jobs, workers or min(len(jobs), os.cpu_count() or 1), say, force)
    else:
        outcomes = _dask(jobs, workers or 2, address, say, force)
    return BatchResult(engine, outcomes, time.perf_counter() - tic)
