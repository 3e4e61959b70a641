"""The ``jaxslam`` command line: run, localize, evaluate, datasets, plot, calibrate,
export-bag.

Bad arguments exit with status 2 and a message that says what is wrong; a missing
dataset names the dataset, every place searched and how to set ``JAXSLAM_DATA``.

One module of about 450 lines: the parser of every subcommand and the thin adapters
from parsed arguments to the functions that do the work (:mod:`jaxslam.app.runs`,
:mod:`jaxslam.app.report`, :mod:`jaxslam.app.localize`, :mod:`jaxslam.app.calibrate`);
the options of all subcommands are kept in one place so that they stay consistent.
"""

from __future__ import annotations

import argparse
import atexit
import json
import os
import sys
import threading
from pathlib import Path
from typing import Any

# The minimum share of relations or GPS fixes that evaluate must match before it
# warns; it is also jaxslam.metrics.scoring.MIN_MATCHED_FRACTION (a test keeps the two
# equal), written here so that this module imports only the standard library at load.
MIN_MATCHED_FRACTION = 0.9

EPILOG = """examples:
  jaxslam run --out runs/demo                      simulated landmark world, ERB, 100 particles
  jaxslam run --dataset victoria-park --algorithm erb-upf --particles 100 --out runs/vp
  jaxslam run --dataset intel --algorithm srupf-gm --particles 30 --out runs/intel
  jaxslam evaluate --relations intel --trajectory runs/intel/trajectory.tum
  jaxslam datasets
  jaxslam export-bag --dataset intel --out runs/robot.bag    a CARMEN log as a ROS 1 bag
  jaxslam datasets --inspect runs/robot.bag       topics, types, counts and rates of a ROS bag
  jaxslam run --dataset runs/robot.bag --scan-topic /scan --odom-topic /odom --out runs/robot
  jaxslam plot runs/intel
  jaxslam localize --map runs/intel --dataset intel --global --particles 10000 --out runs/intel-loc
  jaxslam calibrate --dataset victoria-park --algorithm erb-upf --out runs/cal
  jaxslam run --dataset victoria-park --params runs/cal/calibration.json --out runs/vp-cal
"""


EVALUATE_DESCRIPTION = f"""\
Score a TUM trajectory and print the scores as JSON. One line on standard error
says how many of the relations (or GPS fixes) could be scored: those with poses
at their stamps (within the trajectory's time span). It is a warning when fewer
than {MIN_MATCHED_FRACTION:.0%} could (a trajectory of part of the log, or stamps other than the
log's): the score then covers that part only.
"""


class CliError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Each option's default shown once.

    ``(default: X)`` is appended to an option's help only where the help does not
    already say what the default is, and never for an option whose default is None,
    False or empty (a flag, an option whose absence the help explains); argparse's
    ``ArgumentDefaultsHelpFormatter`` appends it to every option, ``(default: None)``
    included, after a help that states the default itself."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if "default" in text.lower() or default is None or default is False or default is argparse.SUPPRESS:
            return text
        if isinstance(default, (list, tuple, dict, str)) and not default:
            return text
        return f"{text} (default: %(default)s)"


class _Parser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose help uses :class:`HelpFormatter` (every subcommand's)."""

    def __init__(self, *args, formatter_class=HelpFormatter, **kwargs):
        super().__init__(*args, formatter_class=formatter_class, **kwargs)


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _nonneg_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"expected an integer >= 0, got {value}")
    return value


def _override(text: str) -> tuple[str, float]:
    if "=" not in text:
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    name, value = text.split("=", 1)
    try:
        return name.strip(), float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"value of {name!r} must be a number, got {value!r}") from None


def build_parser() -> argparse.ArgumentParser:
    from jaxslam.datasets.registry import ALGORITHMS

    parser = _Parser(
        prog="jaxslam",
        description="Batched JAX particle filters for SLAM (RB/ERB unscented FastSLAM, SRUPF-GM, GMapping-style).",
        epilog=EPILOG,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True

    run = sub.add_parser(
        "run",
        help="run a SLAM filter on a dataset or a built-in simulator and write its outputs",
    )
    run.add_argument("--dataset", default=None,
                     help="dataset name (see `jaxslam datasets`), a path to a CARMEN log or to a ROS bag; "
                          "default: the built-in simulator that suits --algorithm")
    run.add_argument("--algorithm", choices=sorted(ALGORITHMS), default=None,
                     help="filter; default erb-upf for landmark data, srupf-gm for laser data")
    run.add_argument("--particles", type=_positive_int, default=None,
                     help="number of particles (default: 100 for landmark data, 30 for laser data)")
    run.add_argument("--seed", type=_nonneg_int, default=0, help="random seed, recorded in summary.json")
    run.add_argument("--out", type=Path, default=None, help="output folder (created; required unless --resume)")
    run.add_argument("--max-steps", type=_positive_int, default=None,
                     help="stop after this many filter steps (landmark data: scans; laser data: about this many "
                          "keyframes, the log cut where the odometry rule reaches them); default: the whole sequence")
    run.add_argument("--set", dest="overrides", type=_override, action="append", default=[], metavar="NAME=VALUE",
                     help="override a noise level or threshold of the filter's Params (repeatable); "
                          "`jaxslam run --list-params --algorithm A` lists names, units and defaults")
    run.add_argument("--linear-update", type=float, default=None, metavar="M",
                     help="laser data: a scan is a keyframe after this much tracked travel (GMapping "
                          "linearUpdate; default 0.5 for srupf-gm, GMapping's 1.0 for gmapping)")
    run.add_argument("--angular-update", type=float, default=None, metavar="RAD",
                     help="laser data: ... or this much tracked rotation (angularUpdate; default 0.5)")
    run.add_argument("--temporal-update", type=float, default=None, metavar="S",
                     help="laser data: ... or after this many seconds (temporalUpdate; default -1: off)")
    run.add_argument("--params", type=Path, default=None, metavar="FILE",
                     help="noise levels from a `jaxslam calibrate` output (DIR/calibration.json); --set wins")
    run.add_argument("--max-range", type=float, default=None, metavar="M",
                     help="CARMEN logs: range limit in m; readings at or beyond it are 'no return' (default: the "
                          "logged limit, lowered to a detected no-return sentinel pile, see summary.json no_return)")
    run.add_argument("--mixed-geometry", choices=("raise", "pad"), default=None,
                     help="CARMEN logs whose beam geometry changes mid-log: refuse them (raise, the default) or "
                          "pad their scans to a common length (pad)")
    run.add_argument("--max-odometry-step", type=float, default=None, metavar="M",
                     help="laser logs: refuse a log whose odometry moves more than this between two scans, a "
                          "fault of the odometry rather than motion (default 10; jaxslam.datasets.checks)")
    run.add_argument("--loop-closure", action=argparse.BooleanOptionalAction, default=None,
                     help="laser data: where the tracking's match fails in a mapped place, search up to 6 m "
                          "(each axis) and 8 deg around it, after long travel without a closure up to 10 m (2 cm "
                          "per m of odometry since the last one), and take a clearly better pose (closes large "
                          "loops that come back metres off the old map; a closure whose beams keep ending in known free space over "
                          "the next 5 m is undone). Default: on for srupf-gm, off for the GMapping-style filter")
    run.add_argument("--start-map", type=Path, default=None, metavar="DIR|map.npz|map.yaml",
                     help="grid filters: continue a saved map (a run folder, its map.npz, or a ROS map_server "
                          "YAML at the run's 0.05 m cells): every particle starts from it, and the map written "
                          "covers it and this log")
    run.add_argument("--initial-pose", type=float, nargs=3, default=None, metavar=("X", "Y", "THETA"),
                     help="with --start-map: the first scan's pose in the map's frame (m, m, rad); default: the "
                          "saved run's last pose where its map.npz records it, else 0 0 0")
    run.add_argument("--localize-first", action="store_true",
                     help="with --start-map: localize the log's first scans in the map by Monte Carlo "
                          "localization from a uniform start over its free space (20000 particles, the first 300 "
                          "scans; exits if it does not converge), then map from the last of them on")
    run.add_argument("--list-params", action="store_true", help="print the algorithm's parameters and exit")
    run.add_argument("--float64", action="store_true", help="run in double precision (default float32)")
    run.add_argument("--checkpoint-every", type=_positive_int, default=None, metavar="N",
                     help="save the full filter state (particles, maps, weights, position in the log) every N "
                          "steps to OUT/checkpoint.npz, atomically; default: none")
    run.add_argument("--resume", type=Path, default=None, metavar="DIR",
                     help="continue the run saved in DIR (its checkpoint.npz and run.json) with its original "
                          "arguments; the result equals an uninterrupted run")
    run.add_argument("--chunk", type=_positive_int, default=None,
                     help="steps per compiled chunk (progress-bar granularity); default: 512 scans for landmark "
                          "data, 256 scans for laser data (--rerun and --checkpoint-every run the same program)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    run.add_argument("--json", action="store_true",
                     help="print summary.json to standard output in place of the short summary")
    run.add_argument("--rerun", type=Path, default=None, metavar="FILE.rrd",
                     help="log the run to a Rerun recording as it goes: map, particles, best path, scans, ESS "
                          '(needs pip install "jaxslam[viz]")')
    run.add_argument("--rerun-spawn", action="store_true", help="... and/or open the Rerun viewer live")
    bag = run.add_argument_group("ROS bags (--dataset path/to/bag: a ROS 1 .bag, a ROS 2 bag folder, .mcap or .db3)")
    bag.add_argument("--scan-topic", default=None, help="sensor_msgs/LaserScan topic; default: the only one")
    bag.add_argument("--odom-topic", default=None,
                     help="nav_msgs/Odometry topic, or /tf for the odom -> base transform; default: the only "
                          "Odometry topic, else /tf")
    bag.add_argument("--base-frame", default=None, help="robot base frame (default: the odometry's child frame)")
    bag.add_argument("--laser-mount", type=float, nargs=3, default=None, metavar=("X", "Y", "THETA"),
                     help="laser pose in the base frame (m, m, rad); default: from /tf_static")
    run.add_argument("--cache-dir", type=Path, default=None, metavar="DIR",
                     help="JAX persistent compilation cache folder, also holding parsed CARMEN logs (default: "
                          "$JAXSLAM_CACHE_DIR, else $XDG_CACHE_HOME/jaxslam/jax or ~/.cache/jaxslam/jax)")
    run.add_argument("--threads", default=None, metavar="N|all",
                     help="threads of XLA's CPU runtime; default $JAXSLAM_THREADS, else one for the landmark "
                          "filters up to 300 particles (faster there: their kernels are too small to share), all "
                          "cores otherwise")
    run.add_argument("--no-cache", action="store_true",
                     help="do not use the compilation cache nor the parsed-log cache (same as JAXSLAM_CACHE_DIR=off)")

    ev = sub.add_parser("evaluate", help="score a TUM trajectory (relations metric or GPS error)",
                        description=EVALUATE_DESCRIPTION)
    ev.add_argument("--trajectory", type=Path, required=True, help="TUM trajectory file (timestamp x y z qx qy qz qw)")
    target = ev.add_mutually_exclusive_group(required=True)
    target.add_argument("--relations", help="Kümmerle et al. relations file, or a dataset name that has one "
                                            "(intel, fr079, mit-killian)")
    target.add_argument("--gps", help="dataset whose GPS to score against (victoria-park)")
    ev.add_argument("--out", type=Path, default=None, help="also write the scores as JSON here")

    ds = sub.add_parser("datasets", help="list known datasets, whether they are found, and where")
    ds.add_argument("--inspect", type=Path, default=None, metavar="BAG",
                    help="list the topics of a ROS bag: types, message counts, rates")

    from jaxslam.app.calibrate import add_parser as add_calibrate_parser

    add_calibrate_parser(sub, _positive_int, _nonneg_int)

    from jaxslam.app.localize import add_parser as add_localize_parser

    add_localize_parser(sub, _positive_int, _nonneg_int)

    from jaxslam.app.export import add_parser as add_export_parser

    add_export_parser(sub, _positive_int, _nonneg_int)

    pl = sub.add_parser("plot", help="re-draw the figures of an output folder from its files")
    pl.add_argument("folder", type=Path, help="output folder written by `jaxslam run`")
    return parser


def cmd_datasets(args) -> int:
    from jaxslam.datasets.paths import ENV_VAR

    if getattr(args, "inspect", None) is not None:
        from jaxslam.datasets.rosbag import inspect_rosbag

        if not args.inspect.exists():
            raise CliError(f"--inspect: {str(args.inspect)!r} does not exist")
        rows = inspect_rosbag(args.inspect)
        width = max([len(r["topic"]) for r in rows] + [5])
        twidth = max([len(r["type"]) for r in rows] + [4])
        print(f"{'topic':<{width}}  {'type':<{twidth}}  {'count':>7}  {'rate_hz':>8}  first_s .. last_s (bag time)")
        for r in rows:
            rate = f"{r['rate_hz']:8.2f}" if r["rate_hz"] is not None else f"{'-':>8}"
            span = f"{r['first_s']:.3f} .. {r['last_s']:.3f}" if r["count"] else "-"
            print(f"{r['topic']:<{width}}  {r['type']:<{twidth}}  {r['count']:>7}  {rate}  {span}")
        return 0
    from jaxslam.datasets.registry import describe, roots_text

    rows = describe()
    width = max(len(r["name"]) for r in rows)
    print(f"data roots searched: {roots_text()}  (set {ENV_VAR} to change)")
    for r in rows:
        mark = "found  " if r["found"] else "MISSING"
        print(f"{r['name']:<{width}}  {r['kind']:<8}  {mark}  {r['description']}")
        print(f"{'':<{width}}  {'':<8}           {r['where']}")
    return 0


def cmd_run(args) -> int:
    from jaxslam.runtime.cache import ENV_VAR as CACHE_ENV_VAR
    from jaxslam.runtime.cache import enable_compilation_cache

    if not args.list_params:
        try:
            enable_compilation_cache("off" if args.no_cache else args.cache_dir)
        except OSError as err:
            if args.cache_dir is not None or os.environ.get(CACHE_ENV_VAR) is not None:
                raise CliError(str(err)) from None
            print(f"jaxslam run: warning: running without the compilation cache: {err}", file=sys.stderr)

    summary = run_from_args(args)
    if summary is None:  # --list-params
        return 0
    if args.json:
        from jaxslam.app.outputs import json_default

        print(json.dumps(summary, indent=2, default=json_default))
    else:
        from jaxslam.app.report import report

        print(report(summary, args.resume if args.resume is not None else args.out))
    return 0


def run_from_args(args: argparse.Namespace) -> dict[str, Any] | None:
    """``jaxslam run``: the parsed arguments as a call of :func:`jaxslam.app.runs.run`
    (``--list-params`` prints the parameters instead; ``--resume`` repeats the
    arguments saved in the folder's ``run.json``)."""
    from jaxslam.app import data, runs
    from jaxslam.datasets.paths import DataFormatError
    from jaxslam.datasets.registry import DEFAULT_ALGORITHM

    if args.list_params:
        from jaxslam.app.params import parameter_table

        algorithm = args.algorithm or DEFAULT_ALGORITHM[data.resolve_dataset(args.dataset, None)[2]]
        print(parameter_table(algorithm))
        return None
    if args.resume is not None:
        saved = args.resume / "run.json"
        if not saved.exists():
            raise runs.RunError(
                f"--resume {str(args.resume)!r}: no run.json there; is it a `jaxslam run` output folder?")
        try:
            run_args = json.loads(saved.read_text())
        except json.JSONDecodeError as err:
            raise DataFormatError(saved, err.lineno, f"not valid JSON: {err.msg}") from None
        except (OSError, UnicodeDecodeError) as err:
            raise DataFormatError(saved, None, f"cannot read: {err}") from None
        run_args = saved_arguments(saved, run_args)
        if args.threads is not None:
            run_args["threads"] = args.threads
        return runs.run(out=args.resume, progress=not args.no_progress, plots=not args.no_plots,
                        checkpoint_every=args.checkpoint_every, resume=True, **run_args)
    if args.out is None:
        raise runs.RunError("--out is required (the folder the outputs go to)")
    overrides = dict(args.overrides or [])
    from_file = {}
    if getattr(args, "params", None) is not None:
        from jaxslam.app.calibrate import load_params_file

        from_file = load_params_file(args.params)
    # each value checked where it was given, before anything is loaded or compiled
    algorithm = args.algorithm or DEFAULT_ALGORITHM[data.resolve_dataset(args.dataset, None)[2]]
    if data.kind_of(algorithm) == data.resolve_dataset(args.dataset, algorithm)[2]:
        runs.check_overrides(algorithm, from_file, origin=f"--params {str(args.params)!r}:")
        runs.check_overrides(algorithm, overrides, origin="--set")
    overrides = {**from_file, **overrides}
    return runs.run(
        out=args.out, dataset=args.dataset, algorithm=args.algorithm, particles=args.particles, seed=args.seed,
        max_steps=args.max_steps, overrides=overrides, progress=not args.no_progress,
        chunk=args.chunk, float64=args.float64, plots=not args.no_plots, checkpoint_every=args.checkpoint_every,
        keyframes={"linear": args.linear_update, "angular": args.angular_update, "temporal": args.temporal_update},
        bag={"scan_topic": args.scan_topic, "odom_topic": args.odom_topic, "base_frame": args.base_frame,
             "laser_offset": args.laser_mount},
        rerun=args.rerun, rerun_spawn=args.rerun_spawn,
        max_range=args.max_range, threads=args.threads, loop_closure=args.loop_closure,
        max_odometry_step=args.max_odometry_step, mixed_geometry=args.mixed_geometry,
        start_map=args.start_map, initial_pose=args.initial_pose, localize_first=args.localize_first,
    )


def saved_arguments(path: Path, saved) -> dict[str, Any]:
    """The arguments of :func:`jaxslam.app.runs.run` recorded in a ``run.json``
    (its ``status`` and ``reason`` left out), or a ``DataFormatError`` naming a key
    that is not one of them."""
    import inspect

    from jaxslam.app import runs
    from jaxslam.datasets.paths import DataFormatError

    if not isinstance(saved, dict):
        raise DataFormatError(path, None, "expected a JSON object of the run's arguments")
    own = {"out", "progress", "plots", "checkpoint_every", "resume"}  # given by the command line
    known = set(inspect.signature(runs.run).parameters) - own
    unknown = sorted(set(saved) - known - {"status", "reason"})
    if unknown:
        raise DataFormatError(path, None, f"unknown key(s) {', '.join(map(repr, unknown))}: not written by "
                                          "this version of `jaxslam run`")
    return {k: v for k, v in saved.items() if k in known}


def cmd_evaluate(args) -> int:
    from jaxslam.app.report import evaluate

    scores = evaluate(args.trajectory, relations=args.relations, gps=args.gps)
    from jaxslam.app.outputs import json_default

    text = json.dumps(scores, indent=2, default=json_default)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    print(f"jaxslam evaluate: {coverage_text(scores)}", file=sys.stderr)
    return 0


def coverage_text(scores: dict[str, Any]) -> str:
    """How many relations (or GPS fixes) ``scores`` scored of how many, a warning below
    :data:`jaxslam.metrics.scoring.MIN_MATCHED_FRACTION`."""
    from jaxslam.metrics.scoring import matched_counts

    scored, total, what = matched_counts(scores)
    share = scored / total if total else 0.0
    text = f"scored {scored} of {total} {what} ({share:.1%})"
    if share >= MIN_MATCHED_FRACTION:
        return text
    return (f"warning: {text}, fewer than {MIN_MATCHED_FRACTION:.0%}: the others fall where the trajectory has "
            f"no pose (a trajectory of part of the log?); the score covers the scored ones only")


def cmd_plot(args) -> int:
    from jaxslam.app.outputs import replot

    for path in replot(args.folder):
        print(path)
    return 0


def cmd_calibrate(args) -> int:
    from jaxslam.app.calibrate import report
    from jaxslam.app.calibrate import run as run_calibrate

    result = run_calibrate(args)
    if args.json:
        from jaxslam.app.outputs import json_default

        print(json.dumps(result, indent=2, default=json_default))
    else:
        print(report(result, args.out))
    return 0


def cmd_export_bag(args) -> int:
    from jaxslam.app.export import report
    from jaxslam.app.export import run as run_export

    print(report(run_export(args)))
    return 0


def cmd_localize(args) -> int:
    from jaxslam.app.localize import run as run_localize
    from jaxslam.runtime.cache import enable_compilation_cache

    try:
        enable_compilation_cache(None)
    except OSError as err:
        print(f"jaxslam localize: warning: running without the compilation cache: {err}", file=sys.stderr)
    summary = run_localize(args)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        from jaxslam.app.localize import report

        print(report(summary, args.out))
    return 0


COMMANDS = {"calibrate": cmd_calibrate, "export-bag": cmd_export_bag, "localize": cmd_localize, "run": cmd_run, "evaluate": cmd_evaluate, "datasets": cmd_datasets, "plot": cmd_plot}


def main(argv: list[str] | None = None) -> int:
    from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
    from jaxslam.app.errors import RunError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except (CliError, RunError, DatasetNotFoundError, DataFormatError) as err:
        parser.exit(2, f"jaxslam {args.command}: error: {' '.join(str(err).split())}\n")  # one line
    except KeyboardInterrupt:
        parser.exit(130, f"jaxslam {args.command}: interrupted\n")


def console_main() -> None:
    """The ``jaxslam`` command: :func:`main`, then a quick exit.

    Python's finalization after a run (tearing down some 1200 modules, JAX's compiled
    programs and XLA's CPU client) takes a few tenths of a second, a noticeable part of
    a warm run's overhead. When :func:`main` returns, every output file has been written and closed,
    so the exit handlers (:mod:`atexit`: Rerun's flush, logging) run, the standard
    streams are flushed and the process ends with :func:`os._exit`. With a non-daemon
    thread still alive, or without CPython's ``atexit._run_exitfuncs``, it exits the
    usual way. Errors (``SystemExit`` from the parser, tracebacks) take the usual way.
    Ctrl-C exits with status 130 and one line (:mod:`jaxslam.app.interrupts`).
    """
    from jaxslam.app.interrupts import exit_on_interrupt  # first: importing this module loads nothing else

    with exit_on_interrupt(next((word for word in sys.argv[1:] if word in COMMANDS), None)):
        code = main()
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon]
    if run_exit_handlers is None or others:
        sys.exit(code)
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code or 0)


if __name__ == "__main__":
    console_main()
