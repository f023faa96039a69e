"""Command line: a thin layer that parses arguments and calls library functions.

Exit codes: 0 success; 2 bad input or config (one line naming the file,
field or record, no traceback); 1 internal error.
"""

from __future__ import annotations

import argparse
import sys
from typing import NoReturn

from .errors import ConfigError, TrackfusionError, WorkerDied


def _cmd_simulate(args: argparse.Namespace) -> int:
    from .simulation.scenarios import simulate_to_dir

    if args.list:
        print(_scenario_list())
        return 0
    if args.scenario is None or args.out is None:
        raise ConfigError("simulate: give a scenario and --out FOLDER (scenarios: 'trackfusion simulate --list')")
    if args.scenario == "tgms-vehicle":  # a vision survey: simulation/tgms_vehicle.py
        from .simulation.tgms_vehicle import simulate_tgms_to_dir
        if args.ideal:
            raise ConfigError("simulate tgms-vehicle: --ideal is not supported (the images carry their noise)")
        print(simulate_tgms_to_dir(args.out, seed=args.seed, overrides=args.set or [], progress=_progress,
                                   force=args.force))
        return 0
    result = simulate_to_dir(args.scenario, args.out, seed=args.seed, ideal=args.ideal,
                             overrides=args.set or [], progress=_progress, force=args.force)
    print(result.format())
    return 0


def _cmd_inspect(args: argparse.Namespace) -> int:
    from .sensors.ros2 import inspect_log_or_bag

    print(inspect_log_or_bag(args.log).format())
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from .evaluation.api import evaluate_files

    target = _json_target(args, inputs=[args.estimate, args.reference])
    result = evaluate_files(args.estimate, args.reference, match=args.match)
    print(result.format_table())
    _write_json(target, result.to_json())
    return 0


def _cmd_run(args: argparse.Namespace) -> int:
    from .log_read import read_ahead

    with read_ahead(args.pipeline) as ahead:  # the log read in a forked child while the toolkit loads
        from .pipeline import format_summary, load_pipeline, run
        from .verdict import verdict_line

        result = run(load_pipeline(args.pipeline), args.out, progress=_progress, force=args.force, read_ahead=ahead)
    print(format_summary(result))
    print(verdict_line(result.metrics))
    return 0


def _cmd_init(args: argparse.Namespace) -> int:
    from .init import init_pipeline

    print(init_pipeline(args.log, args.out, kind=args.vehicle, imu_grade=args.imu_grade, sets=args.set or [],
                        force=args.force, progress=_progress).format())
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from .demo import run_demo

    run_demo(args.out, progress=_progress, seed=args.seed, overrides=args.set or [], force=args.force)
    return 0


def _cmd_import(args: argparse.Namespace) -> int:
    from .sensors.importers import import_to_mcap
    from .sensors.mcap_log import inspect_log

    import_to_mcap(args.mapping, args.out, force=args.force)
    print(inspect_log(args.out).format())
    return 0


def _cmd_export(args: argparse.Namespace) -> int:
    from .sensors.importers import export_csv

    files = export_csv(args.log, args.out, force=args.force)
    print(f"wrote {', '.join(files)} to {args.out}/")
    return 0


def _cmd_batch(args: argparse.Namespace) -> int:
    from .batch import run_batch

    target = _json_target(args, inputs=args.pipelines)
    result = run_batch(args.pipelines, engine=args.engine, address=args.address, workers=args.workers,
                       out_root=args.out_root, progress=_progress, force=args.force)
    print(result.format_table())
    _write_json(target, result.to_json())
    return result.exit_code


def _cmd_report(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .outdir import OutputFile, check_all
    from .report.html import write_report, write_report_pdf

    run_dir = Path(args.run_dir)
    inputs = [p for p in run_dir.glob("*") if p.name not in ("report.html", "report.pdf")] if run_dir.is_dir() else []
    html = OutputFile(args.out if args.out else run_dir / "report.html", args.force, inputs=inputs,
                      command="trackfusion report")
    pdf = OutputFile(run_dir / "report.pdf", args.force, inputs=inputs, command="trackfusion report")
    check_all([html] + [pdf] * args.pdf)
    with html.writing() as path:
        print(f"wrote {write_report(args.run_dir, path)}")
    if args.pdf:
        with pdf.writing() as path:
            print(f"wrote {write_report_pdf(args.run_dir, path)}")
    return 0


def _cmd_calibrate_vision(args: argparse.Namespace) -> int:
    from .outdir import OutputFile
    from .vision.calibration import calibrate_folder

    target = OutputFile(args.out, args.force, inputs=[args.folder], command="trackfusion calibrate-vision")
    target.check()  # before the calibration's computing
    with target.writing() as path:
        results = calibrate_folder(args.folder, path, fit_k3=args.fit_k3)
    for r in results:
        print(f"{r.unit.side}: {r.views} views, reprojection rms {r.reprojection_rms_px:.3f} px, "
              f"laser plane rms {r.laser_plane_rms_mm:.4f} mm ({r.laser_points} points)")
    return 0


def _json_target(args: argparse.Namespace, inputs):
    """The ``--json`` file of a command, checked before it computes (None without ``--json``)."""
    from .outdir import OutputFile
    if not args.json:
        return None
    target = OutputFile(args.json, args.force, what="--json", inputs=inputs, command=f"trackfusion {args.command}")
    target.check()
    return target


def _write_json(target, obj) -> None:
    from .sensors.fileio import write_json_atomic
    if target is not None:
        with target.writing() as path:
            write_json_atomic(path, obj)


def _scenario_list() -> str:
    from .simulation.config import scenario_descriptions
    from .simulation.tgms_vehicle import DESCRIPTION, NAME
    rows = {**scenario_descriptions(), NAME: DESCRIPTION}
    width = max(len(n) for n in rows)
    return "\n".join(f"{n:<{width}}  {d}" for n, d in rows.items())


#: the progress callback of the running command (:mod:`trackfusion.progress`), set by :func:`main`
_say = None


def _progress(message: str) -> None:
    """Progress goes to stderr so stdout stays machine-readable (bars on a terminal, lines otherwise)."""
    if _say is None:
        print(message, file=sys.stderr, flush=True)
    else:
        _say(message)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version("trackfusion")
    except PackageNotFoundError:
        return "unknown (not installed)"


def _add_simulate_parser(sub, force: argparse.ArgumentParser) -> None:
    """``simulate``: a scenario into a folder (or ``--list``)."""
    s = sub.add_parser("simulate", help="simulate a survey scenario into a folder", parents=[force])
    s.add_argument("scenario", nargs="?", help="scenario name (see 'trackfusion simulate --list')")
    s.add_argument("--list", action="store_true", help="list the scenarios and exit")
    s.add_argument("--out", help="output folder (required with a scenario)")
    s.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    s.add_argument("--ideal", action="store_true", help="turn every sensor error off")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario parameter (dotted key), repeatable")
    s.set_defaults(func=_cmd_simulate)


def _add_inspect_parser(sub, force: argparse.ArgumentParser) -> None:
    """``inspect``: the per-topic summary of a raw log."""
    s = sub.add_parser("inspect", help="summarise a raw MCAP log")
    s.add_argument("log")
    s.set_defaults(func=_cmd_inspect)


def _add_import_parser(sub, force: argparse.ArgumentParser) -> None:
    """``import``: CSV/text sensor files into a raw log."""
    s = sub.add_parser("import", help="import CSV/text sensor files into an MCAP raw log (docs/import.md)",
                       parents=[force])
    s.add_argument("mapping", help="mapping YAML: files, columns, units (paths relative to it)")
    s.add_argument("--out", required=True, help="MCAP log to write")
    s.set_defaults(func=_cmd_import)


def _add_export_parser(sub, force: argparse.ArgumentParser) -> None:
    """``export``: a raw log as CSV files and an import mapping."""
    s = sub.add_parser("export", help="export an MCAP raw log as CSV files and an import mapping", parents=[force])
    s.add_argument("log")
    s.add_argument("--out", required=True, help="output folder")
    s.set_defaults(func=_cmd_export)


def _add_init_parser(sub, force: argparse.ArgumentParser) -> None:
    """``init``: a pipeline YAML for a log."""
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


def _add_run_parser(sub, force: argparse.ArgumentParser) -> None:
    """``run``: one survey with its pipeline YAML."""
    s = sub.add_parser("run", help="process a survey with a pipeline YAML", parents=[force])
    s.add_argument("pipeline", help="pipeline YAML (paths inside are relative to its folder)")
    s.add_argument("--out", default=None, help="output folder (default: out/ beside the YAML)")
    s.set_defaults(func=_cmd_run)


def _add_batch_parser(sub, force: argparse.ArgumentParser) -> None:
    """``batch``: many pipelines in parallel."""
    s = sub.add_parser("batch", help="run many pipelines in parallel (docs/batch.md); exit 3 if any failed",
                       parents=[force])
    s.add_argument("pipelines", nargs="+", metavar="PIPELINE.yaml")
    s.add_argument("--engine", choices=["local", "dask"], default="local",
                   help="local process pool (default) or a Dask cluster")
    s.add_argument("--address", default=None, help="Dask scheduler address (default: a LocalCluster)")
    s.add_argument("--workers", type=int, default=None,
                   help="worker processes (local: default CPU count; LocalCluster: default 2)")
    s.add_argument("--out-root", default=None, help="write survey X.yaml to OUT_ROOT/X/ (default out/ beside it)")
    s.add_argument("--json", default=None, help="write the batch summary as JSON to this file")
    s.set_defaults(func=_cmd_batch)


def _add_evaluate_parser(sub, force: argparse.ArgumentParser) -> None:
    """``evaluate``: relative accuracy against a reference."""
    s = sub.add_parser("evaluate", help="relative accuracy of a trajectory against a reference", parents=[force])
    s.add_argument("estimate")
    s.add_argument("reference")
    s.add_argument("--json", help="write the figures as JSON to this file")
    s.add_argument("--match", choices=["time", "chainage"], default="time",
                   help="match estimate and reference by time (default) or chainage")
    s.set_defaults(func=_cmd_evaluate)


def _add_report_parser(sub, force: argparse.ArgumentParser) -> None:
    """``report``: report.html (and report.pdf) of a run folder."""
    s = sub.add_parser("report", help="write report.html of a run folder (and report.pdf with --pdf)",
                       parents=[force])
    s.add_argument("run_dir", help="output folder of 'trackfusion run'")
    s.add_argument("--out", default=None, help="report file (default RUN_DIR/report.html)")
    s.add_argument("--pdf", action="store_true", help="also print it to RUN_DIR/report.pdf (needs chromium)")
    s.set_defaults(func=_cmd_report)


def _add_calibrate_vision_parser(sub, force: argparse.ArgumentParser) -> None:
    """``calibrate-vision``: camera-laser units from calibration sets."""
    s = sub.add_parser("calibrate-vision", help="calibrate camera-laser units from calibration sets (docs/vision.md)",
                       parents=[force])
    s.add_argument("folder", help="a calibration set (calibration_set.yaml) or a folder of them (left/, right/)")
    s.add_argument("--out", required=True, help="calibration YAML to write")
    s.add_argument("--fit-k3", action="store_true", help="also fit the k3 distortion term (wide lenses)")
    s.set_defaults(func=_cmd_calibrate_vision)


def _add_demo_parser(sub, force: argparse.ArgumentParser) -> None:
    """``demo``: simulate and evaluate a survey, end to end."""
    s = sub.add_parser("demo", help="simulate a survey and evaluate it, end to end", parents=[force])
    s.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    s.add_argument("--seed", type=int, default=0, help="random seed of the simulated survey (default 0)")
    s.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a scenario parameter (as in 'simulate'), e.g. a shorter survey")
    s.set_defaults(func=_cmd_demo)


#: the subcommands' parsers in the order of the help: each adds its own to ``sub`` (the subparsers
#: of :func:`build_parser`; ``force``: the parent parser of the shared ``--force`` option)
_SUBCOMMAND_PARSERS = (_add_simulate_parser, _add_inspect_parser, _add_import_parser, _add_export_parser,
                       _add_init_parser, _add_run_parser, _add_batch_parser, _add_evaluate_parser,
                       _add_report_parser, _add_calibrate_vision_parser, _add_demo_parser)


def build_parser() -> argparse.ArgumentParser:
    """The ``trackfusion`` argument parser."""
    p = argparse.ArgumentParser(prog="trackfusion", description=__doc__.splitlines()[0])
    p.add_argument("--version", action="version", version=f"trackfusion {_version()}")
    talk = p.add_mutually_exclusive_group()
    talk.add_argument("-q", "--quiet", action="store_true", help="no progress, only warnings, errors and results")
    talk.add_argument("-v", "--verbose", action="store_true", help="progress lines with the time since the start")
    sub = p.add_subparsers(dest="command", required=True)
    force = argparse.ArgumentParser(add_help=False)
    force.add_argument("--force", action="store_true",
                       help="write even where the output holds files trackfusion did not write "
                            "(they are kept unless a new output has the same name; inputs are never replaced)")
    for add in _SUBCOMMAND_PARSERS:
        add(sub, force)
    return p


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``trackfusion`` command; returns the exit code."""
    global _say
    from .progress import NORMAL, QUIET, VERBOSE, Progress

    args = build_parser().parse_args(argv)
    progress = Progress(QUIET if args.quiet else VERBOSE if args.verbose else NORMAL)
    _say = progress
    try:
        return args.func(args)
    except TrackfusionError as exc:
        progress.close()
        print(f"trackfusion {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except WorkerDied as exc:  # not the input's fault: exit 1, one line
        progress.close()
        print(f"trackfusion {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        progress.close()
        print("trackfusion: interrupted", file=sys.stderr)
        return 130
    finally:
        progress.close()
        _say = None


def exit_now(code: int) -> NoReturn:
    """End the process with ``code`` at once: the ``atexit`` handlers run and stdout/stderr are
    flushed, but the interpreter's teardown of every module and object (about a second after a
    ``run``, with scipy, gtsam and matplotlib loaded: docs/solver_speed.md) is skipped. Every output
    file is closed by then (written atomically). With threads other than the main one still
    running, the ordinary exit (which waits for them)."""
    import atexit
    import os

    from .forked import other_threads_running
    if other_threads_running():
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
