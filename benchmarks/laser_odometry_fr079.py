"""Heading increments of the laser-corrected odometry (jaxslam.grid.laser_odometry)
against GMapping's corrected FR079 poses, next to the wheel odometry's.

Every scan of ``freiburg-079-corrected`` is found in the raw ``fr079`` log by its
ranges (identical to 3 decimals); for consecutive matched scans, and over 20 matched
scans, the heading change of each odometry is compared with the corrected poses'.
The reference is GMapping's estimate, not ground truth. Prints a table and writes
``benchmarks/results/laser_odometry_fr079.json``.

    python benchmarks/laser_odometry_fr079.py [--min-gain 0.02 0.1]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv=None) -> int:
    from _common import print_table, write_json

    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.datasets.geometry import se2_between, se2_compose, wrap_angle
    from jaxslam.grid.laser_odometry import LaserOdometryConfig, laser_heading_increments

    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--min-gain", type=float, nargs="+", default=[0.02, 0.1])
    args = parser.parse_args(argv)
    raw = load_dataset_log("fr079")
    ref = load_dataset_log("freiburg-079-corrected", max_backstep=np.inf)
    index = {r.tobytes(): i for i, r in enumerate(np.round(raw.ranges.astype(np.float64), 3))}
    pairs = [(index.get(r.tobytes()), j) for j, r in enumerate(np.round(ref.ranges.astype(np.float64), 3))]
    pairs = [(i, j) for i, j in pairs if i is not None]
    ri = np.array([i for i, _ in pairs])
    reference = ref.laser_poses[np.array([j for _, j in pairs])]
    forward = np.diff(ri) > 0

    def errors(odom: np.ndarray, k: int) -> np.ndarray:
        est = se2_between(odom[ri[:-k]], odom[ri[k:]])[:, 2]
        return np.degrees(np.abs(wrap_angle(est - se2_between(reference[:-k], reference[k:])[:, 2])))

    def row(name: str, odom: np.ndarray, extra: dict) -> dict:
        e1 = errors(odom, 1)[forward]
        e20 = errors(odom, 20)
        return {"odometry": name, **extra, "inc_abs_mean_deg": float(e1.mean()), "inc_max_deg": float(e1.max()),
                "inc_over_5deg": int((e1 > 5).sum()), "w20_abs_mean_deg": float(e20.mean()),
                "w20_p99_deg": float(np.percentile(e20, 99)), "w20_max_deg": float(e20.max())}

    rows = [row("wheel", raw.odom_poses, {"matched": len(pairs)})]
    for gain in args.min_gain:
        t0 = time.perf_counter()
        increments, info = laser_heading_increments(raw, LaserOdometryConfig(min_gain=gain))
        seconds = time.perf_counter() - t0
        odom = np.empty_like(raw.odom_poses)
        odom[0] = raw.odom_poses[0]
        for i, u in enumerate(increments):
            odom[i + 1] = se2_compose(odom[i], u)
        rows.append(row(f"laser min_gain={gain}", odom,
                        {"matched": len(pairs), "accepted": float(info["accepted"].mean()), "seconds": seconds}))
    columns = ["odometry", "accepted", "inc_abs_mean_deg", "inc_max_deg", "inc_over_5deg", "w20_abs_mean_deg",
               "w20_p99_deg", "w20_max_deg", "seconds"]
    print_table(rows, columns)
    print(write_json("laser_odometry_fr079", {"rows": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
