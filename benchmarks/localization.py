"""Localization in maps of the GMapping-corrected logs: tracking and global localization.

For each log, the map is built from the corrected log with its own poses
(:func:`jaxslam.grid.known_poses.known_pose_log_odds`, 5 cm); the log to localize is
the same scans with generated wheel odometry (:func:`jaxslam.datasets.perturb.make_perturbed_log`,
noise level ``low`` or ``high``, one seed per run), scored against the corrected poses.

* ``tracking``: the start pose given (0.1 m, 0.05 rad spread), the default capacity:
  mean / max position error, mean heading error, scans more than 0.5 m off
  (``diverged`` when any is).
* ``global``: a uniform start over the map's free space at each particle count:
  ``success`` when the estimate stays within 0.5 m and 10 deg of the reference from
  some scan to the end of the log; that scan; the filter's wall time and scans per
  second.

    python benchmarks/localization.py --logs intel --tracking-seeds 0 1 2 \
        --global-particles 1000 10000 --global-seeds 0 1 2 [--noise low] [--tag NAME]

Writes ``benchmarks/results/localization[_TAG].json`` and ``.png`` (tracking error
along each log; global success rate and wall time per particle count).
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

from jaxslam.datasets.carmen import load_carmen  # noqa: E402
from jaxslam.datasets.registry import load_dataset_log  # noqa: E402
from jaxslam.datasets.perturb import CORRECTED_LOGS, make_perturbed_log  # noqa: E402
from jaxslam.grid.known_poses import known_pose_log_odds, known_pose_map  # noqa: E402
from jaxslam.localization.experiment import localize, tracking_errors  # noqa: E402

TRACK_COLUMNS = ["log", "seed", "mean_m", "max_m", "mean_deg", "over_0_5m", "particles_mean", "injections",
                 "wall_s", "scans_per_s"]
GLOBAL_COLUMNS = ["log", "particles", "seed", "success", "converged_scan", "final_err_m", "particles_mean",
                  "wall_s", "scans_per_s"]


def build_map(name: str, resolution: float = 0.05):
    reference = load_dataset_log(CORRECTED_LOGS[name])
    started = time.perf_counter()
    log_odds, origin = known_pose_log_odds(reference.ranges, reference.valid, reference.angles,
                                           reference.laser_poses, resolution, reference.max_range,
                                           angle_offsets=reference.angle_offsets)
    return known_pose_map(log_odds, origin, resolution), reference.laser_poses, time.perf_counter() - started


def converged_scan(distance, heading, metres=0.5, degrees=10.0):
    bad = np.flatnonzero((distance >= metres) | (heading >= np.radians(degrees)))
    start = 0 if bad.size == 0 else int(bad[-1]) + 1
    return None if start >= distance.size else start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--logs", nargs="+", default=["intel"], choices=sorted(CORRECTED_LOGS))
    parser.add_argument("--noise", default="low", choices=["low", "high"])
    parser.add_argument("--tracking-seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--tracking-particles", type=int, default=5000)
    parser.add_argument("--global-particles", type=int, nargs="*", default=[1000, 10000])
    parser.add_argument("--global-seeds", type=int, nargs="*", default=[0, 1, 2])
    parser.add_argument("--tag", default="")
    args = parser.parse_args()

    tracking, global_rows, curves = [], [], {}
    with tempfile.TemporaryDirectory() as scratch:
        for name in args.logs:
            grid, reference, map_s = build_map(name)
            print(f"{name}: map {grid.shape[1]} x {grid.shape[0]} cells from {reference.shape[0]} poses "
                  f"in {map_s:.1f} s", flush=True)
            seeds = sorted(set(args.tracking_seeds) | set(args.global_seeds))
            logs = {s: load_carmen(make_perturbed_log(name, args.noise, s, scratch).log_path) for s in seeds}
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
            for particles in args.global_particles:
                for seed in args.global_seeds:
                    result = localize(logs[seed], grid, particles=particles, seed=seed)
                    distance, heading = tracking_errors(result.trajectory, reference)
                    start = converged_scan(distance, heading)
                    row = {"log": name, "particles": particles, "seed": seed, "success": start is not None,
                           "converged_scan": start, "final_err_m": float(distance[-1]),
                           "particles_mean": float(result.info["particles"].mean()), "wall_s": result.wall_s,
                           "compile_s": result.compile_s, "scans": int(distance.size),
                           "scans_per_s": distance.size / result.wall_s}
                    global_rows.append(row)
                    print_table([row], GLOBAL_COLUMNS)
    rates = {}
    for name in args.logs:
        for particles in args.global_particles:
            rows = [r for r in global_rows if r["log"] == name and r["particles"] == particles]
            if rows:
                rates[f"{name} {particles}"] = {
                    "success_rate": float(np.mean([r["success"] for r in rows])),
                    "converged_scan_median": (float(np.median([r["converged_scan"] for r in rows if r["success"]]))
                                              if any(r["success"] for r in rows) else None),
                    "wall_s_mean": float(np.mean([r["wall_s"] for r in rows])),
                    "scans_per_s_mean": float(np.mean([r["scans_per_s"] for r in rows])),
                }
    print("\ntracking"); print_table(tracking, TRACK_COLUMNS)
    print("\nglobal"); print_table(global_rows, GLOBAL_COLUMNS)
    print("\nglobal, per particle count"); print_table([{"case": k, **v} for k, v in rates.items()],
                                                       ["case", "success_rate", "converged_scan_median",
                                                        "wall_s_mean", "scans_per_s_mean"])
    stem = "localization" + (f"_{args.tag}" if args.tag else "")
    path = write_json(stem, {"noise": args.noise, "tracking_particles": args.tracking_particles,
                             "tracking": tracking, "global": global_rows, "global_summary": rates,
                             "command": " ".join(sys.argv)})
    _plot(RESULTS / f"{stem}.png", curves, rates, args)
    print(path)


def _plot(path, curves, rates, args):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.5))
    for label, distance in curves.items():
        left.plot(distance, lw=0.8, label=label)
    left.set_yscale("log")
    left.set_xlabel("scan")
    left.set_ylabel("position error (m)")
    left.set_title(f"tracking, {args.tracking_particles} particles, odometry noise {args.noise}")
    if curves:
        left.legend(fontsize=7)
    labels = list(rates)
    if labels:
        x = np.arange(len(labels))
        right.bar(x, [rates[k]["success_rate"] for k in labels], color="tab:green", label="success rate")
        right.set_xticks(x, labels, rotation=20, fontsize=8)
        right.set_ylim(0, 1.05)
        right.set_ylabel("success rate")
        twin = right.twinx()
        twin.plot(x, [rates[k]["scans_per_s_mean"] for k in labels], "o-", color="tab:blue")
        twin.set_ylabel("scans per second (filter)", color="tab:blue")
        right.set_title(f"global localization, seeds {args.global_seeds}")
    left.set_visible(bool(curves))
    right.set_visible(bool(labels))
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
