"""What ``jaxslam run`` / ``evaluate`` do, as functions a script can call.

``run(...)`` resolves a dataset (a name in :mod:`jaxslam.datasets.registry`, a path to
a CARMEN log or a ROS bag, or a built-in simulator), runs the chosen filter, scores it
as the registry says (:mod:`jaxslam.metrics.scoring`: relations, GPS or ground truth)
and writes an output folder (:mod:`jaxslam.app.outputs`): ``summary.json`` — what was run
(algorithm, dataset, particles, seed, steps, ...), timings (``wall_s`` after
compilation, ``compile_s`` apart), resamplings, scores — ``trajectory.tum``, the map or
the landmarks, ``arrays.npz`` and the figures. The command line adapts its arguments
to :func:`run` in :mod:`jaxslam.app.cli`.
"""

from __future__ import annotations

import contextlib
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.runtime.compiler import cpus_allowed, set_threads
from jaxslam.datasets.checks import MAX_ODOMETRY_STEP, check_laser_log
from jaxslam.datasets.paths import DatasetNotFoundError
from jaxslam.datasets.registry import ALGORITHMS, DATASETS, DEFAULT_ALGORITHM, DatasetInfo, algorithms, lookup
from jaxslam.app.errors import RunError
from jaxslam.app.outputs import marked_run, prefetch_plotting, prepare_folder, write_summary, write_with_figures

DEFAULT_PARTICLES = {"landmark": 100, "laser": 30}


def _kind_of(algorithm: str) -> str:
    return ALGORITHMS[algorithm]


CARMEN_SUFFIXES = (".clf", ".log", ".carmen", ".gz")
"""Names of CARMEN logs (plain or gzipped; any existing file is read as one unless it
is a ROS bag)."""

FILE_KINDS = (
    "a CARMEN log file (.clf, .log or .carmen, plain or gzipped as .gz), a ROS 1 bag (.bag) or a ROS 2 bag "
    "(its folder, with metadata.yaml, or its .db3 or .mcap file)"
)
"""The files ``--dataset`` accepts besides the dataset names (:func:`resolve_dataset`)."""


def resolve_dataset(dataset: str | None, algorithm: str | None) -> tuple[DatasetInfo | None, Path | None, str]:
    """``(info, path, kind)`` for a dataset name, a path to a CARMEN log or a ROS bag,
    or None (the built-in simulator that suits ``algorithm``)."""
    from jaxslam.datasets.rosbag import ROSBAG_SUFFIXES

    if dataset is None:
        kind = _kind_of(algorithm) if algorithm else "landmark"
        return lookup("sim-landmarks" if kind == "landmark" else "sim-laser"), None, kind
    candidate = Path(dataset).expanduser()
    if candidate.suffix in CARMEN_SUFFIXES + ROSBAG_SUFFIXES or candidate.exists():
        if not candidate.exists():
            what = "ROS bag" if candidate.suffix in ROSBAG_SUFFIXES else "CARMEN log"
            raise DatasetNotFoundError(f"{what} {str(candidate)!r} does not exist")
        return None, candidate, "laser"
    try:
        info = lookup(dataset)
    except KeyError:
        raise RunError(f"unknown dataset {dataset!r}: no such dataset name nor file; --dataset takes a dataset "
                       f"name ({', '.join(DATASETS)}; `jaxslam datasets` says which are found), {FILE_KINDS}") from None
    return info, None, info.kind


def param_fields(algorithm: str) -> dict[str, Any]:
    """Each ``Params`` field of the algorithm (for a grid filter, each leaf by its path)
    with its default (scalars as floats)."""
    if _kind_of(algorithm) == "landmark":
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
    a thread once the data is loaded."""
    from jaxslam.feature.experiment import run_landmark_slam
    from jaxslam.metrics.scoring import score_landmark_run
    from jaxslam.app.outputs import landmark_arrays, write_landmark_outputs

    loading = time.perf_counter()
    sequence = info.load(seed=seed, max_steps=max_steps)
    live = {} if viz is None else {"callback": viz.landmark_callback(np.asarray(sequence.times))}
    load_s = time.perf_counter() - loading
    if prefetch:
        prefetch_plotting()
    result = run_landmark_slam(
        sequence, algorithm=algorithm, particles=particles, seed=seed, params=overrides,
        progress=progress, chunk=min(chunk or 512, 50) if viz is not None else chunk or 512, dtype=dtype,
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


def _load_log(info, path, seed, bag, max_range, mixed_geometry=None):
    """The laser log of a registry entry, a ROS bag or a CARMEN log path, and how the
    log cache served it (:mod:`jaxslam.datasets.log_cache`; CARMEN logs only, in the
    compilation-cache folder when that is on)."""
    if path is not None and _is_bag(path):
        from jaxslam.datasets.paths import DataFormatError
        from jaxslam.datasets.rosbag import load_rosbag

        try:
            return load_rosbag(path, **(bag or {})), "off"
        except (DataFormatError, FileNotFoundError):
            raise
        except Exception as err:  # noqa: BLE001 - any failure of the bag reader on damaged bytes
            # DataFormatError joins a parser's multi-line message into one line
            detail = f"{type(err).__name__}: {err}" if str(err).strip() else type(err).__name__
            raise DataFormatError(path, None, f"cannot read the bag ({detail})") from None
    options = {"max_range": max_range} if max_range is not None else {}
    if mixed_geometry is not None:
        options["mixed_geometry"] = mixed_geometry
    if info is not None and info.loader != "carmen":
        return info.load(seed=seed, **options), "off"
    from jaxslam.datasets.log_cache import load_carmen_cached

    if info is not None:
        path, options = info.paths()[0], {**info.options, **options}
    return load_carmen_cached(path, _log_cache_folder(), **options)


def load_checked_log(info, path, seed=0, bag=None, max_range=None, mixed_geometry=None, max_odometry_step=None,
                     temporal=False):
    """``(log, log_cache, log_checks)``: the laser log of a registry entry ``info`` or
    a ``path`` (CARMEN log or ROS bag), how the log cache served it, and what
    :func:`jaxslam.datasets.checks.check_laser_log` found (a log that cannot give a
    true map raises ``DataFormatError`` naming the file and the scan). A warning line
    says when the scan stamps do not advance."""
    log, log_cache = _load_log(info, path, seed, bag, max_range, mixed_geometry)
    log_checks = check_laser_log(log, MAX_ODOMETRY_STEP if max_odometry_step is None else max_odometry_step,
                                 temporal=temporal)
    if not log_checks["stamps_advance"]:
        print(f"jaxslam run: warning: {log.path}: its scan stamps do not advance ({log_checks['scans']} scans over "
              f"{log_checks['stamp_span_s']:g} s); trajectory.tum carries them as logged", file=sys.stderr)
    return log, log_cache, log_checks


def _log_cache_folder() -> str | None:
    """The compilation-cache folder (the log cache lives beside the compiled programs),
    or None when that cache is off."""
    import jax

    return jax.config.jax_compilation_cache_dir


def run_grid(info, path, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype,
             checkpoint=None, keyframes=None, bag=None, viz=None, max_range=None, prefetch=False, loop_closure=None,
             max_odometry_step=None, mixed_geometry=None):
    """Run a grid filter on a laser log and score it: ``(summary, arrays, write_files)``,
    the figures' data (:func:`jaxslam.app.outputs.grid_arrays`) and a function that writes
    the run's files. ``prefetch``: import the plotting module on a thread once the log
    is loaded."""
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
            **{f"{k}_update": v for k, v in (keyframes or {}).items()},
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
        "track_refused_noise_scale": result.params.get("tracking.refused_noise_scale"),
        "finite": bool(np.all(np.isfinite(result.trajectory))),
        "log_stats": getattr(log, "stats", {}), "load_s": load_s, "log_cache": log_cache,
        "max_range": float(getattr(log, "max_range", np.nan)), "no_return": getattr(log, "no_return", {}),
        "odometry_repair": getattr(log, "odometry_repair", {}), "log_checks": log_checks,
    }
    if path is not None and _is_bag(path):
        summary["bag"] = dict(log.params)  # the topics and frames used
    summary.update(score_grid_run(info, result, log))
    arrays = grid_arrays(result, title=f"{algorithm}, {name}, {particles} particles")
    comment = f"jaxslam {algorithm} on {name}, {particles} particles, seed {seed}"
    return summary, arrays, lambda: write_grid_outputs(out, result, arrays, comment)


# --------------------------------------------------------------------------- live view (Rerun)


def _open_viz(rerun_path, rerun_spawn, name):
    """A :class:`jaxslam.viz.rerun_log.RerunLog`, or a RunError naming the install command."""
    if rerun_path is None and not rerun_spawn:
        return None
    try:
        from jaxslam.viz.rerun_log import RerunLog

        return RerunLog(rerun_path, spawn=rerun_spawn, name=f"jaxslam {name}")
    except ImportError as err:
        raise RunError(f"--rerun/--rerun-spawn: {err}") from None


def _grid_live_log(viz, log, chunk):
    """Follow a grid run (its keyframes are collected as the run goes)."""
    from jaxslam.viz.rerun_log import GridLiveLog

    return GridLiveLog(viz, log, every=min(chunk or 100, 100))


# --------------------------------------------------------------------------- ROS bags

BAG_OPTIONS = ("scan_topic", "odom_topic", "base_frame", "laser_offset")


def _is_bag(path) -> bool:
    from jaxslam.datasets.rosbag import is_rosbag

    return is_rosbag(path)


def _bag_options(bag: dict | None, path) -> dict:
    """The ROS bag options that are set; an error if set for something that is not a bag."""
    options = {k: v for k, v in (bag or {}).items() if v is not None}
    unknown = set(options) - set(BAG_OPTIONS)
    if unknown:
        raise RunError(f"unknown ROS bag option(s) {sorted(unknown)}; use {', '.join(BAG_OPTIONS)}")
    if options and (path is None or not _is_bag(path)):
        raise RunError("--scan-topic/--odom-topic/--base-frame/--laser-mount apply to ROS bags only "
                       "(a .bag file, a ROS 2 bag folder, .mcap or .db3)")
    if "laser_offset" in options:
        options["laser_offset"] = [float(v) for v in options["laser_offset"]]
        if not np.isfinite(options["laser_offset"]).all():
            raise RunError(f"--laser-mount {' '.join(map(str, options['laser_offset']))}: must be three finite numbers")
    return options


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
) -> dict[str, Any]:
    """Run one filter and write its output folder; returns the summary dict.

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
    if _kind_of(algorithm) != kind:
        name = info.name if info is not None else str(path)
        choices = algorithms(kind)
        raise RunError(f"algorithm {algorithm!r} needs {_kind_of(algorithm)} data but dataset {name!r} is "
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
    bag = _bag_options(bag, path)
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
        if kind != "laser" or (info is not None and info.simulated) or (path is not None and _is_bag(path)):
            raise RunError("--mixed-geometry applies to CARMEN logs only")
        run_args["mixed_geometry"] = mixed_geometry
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
    for name in ("max_odometry_step", "mixed_geometry"):
        if name in run_args:
            extra[name] = run_args[name]
    if bag:
        extra["bag"] = bag
    viz = _open_viz(rerun, rerun_spawn, Path(dataset_name).name)
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


# --------------------------------------------------------------------------- the run's report

# The files of an output folder, in the order the report names them.
OUTPUT_FILES = ("summary.json", "trajectory.tum", "landmarks.csv", "map.pgm", "map.yaml", "map.png",
                "trajectory.png", "map_trajectory.png", "health.png", "arrays.npz", "run.json", "checkpoint.npz")


def _number(value, digits: int) -> str:
    """``value`` with ``digits`` decimals; ``n/a`` for None or NaN."""
    if value is None or not np.isfinite(value):
        return "n/a"
    return f"{value:.{digits}f}"


def _score_rows(summary: dict[str, Any]) -> list[tuple[str, str]]:
    from jaxslam.metrics.scoring import matched_counts

    counted = matched_counts(summary)
    rows = []
    if "trans_err_mean_m" in summary:
        scored, total, _ = counted
        rows.append(("relations error", f"{_number(summary['trans_err_mean_m'], 3)} m mean, "
                     f"{_number(summary['trans_err_median_m'], 3)} m median, "
                     f"{_number(summary['trans_err_max_m'], 3)} m max ({summary['n_trans_err_over_0_5m']} over "
                     f"0.5 m), {_number(summary['rot_err_mean_deg'], 2)} deg mean; {scored} of {total} scored"))
    if "gps_mean_m" in summary:
        scored, total, _ = counted
        rows.append(("GPS error", f"{_number(summary['gps_mean_m'], 2)} m mean, {_number(summary['gps_rms_m'], 2)} "
                     f"m RMS, {_number(summary['gps_max_m'], 2)} m max; {scored} of {total} fixes used"))
    if "pos_err_mean_m" in summary:
        text = (f"{_number(summary['pos_err_mean_m'], 3)} m mean, {_number(summary['pos_err_rms_m'], 3)} m RMS, "
                f"{_number(summary['pos_err_max_m'], 3)} m max against the ground truth")
        if "nees_mean" in summary:
            text += f"; pose NEES {_number(summary['nees_mean'], 2)} (consistent: {summary['nees_expected']:g})"
        rows.append(("position error", text))
    return rows or [("score", "none: no reference for this data (relations, GPS or ground truth)")]


def report(summary: dict[str, Any], out: str | Path) -> str:
    """A few lines for the terminal at the end of a run: what ran, its score, its times
    and where its files are (the whole summary is ``out/summary.json``).

    Args:
        summary: what :func:`run` returned.
        out: the output folder.
    """
    out = Path(out)
    if "keyframes" in summary:  # laser data
        steps = (f"{summary['scans']} scans, {summary['keyframes']} keyframes, {summary['resamplings']} "
                 f"resamplings, {summary.get('closures', 0)} loop closures")
        if summary.get("closures_undone"):
            steps += f" ({summary['closures_undone']} undone)"
        rate, unit = summary.get("keyframes_per_s"), "keyframes/s"
    else:
        steps = f"{summary['steps']} steps, {summary['resamplings']} resamplings, {summary['landmarks']} landmarks"
        rate, unit = summary.get("steps_per_s"), "steps/s"
    rows = [("filter", steps), *_score_rows(summary)]
    if not summary.get("finite", True):
        rows.append(("warning", "the trajectory has non-finite poses"))
    repairs = {k: v for k, v in summary.get("repairs", {}).items() if v}
    if repairs:
        rows.append(("repaired", ", ".join(f"{v} {k.removeprefix('num_').replace('_', ' ')}"
                                           for k, v in repairs.items())))
    counts = summary.get("compilations", {})
    compiled = (f" ({counts['compiled']} programs compiled, {counts['cache_hits']} loaded from the cache)"
                if "compiled" in counts else "")
    rows.append(("time", f"{_number(summary.get('total_s'), 1)} s in all: compilation "
                 f"{_number(summary['compile_s'], 1)} s{compiled}, filter loop {_number(summary['wall_s'], 2)} s "
                 f"({_number(rate, 0)} {unit})"))
    present = {p.name for p in out.iterdir() if p.is_file()} if out.is_dir() else set()
    files = [name for name in OUTPUT_FILES if name in present]
    files += sorted(name for name in present - set(OUTPUT_FILES) if not name.endswith(".tmp"))
    rows.append(("files", f"{out}: {', '.join(files)}"))
    if summary.get("rerun"):
        rows.append(("recording", str(summary["rerun"])))
    width = max(len(label) for label, _ in rows)
    head = f"{summary['algorithm']} on {summary['dataset']}, {summary['particles']} particles, seed {summary['seed']}"
    return "\n".join([head, *(f"  {label:<{width}}  {text}" for label, text in rows)])


def evaluate(trajectory: Path, relations: str | None = None, gps: str | None = None) -> dict[str, Any]:
    """Score a TUM trajectory by a relations file (or dataset name) or by GPS."""
    from jaxslam.metrics.trajectory_io import read_tum

    if not Path(trajectory).exists():
        raise DatasetNotFoundError(f"trajectory file {str(trajectory)!r} does not exist")
    times, poses = read_tum(trajectory)
    if relations is not None:
        from jaxslam.metrics.relations import load_relations, relations_metric

        path = Path(relations)
        if not path.exists():
            try:
                info = lookup(relations)
            except KeyError as err:
                raise RunError(f"{relations!r} is neither a relations file nor a dataset name: {err.args[0]}") from None
            path = info.relations_path()
            if path is None:
                raise RunError(f"dataset {info.name!r} has no relations file")
        scores = relations_metric(load_relations(path), times, poses)
        scores["relations_file"] = str(path)
        return scores
    try:
        info = lookup(gps)
    except KeyError as err:
        raise RunError(f"--gps: {err.args[0]}") from None
    if not info.gps:
        with_gps = ", ".join(name for name, entry in DATASETS.items() if entry.gps)
        raise RunError(f"GPS scoring is available for {with_gps}, not {info.name!r}")
    from jaxslam.datasets.victoria_park import load_gps
    from jaxslam.metrics.gps import gps_error

    fixes = load_gps()
    scores = gps_error(times, poses[:, :2], fixes.times, fixes.xy)
    return {k: v for k, v in scores.items() if k not in ("used", "errors_m")}
