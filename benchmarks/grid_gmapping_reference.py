"""GMapping's own result on Intel and FR079, scored like ours: the relations error of
the GMapping-corrected logs (``carmen_gmapping_corrected/``).

Each corrected log holds, for the scans GMapping processed, the laser pose of its
best particle at that time. Its scans are found in the raw benchmark log by their
range vectors (all of them are there, README of ``carmen_raw/``), turned into robot
poses (laser pose composed with the inverse laser offset), and every other raw scan
gets the last corrected pose composed with the raw odometry since, exactly as
jaxslam's trajectories (:func:`jaxslam.metrics.trajectory_io.interpolate_poses`).
The Kümmerle et al. relations then score it with :func:`relations_metric`.

    python benchmarks/grid_gmapping_reference.py [--datasets intel fr079]

Writes ``benchmarks/results/grid_gmapping_reference.json``.
"""

from __future__ import annotations

import argparse

import numpy as np
from grid_common import RESULTS, machine_info, raw_scan_indices, robot_poses, save_json

from jaxslam.datasets.registry import load_dataset_log
from jaxslam.datasets.geometry import se2_compose, se2_inverse
from jaxslam.metrics.relations import load_dataset_relations, relations_metric
from jaxslam.metrics.trajectory_io import interpolate_poses

CORRECTED = {"intel": "intel-corrected", "fr079": "fr079-corrected"}


def corrected_trajectory(name: str) -> tuple[np.ndarray, np.ndarray, dict]:
    """``(scan_times, poses (S, 3), counts)`` for every scan of the raw log ``name``."""
    raw = load_dataset_log(name)
    corrected = load_dataset_log(CORRECTED[name])
    found = raw_scan_indices(raw, corrected.ranges)
    if np.any(found < 0):
        raise RuntimeError(f"{int(np.sum(found < 0))} corrected scans of {name} are not in the raw log")
    order = np.argsort(found, kind="stable")
    keyframes, laser_poses = found[order], corrected.laser_poses[order]
    keep = np.concatenate([[True], np.diff(keyframes) > 0])  # a repeated scan keeps its first pose
    keyframes, laser_poses = keyframes[keep], laser_poses[keep]
    robot = robot_poses(laser_poses, raw.laser_offset)
    if keyframes[0] != 0:  # before GMapping's first scan: raw odometry from its pose
        keyframes = np.concatenate([[0], keyframes])
        robot = np.concatenate([robot[:1], robot], 0)
        robot[0] = se2_compose(robot[1], se2_compose(se2_inverse(raw.odom_poses[keyframes[1]]), raw.odom_poses[0]))
    poses = interpolate_poses(keyframes, robot, raw.odom_poses)
    counts = {"raw_scans": raw.num_scans, "corrected_scans": corrected.num_scans,
              "matched_scans": int(np.sum(keep))}
    return np.asarray(raw.scan_times), poses, counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", nargs="+", default=list(CORRECTED), choices=list(CORRECTED))
    args = ap.parse_args()
    records = []
    print(f"{'dataset':8s} {'scans':>6s} {'GMapping scans':>14s} {'trans mean (m)':>15s} {'rot mean (deg)':>15s}")
    for name in args.datasets:
        times, poses, counts = corrected_trajectory(name)
        metric = relations_metric(load_dataset_relations(name), times, poses)
        records.append({"dataset": name, "corrected_log": CORRECTED[name], **counts, **metric})
        print(f"{name:8s} {counts['raw_scans']:6d} {counts['matched_scans']:14d} "
              f"{metric['trans_err_mean_m']:15.3f} {metric['rot_err_mean_deg']:15.2f}")
    save_json(RESULTS / "grid_gmapping_reference.json", {"runs": records, "machine": machine_info(),
                                                           "command": "python benchmarks/grid_gmapping_reference.py"})


if __name__ == "__main__":
    main()
