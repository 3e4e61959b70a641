"""Streaming latency on a CARMEN log: the batch run and the streaming mapper in one process.

1. ``run_grid_slam`` (batch: keyframes in jitted chunks of 64): wall time per keyframe
   (compilation apart), measured before and after the streaming runs (the ratios use
   the mean of the two).
2. :class:`jaxslam.grid.stream.StreamingGridSlam` fed the same log scan by scan
   (``add_scan`` with each scan's odometry): wall time of every ``add_scan`` call,
   split into keyframes (one jitted filter step each, blocked on its result) and the
   other scans (host work only). The first keyframe (init) and the second (the
   step's compilation) are reported apart; compilations after them are counted.
3. Whether both give the same keyframe poses and map bit for bit.

The streaming mapper runs twice: with its default ray budget (``max_points``: twice
the first keyframe's need, doubled when a keyframe needs more, one compilation each)
and with the batch run's budget (the batch run sizes it from all scans in advance;
the per-keyframe cost grows with it).

Writes ``benchmarks/results/grid_stream_latency_<dataset>.json``.

    python benchmarks/grid_stream_latency.py [--dataset intel] [--particles 30] [--max-keyframes N]
"""

from __future__ import annotations

import argparse
import time

import jax
import numpy as np
from _common import print_table, write_json

from jaxslam.datasets.registry import load_dataset_log
from jaxslam.grid.experiment import keyframe_rule, run_grid_slam
from jaxslam.grid.stream import StreamingGridSlam


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", default="intel")
    parser.add_argument("--algorithm", default="srupf-gm")
    parser.add_argument("--particles", type=int, default=30)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--max-keyframes", type=int, default=None)
    args = parser.parse_args()

    log = load_dataset_log(args.dataset)
    batch = run_grid_slam(log, algorithm=args.algorithm, particles=args.particles, seed=args.seed,
                          max_keyframes=args.max_keyframes, progress=False)
    steps = int(batch.keyframes.shape[0]) - 1
    batch_per_keyframe = batch.wall_s / steps

    compiles = {"count": 0, "active": False}

    def listen(event, duration, **kwargs):
        if compiles["active"] and "backend_compile" in event:
            compiles["count"] += 1

    jax.monitoring.register_event_duration_secs_listener(listen)
    linear, angular, temporal = keyframe_rule()
    last = int(batch.keyframes[-1])
    rows = [{"what": "batch run_grid_slam, per keyframe", "median_ms": 1e3 * batch_per_keyframe, "n": steps,
             "max_points": batch.config.max_points}]
    variants = {}
    for variant, max_points in (("auto ray budget", None), ("ray budget of the batch run", batch.config.max_points)):
        compiles["count"] = 0
        slam = StreamingGridSlam(log.angles, log.laser_offset, algorithm=args.algorithm, particles=args.particles,
                                 seed=args.seed, linear_update=linear, angular_update=angular,
                                 temporal_update=temporal, max_points=max_points)
        other = []
        started = time.perf_counter()
        for i in range(last + 1):
            if len(slam.keyframes) == 2:
                compiles["active"] = True
            t0 = time.perf_counter()
            flags = slam.add_scan(log.scan_times[i], log.ranges[i], log.valid[i], odom_pose=log.odom_poses[i])
            if not flags[-1]:
                other.append(time.perf_counter() - t0)
        total = time.perf_counter() - started
        compiles["active"] = False
        latency = np.asarray(slam.latency_s[2:])
        identical = bool(np.array_equal(slam.keyframe_poses(), batch.keyframe_poses)
                         and np.array_equal(slam.map()[0], batch.map_log_odds))
        variants[variant] = {
            "total_s": total, "keyframe_median_s": float(np.median(latency)),
            "keyframe_p99_s": float(np.percentile(latency, 99)), "keyframe_max_s": float(np.max(latency)),
            "other_scan_median_s": float(np.median(other)), "other_scan_p99_s": float(np.percentile(other, 99)),
            "first_keyframe_s": slam.latency_s[0], "second_keyframe_s": slam.latency_s[1],
            "compilations_after_first_step": compiles["count"], "step_versions": slam.step_versions(),
            "max_points": slam.config.max_points, "growths": slam.stats.growths, "counts": slam.counts,
            "median_keyframe_ratio_stream_over_batch": float(np.median(latency)) / batch_per_keyframe,
            "identical_keyframe_poses_and_map": identical,
        }
        rows += [
            {"what": f"stream keyframe, {variant}", "median_ms": 1e3 * float(np.median(latency)),
             "p99_ms": 1e3 * float(np.percentile(latency, 99)), "max_ms": 1e3 * float(np.max(latency)),
             "n": int(latency.size), "max_points": slam.config.max_points,
             "ratio": float(np.median(latency)) / batch_per_keyframe, "compiles_after_1st": compiles["count"],
             "identical": identical},
            {"what": f"stream other scan, {variant}", "median_ms": 1e3 * float(np.median(other)),
             "p99_ms": 1e3 * float(np.percentile(other, 99)), "max_ms": 1e3 * float(np.max(other)), "n": len(other)},
            {"what": f"stream init + compile, {variant}", "median_ms": 1e3 * (slam.latency_s[0] + slam.latency_s[1]),
             "n": 2},
        ]
    # The batch run again (its runner is cached): the machine's load drifts, so the
    # ratio uses the mean of the runs before and after the streams.
    again = run_grid_slam(log, algorithm=args.algorithm, particles=args.particles, seed=args.seed,
                          max_keyframes=args.max_keyframes, progress=False)
    batch_after = again.wall_s / steps
    batch_mean = 0.5 * (batch_per_keyframe + batch_after)
    rows.insert(1, {"what": "batch run_grid_slam again, per keyframe", "median_ms": 1e3 * batch_after, "n": steps,
                    "max_points": again.config.max_points})
    for row in rows:
        if "ratio" in row:
            row["ratio"] = row["median_ms"] / (1e3 * batch_mean)
    for variant in variants.values():
        variant["median_keyframe_ratio_stream_over_batch"] = variant["keyframe_median_s"] / batch_mean
    print_table(rows, ["what", "median_ms", "p99_ms", "max_ms", "n", "max_points", "ratio", "compiles_after_1st",
                       "identical"])
    path = write_json(f"grid_stream_latency_{args.dataset}", {
        "dataset": args.dataset, "algorithm": args.algorithm, "particles": args.particles, "seed": args.seed,
        "scans": last + 1, "keyframes": steps + 1,
        "batch": {"wall_s": batch.wall_s, "compile_s": batch.compile_s, "s_per_keyframe": batch_per_keyframe,
                  "s_per_keyframe_after_streams": batch_after, "s_per_keyframe_mean": batch_mean,
                  "max_points": batch.config.max_points, "growths": batch.growths},
        "stream": variants,
        "note": "machine shared with other jobs; compare the ratios, measured in one process",
    })
    print(path)


if __name__ == "__main__":
    main()
