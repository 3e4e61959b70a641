"""What ``jaxslam run`` / ``evaluate`` / ``plot`` do, as functions a script can call.

``run(...)`` resolves a dataset (a name, a path to a CARMEN log, or a built-in
simulator), runs the chosen filter, scores it where a reference exists (GPS for
Victoria Park, relations for the CARMEN benchmark logs, ground truth for the
simulators) and writes an output folder:

* ``summary.json`` — what was run (algorithm, dataset, particles, seed, steps, ...),
  timings (``wall_s`` after compilation, ``compile_s`` apart), resamplings, scores;
* ``trajectory.tum`` — the estimate in the TUM format;
* landmark runs: ``landmarks.csv`` (id, x, y, covariance) and ``trajectory.png``
  (trajectory, reference, landmarks with 3-sigma ellipses);
* grid runs: ``map.pgm`` + ``map.yaml`` (ROS map_server convention) and ``map.png``;
* ``health.png`` — ESS and resampling over time; ``arrays.npz`` — the data the
  figures are drawn from, so ``jaxslam plot`` can redraw them.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path
from typing import Any

import numpy as np

from jaxslam.datasets.paths import DataFormatError, DatasetNotFoundError
from jaxslam.datasets.registry import DatasetInfo, lookup

LANDMARK_ALGORITHMS = ("erb-upf", "rb-upf")
GRID_ALGORITHMS = ("srupf-gm", "srupf-gm-npc", "gmapping")
DEFAULT_ALGORITHM = {"landmark": "erb-upf", "laser": "srupf-gm"}
DEFAULT_PARTICLES = {"landmark": 100, "laser": 30}


class RunError(ValueError):
    """A user-facing problem with a run's arguments (the CLI exits with status 2)."""


def _kind_of(algorithm: str) -> str:
    return "landmark" if algorithm in LANDMARK_ALGORITHMS else "laser"


def resolve_dataset(dataset: str | None, algorithm: str | None) -> tuple[DatasetInfo | None, Path | None, str]:
    """``(info, path, kind)`` for a dataset name, a path to a CARMEN log, or None."""
    if dataset is None:
        kind = _kind_of(algorithm) if algorithm else "landmark"
        return lookup("sim-landmarks" if kind == "landmark" else "sim-laser"), None, kind
    candidate = Path(dataset).expanduser()
    if candidate.suffix in {".clf", ".log", ".gz", ".carmen", ".bag", ".mcap", ".db3"} or candidate.exists():
        if not candidate.exists():
            what = "ROS bag" if candidate.suffix in {".bag", ".mcap", ".db3"} else "CARMEN log"
            raise DatasetNotFoundError(f"{what} {str(candidate)!r} does not exist")
        return None, candidate, "laser"
    try:
        info = lookup(dataset)
    except KeyError as err:
        raise RunError(err.args[0]) from None
    return info, None, info.kind


def _json_default(value):
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def write_json(path: Path, payload: dict) -> None:
    """Write JSON atomically (temporary file, then rename)."""
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps(payload, indent=2, default=_json_default) + "\n")
    tmp.replace(path)


def _overrides_dict(overrides) -> dict[str, float]:
    return {name: value for name, value in (overrides or [])}


# --------------------------------------------------------------------------- landmark


def load_landmark_sequence(info: DatasetInfo, max_steps: int | None, seed: int):
    """The sequence of a landmark dataset (the simulator draws its world from ``seed``),
    cut to ``max_steps`` scans."""
    if info.name == "sim-landmarks":
        from jaxslam.datasets import landmark_sim

        sequence = landmark_sim.simulate(seed=seed)
    else:
        from jaxslam.datasets import victoria_park

        sequence = victoria_park.load_sequence(max_steps=max_steps)
    if max_steps is not None:
        sequence = _truncate(sequence, max_steps)
    return sequence


def _truncate(sequence, max_steps: int):
    import dataclasses

    t = sequence.times.shape[0]
    if max_steps >= t:
        return sequence
    changes = {}
    for field in dataclasses.fields(sequence):
        value = getattr(sequence, field.name)
        if isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == t and not field.name.startswith("gps"):
            changes[field.name] = value[:max_steps]
    return dataclasses.replace(sequence, **changes)


def _param_fields(algorithm: str) -> dict[str, Any]:
    """Each ``Params`` field of the algorithm with its default (scalars as floats)."""
    if _kind_of(algorithm) == "landmark":
        from jaxslam.feature.params import Params

        defaults = Params()
    else:
        from jaxslam.grid.types import default_params

        defaults = default_params(np.zeros(1, np.float32))
    values = {}
    for name in defaults._fields:
        value = getattr(defaults, name)
        if np.ndim(value) == 0 and not isinstance(value, tuple):
            try:
                value = float(value)
            except (TypeError, ValueError):
                pass
        values[name] = value
    return values


def check_overrides(algorithm: str, overrides: dict[str, float]) -> None:
    fields = _param_fields(algorithm)
    for name, _ in overrides.items():
        default = fields.get(name, KeyError)
        if default is KeyError:
            scalar = sorted(n for n, v in fields.items() if isinstance(v, (int, float)))
            raise RunError(f"--set {name}: {algorithm} has no parameter {name!r}; numeric parameters: {', '.join(scalar)}")
        if not isinstance(default, (int, float)):
            raise RunError(f"--set {name}: parameter {name!r} is not a single number and cannot be set here")


def run_landmark(info, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype,
                 checkpoint=None, viz=None):
    from jaxslam.feature.experiment import run_landmark_slam
    from jaxslam.metrics.trajectory_io import write_tum

    loading = time.perf_counter()
    sequence = load_landmark_sequence(info, max_steps, seed)
    live = {} if viz is None else {"callback": viz.landmark_callback(np.asarray(sequence.times))}
    load_s = time.perf_counter() - loading
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
    reference_xy = None
    true_landmarks = None
    if info.name == "victoria-park":
        from jaxslam.metrics.gps import gps_error

        scores = gps_error(result.times, result.trajectory[:, :2], sequence.gps_times, sequence.gps_xy)
        summary.update({k: scores[k] for k in ("gps_mean_m", "gps_rms_m", "gps_max_m", "n_used", "n_skipped")})
        summary["gps_alignment"] = {"rotation_rad": scores["rotation_rad"], "translation": scores["translation"]}
        rot, trans = np.asarray(scores["rotation"]), np.asarray(scores["translation"])
        reference_xy = (np.asarray(sequence.gps_xy) - trans) @ rot  # GPS mapped into the filter frame
        reference_xy = reference_xy[np.asarray(scores["used"], bool)]
        ref_label = "GPS (aligned)"
    else:
        errors = np.linalg.norm(result.trajectory[:, :2] - sequence.true_poses[:, :2], axis=1)
        summary.update({"pos_err_mean_m": float(errors.mean()), "pos_err_rms_m": float(np.sqrt((errors**2).mean())),
                        "pos_err_max_m": float(errors.max())})
        try:
            from jaxslam.metrics.nees import pose_nees

            nees = pose_nees(result.trajectory, result.pose_covs, sequence.true_poses)
            summary["nees_mean"] = float(np.nanmean(nees))
            summary["nees_expected"] = 3.0
        except ImportError:
            pass
        reference_xy = sequence.true_poses[:, :2]
        true_landmarks = sequence.landmarks
        ref_label = "ground truth"
    writing = time.perf_counter()
    write_tum(out / "trajectory.tum", result.times, result.trajectory,
              comment=f"jaxslam {algorithm} on {info.name}, {particles} particles, seed {seed}")
    with open(out / "landmarks.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow(["id", "x_m", "y_m", "cov_xx", "cov_xy", "cov_yy"])
        for i, (m, c) in enumerate(zip(result.landmark_means, result.landmark_covs)):
            writer.writerow([i, f"{m[0]:.4f}", f"{m[1]:.4f}", f"{c[0, 0]:.6g}", f"{c[0, 1]:.6g}", f"{c[1, 1]:.6g}"])
    np.savez_compressed(
        out / "arrays.npz", kind="landmark", times=result.times, trajectory=result.trajectory,
        landmark_means=result.landmark_means, landmark_covs=result.landmark_covs,
        reference_xy=reference_xy if reference_xy is not None else np.zeros((0, 2)),
        reference_label=ref_label,
        true_landmarks=true_landmarks if true_landmarks is not None else np.zeros((0, 2)),
        ess=result.info["ess"], resampled=result.info["resampled"], particles=particles,
        weight_variance=result.info.get("weight_variance", np.zeros(0)),
        title=f"{algorithm}, {info.name}, {particles} particles",
    )
    summary["output_s"] = time.perf_counter() - writing
    return summary


# --------------------------------------------------------------------------- grid


def run_grid(info, path, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype,
             checkpoint=None, keyframes=None, bag=None, viz=None, max_range=None):
    from jaxslam.grid import experiment as grid_experiment
    from jaxslam.metrics.trajectory_io import write_tum

    name = info.name if info is not None else str(path)
    loading = time.perf_counter()
    if info is not None and info.name == "sim-laser":
        from jaxslam.datasets import laser_sim

        log = laser_sim.simulate(seed=seed)
    elif path is not None and _is_bag(path):
        from jaxslam.datasets.rosbag import load_rosbag

        log = load_rosbag(path, **(bag or {}))
    else:
        from jaxslam.datasets.carmen import load_dataset_log

        log = load_dataset_log(info.name if info is not None else str(path),
                               **({"max_range": max_range} if max_range is not None else {}))
    load_s = time.perf_counter() - loading
    live = None
    if viz is not None:
        live = _grid_live_log(viz, log, max_steps, keyframes, chunk)
        checkpoint, chunk = live, live.every
    result = grid_experiment.run_grid_slam(
        log, algorithm=algorithm, particles=particles, seed=seed, params=overrides,
        progress=progress, max_keyframes=max_steps, dtype=dtype, **({"chunk": chunk} if chunk else {}),
        **({"checkpoint": checkpoint} if checkpoint is not None else {}),
        **{f"{k}_update": v for k, v in (keyframes or {}).items()},
    )
    if live is not None and not np.array_equal(live.keyframes, result.keyframes):
        raise RunError("the live view placed the keyframes differently from the run (a bug); its recording is wrong")
    summary: dict[str, Any] = {
        "algorithm": algorithm, "dataset": name, "particles": particles, "seed": seed,
        "scans": int(result.scan_times.shape[0]), "keyframes": int(result.keyframes.shape[0]),
        "keyframe_rule": result.summary()["keyframe_rule"],
        **{k: result.summary()[k] for k in ("maps", "map_shape", "map_growths", "map_growth_steps")},
        "wall_s": result.wall_s, "compile_s": result.compile_s,
        "keyframes_per_s": result.keyframes.shape[0] / result.wall_s if result.wall_s > 0 else None,
        "resamplings": result.resamplings, "dtype": np.dtype(dtype).name,
        "finite": bool(np.all(np.isfinite(result.trajectory))),
        "log_stats": getattr(log, "stats", {}), "load_s": load_s,
        "max_range": float(getattr(log, "max_range", np.nan)), "no_return": getattr(log, "no_return", {}),
    }
    if path is not None and _is_bag(path):
        summary["bag"] = dict(log.params)  # the topics and frames used
    writing = time.perf_counter()
    write_tum(out / "trajectory.tum", result.scan_times, result.trajectory,
              comment=f"jaxslam {algorithm} on {name}, {particles} particles, seed {seed}")
    output_s = time.perf_counter() - writing
    relations = info.relations_path() if info is not None else None
    if relations is not None:
        from jaxslam.metrics.relations import load_relations, relations_metric

        scores = relations_metric(load_relations(relations), result.scan_times, result.trajectory)
        summary.update(scores)
    if hasattr(log, "true_poses"):
        errors = np.linalg.norm(result.trajectory[:, :2] - np.asarray(log.true_poses)[:, :2], axis=1)
        summary.update({"pos_err_mean_m": float(errors.mean()), "pos_err_max_m": float(errors.max())})
    from jaxslam.grid.export import save_map

    writing = time.perf_counter()
    save_map(out, result.map_log_odds, result.resolution, result.origin, name="map", trajectory=result.trajectory)
    np.savez_compressed(
        out / "arrays.npz", kind="laser", times=result.scan_times, trajectory=result.trajectory,
        log_odds=result.map_log_odds, resolution=result.resolution, origin=np.asarray(result.origin),
        ess=result.info["ess"], resampled=result.info["resampled"], particles=particles,
        title=f"{algorithm}, {name}, {particles} particles",
    )
    summary["output_s"] = output_s + time.perf_counter() - writing
    return summary


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


def _grid_live_log(viz, log, max_steps, keyframes, chunk):
    """Follow a grid run: the same keyframes as run_grid_slam chooses."""
    from jaxslam.datasets.carmen import select_keyframes
    from jaxslam.grid import experiment as grid_experiment
    from jaxslam.viz.rerun_log import GridLiveLog

    name = grid_experiment._dataset_name(log)
    rule = grid_experiment.keyframe_rule(name, *((keyframes or {}).get(k) for k in ("linear", "angular", "temporal")))
    chosen = select_keyframes(log.odom_poses, *rule, times=log.scan_times)[:max_steps]
    return GridLiveLog(viz, log, chosen, every=min(chunk or 25, 25))


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
    of the "no return" sentinel detection (:func:`jaxslam.datasets.carmen.detect_no_return`).
    """
    import jax
    import jax.numpy as jnp

    info, path, kind = resolve_dataset(dataset, algorithm)
    algorithm = algorithm or DEFAULT_ALGORITHM[kind]
    if _kind_of(algorithm) != kind:
        name = info.name if info is not None else str(path)
        choices = LANDMARK_ALGORITHMS if kind == "landmark" else GRID_ALGORITHMS
        raise RunError(f"algorithm {algorithm!r} needs {_kind_of(algorithm)} data but dataset {name!r} is "
                       f"{kind} data; use one of: {', '.join(choices)}")
    if info is not None and not info.simulated:
        info.paths()  # raises DatasetNotFoundError naming what is missing
    overrides = dict(overrides or {})
    check_overrides(algorithm, overrides)
    keyframes = {k: float(v) for k, v in (keyframes or {}).items() if v is not None}
    unknown = set(keyframes) - {"linear", "angular", "temporal"}
    if unknown:
        raise RunError(f"unknown keyframe threshold(s) {sorted(unknown)}; use linear, angular, temporal")
    if keyframes and kind != "laser":
        raise RunError("keyframe thresholds (--linear-update/--angular-update/--temporal-update) apply to laser "
                       "data only; the landmark filters process every scan")
    bag = _bag_options(bag, path)
    if (rerun is not None or rerun_spawn) and (checkpoint_every is not None or resume):
        raise RunError("--rerun/--rerun-spawn cannot be combined with --checkpoint-every/--resume")
    particles = particles or DEFAULT_PARTICLES[kind]
    if float64:
        jax.config.update("jax_enable_x64", True)
    dtype = jnp.float64 if float64 else jnp.float32
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dataset_name = info.name if info is not None else str(Path(path).resolve())
    run_args = {"dataset": dataset_name, "algorithm": algorithm, "particles": particles, "seed": seed,
                "max_steps": max_steps, "overrides": overrides, "float64": float64, "chunk": chunk}
    if keyframes:
        run_args["keyframes"] = keyframes
    if bag:
        run_args["bag"] = bag
    if max_range is not None:
        if kind != "laser" or (info is not None and info.simulated):
            raise RunError("--max-range applies to CARMEN logs only")
        if not max_range > 0:
            raise RunError(f"--max-range must be positive, got {max_range}")
        run_args["max_range"] = float(max_range)
    checkpoint = None
    if checkpoint_every is not None or resume:
        from jaxslam.checkpoint import Checkpoint

        fingerprint = {k: v for k, v in run_args.items() if k != "chunk"}
        checkpoint = Checkpoint(out / "checkpoint.npz", every=checkpoint_every, fingerprint=fingerprint,
                                resume=resume)
        if resume and not checkpoint.path.exists():
            raise RunError(f"--resume: no checkpoint in {str(out)!r} (run with --checkpoint-every N first)")
    if not resume:
        write_json(out / "run.json", run_args)
    from jaxslam.cache import CompileCounter

    started = time.time()
    runner = run_landmark if kind == "landmark" else run_grid
    args = (info, algorithm, particles, seed, out, max_steps, overrides, progress, chunk, dtype)
    if kind == "laser":
        args = (info, path) + args[1:]
    extra = {"keyframes": keyframes} if keyframes else {}
    if max_range is not None:
        extra["max_range"] = float(max_range)
    if bag:
        extra["bag"] = bag
    viz = _open_viz(rerun, rerun_spawn, dataset_name)
    if viz is not None:
        extra["viz"] = viz
    try:
        with CompileCounter() as compilations:
            summary = runner(*args, checkpoint=checkpoint, **extra)
    finally:
        if viz is not None:
            viz.close()
    if rerun is not None:
        summary["rerun"] = str(rerun)
    summary["resumed"] = bool(resume)
    summary["overrides"] = overrides
    summary["jaxslam_version"] = __import__("jaxslam").__version__
    summary["jax_version"] = jax.__version__
    # XLA programs compiled or loaded from the persistent cache (jaxslam.cache)
    summary["compilations"] = compilations.as_dict()
    summary["cache_dir"] = jax.config.jax_compilation_cache_dir
    # load_s, output_s: reading the data; writing the files and figures (seconds)
    writing = time.perf_counter()
    if plots:
        replot(out)
    summary["output_s"] = summary.get("output_s", 0.0) + time.perf_counter() - writing
    summary["total_s"] = time.time() - started
    write_json(out / "summary.json", summary)
    return summary


def run_from_args(args) -> dict[str, Any] | None:
    """The ``jaxslam run`` subcommand."""
    if args.list_params:
        algorithm = args.algorithm or DEFAULT_ALGORITHM[resolve_dataset(args.dataset, None)[2]]
        for name, default in _param_fields(algorithm).items():
            print(f"{name:24s} {default!r}")
        return None
    if args.resume is not None:
        saved = args.resume / "run.json"
        if not saved.exists():
            raise RunError(f"--resume {str(args.resume)!r}: no run.json there; is it a `jaxslam run` output folder?")
        try:
            run_args = json.loads(saved.read_text())
        except json.JSONDecodeError as err:
            raise DataFormatError(saved, err.lineno, f"not valid JSON: {err.msg}") from None
        return run(out=args.resume, progress=not args.no_progress, plots=not args.no_plots,
                   checkpoint_every=args.checkpoint_every, resume=True, **run_args)
    if args.out is None:
        raise RunError("--out is required (the folder the outputs go to)")
    overrides = _overrides_dict(args.overrides)
    if getattr(args, "params", None) is not None:
        from jaxslam.calibrate.cli import load_params_file

        overrides = {**load_params_file(args.params), **overrides}
    return run(
        out=args.out, dataset=args.dataset, algorithm=args.algorithm, particles=args.particles, seed=args.seed,
        max_steps=args.max_steps, overrides=overrides, progress=not args.no_progress,
        chunk=args.chunk, float64=args.float64, plots=not args.no_plots, checkpoint_every=args.checkpoint_every,
        keyframes={"linear": args.linear_update, "angular": args.angular_update, "temporal": args.temporal_update},
        bag={"scan_topic": args.scan_topic, "odom_topic": args.odom_topic, "base_frame": args.base_frame,
             "laser_offset": args.laser_mount},
        rerun=args.rerun, rerun_spawn=args.rerun_spawn,
        max_range=args.max_range,
    )


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
    info = lookup(gps)
    if info.name != "victoria-park":
        raise RunError(f"GPS scoring is available for victoria-park, not {info.name!r}")
    from jaxslam.datasets.victoria_park import load_gps
    from jaxslam.metrics.gps import gps_error

    fixes = load_gps()
    scores = gps_error(times, poses[:, :2], fixes.times, fixes.xy)
    return {k: v for k, v in scores.items() if k not in ("used", "errors_m")}


def replot(folder: str | Path) -> list[Path]:
    """Draw the figures of an output folder from its ``arrays.npz``."""
    from jaxslam import plotting

    folder = Path(folder)
    arrays_path = folder / "arrays.npz"
    if not arrays_path.exists():
        raise DatasetNotFoundError(f"{str(arrays_path)!r} not found: is {str(folder)!r} a `jaxslam run` output folder?")
    try:
        data = np.load(arrays_path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise DataFormatError(arrays_path, None, f"cannot read: {err}") from None
    title = str(data["title"])
    written = []
    if str(data["kind"]) == "landmark":
        fig = plotting.plot_landmark_slam(
            data["trajectory"], data["landmark_means"], data["landmark_covs"],
            reference_xy=data["reference_xy"], reference_label=str(data["reference_label"]),
            true_landmarks=data["true_landmarks"], title=title,
        )
        written.append(plotting.save(fig, folder / "trajectory.png"))
    else:
        fig = plotting.plot_grid_map(data["log_odds"], float(data["resolution"]), data["origin"],
                                     trajectory=data["trajectory"], title=title)
        written.append(plotting.save(fig, folder / "map_trajectory.png"))
    wv = data["weight_variance"] if "weight_variance" in data and data["weight_variance"].size else None
    fig = plotting.plot_filter_health(data["ess"], data["resampled"], int(data["particles"]), wv, title=title)
    written.append(plotting.save(fig, folder / "health.png"))
    return written
