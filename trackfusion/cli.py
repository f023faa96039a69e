"""Command line: a thin layer that parses arguments and calls library functions.

Exit codes: 0 success; 2 bad input or config (one line naming the file,
field or record, no traceback); 1 internal error.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

from .errors import TrackfusionError
from .parallel import PartWorkerDied


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulation.scenarios import simulate_to_dir

    result = simulate_to_dir(args.scenario, args.out, seed=args.seed, ideal=args.ideal,
                             overrides=args.set or [], progress=_progress)
    print(result.format())
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from .sensors.mcap_log import inspect_log

    print(inspect_log(args.log).format())
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluation.api import evaluate_files
    from .sensors.fileio import write_json_atomic

    result = evaluate_files(args.estimate, args.reference, match=args.match)
    print(result.format_table())
    if args.json:
        write_json_atomic(args.json, result.to_json())
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .pipeline import format_summary, load_pipeline, run

    result = run(load_pipeline(args.pipeline), args.out, progress=_progress)
    print(format_summary(result))
    return 0


def _cmd_init(args: argparse.Namespace) -> int:
    from .init import init_pipeline

    print(init_pipeline(args.log, args.out, kind=args.vehicle, imu_grade=args.imu_grade, sets=args.set or [],
                        force=args.force, progress=_progress).format())
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    run_demo(args.out, progress=_progress, seed=args.seed, overrides=args.set or [])
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from .sensors.importers import import_to_mcap
    from .sensors.mcap_log import inspect_log

    import_to_mcap(args.mapping, args.out)
    print(inspect_log(args.out).format())
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from .sensors.importers import export_csv

    files = export_csv(args.log, args.out)
    print(f"wrote {', '.join(files)} to {args.out}/")
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    from .batch import run_batch
    from .sensors.fileio import write_json_atomic

    result = run_batch(args.pipelines, engine=args.engine, address=args.address, workers=args.workers,
                       out_root=args.out_root, progress=_progress)
    print(result.format_table())
    if args.json:
        write_json_atomic(args.json, result.to_json())
    return result.exit_code


def _cmd_report(args: argparse.Namespace) -> int:
    from .report.html import write_report, write_report_pdf

    print(f"wrote {write_report(args.run_dir, args.out)}")
    if args.pdf:
        print(f"wrote {write_report_pdf(args.run_dir)}")
    return 0


def _cmd_calibrate_vision(args: argparse.Namespace) -> int:
    from .vision.calibration import calibrate_folder

    for r in calibrate_folder(args.folder, args.out, fit_k3=args.fit_k3):
        print(f"{r.unit.side}: {r.views} views, reprojection rms {r.reprojection_rms_px:.3f} px, "
              f"laser plane rms {r.laser_plane_rms_mm:.4f} mm ({r.laser_points} points)")
    return 0


def _progress(message: str) -> None:
    """Progress lines go to stderr so stdout stays machine-readable."""
    print(message, file=sys.stderr, flush=True)


def build_parser() -> argparse.ArgumentParser:
    """The ``trackfusion`` argument parser."""
    p = argparse.ArgumentParser(prog="trackfusion", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    s = sub.add_parser("simulate", help="simulate a survey scenario into a folder")
    s.add_argument("scenario", help="scenario name (see 'trackfusion simulate --list')" )
    s.add_argument("--out", required=True, help="output folder")
    s.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    s.add_argument("--ideal", action="store_true", help="turn every sensor error off")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario parameter (dotted key), repeatable")
    s.set_defaults(func=_cmd_simulate)

    s = sub.add_parser("inspect", help="summarise a raw MCAP log")
    s.add_argument("log")
    s.set_defaults(func=_cmd_inspect)

    s = sub.add_parser("import", help="import CSV/text sensor files into an MCAP raw log (docs/import.md)")
    s.add_argument("mapping", help="mapping YAML: files, columns, units (paths relative to it)")
    s.add_argument("--out", required=True, help="MCAP log to write")
    s.set_defaults(func=_cmd_import)

    s = sub.add_parser("export", help="export an MCAP raw log as CSV files and an import mapping")
    s.add_argument("log")
    s.add_argument("--out", required=True, help="output folder")
    s.set_defaults(func=_cmd_export)

    from .sensors.imu import IMU_GRADES
    from .vehicles import VEHICLE_KINDS
    s = sub.add_parser("init", help="write a runnable, commented pipeline YAML for a log (docs/init.md)")
    s.add_argument("log", help="raw log")
    s.add_argument("--out", required=True, help="pipeline YAML to write (not overwritten without --force)")
    s.add_argument("--vehicle", choices=VEHICLE_KINDS, default="trolley", help="what carries the IMU (default trolley)")
    s.add_argument("--imu-grade", choices=list(IMU_GRADES), default=None,
                   help="the IMU's datasheet grade (default: the log's record, else navigation)")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="a pipeline key (dotted, e.g. sensors.gnss.lever_arm_b_m=[0.1,0.3,0.2]; YAML value), repeatable")
    s.add_argument("--force", action="store_true", help="overwrite an existing --out")
    s.set_defaults(func=_cmd_init)

    s = sub.add_parser("run", help="process a survey with a pipeline YAML")
    s.add_argument("pipeline", help="pipeline YAML (paths inside are relative to its folder)")
    s.add_argument("--out", default=None, help="output folder (default: out/ beside the YAML)")
    s.set_defaults(func=_cmd_run)

    s = sub.add_parser("batch", help="run many pipelines in parallel (docs/batch.md); exit 3 if any failed")
    s.add_argument("pipelines", nargs="+", metavar="PIPELINE.yaml")
    s.add_argument("--engine", choices=["local", "dask"], default="local",
                   help="local process pool (default) or a Dask cluster")
    s.add_argument("--address", default=None, help="Dask scheduler address (default: a LocalCluster)")
    s.add_argument("--workers", type=int, default=None,
                   help="worker processes (local: default CPU count; LocalCluster: default 2)")
    s.add_argument("--out-root", default=None, help="write survey X.yaml to OUT_ROOT/X/ (default out/ beside it)")
    s.add_argument("--json", default=None, help="write the batch summary as JSON to this file")
    s.set_defaults(func=_cmd_batch)

    s = sub.add_parser("evaluate", help="relative accuracy of a trajectory against a reference")
    s.add_argument("estimate")
    s.add_argument("reference")
    s.add_argument("--json", help="write the figures as JSON to this file")
    s.add_argument("--match", choices=["time", "chainage"], default="time",
                   help="match estimate and reference by time (default) or chainage")
    s.set_defaults(func=_cmd_evaluate)

    s = sub.add_parser("report", help="write report.html of a run folder (and report.pdf with --pdf)")
    s.add_argument("run_dir", help="output folder of 'trackfusion run'")
    s.add_argument("--out", default=None, help="report file (default RUN_DIR/report.html)")
    s.add_argument("--pdf", action="store_true", help="also print it to RUN_DIR/report.pdf (needs chromium)")
    s.set_defaults(func=_cmd_report)

    s = sub.add_parser("calibrate-vision", help="calibrate camera-laser units from calibration sets (docs/vision.md)")
    s.add_argument("folder", help="a calibration set (calibration_set.yaml) or a folder of them (left/, right/)")
    s.add_argument("--out", required=True, help="calibration YAML to write")
    s.add_argument("--fit-k3", action="store_true", help="also fit the k3 distortion term (wide lenses)")
    s.set_defaults(func=_cmd_calibrate_vision)

    s = sub.add_parser("demo", help="simulate a survey and evaluate it, end to end")
    s.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the simulated survey (default 0)")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario parameter (as in 'simulate'), e.g. a shorter survey")
    s.set_defaults(func=_cmd_demo)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``trackfusion`` command; returns the exit code."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except TrackfusionError as exc:
        print(f"trackfusion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except PartWorkerDied as exc:  # not the input's fault: exit 1, one line
        print(f"trackfusion {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("trackfusion: interrupted", file=sys.stderr)
        return 130


def exit_now(code: int) -> NoReturn:
    """End the process with ``code`` at once: the ``atexit`` handlers run and stdout/stderr are
    flushed, but the interpreter's teardown of every module and object (about a second after a
    ``run``, with scipy, gtsam and matplotlib loaded: docs/solver_speed.md) is skipped. Every output
    file is closed by then (written atomically). With threads other than the main one still
    running, the ordinary exit (which waits for them)."""
    import atexit
    import os
    import threading
    if threading.active_count() > 1:
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken stream: nothing more can be said on it
            pass
    os._exit(code)


def entry() -> NoReturn:
    """The ``trackfusion`` command (pyproject.toml): :func:`main`, then :func:`exit_now`."""
    exit_now(main())


if __name__ == "__main__":
    entry()
