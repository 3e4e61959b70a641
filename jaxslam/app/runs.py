"""What ``jaxslam run`` does, as a function a script can call.

``run(...)`` resolves a dataset (a name in :mod:`jaxslam.datasets.registry`, a path to
a CARMEN log or a ROS bag, or a built-in simulator: :mod:`jaxslam.app.data`), runs the chosen filter, scores it
as the registry says (:mod:`jaxslam.metrics.scoring`: relations, GPS or ground truth)
and writes an output folder (:mod:`jaxslam.app.outputs`): ``summary.json`` — what was run
(algorithm, dataset, particles, seed, steps, ...), timings (``wall_s`` after
compilation, ``compile_s`` apart), resamplings, scores — ``trajectory.tum``, the map or
the landmarks, ``arrays.npz`` and the figures. The command line adapts its arguments
to :func:`run` in :mod:`jaxslam.app.cli`; what a run prints at its end and ``jaxslam
evaluate`` are :mod:`jaxslam.app.report`.

One module, a little over 400 lines: :func:`run` checks the options of both kinds of
run against the data (which options apply to laser logs, bags, landmark sequences),
records them for ``--resume`` and the checkpoint's fingerprint, and dispatches to
:func:`run_landmark` or :func:`run_grid`; those two are short and share the summary's
layout with it.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.runtime.compiler import cpus_allowed, set_threads
from jaxslam.datasets.carmen import scan_range
from jaxslam.datasets.registry import DEFAULT_ALGORITHM, algorithms
from jaxslam.app.data import bag_options, is_bag, kind_of, load_checked_log, resolve_dataset
from jaxslam.app.errors import RunError
from jaxslam.app.outputs import (marked_run, open_live_view, prefetch_plotting, prepare_folder, write_summary,
                                 write_with_figures)

DEFAULT_PARTICLES = {"landmark": 100, "laser": 30}


def param_fields(algorithm: str) -> dict[str, Any]:
    """Each ``Params`` field of the algorithm (for a grid filter, each leaf by its path)
    with its default (scalars as floats)."""
    if kind_of(algorithm) == "landmark":
        from jaxslam.feature.params import Params

        defaults = Params()
        leaves = {name: getattr(defaults, name) for name in defaults._fields}
    else:
        from jaxslam.grid.algorithms import grid_algorithm
        from jaxslam.grid.types import get_path, param_paths

        defaults = grid_algorithm(algorithm).make_params(np.zeros(1, np.float32))
        leaves = {path: get_path(defaults, path) for path in param_paths()}
    values = {}
    for name, value in leaves.items():
        if np.ndim(value) == 0 and not isinstance(value, tuple):
            try:
                value = float(value)
            except (TypeError, ValueError):
                pass
        values[name] = value
    return values


def check_overrides(algorithm: str, overrides: dict[str, float], origin: str = "--set") -> dict[str, Any]:
    """``overrides`` by ``Params`` field (a grid filter's by path), each value checked against
    its specification (:mod:`jaxslam.app.params`); a ``RunError`` naming ``origin``,
    the parameter and the value otherwise."""
    from jaxslam.app.params import check_value

    fields = {}
    for name, value in overrides.items():
        try:
            fields[check_value(algorithm, name, value, origin)] = value
        except ValueError as err:
            raise RunError(str(err)) from None
    return fields


# --------------------------------------------------------------------------- landmark


def run_landmark(info, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype,
                 checkpoint=None, viz=None, prefetch=False):
    """Run a landmark filter on ``info``'s sequence and score it: ``(summary, arrays,
    write_files)``, the figures' data (:func:`jaxslam.app.outputs.landmark_arrays`) and a
    function that writes the run's files. ``prefetch``: import the plotting module on
    a thread once the data is loaded. The other arguments are :func:`run`'s options
    that a landmark run uses, passed on by name."""
    from jaxslam.feature.experiment import run_landmark_slam
    from jaxslam.metrics.scoring import score_landmark_run
    from jaxslam.app.outputs import landmark_arrays, write_landmark_outputs

    loading = time.perf_counter()
    sequence = info.load(seed=seed, max_steps=max_steps)
    # the live view every 50 steps, with the plain run's chunk (its compiled program)
    live = {} if viz is None else {"callback": viz.landmark_callback(np.asarray(sequence.times)),
                                   "callback_every": 50}
    load_s = time.perf_counter() - loading
    if prefetch:
        prefetch_plotting()
    result = run_landmark_slam(
        sequence, algorithm=algorithm, particles=particles, seed=seed, params=overrides,
        progress=progress, chunk=chunk or 512, dtype=dtype,
        checkpoint=checkpoint, **live,
    )
    if viz is not None:
        viz.landmark_run(result, np.asarray(sequence.times))
    summary: dict[str, Any] = {
        "algorithm": algorithm, "dataset": info.name, "particles": particles, "seed": seed,
        "steps": result.steps, "wall_s": result.wall_s, "compile_s": result.compile_s,
        "steps_per_s": result.steps / result.wall_s if result.wall_s > 0 else None,
        "resamplings": result.resamplings, "landmarks": result.landmarks,
        "dtype": np.dtype(dtype).name, "load_s": load_s,
    }
    finite = bool(np.all(np.isfinite(result.trajectory)))
    summary["finite"] = finite
    # numerical and input trouble handled inside the filter, counted over the run
    summary["repairs"] = {name: int(np.sum(result.info[name])) for name in (
        "num_invalid_controls", "num_invalid_observations", "num_nonfinite_particles",
        "num_rejected_landmarks", "num_cov_repairs") if name in result.info}
    summary["input_recovered"] = dict(getattr(sequence, "meta", {}).get("recovered", {}))
    scored = score_landmark_run(info, result, sequence)
    summary.update(scored.scores)
    arrays = landmark_arrays(result, title=f"{algorithm}, {info.name}, {particles} particles",
                             reference_xy=scored.reference_xy, reference_label=scored.reference_label,
                             true_landmarks=scored.true_landmarks)
    comment = f"jaxslam {algorithm} on {info.name}, {particles} particles, seed {seed}"
    return summary, arrays, lambda: write_landmark_outputs(out, result, arrays, comment)


# --------------------------------------------------------------------------- grid


def run_grid(info, path, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype,
             checkpoint=None, keyframes=None, bag=None, viz=None, max_range=None, prefetch=False, loop_closure=None,
             max_odometry_step=None, mixed_geometry=None, start_map=None, initial_pose=None, localize_first=False):
    """Run a grid filter on a laser log and score it: ``(summary, arrays, write_files)``,
    the figures' data (:func:`jaxslam.app.outputs.grid_arrays`) and a function that writes
    the run's files. ``prefetch``: import the plotting module on a thread once the log
    is loaded. The other arguments are :func:`run`'s options that a grid run uses,
    passed on by name."""
    from jaxslam.grid import experiment as grid_experiment
    from jaxslam.grid.paged import PoolLimitError
    from jaxslam.metrics.scoring import score_grid_run
    from jaxslam.app.outputs import grid_arrays, write_grid_outputs

    name = info.name if info is not None else str(path)
    loading = time.perf_counter()
    temporal = (keyframes or {}).get("temporal", overrides.get("keyframes.temporal_update", -1.0))
    log, log_cache, log_checks = load_checked_log(info, path, seed, bag, max_range, mixed_geometry,
                                                  max_odometry_step, temporal is not None and float(temporal) > 0)
    load_s = time.perf_counter() - loading
    if prefetch:
        prefetch_plotting()
    start = {}
    if start_map is not None:
        start = {"start_map": start_map, "initial_pose": initial_pose}
        if localize_first:
            first, start["initial_pose"], localized = localized_start(log, start_map, seed)
            log = scan_range(log, first)
    live = None
    if viz is not None:
        live = _grid_live_log(viz, log, chunk)
        checkpoint, chunk = live, live.every
    try:
        result = grid_experiment.run_grid_slam(
            log, algorithm=algorithm, particles=particles, seed=seed, params=overrides,
            config=None if loop_closure is None else {"closure": bool(loop_closure)},
            progress=progress, max_keyframes=max_steps, dtype=dtype, **({"chunk": chunk} if chunk else {}),
            **({"checkpoint": checkpoint} if checkpoint is not None else {}),
            **{f"{k}_update": v for k, v in (keyframes or {}).items()}, **start,
        )
    except PoolLimitError as err:
        raise RunError(f"--particles {particles}: {err}") from None
    if live is not None and not np.array_equal(live.keyframes, result.keyframes):
        raise RunError("the live view placed the keyframes differently from the run (a bug); its recording is wrong")
    summary: dict[str, Any] = {
        "algorithm": algorithm, "dataset": name, "particles": particles, "seed": seed,
        "scans": int(result.scan_times.shape[0]), "keyframes": int(result.keyframes.shape[0]),
        **{k: result.summary()[k] for k in ("keyframe_rule", "range_rule", "maps", "map_shape", "map_growths",
                                            "map_growth_steps", "map_recompilations", "xla_compiler_options")},
        **result.closure_summary(),
        "wall_s": result.wall_s, "compile_s": result.compile_s,
        "keyframes_per_s": result.keyframes.shape[0] / result.wall_s if result.wall_s > 0 else None,
        "resamplings": result.resamplings, "dtype": np.dtype(dtype).name, "loop_closure": bool(result.config.closure),
        "coarse_iterations": int(result.config.coarse_iterations),
        "recover_radius": float(result.config.recover_radius),
        "tracking.refused_noise_scale": result.params.get("tracking.refused_noise_scale"),
        "finite": bool(np.all(np.isfinite(result.trajectory))),
        "log_stats": getattr(log, "stats", {}), "load_s": load_s, "log_cache": log_cache,
        "max_range": float(getattr(log, "max_range", np.nan)), "no_return": getattr(log, "no_return", {}),
        "odometry_repair": getattr(log, "odometry_repair", {}), "log_checks": log_checks,
    }
    if start_map is not None:
        summary["start_map"] = {"map": str(start_map.source), "shape": list(start_map.shape),
                                "origin": list(start_map.origin),
                                "initial_pose": [float(v) for v in result.trajectory[0]],
                                "pose_from": ("localization" if localize_first else
                                              "--initial-pose" if initial_pose is not None else
                                              "the saved run's last pose" if start_map.pose is not None else
                                              "the map frame's origin")}
        if result.start_match is not None:
            summary["start_map"]["first_scan_match"] = result.start_match
        if localize_first:
            summary["start_map"]["localization"] = localized
    if path is not None and is_bag(path):
        summary["bag"] = dict(log.params)  # the topics and frames used
    summary.update(score_grid_run(info, result, log))
    arrays = grid_arrays(result, title=f"{algorithm}, {name}, {particles} particles")
    comment = f"jaxslam {algorithm} on {name}, {particles} particles, seed {seed}"
    return summary, arrays, lambda: write_grid_outputs(out, result, arrays, comment)


# --------------------------------------------------------------------------- continuing a saved map

LOCALIZE_PARTICLES = 20000  # --localize-first: MCL's capacity (the number in use adapts)
LOCALIZE_SCANS = 300  # ... and the first scans it may take to converge


def _start_map(start_map, initial_pose, localize_first: bool, kind: str, algorithm: str):
    """The saved map of ``--start-map``, read and checked before anything runs, or None."""
    if start_map is None:
        if initial_pose is not None or localize_first:
            raise RunError("--initial-pose and --localize-first need --start-map")
        return None
    if kind != "laser":
        raise RunError(f"--start-map applies to the grid filters (laser data), not {algorithm!r}")
    if initial_pose is not None and localize_first:
        raise RunError("--initial-pose and --localize-first exclude each other")
    if initial_pose is not None and (len(initial_pose) != 3 or not np.all(np.isfinite(initial_pose))):
        raise RunError(f"--initial-pose {list(initial_pose)}: must be three finite numbers (x y theta)")
    from jaxslam.grid.experiment import RESOLUTION
    from jaxslam.grid.mapfile import load_map
    from jaxslam.grid.startmap import StartMapError, check_start_map

    grid = load_map(start_map, require_free=localize_first)
    try:
        check_start_map(grid, RESOLUTION)
    except StartMapError as err:
        raise RunError(f"--start-map {err}") from None
    return grid


def localized_start(log, grid, seed: int, particles: int = LOCALIZE_PARTICLES, scans: int = LOCALIZE_SCANS):
    """``(scan, pose, report)``: where mapping starts after Monte Carlo localization
    from a uniform start over the map's free space
    (:func:`jaxslam.localization.experiment.localize`) on the first ``scans`` scans.

    The cloud has converged by the localizer's own rule
    (:func:`jaxslam.localization.experiment.self_convergence`: within 0.5 m, holding
    90 % of the weight, at 10 measurements in a row); it then keeps tracking to the
    last of those scans, whose estimate starts the mapping there. A
    :class:`~jaxslam.app.errors.RunError` if the cloud does not converge."""
    from jaxslam.localization.experiment import localize, self_convergence

    result = localize(log, grid, particles=particles, seed=seed, max_steps=scans, snapshots=0)
    first = self_convergence(result)
    if first is None:
        raise RunError(f"--localize-first: the localization in {str(grid.source)!r} did not converge in the first "
                       f"{result.trajectory.shape[0]} scans of the log (no cloud within 0.5 m holding 90 % of the "
                       "weight at 10 measurements in a row); give --initial-pose")
    scan = int(result.trajectory.shape[0] - 1)  # localize's step s is scan s
    report = {"particles": particles, "converged_scan": int(first), "start_scan": scan,
              "rule": {"spread_m": 0.5, "cluster_weight": 0.9, "hold": 10}, "wall_s": result.wall_s}
    return scan, result.trajectory[scan], report


# --------------------------------------------------------------------------- live view (Rerun)


def _grid_live_log(viz, log, chunk):
    """Follow a grid run (its keyframes are collected as the run goes), one update per
    chunk of the run: the plain run's chunk, so the live view runs its compiled program."""
    from jaxslam.grid.driver import DEFAULT_CHUNK
    from jaxslam.viz.rerun_log import GridLiveLog

    return GridLiveLog(viz, log, every=chunk or DEFAULT_CHUNK)


# --------------------------------------------------------------------------- entry points


def run(
    out: str | Path,
    dataset: str | None = None,
    algorithm: str | None = None,
    particles: int | None = None,
    seed: int = 0,
    max_steps: int | None = None,
    overrides: dict[str, float] | None = None,
    progress: bool = True,
    chunk: int | None = None,
    float64: bool = False,
    plots: bool = True,
    checkpoint_every: int | None = None,
    resume: bool = False,
    keyframes: dict[str, float] | None = None,
    bag: dict[str, Any] | None = None,
    rerun: str | Path | None = None,
    rerun_spawn: bool = False,
    max_range: float | None = None,
    threads: int | str | None = None,
    loop_closure: bool | None = None,
    max_odometry_step: float | None = None,
    mixed_geometry: str | None = None,
    start_map: str | Path | None = None,
    initial_pose=None,
    localize_first: bool = False,
) -> dict[str, Any]:
    """Run one filter and write its output folder; returns the summary dict.

    The keywords are the options of ``jaxslam run``, one for one: ``run.json``
    records them by name and ``--resume`` calls this function with them again
    (:func:`jaxslam.app.cli.saved_arguments` reads this signature), so they stay
    flat rather than grouped.

    ``start_map`` (grid filters): a saved map (a run folder, ``map.npz`` or a
    ``map_server`` YAML, :func:`jaxslam.grid.mapfile.load_map`) that every particle
    starts from, so that the run continues it (:mod:`jaxslam.grid.startmap`);
    ``initial_pose`` ``(x, y, theta)`` places the first scan in it (default: the saved
    run's last pose where ``map.npz`` records it, else ``(0, 0, 0)``);
    ``localize_first`` localizes the first scans in the map (:func:`localized_start`)
    and maps from the last of them on.

    With ``checkpoint_every`` the full filter state is saved atomically to
    ``out/checkpoint.npz`` every that many steps; ``resume`` continues from it (and
    refuses a checkpoint of a different run). The run's arguments are recorded in
    ``out/run.json`` so that ``jaxslam run --resume OUT`` needs nothing else.
    ``keyframes`` (laser data only) sets any of ``linear``, ``angular``, ``temporal``
    of the keyframe rule (see :func:`jaxslam.grid.experiment.keyframe_rule`).
    ``bag`` (ROS bags only) sets any of ``scan_topic``, ``odom_topic``, ``base_frame``,
    ``laser_offset`` for :func:`jaxslam.datasets.rosbag.load_rosbag`; the trajectory's
    stamps are the scans' header stamps (the bag's time base).
    ``rerun`` (a ``.rrd`` path) and/or ``rerun_spawn`` log the run to Rerun as it goes
    (:mod:`jaxslam.viz.rerun_log`; needs ``pip install "jaxslam[viz]"``).
    ``max_range`` (CARMEN logs) sets the range limit, in place of the logged one and
    of the "no return" sentinel detection (:func:`jaxslam.datasets.no_return.detect_no_return`).
    ``float64`` runs the filter in double precision: JAX's 64-bit mode is switched on
    for this run only (``jax.enable_x64``), the default float32 path never touches it.
    ``loop_closure`` (laser data) turns the tracking's loop-closure search
    (:mod:`jaxslam.grid.closure`) on or off; None keeps the algorithm's default (on for
    SRUPF-GM, off for the GMapping-style filter: :data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`).
    ``run.json`` and a checkpoint's fingerprint record what ran, default or not.
    ``mixed_geometry`` (CARMEN logs): ``"pad"`` pads the scans of a log whose beam
    geometry changes to a common length (:func:`jaxslam.datasets.carmen.load_carmen`),
    ``"raise"`` (the default) refuses such a log.
    ``max_odometry_step`` (laser data; m, default
    :data:`jaxslam.datasets.checks.MAX_ODOMETRY_STEP`): a log whose odometry moves
    farther between two scans is refused (:func:`jaxslam.datasets.checks.check_laser_log`,
    which also refuses logs of fewer than two scans or without a single return).
    The folder is written whole or marked as not (:func:`jaxslam.app.outputs.marked_run`:
    ``run.json`` ``status``).
    ``threads`` sizes XLA's CPU thread pool (a count or ``"all"``; default
    ``$JAXSLAM_THREADS``, else :func:`jaxslam.runtime.compiler.auto_threads`):
    :func:`jaxslam.runtime.compiler.set_threads`, which can act only before the process's
    first JAX computation; ``summary.json`` ``xla_threads`` says what was in effect.
    """
    import jax
    import jax.numpy as jnp

    info, path, kind = resolve_dataset(dataset, algorithm)
    algorithm = algorithm or DEFAULT_ALGORITHM[kind]
    if kind_of(algorithm) != kind:
        name = info.name if info is not None else str(path)
        choices = algorithms(kind)
        raise RunError(f"algorithm {algorithm!r} needs {kind_of(algorithm)} data but dataset {name!r} is "
                       f"{kind} data; use one of: {', '.join(choices)}")
    if info is not None and not info.simulated:
        info.paths()  # raises DatasetNotFoundError naming what is missing
    overrides = dict(overrides or {})
    fields = check_overrides(algorithm, overrides)
    keyframes = {k: float(v) for k, v in (keyframes or {}).items() if v is not None}
    unknown = set(keyframes) - {"linear", "angular", "temporal"}
    if unknown:
        raise RunError(f"unknown keyframe threshold(s) {sorted(unknown)}; use linear, angular, temporal")
    if kind == "laser":
        for key, value in keyframes.items():
            check_overrides(algorithm, {f"keyframes.{key}_update": value}, origin=f"--{key}-update:")
    if keyframes and kind != "laser":
        raise RunError("keyframe thresholds (--linear-update/--angular-update/--temporal-update) apply to laser "
                       "data only; the landmark filters process every scan")
    bag = bag_options(bag, path)
    if (rerun is not None or rerun_spawn) and (checkpoint_every is not None or resume):
        raise RunError("--rerun/--rerun-spawn cannot be combined with --checkpoint-every/--resume")
    particles = particles or DEFAULT_PARTICLES[kind]
    try:
        xla_threads = set_threads(threads, algorithm, particles)
    except ValueError as err:
        raise RunError(f"--threads {threads}: {err}" if threads is not None else str(err)) from None
    dtype = jnp.float64 if float64 else jnp.float32
    out = prepare_folder(Path(out))
    dataset_name = info.name if info is not None else str(Path(path).resolve())
    run_args = {"dataset": dataset_name, "algorithm": algorithm, "particles": particles, "seed": seed,
                "max_steps": max_steps, "overrides": overrides, "float64": float64, "chunk": chunk}
    if keyframes:
        run_args["keyframes"] = keyframes
    if bag:
        run_args["bag"] = bag
    if max_range is not None:
        run_args["max_range"] = _log_metres("--max-range", max_range, kind, info, "CARMEN logs")
    if threads is not None:
        run_args["threads"] = threads
    if max_odometry_step is not None:
        run_args["max_odometry_step"] = _log_metres("--max-odometry-step", max_odometry_step, kind, info,
                                                    "laser logs (CARMEN logs and ROS bags)")
    if mixed_geometry is not None:
        if mixed_geometry not in ("raise", "pad"):
            raise RunError(f"--mixed-geometry must be 'raise' or 'pad', got {mixed_geometry!r}")
        if kind != "laser" or (info is not None and info.simulated) or (path is not None and is_bag(path)):
            raise RunError("--mixed-geometry applies to CARMEN logs only")
        run_args["mixed_geometry"] = mixed_geometry
    grid = _start_map(start_map, initial_pose, localize_first, kind, algorithm)
    if grid is not None:
        run_args["start_map"] = str(Path(grid.source).resolve())
        if initial_pose is not None:
            run_args["initial_pose"] = [float(v) for v in initial_pose]
        if localize_first:
            run_args["localize_first"] = True
    if kind == "laser" and max_steps is not None and max_steps < 2:
        raise RunError(f"--max-steps {max_steps}: a laser run needs at least 2 keyframes")
    if loop_closure is not None and kind != "laser":
        raise RunError("--loop-closure / --no-loop-closure apply to laser data only")
    if kind == "laser":
        # What runs, recorded even when it is the algorithm's default: a checkpoint's
        # fingerprint then names it, and a default that changes between versions
        # cannot silently switch the search on or off in a resumed run.
        from jaxslam.grid.algorithms import grid_algorithm

        entry = grid_algorithm(algorithm)
        loop_closure = entry.config_default("closure") if loop_closure is None else bool(loop_closure)
        run_args["loop_closure"] = loop_closure
    checkpoint = None
    if checkpoint_every is not None or resume:
        from jaxslam.runtime.checkpoint import Checkpoint

        fingerprint = {k: v for k, v in run_args.items() if k not in ("chunk", "threads")}
        if kind == "laser":  # a default that changed between versions must not change a resumed run
            fingerprint["coarse_iterations"] = entry.config_default("coarse_iterations")
            fingerprint["recover_radius"] = entry.config_default("recover_radius")
            fingerprint["track_refused_noise_scale"] = float(entry.param_default("tracking.refused_noise_scale"))
        checkpoint = Checkpoint(out / "checkpoint.npz", every=checkpoint_every, fingerprint=fingerprint,
                                resume=resume)
        if resume and not checkpoint.path.exists():
            raise RunError(f"--resume: no checkpoint in {str(out)!r} (run with --checkpoint-every N first)")
    with marked_run(out, run_args) as stage:
        return _run_and_write(out, stage, run_args, info, path, kind, algorithm, particles, seed, max_steps,
                              overrides, fields, progress, chunk, dtype, float64, plots, checkpoint, keyframes, bag,
                              rerun, rerun_spawn, dataset_name, max_range, loop_closure, resume, xla_threads)


def _log_metres(option: str, value, kind: str, info, logs: str) -> float:
    """A length option of recorded laser logs, checked."""
    if kind != "laser" or (info is not None and info.simulated):
        raise RunError(f"{option} applies to {logs} only")
    if not (np.isfinite(value) and value > 0):
        raise RunError(f"{option} must be a positive number of metres, got {value}")
    return float(value)


def _run_and_write(out, stage, run_args, info, path, kind, algorithm, particles, seed, max_steps, overrides,
                   fields, progress, chunk, dtype, float64, plots, checkpoint, keyframes, bag, rerun, rerun_spawn,
                   dataset_name, max_range, loop_closure, resume, xla_threads):
    """The run itself, its files written to ``stage`` (see :func:`marked_run`)."""
    import jax

    from jaxslam.runtime.cache import CompileCounter

    started = time.time()
    runner = run_landmark if kind == "landmark" else run_grid
    args = (info, algorithm, particles, seed, stage, max_steps, fields, progress, chunk, dtype)
    if kind == "laser":
        args = (info, path) + args[1:]
    extra = {"keyframes": keyframes} if keyframes else {}
    # The matplotlib import (about a second of Python) overlaps the filter loop, where
    # XLA releases the GIL; started before the loading it slowed a cached load 9x.
    extra["prefetch"] = bool(plots)
    if max_range is not None:
        extra["max_range"] = float(max_range)
    if loop_closure is not None:
        extra["loop_closure"] = bool(loop_closure)
    for name in ("max_odometry_step", "mixed_geometry", "initial_pose", "localize_first"):
        if name in run_args:
            extra[name] = run_args[name]
    if "start_map" in run_args:
        extra["start_map"] = _start_map(run_args["start_map"], None, False, kind, algorithm)
    if bag:
        extra["bag"] = bag
    viz = open_live_view(rerun, rerun_spawn, Path(dataset_name).name)
    if viz is not None:
        extra["viz"] = viz
    precision = jax.enable_x64(True) if float64 else contextlib.nullcontext()
    try:
        with precision, CompileCounter() as compilations:
            summary, arrays, write_files = runner(*args, checkpoint=checkpoint, **extra)
    finally:
        if viz is not None:
            viz.close()
    if rerun is not None:
        summary["rerun"] = str(rerun)
    summary["resumed"] = bool(resume)
    summary["overrides"] = overrides
    summary["jaxslam_version"] = __import__("jaxslam").__version__
    summary["jax_version"] = jax.__version__
    # XLA programs compiled or loaded from the persistent cache (jaxslam.runtime.cache)
    summary["compilations"] = compilations.as_dict()
    summary["cache_dir"] = jax.config.jax_compilation_cache_dir
    summary["xla_threads"] = xla_threads
    # XLA's CPU compiler builds another program for another set of usable CPUs
    # (taskset), and on chaotic logs that can change the result (README, "Compilation cache")
    summary["cpus_allowed"] = cpus_allowed()
    # load_s, output_s: reading the data; writing the files and drawing the figures
    # (seconds; the two overlap)
    writing = time.perf_counter()
    write_with_figures(stage, write_files, arrays if plots else None)
    summary["output_s"] = time.perf_counter() - writing
    summary["total_s"] = time.time() - started
    return write_summary(stage / "summary.json", summary)


