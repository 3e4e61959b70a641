"""The ``jaxslam`` command line: run, localize, evaluate, datasets, plot.

Bad arguments exit with status 2 and a message that says what is wrong; a missing
dataset names the dataset, every place searched and how to set ``JAXSLAM_DATA``.
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

from jaxslam.datasets.registry import ALGORITHMS
from jaxslam.app.outputs import json_default

EPILOG = """examples:
  jaxslam run --out runs/demo                      simulated landmark world, ERB, 100 particles
  jaxslam run --dataset victoria-park --algorithm erb-upf --particles 100 --out runs/vp
  jaxslam run --dataset intel --algorithm srupf-gm --particles 30 --out runs/intel
  jaxslam evaluate --relations intel --trajectory runs/intel/trajectory.tum
  jaxslam datasets
  jaxslam datasets --inspect robot.bag            topics, types, counts and rates of a ROS bag
  jaxslam run --dataset robot.bag --scan-topic /scan --odom-topic /odom --out runs/robot
  jaxslam plot runs/intel
  jaxslam localize --map runs/intel --dataset intel --global --particles 10000 --out runs/intel-loc
  jaxslam calibrate --dataset victoria-park --algorithm erb-upf --out runs/cal
  jaxslam run --dataset victoria-park --params runs/cal/calibration.json --out runs/vp-cal
"""


class CliError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""


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
    parser = argparse.ArgumentParser(
        prog="jaxslam",
        description="Batched JAX particle filters for SLAM (RB/ERB unscented FastSLAM, SRUPF-GM, GMapping-style).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True

    run = sub.add_parser(
        "run",
        help="run a SLAM filter on a dataset or a built-in simulator and write its outputs",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    run.add_argument("--dataset", default=None,
                     help="dataset name (see `jaxslam datasets`), a path to a CARMEN log or to a ROS bag; "
                          "default: the built-in simulator that suits --algorithm")
    run.add_argument("--algorithm", choices=sorted(ALGORITHMS), default=None,
                     help="filter; default erb-upf for landmark data, srupf-gm for laser data")
    run.add_argument("--particles", type=_positive_int, default=None,
                     help="number of particles (default: 100 landmark, 30 laser)")
    run.add_argument("--seed", type=_nonneg_int, default=0, help="random seed (recorded in summary.json)")
    run.add_argument("--out", type=Path, default=None, help="output folder (created; required unless --resume)")
    run.add_argument("--max-steps", type=_positive_int, default=None,
                     help="stop after this many filter steps (landmark data: scans; laser data: about this many "
                          "keyframes, the log cut where the odometry rule reaches them)")
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
    run.add_argument("--loop-closure", action=argparse.BooleanOptionalAction, default=None,
                     help="laser data: where the tracking's match fails in a mapped place, search up to 4 m and "
                          "8 deg around it and take a clearly better pose (closes large loops such as MIT "
                          "Killian's; a closure whose beams keep ending in known free space over the next 5 m "
                          "is undone). Default: on for srupf-gm, off for the GMapping-style filter")
    run.add_argument("--list-params", action="store_true", help="print the algorithm's parameters and exit")
    run.add_argument("--float64", action="store_true", help="run in double precision (default float32)")
    run.add_argument("--checkpoint-every", type=_positive_int, default=None, metavar="N",
                     help="save the full filter state (particles, maps, weights, position in the log) every N "
                          "steps to OUT/checkpoint.npz, atomically")
    run.add_argument("--resume", type=Path, default=None, metavar="DIR",
                     help="continue the run saved in DIR (its checkpoint.npz and run.json) with its original "
                          "arguments; the result equals an uninterrupted run")
    run.add_argument("--chunk", type=_positive_int, default=None,
                     help="steps per compiled chunk (progress-bar granularity)")
    run.add_argument("--no-progress", action="store_true", help="no progress bar")
    run.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
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
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
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
    if summary is not None:
        print(json.dumps(summary, indent=2, default=json_default))
    return 0


def run_from_args(args: argparse.Namespace) -> dict[str, Any] | None:
    """``jaxslam run``: the parsed arguments as a call of :func:`jaxslam.app.runs.run`
    (``--list-params`` prints the parameters instead; ``--resume`` repeats the
    arguments saved in the folder's ``run.json``)."""
    from jaxslam.app import runs
    from jaxslam.datasets.paths import DataFormatError
    from jaxslam.datasets.registry import DEFAULT_ALGORITHM

    if args.list_params:
        algorithm = args.algorithm or DEFAULT_ALGORITHM[runs.resolve_dataset(args.dataset, None)[2]]
        chosen = ("usable_range", "score_range")  # grid filters: from the log (jaxslam.grid.range_rule)
        for name, default in runs.param_fields(algorithm).items():
            note = "  (indoor logs; chosen from the log's readings unless set: summary.json range_rule)"
            print(f"{name:24s} {default!r}" + (note if name in chosen else ""))
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
        if args.threads is not None:
            run_args["threads"] = args.threads
        return runs.run(out=args.resume, progress=not args.no_progress, plots=not args.no_plots,
                        checkpoint_every=args.checkpoint_every, resume=True, **run_args)
    if args.out is None:
        raise runs.RunError("--out is required (the folder the outputs go to)")
    overrides = dict(args.overrides or [])
    if getattr(args, "params", None) is not None:
        from jaxslam.app.calibrate import load_params_file

        overrides = {**load_params_file(args.params), **overrides}
    return runs.run(
        out=args.out, dataset=args.dataset, algorithm=args.algorithm, particles=args.particles, seed=args.seed,
        max_steps=args.max_steps, overrides=overrides, progress=not args.no_progress,
        chunk=args.chunk, float64=args.float64, plots=not args.no_plots, checkpoint_every=args.checkpoint_every,
        keyframes={"linear": args.linear_update, "angular": args.angular_update, "temporal": args.temporal_update},
        bag={"scan_topic": args.scan_topic, "odom_topic": args.odom_topic, "base_frame": args.base_frame,
             "laser_offset": args.laser_mount},
        rerun=args.rerun, rerun_spawn=args.rerun_spawn,
        max_range=args.max_range, threads=args.threads, loop_closure=args.loop_closure,
    )


def cmd_evaluate(args) -> int:
    from jaxslam.app import runs

    scores = runs.evaluate(args.trajectory, relations=args.relations, gps=args.gps)
    text = json.dumps(scores, indent=2, default=json_default)
    print(text)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text + "\n")
    return 0


def cmd_plot(args) -> int:
    from jaxslam.app.outputs import replot

    for path in replot(args.folder):
        print(path)
    return 0


def cmd_calibrate(args) -> int:
    from jaxslam.app.calibrate import run as run_calibrate

    print(json.dumps(run_calibrate(args), indent=2, default=json_default))
    return 0


def cmd_localize(args) -> int:
    from jaxslam.app.localize import run as run_localize
    from jaxslam.runtime.cache import enable_compilation_cache

    try:
        enable_compilation_cache(None)
    except OSError as err:
        print(f"jaxslam localize: warning: running without the compilation cache: {err}", file=sys.stderr)
    print(json.dumps(run_localize(args), indent=2))
    return 0


COMMANDS = {"calibrate": cmd_calibrate, "localize": cmd_localize, "run": cmd_run, "evaluate": cmd_evaluate, "datasets": cmd_datasets, "plot": cmd_plot}


def main(argv: list[str] | None = None) -> int:
    from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
    from jaxslam.app.runs import RunError

    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return COMMANDS[args.command](args)
    except (CliError, RunError, DatasetNotFoundError, DataFormatError) as err:
        parser.exit(2, f"jaxslam {args.command}: error: {err}\n")
    except KeyboardInterrupt:
        parser.exit(130, "interrupted\n")


def console_main() -> None:
    """The ``jaxslam`` command: :func:`main`, then a quick exit.

    Python's finalization after a run (tearing down some 1200 modules, JAX's compiled
    programs and XLA's CPU client) took 0.35-0.45 s, a tenth of a warm Intel run's
    overhead. When :func:`main` returns, every output file has been written and closed,
    so the exit handlers (:mod:`atexit`: Rerun's flush, logging) run, the standard
    streams are flushed and the process ends with :func:`os._exit`. With a non-daemon
    thread still alive, or without CPython's ``atexit._run_exitfuncs``, it exits the
    usual way. Errors (``SystemExit`` from the parser, tracebacks) take the usual way.
    """
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
