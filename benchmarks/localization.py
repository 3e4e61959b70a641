"""Localization in maps of the GMapping-corrected logs: tracking, global localization,
a kidnapping, and ROS AMCL side by side.

For each log, the map is built from the corrected log with its own poses
(:func:`jaxslam.grid.known_poses.known_pose_log_odds`, 5 cm); the log to localize is
the same scans with generated wheel odometry (:func:`jaxslam.datasets.perturb.make_perturbed_log`,
noise level ``low`` or ``high``, one seed per run), scored against the corrected poses.

* ``tracking``: the start pose given (0.1 m, 0.05 rad spread), the default capacity:
  mean / max position error, mean heading error, scans more than 0.5 m off
  (``diverged`` when any is).
* ``global``: a uniform start over the map's free space at each particle count:
  ``success`` when the estimate stays within 0.5 m and 10 deg of the reference from
  some scan to the end of the log (at least the last 10 scans); that scan and its log time; the filter's wall time
  and scans per second (filter loop, and loop plus compilation and start).
  ``--process-timing`` also times one whole ``jaxslam localize`` process per particle
  count (seed 0: import, map and log reading, compilation, the run, the files).
* ``kidnap``: the log cut at scan ``k`` and continued from scan ``m`` (a robot lifted
  and carried elsewhere: the scans jump to another place of the building while the
  odometry shows no motion across the cut; ``k`` and ``m`` drawn per seed, at least
  ``--kidnap-min-jump`` metres apart); tracking from the start pose, then the scans and
  log seconds after the cut until the estimate stays within 0.5 m and 10 deg.
* ``amcl`` (``--amcl``): ROS AMCL (``../shared/tools/amcl``'s ``amcl_carmen``, built
  from ``ros-planning/navigation``) and ``jaxslam localize``, each a whole process on the
  same ``map_server`` map and the same perturbed log, tracking (``-initial_log``, the
  initial spread of jaxslam's) and global (``-global``), at the same particle capacity,
  both scored here by the same rule. AMCL runs at amcl_node's defaults (``ros``) and with
  its odometry noise sized for the log's steps (``alpha``: ``odom_alpha1..4`` = 0.02), both
  with the recovery alphas ``0.001 / 0.1`` (amcl_node's fallback; its configuration
  default 0 / 0 turns recovery off) and jaxslam's 60 beams per measurement (amcl_node:
  30). AMCL places cell ``i``'s centre at ``origin + i res``, half a cell off the
  ``map_server`` convention jaxslam follows (about 2 cm of its tracking error here).

    python benchmarks/localization.py --logs intel --tracking-seeds 0 1 2 \
        --global-particles 1000 10000 100000 --global-seeds 0 1 2 3 4 5 6 7 8 9 \
        --seeds-at 100000=5 --kidnap-seeds 0 1 2 3 4 --process-timing [--noise low] [--tag NAME]
    python benchmarks/localization.py --logs intel --amcl --tracking-seeds 0 1 2 \
        --global-particles 1000 10000 --global-seeds 0 1 2 --tag amcl

Writes ``benchmarks/results/localization[_TAG].json`` and ``.png`` (tracking and
kidnapping error along each log; global success rate and scans per second per
particle count; with ``--amcl`` the errors of both localizers).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

from jaxslam.datasets.carmen import PER_SCAN_FIELDS, load_carmen  # noqa: E402
from jaxslam.datasets.geometry import se2_between  # noqa: E402
from jaxslam.datasets.registry import load_dataset_log  # noqa: E402
from jaxslam.datasets.perturb import CORRECTED_LOGS, make_perturbed_log  # noqa: E402
from jaxslam.grid.export import save_map  # noqa: E402
from jaxslam.grid.known_poses import known_pose_log_odds, known_pose_map  # noqa: E402
from jaxslam.localization.experiment import localize, tracking_errors  # noqa: E402
from jaxslam.metrics.trajectory_io import read_tum  # noqa: E402

TRACK_COLUMNS = ["log", "seed", "mean_m", "max_m", "mean_deg", "over_0_5m", "particles_mean", "injections",
                 "wall_s", "scans_per_s"]
GLOBAL_COLUMNS = ["log", "particles", "seed", "success", "converged_scan", "converged_after_s", "final_err_m",
                  "particles_mean", "wall_s", "scans_per_s", "scans_per_s_with_compile"]
KIDNAP_COLUMNS = ["log", "seed", "cut_scan", "resume_scan", "jump_m", "before_mean_m", "recovered",
                  "recovery_scans", "recovery_s", "injections_after", "wall_s"]
AMCL_COLUMNS = ["log", "mode", "localizer", "particles", "seed", "success", "converged_scan", "mean_m",
                "median_m", "particles_mean", "per_update_ms", "process_s"]
AMCL = Path(os.environ.get("AMCL_CARMEN", "/tmp/amcl_build/amcl_carmen"))
AMCL_SETTINGS = {
    "ros": [],
    "alpha": ["-odom_alpha1", "0.02", "-odom_alpha2", "0.02", "-odom_alpha3", "0.02", "-odom_alpha4", "0.02"],
}
AMCL_COMMON = ["-laser_max_beams", "60"]  # jaxslam's beams per measurement (amcl_node's default: 30)
AMCL_RECOVERY = ["-recovery_alpha_slow", "0.001", "-recovery_alpha_fast", "0.1"]
INITIAL_STD = (0.1, 0.1, 0.05)


def build_map(name: str, resolution: float = 0.05):
    reference = load_dataset_log(CORRECTED_LOGS[name])
    started = time.perf_counter()
    log_odds, origin = known_pose_log_odds(reference.ranges, reference.valid, reference.angles,
                                           reference.laser_poses, resolution, reference.max_range,
                                           angle_offsets=reference.angle_offsets)
    return (known_pose_map(log_odds, origin, resolution), reference.laser_poses, time.perf_counter() - started,
            (log_odds, origin, resolution), np.asarray(reference.scan_times, np.float64))


def converged_scan(distance, heading, metres=0.5, degrees=10.0, start: int = 0, hold: int = 10):
    """The first scan at or after ``start`` from which every error is within the bounds,
    if that holds for at least ``hold`` scans (the log's last few scans alone do not count)."""
    bad = np.flatnonzero((distance[start:] >= metres) | (heading[start:] >= np.radians(degrees)))
    first = start if bad.size == 0 else start + int(bad[-1]) + 1
    return None if first > distance.size - max(hold, 1) else first


def kidnapped(log, reference: np.ndarray, reference_times: np.ndarray, cut: int, resume: int):
    """Scans ``0..cut`` then ``resume..``, the odometry without motion across the cut,
    the second part's stamps moved to follow the first's; with its reference poses and
    the reference's stamps moved likewise (the log time)."""
    first, second = np.arange(cut + 1), np.arange(resume, reference.shape[0])
    rows = np.concatenate([first, second])
    fields = {f: np.asarray(getattr(log, f))[rows] for f in PER_SCAN_FIELDS if getattr(log, f, None) is not None}
    odom = np.asarray(log.odom_poses, np.float64)
    rel = se2_between(np.repeat(odom[resume][None], second.size, 0), odom[second])
    anchor = odom[cut]
    c, s = math.cos(anchor[2]), math.sin(anchor[2])
    moved = np.stack([anchor[0] + c * rel[:, 0] - s * rel[:, 1], anchor[1] + s * rel[:, 0] + c * rel[:, 1],
                      np.angle(np.exp(1j * (anchor[2] + rel[:, 2])))], -1)
    fields["odom_poses"] = np.concatenate([odom[first], moved])
    times = np.asarray(log.scan_times, np.float64)
    step = float(np.median(np.diff(times)))
    shift = times[cut] + step - times[resume]
    fields["scan_times"] = np.concatenate([times[first], times[second] + shift])
    if "logger_times" in fields:
        logger = np.asarray(log.logger_times, np.float64)
        fields["logger_times"] = np.concatenate([logger[first], logger[second] + shift])
    gap = float(np.median(np.diff(reference_times)))
    moved_times = np.concatenate([reference_times[first],
                                  reference_times[second] + reference_times[cut] + gap - reference_times[resume]])
    return dataclasses.replace(log, **fields), reference[rows], moved_times


def kidnap_points(reference: np.ndarray, seed: int, min_jump: float) -> tuple[int, int]:
    """``(cut, resume)``: the cut in the log's second quarter, the resumption in its
    third, at least ``min_jump`` m apart."""
    rng = np.random.default_rng(1000 + seed)
    size = reference.shape[0]
    for _ in range(1000):
        cut = int(rng.integers(size // 4, size // 2))
        resume = int(rng.integers(size // 2, 3 * size // 4))
        if np.hypot(*(reference[resume, :2] - reference[cut, :2])) >= min_jump:
            return cut, resume
    raise ValueError(f"no two scans {min_jump} m apart")


def tum_poses(path: Path, count: int) -> np.ndarray:
    _, poses = read_tum(path)
    if poses.shape[0] != count:
        raise ValueError(f"{path}: {poses.shape[0]} poses for {count} scans")
    return poses


def timed_process(command: list[str]) -> tuple[float, str]:
    started = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True)
    elapsed = time.perf_counter() - started
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({done.returncode}): {done.stderr[-2000:]}")
    return elapsed, done.stdout


def jaxslam_process(map_yaml: Path, log_path: Path, out: Path, particles: int, seed: int,
                    initial_pose=None) -> tuple[float, dict, Path]:
    command = [sys.executable, "-m", "jaxslam.app.cli", "localize", "--map", str(map_yaml), "--dataset",
               str(log_path), "--out", str(out), "--particles", str(particles), "--seed", str(seed), "--no-plots"]
    if initial_pose is not None:
        command += ["--initial-pose", *(repr(float(v)) for v in initial_pose),
                    "--initial-std", *(str(v) for v in INITIAL_STD)]
    else:
        command += ["--global"]
    elapsed, _ = timed_process(command)
    return elapsed, json.loads((out / "summary.json").read_text()), out / "trajectory.tum"


def amcl_process(map_yaml: Path, log_path: Path, out: Path, particles: int, min_particles: int, seed: int,
                 setting: str, global_start: bool) -> tuple[float, dict]:
    command = [str(AMCL), "-map", str(map_yaml), "-o", str(out), "-out_every", "scan", "-seed", str(seed + 1),
               "-max_particles", str(particles), "-min_particles", str(min_particles),
               *AMCL_COMMON, *AMCL_SETTINGS[setting], *AMCL_RECOVERY]
    if global_start:
        command += ["-global"]
    else:
        command += ["-initial_log", "-initial_cov", *(f"{s * s:.6g}" for s in INITIAL_STD)]
    elapsed, stdout = timed_process(["nice", "-n", "0", *command, str(log_path)])
    return elapsed, json.loads(stdout.strip().splitlines()[-1])


def scored(poses: np.ndarray, reference: np.ndarray) -> dict:
    distance, heading = tracking_errors(poses, reference)
    start = converged_scan(distance, heading)
    return {"success": start is not None, "converged_scan": start, "mean_m": float(distance.mean()),
            "median_m": float(np.median(distance)), "max_m": float(distance.max()),
            "mean_deg": float(np.degrees(heading).mean()), "final_err_m": float(distance[-1]),
            "distance": distance}


def amcl_cases(name, args, map_yaml, logs, log_paths, reference, scratch) -> list[dict]:
    """jaxslam and AMCL processes on the same map and logs (see the module docstring)."""
    if not AMCL.exists():
        raise SystemExit(f"--amcl: {AMCL} not found; build it with ../shared/tools/amcl/build.sh "
                         "(or set AMCL_CARMEN)")
    rows = []
    cases = [("tracking", args.tracking_particles, s) for s in args.tracking_seeds]
    cases += [("global", p, s) for p in args.global_particles for s in args.global_seeds]
    for mode, particles, seed in cases:
        global_start = mode == "global"
        count = int(np.asarray(logs[seed].ranges).shape[0])
        out = Path(scratch) / f"jaxslam_{mode}_{particles}_{seed}"
        process_s, summary, tum = jaxslam_process(map_yaml, log_paths[seed], out, particles, seed,
                                                  None if global_start else reference[0])
        score = scored(tum_poses(tum, count), reference)
        min_particles = summary["particles_min"] if not global_start else min(particles, max(100, particles // 50))
        row = {"log": name, "mode": mode, "localizer": "jaxslam", "particles": particles, "seed": seed,
               **{k: v for k, v in score.items() if k != "distance"},
               "particles_mean": summary["particles_mean"], "updates": summary["measurements"],
               "per_update_ms": 1e3 * summary["wall_s"] / max(summary["measurements"], 1),
               "per_scan_ms": 1e3 * summary["wall_s"] / count, "loop_s": summary["wall_s"],
               "compile_s": summary["compile_s"], "process_s": process_s}
        rows.append(row)
        print_table([row], AMCL_COLUMNS)
        for setting in AMCL_SETTINGS:
            tum = Path(scratch) / f"amcl_{setting}_{mode}_{particles}_{seed}.tum"
            process_s, stats = amcl_process(map_yaml, log_paths[seed], tum, particles,
                                            min(particles, max(100, particles // 50)), seed, setting, global_start)
            score = scored(tum_poses(tum, count), reference)
            row = {"log": name, "mode": mode, "localizer": f"amcl {setting}", "particles": particles, "seed": seed,
                   **{k: v for k, v in score.items() if k != "distance"},
                   "particles_mean": stats["particles_mean"], "updates": stats["updates"],
                   "per_update_ms": 1e3 * stats["update_mean_s"], "per_scan_ms": 1e3 * stats["loop_s"] / count,
                   "loop_s": stats["loop_s"], "compile_s": 0.0, "process_s": process_s,
                   "amcl_total_s": stats["total_s"]}
            rows.append(row)
            print_table([row], AMCL_COLUMNS)
    return rows


def amcl_ratios(rows: list[dict]) -> list[dict]:
    """Per mode, particle count and AMCL setting: success rates and the time ratios
    AMCL / jaxslam (means over the seeds)."""
    out = []
    keys = sorted({(r["log"], r["mode"], r["particles"]) for r in rows})
    for log, mode, particles in keys:
        group = [r for r in rows if (r["log"], r["mode"], r["particles"]) == (log, mode, particles)]
        ours = [r for r in group if r["localizer"] == "jaxslam"]
        for setting in AMCL_SETTINGS:
            theirs = [r for r in group if r["localizer"] == f"amcl {setting}"]
            if not ours or not theirs:
                continue
            mean = lambda rs, k: float(np.mean([r[k] for r in rs]))  # noqa: E731
            out.append({"log": log, "mode": mode, "particles": particles, "amcl": setting,
                        "jaxslam_success": mean(ours, "success"), "amcl_success": mean(theirs, "success"),
                        "jaxslam_mean_m": mean(ours, "mean_m"), "amcl_mean_m": mean(theirs, "mean_m"),
                        "per_update_ratio": mean(theirs, "per_update_ms") / mean(ours, "per_update_ms"),
                        "per_scan_ratio": mean(theirs, "per_scan_ms") / mean(ours, "per_scan_ms"),
                        "process_ratio": mean(theirs, "process_s") / mean(ours, "process_s")})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", nargs="+", default=["intel"], choices=sorted(CORRECTED_LOGS))
    parser.add_argument("--noise", default="low", choices=["low", "high"])
    parser.add_argument("--tracking-seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--tracking-particles", type=int, default=5000)
    parser.add_argument("--global-particles", type=int, nargs="*", default=[1000, 10000])
    parser.add_argument("--global-seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--seeds-at", action="append", default=[], metavar="PARTICLES=K",
                        help="at this particle count, only the first K of --global-seeds")
    parser.add_argument("--kidnap-seeds", type=int, nargs="*", default=[])
    parser.add_argument("--kidnap-particles", type=int, default=10000)
    parser.add_argument("--kidnap-min-jump", type=float, default=10.0)
    parser.add_argument("--process-timing", action="store_true",
                        help="time one whole `jaxslam localize` process per global particle count")
    parser.add_argument("--amcl", action="store_true",
                        help="only the side-by-side with ROS AMCL (tracking seeds, global counts and seeds)")
    parser.add_argument("--tag", default="")
    parser.add_argument("--replot", action="store_true", help="only draw the figure again from the JSON")
    args = parser.parse_args()
    seeds_at = {int(k): int(v) for k, v in (item.split("=") for item in args.seeds_at)}
    stem = "localization" + (f"_{args.tag}" if args.tag else "")
    if args.replot:
        data = json.loads((RESULTS / f"{stem}.json").read_text())
        if "amcl" in data:
            _plot_amcl(RESULTS / f"{stem}.png", data["amcl"])
        else:
            args.logs = sorted({r["log"] for r in data["global"]}) or args.logs
            args.global_particles = sorted({r["particles"] for r in data["global"]})
            _plot(RESULTS / f"{stem}.png", data["curves"]["tracking"], data["curves"]["kidnap"],
                  rates(data["global"], args), args, raw_scan_rates(args.logs))
        return

    tracking, global_rows, kidnaps, processes, amcl_rows = [], [], [], [], []
    curves, kidnap_curves, amcl_curves = {}, {}, {}

    def save(final: bool = False) -> Path:
        payload = {"noise": args.noise, "tracking_particles": args.tracking_particles,
                   "kidnap_particles": args.kidnap_particles, "tracking": tracking, "global": global_rows,
                   "global_summary": rates(global_rows, args), "kidnap": kidnaps, "process_timing": processes,
                   "curves": {"tracking": curves, "kidnap": kidnap_curves},
                   "command": " ".join(sys.argv), "complete": final}
        if args.amcl:
            payload = {"noise": args.noise, "amcl": amcl_rows, "amcl_summary": amcl_ratios(amcl_rows),
                       "amcl_settings": {k: AMCL_COMMON + v + AMCL_RECOVERY for k, v in AMCL_SETTINGS.items()},
                       "command": " ".join(sys.argv), "complete": final}
        return write_json(stem, payload)

    with tempfile.TemporaryDirectory() as scratch:
        for name in args.logs:
            grid, reference, map_s, (log_odds, origin, resolution), reference_times = build_map(name)
            print(f"{name}: map {grid.shape[1]} x {grid.shape[0]} cells from {reference.shape[0]} poses "
                  f"in {map_s:.1f} s", flush=True)
            map_yaml = save_map(Path(scratch) / name, log_odds, resolution, origin)["yaml"]
            seeds = sorted(set(args.tracking_seeds) | set(args.global_seeds) | set(args.kidnap_seeds))
            log_paths = {s: make_perturbed_log(name, args.noise, s, scratch).log_path for s in seeds}
            logs = {s: load_carmen(p) for s, p in log_paths.items()}
            if args.amcl:
                amcl_rows += amcl_cases(name, args, map_yaml, logs, log_paths, reference, scratch)
                save()
                continue
            for seed in args.tracking_seeds:
                result = localize(logs[seed], grid, particles=args.tracking_particles, seed=seed,
                                  initial_pose=reference[0])
                distance, heading = tracking_errors(result.trajectory, reference)
                curves[f"{name} s{seed}"] = distance.tolist()
                row = {"log": name, "seed": seed, "mean_m": float(distance.mean()), "max_m": float(distance.max()),
                       "mean_deg": float(np.degrees(heading).mean()), "over_0_5m": int(np.sum(distance > 0.5)),
                       "particles_mean": float(result.info["particles"].mean()),
                       "injections": int(np.sum(result.info["injected"] > 0)), "wall_s": result.wall_s,
                       "compile_s": result.compile_s, "scans": int(distance.size),
                       "scans_per_s": distance.size / result.wall_s}
                tracking.append(row)
                print_table([row], TRACK_COLUMNS)
                save()
            for seed in args.kidnap_seeds:
                cut, resume = kidnap_points(reference, seed, args.kidnap_min_jump)
                log, truth, times = kidnapped(logs[seed], reference, reference_times, cut, resume)
                result = localize(log, grid, particles=args.kidnap_particles, seed=seed, initial_pose=truth[0])
                distance, heading = tracking_errors(result.trajectory, truth)
                back = converged_scan(distance, heading, start=cut + 1)
                kidnap_curves[f"{name} s{seed}"] = (distance.tolist(), cut)
                row = {"log": name, "seed": seed, "cut_scan": cut, "resume_scan": resume,
                       "jump_m": float(np.hypot(*(reference[resume, :2] - reference[cut, :2]))),
                       "before_mean_m": float(distance[: cut + 1].mean()),
                       "recovered": back is not None,
                       "recovery_scans": None if back is None else int(back - cut - 1),
                       "recovery_s": None if back is None else float(times[back] - times[cut + 1]),
                       "injections_after": int(np.sum(result.info["injected"][cut + 1:] > 0)),
                       "scans": int(distance.size), "wall_s": result.wall_s, "compile_s": result.compile_s}
                kidnaps.append(row)
                print_table([row], KIDNAP_COLUMNS)
                save()
            for particles in args.global_particles:
                for seed in args.global_seeds[: seeds_at.get(particles, len(args.global_seeds))]:
                    started = time.perf_counter()
                    result = localize(logs[seed], grid, particles=particles, seed=seed)
                    whole = time.perf_counter() - started
                    distance, heading = tracking_errors(result.trajectory, reference)
                    start = converged_scan(distance, heading)
                    row = {"log": name, "particles": particles, "seed": seed, "success": start is not None,
                           "converged_scan": start,
                           "converged_after_s": None if start is None else float(
                               reference_times[start] - reference_times[0]),
                           "final_err_m": float(distance[-1]),
                           "particles_mean": float(result.info["particles"].mean()), "wall_s": result.wall_s,
                           "compile_s": result.compile_s, "with_compile_s": whole, "scans": int(distance.size),
                           "scans_per_s": distance.size / result.wall_s,
                           "scans_per_s_with_compile": distance.size / whole}
                    global_rows.append(row)
                    print_table([row], GLOBAL_COLUMNS)
                    save()
                if args.process_timing:
                    process_s, summary, _ = jaxslam_process(map_yaml, log_paths[args.global_seeds[0]],
                                                            Path(scratch) / f"process_{particles}", particles,
                                                            args.global_seeds[0])
                    scans = summary["scans"]
                    row = {"log": name, "particles": particles, "seed": args.global_seeds[0],
                           "process_s": process_s, "scans": scans, "scans_per_s_process": scans / process_s,
                           "compile_s": summary["compile_s"], "loop_s": summary["wall_s"],
                           "log_duration_s": summary["log_duration_s"]}
                    processes.append(row)
                    print_table([row], list(row))
                    save()
    path = save(final=True)
    if args.amcl:
        print("\namcl"); print_table(amcl_rows, AMCL_COLUMNS)
        summary_rows = amcl_ratios(amcl_rows)
        print("\nratios (AMCL / jaxslam)"); print_table(summary_rows, list(summary_rows[0]) if summary_rows else [])
        _plot_amcl(RESULTS / f"{stem}.png", amcl_rows)
        print(path)
        return
    print("\ntracking"); print_table(tracking, TRACK_COLUMNS)
    print("\nkidnap"); print_table(kidnaps, KIDNAP_COLUMNS)
    print("\nglobal"); print_table(global_rows, GLOBAL_COLUMNS)
    table = rates(global_rows, args)
    print("\nglobal, per particle count"); print_table([{"case": k, **v} for k, v in table.items()],
                                                       ["case", "seeds", "success_rate", "converged_scan_median",
                                                        "converged_s_median", "wall_s_mean", "scans_per_s_mean"])
    _plot(RESULTS / f"{stem}.png", curves, kidnap_curves, table, args, raw_scan_rates(args.logs))
    print(path)


def rates(global_rows: list[dict], args) -> dict:
    table = {}
    for name in args.logs:
        for particles in args.global_particles:
            rows = [r for r in global_rows if r["log"] == name and r["particles"] == particles]
            if rows:
                good = [r for r in rows if r["success"]]
                table[f"{name} {particles}"] = {
                    "seeds": len(rows),
                    "success_rate": float(np.mean([r["success"] for r in rows])),
                    "converged_scan_median": float(np.median([r["converged_scan"] for r in good])) if good else None,
                    "converged_s_median": float(np.median([r["converged_after_s"] for r in good])) if good else None,
                    "wall_s_mean": float(np.mean([r["wall_s"] for r in rows])),
                    "scans_per_s_mean": float(np.mean([r["scans_per_s"] for r in rows])),
                    "scans_per_s_with_compile_mean": float(np.mean([r["scans_per_s_with_compile"] for r in rows])),
                }
    return table


def raw_scan_rates(logs) -> dict[str, float]:
    """Scans per second of the raw log each localized log was corrected from (the log of
    the same name, :func:`jaxslam.datasets.registry.load_dataset_log`; its scans over its
    duration): the rate a filter keeps up with on the robot. The corrected logs are
    GMapping's keyframes, whose spacing is no sensor's rate."""
    rates = {}
    for name in logs:
        raw = load_dataset_log(name)
        duration = float(raw.scan_times[-1] - raw.scan_times[0])
        if duration > 0:
            rates[Path(str(name)).name] = raw.num_scans / duration
    return rates


def _plot(path, curves, kidnap_curves, table, args, scan_rates: dict[str, float]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, middle, right) = plt.subplots(1, 3, figsize=(17, 4.5))
    for label, distance in curves.items():
        left.plot(distance, lw=0.8, label=label)
    left.set_yscale("log")
    left.set_xlabel("scan")
    left.set_ylabel("position error (m)")
    left.set_title(f"tracking, {args.tracking_particles} particles, odometry noise {args.noise}", fontsize=9)
    if curves:
        left.legend(fontsize=7)
    for label, (distance, cut) in kidnap_curves.items():
        middle.plot(np.arange(len(distance)) - cut - 1, distance, lw=0.8, label=label)
    middle.axvline(0, color="k", lw=0.6, ls=":")
    middle.axhline(0.5, color="tab:red", lw=0.6, ls=":")
    middle.set_yscale("log")
    middle.set_xlabel("scans after the kidnapping")
    middle.set_ylabel("position error (m)")
    middle.set_title(f"kidnapping, {args.kidnap_particles} particles", fontsize=9)
    if kidnap_curves:
        middle.legend(fontsize=7)
    labels = list(table)
    if labels:
        x = np.arange(len(labels))
        right.bar(x, [table[k]["success_rate"] for k in labels], color="tab:green", label="success rate")
        right.set_xticks(x, [f"{k}\n({table[k]['seeds']} seeds)" for k in labels], fontsize=8)
        right.set_ylim(0, 1.05)
        right.set_ylabel("success rate")
        twin = right.twinx()
        twin.plot(x, [table[k]["scans_per_s_mean"] for k in labels], "o-", color="tab:blue", label="filter loop")
        twin.plot(x, [table[k]["scans_per_s_with_compile_mean"] for k in labels], "s--", color="tab:blue",
                  label="with compilation")
        for rate in scan_rates.values():
            twin.axhline(rate, color="tab:gray", lw=0.8, ls=":")
        twin.set_yscale("log")
        twin.set_ylabel("scans per second", color="tab:blue")
        twin.legend(fontsize=7, loc="upper right")
        rates_text = ", ".join(f"{log} {rate:.1f}/s" for log, rate in scan_rates.items())
        right.set_title("global localization" + (f" (dotted: the raw log's scan rate, {rates_text})"
                                                 if scan_rates else ""), fontsize=9)
    left.set_visible(bool(curves))
    middle.set_visible(bool(kidnap_curves))
    right.set_visible(bool(labels))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _plot_amcl(path, rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(13, 4.5))
    cases = sorted({(r["mode"], r["particles"]) for r in rows})
    names = ["jaxslam"] + [f"amcl {s}" for s in AMCL_SETTINGS]
    width = 0.8 / len(names)
    x = np.arange(len(cases))
    for i, name in enumerate(names):
        success = [np.mean([r["success"] for r in rows if (r["mode"], r["particles"]) == c and r["localizer"] == name])
                   for c in cases]
        per_update = [np.mean([r["per_update_ms"] for r in rows
                               if (r["mode"], r["particles"]) == c and r["localizer"] == name]) for c in cases]
        left.bar(x + (i - 1) * width, success, width, label=name)
        right.bar(x + (i - 1) * width, per_update, width, label=name)
    for ax in (left, right):
        ax.set_xticks(x, [f"{m}\n{p:,} particles" for m, p in cases], fontsize=8)
        ax.legend(fontsize=7)
    left.set_ylim(0, 1.05)
    left.set_ylabel("converged and stayed (share of seeds)")
    right.set_yscale("log")
    right.set_ylabel("time per filter update (ms)")
    left.set_title("success: within 0.5 m and 10 deg from some scan to the end", fontsize=9)
    right.set_title("per update (jaxslam: filter loop / measurements)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
