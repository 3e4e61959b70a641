"""Robustness suite for grid SLAM: one set of defaults on logs nobody tuned for.

For each log, seed and filter (jaxslam ``srupf-gm`` and ``gmapping``, and GMapping
C++ where built, :mod:`benchmarks.gmapping_cpp`) it reports the relations error
(Kümmerle et al. 2009: mean, median, max, count over 0.5 m and over 1 m), the wall
time and CPU time of the whole process, and two diagnostics of a grid filter's failure
modes:

* **path jumps**: at each keyframe ``k`` of the chosen path, the correction against
  odometry ``c_k = (x_{k-1} (+) (o_{k-1}^-1 (+) o_k))^-1 (+) x_k``; we report its
  largest translation and rotation and how many exceed 0.3 m. A relation between
  scans less than ``SHORT_S`` s apart
  that is off by more than 0.5 m is counted as ``bad_short`` (on perturbed logs, whose
  scans are GMapping keyframes about 1 m apart: consecutive scans); the others as
  ``bad_long`` (loop closures, long stretches).
* the scan indices of the ten worst relations (``worst``), to find the place, and the
  scans of the five largest jumps (``jump_keyframes``).

The summary (:func:`summarize`, per log and filter) gives the worst seed and, for the
tail of a log's seeds, the median seed's mean relations error and the share of seeds
whose mean exceeds :data:`TAIL_FACTOR` times it (``tail_share``), beside the worst
relation over every seed (``worst_max_m``). The runs are chaotic: another CPU compiles
another program and draws other runs from the same seeds. ``--code-split 8,32`` runs
every jaxslam run once per value of XLA's ``xla_cpu_parallel_codegen_split_count``
(jaxslam fixes it, :mod:`jaxslam.runtime.compiler`; another value compiles another
program from the same code, a stand-in for another CPU's), and the summary has one
row per value, so a tail that belongs to one program's draw shows as such.

Logs:

* ``raw``: the raw benchmark logs in ``carmen_raw/`` (intel, fr079 and mit-killian are
  scored with the benchmark relations; mit-csail and fr-clinic have none and get
  times only);
* ``mrpt``: the MRPT logs (no ground truth: times and maps only);
* ``perturbed``: GMapping-corrected logs with synthetic odometry error,
  :mod:`jaxslam.datasets.perturb` (``--perturbed`` names, ``--levels``; the seed is
  both the perturbation seed and the filters' seed), scored on relations sampled
  from the corrected poses. Where the corrected log was made from a raw benchmark log
  that has relations (intel, fr079), the run is scored on the benchmark relations as
  well (``bench_*`` columns): each scan is found in the raw log by its range readings
  (:func:`grid_common.raw_scan_indices`, as ``grid_gmapping_reference.py`` does), the
  estimated laser poses become robot poses through the raw log's laser offset, and the
  relations between scans the perturbed log holds are scored (FR079: 1672 of 1685;
  Intel's corrected log keeps 910 of 13631 scans: 90 of 2984). The corrected poses
  are GMapping's own estimate, so GMapping's systematic errors are in the first
  reference and not in the second.

Every filter uses the same defaults on every log: ``run_grid_slam``'s default
parameters and configuration (every scan tracked, the filter's keyframe rule on the
tracked motion, ``keyframes`` of :data:`jaxslam.grid.algorithms.GRID_ALGORITHMS`: 0.5 m / 0.5 rad for
``srupf-gm``, GMapping's 1 m / 0.5 rad for ``gmapping``; runs before the stress test of
``grid_stress.py`` used 1 m for both, :mod:`jaxslam.grid.tracking`); GMapping C++ its own
defaults. GMapping C++ gets the
range limit jaxslam's reader took for the log, minus 0.01 (slam_gmapping's rule), and
runs at the script's own niceness, like the jaxslam workers (run the script under
``nice``; compare ``cpu_s`` as well as ``wall_s`` on a shared machine).
Each jaxslam run happens in a fresh process (``--worker``) that calls only
:func:`jaxslam.grid.experiment.run_grid_slam`; its jitted code is cached on disk
between runs of one log shape (``JAX_COMPILATION_CACHE_DIR``, default
``/tmp/jaxslam_robust_jax_cache``), so compile time drops after the first seed.

Writes ``benchmarks/results/grid_robustness[_TAG].json`` (``--out OUT``: ``OUT.json``;
after every run, so a late failure loses nothing) and the maps (PNG, path in red) under
``benchmarks/results/grid_robustness_maps[/TAG]/``.

    python benchmarks/grid_robustness.py --logs intel --perturbed fr101,edmonton \\
        --levels low,high --seeds 0,1,2 --particles 30 --tag baseline
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

RESULTS = ROOT / "benchmarks" / "results"
RAW_LOGS = ("intel", "fr079", "mit-killian", "mit-csail", "fr-clinic")
MRPT_LOGS = ("mrpt-sena", "mrpt-ual", "mrpt-localization-demo")
JAX_FILTERS = ("srupf-gm", "gmapping")
FILTERS = (*JAX_FILTERS, "gmapping-cpp")
SHORT_S = 1.0
JUMP_M = 0.3
TAIL_FACTOR = 2.0
"""A seed is in a log's tail when its mean relations error exceeds this times the median seed's."""
SPLIT_OPTION = "xla_cpu_parallel_codegen_split_count"
# Least share of a perturbed log's scans that must be found in the raw log to score it on
# the raw log's benchmark relations.
BENCH_MIN_FOUND = 0.95


# ---------------------------------------------------------------------------
# Worker: one jaxslam run in this process.
# ---------------------------------------------------------------------------
def worker(spec: dict) -> dict:
    from jaxslam.runtime.cache import enable_compilation_cache
    from jaxslam.runtime.compiler import set_threads

    set_threads(None, spec["algorithm"], int(spec["particles"]))  # XLA's thread pool as `jaxslam run` sizes it
    # jaxslam's cache setup, not JAX's alone: its keys include the thread pool and the CPU
    # set (jaxslam.runtime.compiler.compile_environment), so pinned and unpinned workers sharing
    # the folder each run their own programs.
    enable_compilation_cache(os.environ.get("JAX_COMPILATION_CACHE_DIR", "/tmp/jaxslam_robust_jax_cache"))
    from jaxslam.grid.experiment import run_grid_slam
    from jaxslam.grid.export import save_map

    t0 = time.perf_counter()
    log = spec["log"]
    laser = spec.get("laser_odometry")
    if laser is not None:
        from jaxslam.datasets.registry import load_dataset_log
        from jaxslam.grid.laser_odometry import LaserOdometryConfig, laser_corrected_log

        log = laser_corrected_log(load_dataset_log(log), LaserOdometryConfig(**laser))
    t_front = time.perf_counter() - t0
    result = run_grid_slam(
        log,
        spec["algorithm"],
        particles=int(spec["particles"]),
        seed=int(spec["seed"]),
        progress=False,
        max_keyframes=spec.get("max_keyframes"),
        params=spec.get("params") or None,
        config=spec.get("config") or None,
    )
    record = result.summary()
    record["process_s"] = time.perf_counter() - t0
    record["laser_odometry_s"] = t_front
    if laser is not None:
        record["laser_odometry_accepted"] = log.stats["laser_odometry_accepted"]
    out = Path(spec["out"])
    np.savez_compressed(
        out,
        trajectory=result.trajectory,
        scan_times=result.scan_times,
        keyframes=result.keyframes,
        keyframe_poses=result.keyframe_poses,
        **{f"info_{k}": v for k, v in result.info.items()},
    )
    if spec.get("map_png"):
        tmp = out.parent / (out.stem + "_map")
        paths = save_map(tmp, result.map_log_odds, result.resolution, result.origin, trajectory=result.keyframe_poses)
        Path(spec["map_png"]).parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(paths["png"], spec["map_png"])
        png = Path(spec["map_png"]).resolve()
        # the repository path, so that the JSON stays valid in any checkout
        record["map_png"] = str(png.relative_to(ROOT)) if png.is_relative_to(ROOT) else str(png)
    return record


def split_flags(flags: str, split: int | None) -> str:
    """``XLA_FLAGS`` for a worker that compiles with ``split`` parts (None: ``flags`` as
    they are, jaxslam's fixed option, :data:`jaxslam.runtime.compiler.OPTIONS`)."""
    if split is None:
        return flags
    return f"{flags} --{SPLIT_OPTION}={int(split)}".strip()


def run_worker(spec: dict, timeout: float, split: int | None = None) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    flags = split_flags(env.get("XLA_FLAGS", ""), split)
    if flags:
        env["XLA_FLAGS"] = flags
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", json.dumps(spec)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env, check=False)
    except subprocess.TimeoutExpired:
        return {"error": f"timeout after {timeout} s"}
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    lines = [line for line in out.stdout.splitlines() if line.startswith("{")]
    if out.returncode != 0 or not lines:
        return {"error": (out.stderr or out.stdout)[-2000:]}
    record = json.loads(lines[-1])
    record["wall_process_s"] = wall
    record["cpu_s"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return record


# ---------------------------------------------------------------------------
# Scoring and failure-mode diagnostics.
# ---------------------------------------------------------------------------
def keyframe_corrections(indices: np.ndarray, poses: np.ndarray, odom: np.ndarray) -> np.ndarray:
    """(K-1, 3) correction of each keyframe pose against the odometry increment."""
    from jaxslam.metrics.trajectory_io import se2_between, se2_compose

    predicted = se2_compose(poses[:-1], se2_between(odom[indices[:-1]], odom[indices[1:]]))
    return se2_between(predicted, poses[1:])


def score(
    relations, short: np.ndarray | None, scan_times, trajectory, kf_indices, kf_poses, odom
) -> dict[str, Any]:
    from jaxslam.metrics.relations import relation_errors, relations_metric

    record: dict[str, Any] = {}
    corr = keyframe_corrections(np.asarray(kf_indices), np.asarray(kf_poses, np.float64), odom)
    jump = np.hypot(corr[:, 0], corr[:, 1])
    record["jump_max_m"] = float(jump.max()) if jump.size else 0.0
    record["jump_max_deg"] = float(np.degrees(np.abs(corr[:, 2]).max())) if jump.size else 0.0
    record["jumps_over_0.3m"] = int(np.sum(jump > JUMP_M))
    record["jump_keyframes"] = [int(kf_indices[k + 1]) for k in np.argsort(-jump)[:5]]
    if relations is None:
        return record
    metric = relations_metric(relations, scan_times, trajectory)
    errors = relation_errors(relations, scan_times, trajectory)
    trans = errors.trans[errors.matched]
    is_short = (np.abs(relations.t2 - relations.t1) < SHORT_S) if short is None else short
    bad = errors.matched & (errors.trans > 0.5)
    record.update(
        {
            "mean_m": metric["trans_err_mean_m"],
            "median_m": float(np.median(trans)) if trans.size else float("nan"),
            "max_m": float(trans.max()) if trans.size else float("nan"),
            "rot_mean_deg": metric["rot_err_mean_deg"],
            "over_0.5m": int(np.sum(trans > 0.5)),
            "over_1m": int(np.sum(trans > 1.0)),
            "n_relations": metric["n_relations"],
            "n_unmatched": metric["n_unmatched"],
            "bad_short": int(np.sum(bad & is_short)),
            "bad_long": int(np.sum(bad & ~is_short)),
        }
    )
    worst = np.argsort(-np.where(errors.matched, errors.trans, -1.0))[:10]
    record["worst"] = [
        [int(errors.index1[r]), int(errors.index2[r]), round(float(errors.trans[r]), 3)]
        for r in worst
        if errors.matched[r]
    ]
    return record


def score_as_tracked(entry: dict, data, times, kf_i, kf_p, odom) -> dict[str, Any]:
    """Where closures were undone: how many, and the relations error of the path as it
    was tracked, before the reported path took them back
    (:func:`jaxslam.grid.undone_closures.put_back`)."""
    if "info_track_undo" not in data.files:
        return {}
    from grid_common import saved_undo
    from jaxslam.grid.undone_closures import put_back

    undo = saved_undo(data)  # with the end's judgment
    record: dict[str, Any] = {"closures_undone": int(np.sum(undo[:, 0] > 0)), "undone_at_end": bool(undo[-1, 0] > 0)}
    if not record["closures_undone"]:
        return record

    tracked = put_back(data["trajectory"], np.arange(data["trajectory"].shape[0]), undo)
    tracked_kf = put_back(kf_p, kf_i, undo)
    scored = {**score(entry["relations"], entry["short"], times, tracked, kf_i, tracked_kf, odom),
              **score_benchmark(entry.get("bench"), tracked)}
    for key in ("mean_m", "max_m", "over_1m", "bench_mean_m"):
        if key in scored:
            record[f"as_tracked_{key}"] = scored[key]
    return record


def benchmark_reference(raw, relations, log):
    """``(stamps, relations, laser_offset)`` to score runs on ``log`` (a perturbed log made
    from the raw log ``raw``) with the raw log's benchmark ``relations``: per scan of
    ``log`` the raw scan's stamp (NaN where the scan is not in the raw log), or None when
    fewer than ``BENCH_MIN_FOUND`` of the scans are found."""
    from grid_common import raw_scan_indices

    index = raw_scan_indices(raw, log.ranges)
    found = index >= 0
    if found.mean() < BENCH_MIN_FOUND:
        return None
    stamps = np.where(found, np.asarray(raw.scan_times, np.float64)[index], np.nan)
    return stamps, relations, np.asarray(raw.laser_offset, np.float64)


def score_benchmark(bench, trajectory) -> dict[str, Any]:
    """``bench_*``: a run's per-scan laser poses ``trajectory`` (the log's first scans, all
    of them unless the run was cut short) scored on a raw log's benchmark relations
    (:func:`benchmark_reference`); empty without them."""
    if bench is None:
        return {}
    from grid_common import robot_poses

    from jaxslam.metrics.relations import relations_metric

    stamps, relations, offset = bench
    trajectory = np.asarray(trajectory, np.float64)
    if trajectory.ndim != 2 or trajectory.shape[1] != 3 or trajectory.shape[0] > stamps.shape[0]:
        raise ValueError(f"trajectory {trajectory.shape} is not one pose per scan of the log ({stamps.shape[0]})")
    stamps = stamps[: trajectory.shape[0]]
    keep = np.isfinite(stamps)
    metric = relations_metric(relations, stamps[keep], robot_poses(trajectory, offset)[keep])
    if not metric["n_relations"]:
        return {"bench_n_relations": 0}
    return {"bench_mean_m": metric["trans_err_mean_m"], "bench_median_m": metric["trans_err_median_m"],
            "bench_max_m": metric["trans_err_max_m"], "bench_over_0.5m": metric["n_trans_err_over_0_5m"],
            "bench_n_relations": metric["n_relations"]}


# ---------------------------------------------------------------------------
# Logs.
# ---------------------------------------------------------------------------
def prepare_logs(args, work: Path) -> list[dict]:
    """Each entry: name, source (name or path for run_grid_slam), path, relations, short mask, seeds."""
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.datasets.perturb import make_perturbed_log
    from jaxslam.metrics.relations import DATASET_RELATIONS, load_dataset_relations

    seeds = [int(s) for s in args.seeds.split(",")]
    entries = []
    for name in [n for n in args.logs.split(",") if n]:
        if name not in RAW_LOGS + MRPT_LOGS:
            raise SystemExit(f"unknown log {name!r}; known: {', '.join(RAW_LOGS + MRPT_LOGS)}")
        log = load_dataset_log(name)
        rel = load_dataset_relations(name) if name in DATASET_RELATIONS else None
        for seed in seeds:
            entries.append({"log": name, "kind": "mrpt" if name in MRPT_LOGS else "raw", "seed": seed,
                            "source": name, "carmen": log, "relations": rel, "short": None})
    for name in [n for n in args.perturbed.split(",") if n]:
        raw = load_dataset_log(name) if name in DATASET_RELATIONS else None
        raw_relations = None if raw is None else load_dataset_relations(name)
        for level in args.levels.split(","):
            for seed in seeds:
                made = make_perturbed_log(name, level, seed, work / "logs")
                from jaxslam.datasets.carmen import load_carmen

                log = load_carmen(made.log_path)
                bench = None if raw is None else benchmark_reference(raw, raw_relations, log)
                entries.append({
                    "log": f"{name}-{level}", "kind": "perturbed", "seed": seed,
                    "source": str(made.log_path), "carmen": log, "relations": made.relations,
                    # short = between consecutive scans (the perturbed logs hold keyframes)
                    "short": np.searchsorted(made.reference.stamps, made.relations.t2)
                    - np.searchsorted(made.reference.stamps, made.relations.t1) == 1,
                    "stamps_replaced": made.stamps_replaced, "bench": bench,
                })
    return entries


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--logs", default="intel,fr079,mit-killian,mit-csail,fr-clinic,mrpt-sena,mrpt-ual",
                        help="raw/MRPT log names, comma separated ('' for none)")
    parser.add_argument("--perturbed", default="intel,fr101,edmonton,seattle,belgioioso,fr079",
                        help="corrected logs to perturb (jaxslam.datasets.perturb.CORRECTED_LOGS)")
    parser.add_argument("--levels", default="low,high")
    parser.add_argument("--seeds", default="0,1,2,3,4")
    parser.add_argument("--filters", default=",".join(FILTERS))
    parser.add_argument("--particles", type=int, default=30)
    parser.add_argument("--max-keyframes", type=int, default=None, help="short runs (jaxslam filters only)")
    parser.add_argument("--tag", default="", help="suffix of the JSON and maps folder")
    parser.add_argument("--out", default="", help="name of the JSON under benchmarks/results/ "
                        "(default grid_robustness[_TAG])")
    parser.add_argument("--timeout", type=float, default=1800.0)
    parser.add_argument("--no-maps", action="store_true")
    parser.add_argument("--variant", action="append", default=[], metavar="NAME=JSON",
                        help='jaxslam settings to compare in one run, e.g. wide={"params": {"matcher.score_sigma": 0.2}} '
                             '(keys "params" and "config" of run_grid_slam, and "laser_odometry": LaserOdometryConfig '
                             'fields to run on jaxslam.grid.laser_odometry.laser_corrected_log; repeatable; '
                             'default: the defaults)')
    parser.add_argument("--work", default="/tmp/grid_robustness", help="scratch folder (logs, trajectories)")
    parser.add_argument("--code-split", default="", metavar="N[,N]",
                        help=f"run every jaxslam run once per value of XLA's {SPLIT_OPTION} (e.g. 8,32; "
                             "default: jaxslam's fixed value only), one summary row per value")
    args = parser.parse_args(argv)
    try:
        splits = [int(v) for v in args.code_split.split(",") if v.strip()]
    except ValueError:
        parser.error(f"--code-split {args.code_split!r}: want positive integers, comma separated")
    if any(v < 1 for v in splits):
        parser.error(f"--code-split {args.code_split!r}: want positive integers, comma separated")
    if splits and f"--{SPLIT_OPTION}" in os.environ.get("XLA_FLAGS", ""):
        parser.error(f"--code-split: XLA_FLAGS already sets {SPLIT_OPTION}")

    from _common import machine_info, print_table
    from gmapping_cpp import GMappingNotBuiltError, GMappingRunError, find_gmapping, run_gmapping

    filters = [f for f in args.filters.split(",") if f]
    for f in filters:
        if f not in FILTERS:
            raise SystemExit(f"unknown filter {f!r}; known: {', '.join(FILTERS)}")
    gmapping_note = None
    if "gmapping-cpp" in filters:
        try:
            find_gmapping()
        except GMappingNotBuiltError as error:
            gmapping_note = str(error)
            print(f"grid_robustness: GMapping C++ left out: {error}", file=sys.stderr)
            filters.remove("gmapping-cpp")
    suffix = f"_{args.tag}" if args.tag else ""
    json_path = RESULTS / f"{args.out or 'grid_robustness' + suffix}.json"
    maps_dir = RESULTS / "grid_robustness_maps" / (args.tag or "default")
    work = Path(args.work) / (args.tag or "default")
    work.mkdir(parents=True, exist_ok=True)
    entries = prepare_logs(args, work)
    variants: list[tuple[str, dict]] = []
    for item in args.variant:
        name, _, text = item.partition("=")
        settings = json.loads(text or "{}")
        if not name or set(settings) - {"params", "config", "laser_odometry"}:
            raise SystemExit(f"--variant {item!r}: want NAME=JSON with keys 'params', 'config', 'laser_odometry'")
        variants.append((name, settings))
    variants = variants or [("", {})]
    from jaxslam.runtime.compiler import OPTIONS

    fixed = int(OPTIONS[SPLIT_OPTION])
    # the fixed value runs as jaxslam compiles it; another one through XLA_FLAGS
    code_splits = [(v, None if v == fixed else v) for v in splits] or [(None, None)]
    runs = [(f, "", {}, None, None) for f in filters if f == "gmapping-cpp"]
    runs = [(f, v, settings, split, flag) for f in filters if f != "gmapping-cpp" for v, settings in variants
            for split, flag in code_splits] + runs

    payload: dict[str, Any] = {
        "machine": machine_info(),
        "load_avg_at_start": os.getloadavg(),
        "settings": {**vars(args), "filters": filters, "gmapping_cpp": gmapping_note or "built",
                     "short_relation_s": SHORT_S, "jump_threshold_m": JUMP_M},
        "runs": [],
    }
    rows = payload["runs"]
    for entry in entries:
        log = entry["carmen"]
        for algorithm, variant, settings, split, split_flag in runs:
            label = f"{algorithm}[{variant}]" if variant else algorithm
            tag = f"{entry['log']}_{label}_s{entry['seed']}".replace("[", "_").replace("]", "")
            tag += "" if split is None else f"_split{split}"
            row: dict[str, Any] = {"log": entry["log"], "kind": entry["kind"], "seed": entry["seed"],
                                   "filter": label, "variant": variant, "settings": settings,
                                   "particles": args.particles,
                                   "scans": log.num_scans, "load_avg": os.getloadavg()[0]}
            if split is not None:
                row["code_split"] = split
            if entry.get("stamps_replaced"):
                row["stamps_replaced"] = entry["stamps_replaced"]
            print(f"[{time.strftime('%H:%M:%S')}] {tag} ...", file=sys.stderr, flush=True)
            try:
                if algorithm == "gmapping-cpp":
                    before = resource.getrusage(resource.RUSAGE_CHILDREN)
                    run = run_gmapping(log.path, args.particles, entry["seed"], log=log,
                                       max_range=float(log.max_range) - 0.01, timeout=args.timeout, nice=None,
                                       workdir=work / "gmapping")
                    after = resource.getrusage(resource.RUSAGE_CHILDREN)
                    row.update({"wall_s": run.wall_s, "filter_s": run.info.get("slam_s"),
                                "cpu_s": (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime),
                                "keyframes": int(run.keyframe_indices.shape[0])})
                    traj, times, kf_i, kf_p = run.trajectory, run.scan_times, run.keyframe_indices, run.keyframe_poses
                    # the same arrays as a jaxslam run's npz, so that a diagnosis can read either
                    np.savez(work / f"{tag}.npz", trajectory=traj, scan_times=times, keyframes=kf_i,
                             keyframe_poses=kf_p)
                else:
                    spec = {"log": entry["source"], "algorithm": algorithm, "particles": args.particles,
                            "seed": entry["seed"], "max_keyframes": args.max_keyframes,
                            "params": settings.get("params"), "config": settings.get("config"),
                            "laser_odometry": settings.get("laser_odometry"),
                            "out": str(work / f"{tag}.npz"),
                            "map_png": None if args.no_maps else str(maps_dir / f"{tag}.png")}
                    rec = run_worker(spec, args.timeout, split_flag)
                    if "error" in rec:
                        raise RuntimeError(rec["error"])
                    data = np.load(spec["out"])
                    row.update({"wall_s": rec["wall_process_s"], "filter_s": rec["wall_s"],
                                "compile_s": rec["compile_s"], "cpu_s": rec["cpu_s"],
                                "keyframes": rec["keyframes"], "resamplings": rec["resamplings"],
                                "map_growths": rec["map_growths"], "map_png": rec.get("map_png"),
                                "closures": rec.get("closures"), "closure_scans": rec.get("closure_scans"),
                                "laser_odometry_s": rec.get("laser_odometry_s"),
                                "laser_odometry_accepted": rec.get("laser_odometry_accepted")})
                    traj, times, kf_i, kf_p = (data["trajectory"], data["scan_times"], data["keyframes"],
                                               data["keyframe_poses"])
                row.update(score(entry["relations"], entry["short"], times, traj, kf_i, kf_p, log.odom_poses))
                row.update(score_benchmark(entry.get("bench"), traj))
                if algorithm != "gmapping-cpp":
                    row.update(score_as_tracked(entry, data, times, kf_i, kf_p, log.odom_poses))
            except (GMappingRunError, RuntimeError, ValueError) as error:
                row["error"] = str(error)[-1500:]
                print(f"  failed: {row['error'][-400:]}", file=sys.stderr)
            rows.append(row)
            RESULTS.mkdir(parents=True, exist_ok=True)
            json_path.write_text(json.dumps(payload, indent=1, default=float) + "\n")

    columns = ["log", "seed", "filter", "mean_m", "median_m", "max_m", "over_0.5m", "over_1m", "n_relations",
               "bad_short", "bad_long", "jump_max_m", "jumps_over_0.3m", "closures", "keyframes", "wall_s", "cpu_s"]
    if any("bench_mean_m" in r for r in rows):
        columns[6:6] = ["bench_mean_m", "bench_max_m", "bench_n_relations"]
    print_table(rows, columns)
    print()
    summary = summarize(rows)
    payload["summary"] = summary
    summary_columns = ["log", "filter", "seeds", "worst_mean_m", "mean_of_means_m", "median_seed_mean_m",
                       "tail_share", "worst_max_m", "over_0.5m_total", "worst_jump_m", "wall_s_mean", "cpu_s_mean"]
    if any("code_split" in r for r in summary):
        summary_columns.insert(2, "code_split")
    if any("bench_worst_mean_m" in r for r in summary):
        summary_columns[6:6] = ["bench_worst_mean_m", "bench_mean_of_means_m"]
    print_table(summary, summary_columns)
    json_path.write_text(json.dumps(payload, indent=1, default=float) + "\n")
    print(f"wrote {json_path}")
    return 0


def tail(means: list[float], factor: float = TAIL_FACTOR) -> tuple[float, float]:
    """``(median, share)``: the median of the seeds' mean relations errors ``means`` and
    the share of seeds whose mean exceeds ``factor`` times it."""
    values = np.asarray(means, np.float64)
    median = float(np.median(values))
    return median, float(np.mean(values > factor * median))


def summarize(rows: list[dict]) -> list[dict]:
    """Per log, filter and code split (``code_split``, where the runs have one) over
    seeds: the worst seed counts, and the tail (:func:`tail`)."""
    out = []

    def key(r: dict) -> tuple:
        return r["log"], r["filter"], r.get("code_split")

    keys = sorted({key(r) for r in rows},
                  key=lambda k: (k[0], FILTERS.index(k[1].split("[")[0]), k[1], -1 if k[2] is None else k[2]))
    for cell in keys:
        log, algorithm, split = cell
        group = [r for r in rows if key(r) == cell and "error" not in r]
        failed = sum(1 for r in rows if key(r) == cell and "error" in r)
        item: dict[str, Any] = {"log": log, "filter": algorithm, "seeds": len(group), "failed_runs": failed}
        if split is not None:
            item["code_split"] = split
        if group and "mean_m" in group[0]:
            median, share = tail([r["mean_m"] for r in group])
            item.update({
                "worst_mean_m": max(r["mean_m"] for r in group),
                "mean_of_means_m": float(np.mean([r["mean_m"] for r in group])),
                "median_seed_mean_m": median,
                "tail_share": share,
                "worst_max_m": max(r["max_m"] for r in group),
                "over_0.5m_total": sum(r["over_0.5m"] for r in group),
            })
        if group and all("bench_mean_m" in r for r in group):
            item.update({
                "bench_worst_mean_m": max(r["bench_mean_m"] for r in group),
                "bench_mean_of_means_m": float(np.mean([r["bench_mean_m"] for r in group])),
                "bench_worst_max_m": max(r["bench_max_m"] for r in group),
            })
        if group:
            item.update({
                "worst_jump_m": max(r["jump_max_m"] for r in group),
                "wall_s_mean": float(np.mean([r["wall_s"] for r in group])),
                "cpu_s_mean": float(np.mean([r["cpu_s"] for r in group])),
            })
        out.append(item)
    return out


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--worker":
        print(json.dumps(worker(json.loads(sys.argv[2])), default=float), flush=True)
    else:
        sys.exit(main())
