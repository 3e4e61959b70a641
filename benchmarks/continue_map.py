"""Mapping that continues: the second part of a log mapped from the first part's saved
map, against the whole log mapped in one run.

Usage:
    python benchmarks/continue_map.py [--dataset intel] [--seeds 0 1 2] [--particles 30]
        [--split 0.5] [--algorithm srupf-gm] [--json continue_map]

For each seed: the whole log in one run; its first ``split`` of the scans in one run,
whose best map is saved as ``map.npz`` (:func:`jaxslam.grid.mapfile.save_map_npz`,
with the run's last pose) and read back (:func:`jaxslam.grid.mapfile.load_map`), as
``jaxslam run --start-map`` reads it; then the rest of the log from that map, started at
the first part's last pose moved by the one odometry step between the parts (the
first scan is then matched in the saved map, :func:`jaxslam.grid.filter.match_start`).
Both the continued trajectory and the whole-log run's are scored by the relations
metric on the relations whose two stamps both lie in the second part.

With ``--localize-first`` the first seed's second part is also started as ``jaxslam run
--localize-first`` starts it (:func:`jaxslam.app.runs.localized_start`: Monte Carlo
localization in the saved map from a uniform start, then mapping from its estimate at
the last of its scans) for ``--localize-keyframes`` keyframes, against the run above
started at the known pose: where the two starts lie apart, and how far the two paths
do over the same scans.

Writes ``benchmarks/results/<json>.json``: per seed the two scores, the relations
scored, the first-scan match and the three runs' times; and ``<json>.png``, the first
seed's continued map with the second part's path.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _common import RESULTS, print_table, write_json  # noqa: E402


def second_part(relations, start_time: float):
    """The relations whose two stamps lie at or after ``start_time``."""
    keep = (relations.t1 >= start_time) & (relations.t2 >= start_time)
    return dataclasses.replace(relations, t1=relations.t1[keep], t2=relations.t2[keep],
                               deltas=relations.deltas[keep], lines=relations.lines[keep])


def one_seed(log, relations, split: int, seed: int, particles: int, algorithm: str, folder: Path,
             image: Path | None = None, localize_keyframes: int = 0) -> dict:
    from jaxslam.datasets.carmen import scan_range
    from jaxslam.datasets.geometry import se2_between, se2_compose
    from jaxslam.grid.export import save_map_png
    from jaxslam.grid.experiment import run_grid_slam
    from jaxslam.grid.mapfile import load_map, save_map_npz
    from jaxslam.metrics.relations import relations_metric

    whole = run_grid_slam(log, algorithm, particles, seed, progress=False)
    first = run_grid_slam(scan_range(log, 0, split), algorithm, particles, seed, progress=False)
    path = save_map_npz(folder / f"first_{seed}.npz", first.map_log_odds, first.resolution, first.origin,
                        log_odds_unit=first.params["map.log_odds_unit"], pose=first.trajectory[-1])
    step = se2_between(log.odom_poses[split - 1], log.odom_poses[split])
    start = se2_compose(first.trajectory[-1], step)
    second = run_grid_slam(scan_range(log, split), algorithm, particles, seed, progress=False,
                           start_map=load_map(path), initial_pose=start)
    if image is not None:  # the continued map, the second part's path in red
        save_map_png(image, second.map_log_odds, second.resolution, second.origin, trajectory=second.trajectory)
    scored = second_part(relations, float(log.scan_times[split]))
    continued = relations_metric(scored, second.scan_times, second.trajectory)
    reference = relations_metric(scored, whole.scan_times, whole.trajectory)
    record = {"seed": seed, "relations": continued["n_relations"],
            "continued_trans_m": continued["trans_err_mean_m"], "continued_rot_deg": continued["rot_err_mean_deg"],
            "whole_trans_m": reference["trans_err_mean_m"], "whole_rot_deg": reference["rot_err_mean_deg"],
            "ratio": continued["trans_err_mean_m"] / reference["trans_err_mean_m"],
            "first_scan_match": second.start_match,
            "wall_s": {"whole": whole.wall_s, "first": first.wall_s, "second": second.wall_s}}
    if localize_keyframes:
        record["localize_first"] = localize_first(scan_range(log, split), load_map(path), second, seed,
                                                  particles, algorithm, localize_keyframes)
    return record


def localize_first(log, grid, known, seed: int, particles: int, algorithm: str, keyframes: int) -> dict:
    """The second part started by localization in the saved map, against ``known`` (the
    run started at the known pose): the start's offset and the paths' largest gap."""
    from jaxslam.app.runs import localized_start
    from jaxslam.datasets.carmen import scan_range
    from jaxslam.datasets.geometry import se2_between
    from jaxslam.grid.experiment import run_grid_slam

    scan, pose, report = localized_start(log, grid, seed)
    mapped = run_grid_slam(scan_range(log, scan), algorithm, particles, seed, progress=False, start_map=grid,
                           initial_pose=pose, max_keyframes=keyframes)
    offset = se2_between(known.trajectory[scan], np.asarray(pose, np.float64))
    scans = mapped.trajectory.shape[0]
    gap = np.hypot(*(mapped.trajectory[:, :2] - known.trajectory[scan:scan + scans, :2]).T)
    return {"converged_scan": report["converged_scan"], "start_scan": scan, "keyframes": keyframes,
            "start_offset_m": float(np.hypot(offset[0], offset[1])), "start_offset_deg": float(np.degrees(offset[2])),
            "scans_compared": int(scans), "max_gap_m": float(gap.max()),
            "first_scan_match": mapped.start_match}


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="intel", help="a registered log with relations")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--particles", type=int, default=30)
    parser.add_argument("--algorithm", default="srupf-gm")
    parser.add_argument("--split", type=float, default=0.5, help="fraction of the scans in the first part")
    parser.add_argument("--localize-first", action="store_true",
                        help="also start the first seed's second part by localization in the saved map")
    parser.add_argument("--localize-keyframes", type=int, default=30, help="keyframes mapped after --localize-first")
    parser.add_argument("--json", default="continue_map")
    args = parser.parse_args(argv)
    if not 0.0 < args.split < 1.0:
        parser.error(f"--split must lie strictly between 0 and 1, got {args.split}")

    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.metrics.relations import load_dataset_relations

    log = load_dataset_log(args.dataset)
    relations = load_dataset_relations(args.dataset)
    scans = int(log.ranges.shape[0])
    split = int(round(args.split * scans))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            image = RESULTS / f"{args.json}.png" if seed == args.seeds[0] else None
            localize = args.localize_keyframes if args.localize_first and seed == args.seeds[0] else 0
            rows.append(one_seed(log, relations, split, seed, args.particles, args.algorithm, Path(tmp), image,
                                 localize))
            print(f"seed {seed}: continued {rows[-1]['continued_trans_m']:.4f} m, "
                  f"whole log {rows[-1]['whole_trans_m']:.4f} m", flush=True)
    print_table(rows, ["seed", "relations", "continued_trans_m", "whole_trans_m", "ratio"])
    path = write_json(args.json, {"dataset": args.dataset, "algorithm": args.algorithm,
                                  "particles": args.particles, "scans": scans, "split_scan": split,
                                  "command": "python benchmarks/continue_map.py " + " ".join(argv or sys.argv[1:]),
                                  "runs": rows})
    print("wrote", path)


if __name__ == "__main__":
    main()
