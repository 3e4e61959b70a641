"""How well consecutive scans of a GMapping-corrected log agree: point-to-point ICP.

A scan matcher's kernel has to be as wide as the distance at which a right match
finds the walls it saw before: where a scan's end points lie several centimetres from
the previous scan's, a kernel that counts nothing beyond a few centimetres scores
right matches near zero. This measures that distance, independently of jaxslam's
matchers: for consecutive scans ``i, i + 1`` of a corrected log (every ``--stride``-th
pair), the end points of scan ``i + 1`` (within the log's range limit) are aligned to
those of scan ``i`` by point-to-point ICP (SciPy's k-d tree, float64; closed-form 2-D
rotation, correspondences within 1.0, 0.5, 0.3 and then 0.2 m), started at the
reference's relative pose. Per pair it reports the RMS of the nearest-neighbour
distances within 0.2 m after the fit (``rms_m``: range noise, plus the spacing of the
points along the walls, which grows with the range; what a cell-based score meets),
their share of the end points (``inliers``) and how far ICP moved the reference's
relative pose (``icp_turn_deg``, ``icp_shift_m``: an independent check of the
reference). Per log: the quartiles of ``rms_m``, the median share and the median
``|icp_turn_deg|``.

    python benchmarks/diagnostics/scan_pair_agreement.py --logs fr-campus,intel,seattle --stride 5

``--steps-over M`` checks instead the pairs whose reference step is more than ``M``
metres sideways (a wheeled robot does not move so in 0.1-1 s; a corrected log's
path can, where the GMapping run that made it corrected its particle). Each such pair
is aligned twice: by ICP from the reference's relative pose, and by ICP from the best
pose of a grid search that does not start from the reference (:func:`grid_search`:
every 0.1 m and 2 deg within 1.5 m and 20 deg of no motion, then every 0.02 m and
0.5 deg around the best). Per pair: the reference's step, the scans' step (the better
of the two fits), and the mean nearest-neighbour distance of the end points (capped at
0.3 m, so a scan that misses the other by more counts 0.3) at each of the two:

    python benchmarks/diagnostics/scan_pair_agreement.py --logs fr-campus,orebro,csail --steps-over 0.5

Writes ``benchmarks/results/scan_pair_agreement[_NAME].json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import print_table, write_json  # noqa: E402

from jaxslam.datasets.geometry import se2_between, wrap_angle  # noqa: E402

GATES = (1.0, 0.5, 0.3, 0.2)


def end_points(ranges: np.ndarray, valid: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """``(n, 2)`` laser-frame end points of the valid beams."""
    r, a = ranges[valid], angles[valid]
    return np.stack([r * np.cos(a), r * np.sin(a)], -1)


def transform(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    return points @ np.array([[c, s], [-s, c]]) + pose[:2]


def icp(reference: np.ndarray, current: np.ndarray, start: np.ndarray, iterations: int = 50):
    """Pose of ``current``'s frame in ``reference``'s that aligns the two point sets:
    ``(pose (3,), inliers, rms)`` with the correspondences within the last gate."""
    from scipy.spatial import cKDTree

    tree = cKDTree(reference)
    pose = np.asarray(start, np.float64).copy()
    for gate in GATES:
        for _ in range(iterations):
            dist, index = tree.query(transform(current, pose))
            use = dist < gate
            if use.sum() < 10:
                return pose, 0, float("nan")
            a, b = current[use], reference[index[use]]
            ma, mb = a.mean(0), b.mean(0)
            h = (a - ma).T @ (b - mb)
            theta = np.arctan2(h[0, 1] - h[1, 0], h[0, 0] + h[1, 1])
            c, s = np.cos(theta), np.sin(theta)
            shift = mb - np.array([[c, -s], [s, c]]) @ ma
            new = np.array([shift[0], shift[1], theta])
            done = np.allclose(new, pose, atol=1e-8)
            pose = new
            if done:
                break
    dist, _ = tree.query(transform(current, pose))
    use = dist < GATES[-1]
    return pose, int(use.sum()), float(np.sqrt(np.mean(dist[use] ** 2))) if use.any() else float("nan")


CAP = 0.3
"""Nearest-neighbour distances are capped here (m) in :func:`misfit`."""


def _capped_mean(dist: np.ndarray) -> np.ndarray:
    """Mean over the last axis of nearest-neighbour distances, each capped at :data:`CAP`."""
    return np.mean(np.minimum(dist, CAP), axis=-1)


def misfit(tree, current: np.ndarray, pose: np.ndarray) -> float:
    """Mean distance (m, each capped at :data:`CAP`) from ``current``'s end points
    placed at ``pose`` to the nearest end point of the k-d ``tree``."""
    dist, _ = tree.query(transform(current, pose))
    return float(_capped_mean(dist))


def grid_search(tree, current: np.ndarray) -> np.ndarray:
    """The relative pose of least :func:`misfit` against the k-d ``tree`` of the first
    scan's end points on a grid around no motion (every 0.1 m and 2 deg within 1.5 m and
    20 deg), refined on a finer grid around the best (every 0.02 m and 0.5 deg within
    0.1 m and 2 deg): a start that does not come from the reference. Each heading's
    translations are scored in one query."""

    def best_of(center, half, step, half_turn, turn_step):
        shifts = np.arange(-half, half + 1e-9, step)
        grid = np.stack(np.meshgrid(shifts, shifts, indexing="ij"), -1).reshape(-1, 2)  # (dx, dy)
        best, best_pose = np.inf, center
        for turn in np.radians(np.arange(-half_turn, half_turn + 1e-9, turn_step)):
            placed = transform(current, center + np.array([0.0, 0.0, turn]))
            dist, _ = tree.query(placed[None, :, :] + grid[:, None, :])
            costs = _capped_mean(dist)
            k = int(np.argmin(costs))
            if costs[k] < best:
                best, best_pose = costs[k], center + np.array([grid[k, 0], grid[k, 1], turn])
        return best_pose

    coarse = best_of(np.zeros(3), 1.5, 0.1, 20.0, 2.0)
    return best_of(coarse, 0.1, 0.02, 2.0, 0.5)


def _log_scans(name: str):
    from jaxslam.datasets.carmen import load_carmen
    from jaxslam.datasets.perturb import load_reference_log

    reference = load_reference_log(name)
    log = load_carmen(reference.path, max_backstep=np.inf)
    ranges = np.asarray(log.ranges, np.float64)
    valid = np.asarray(log.valid) & np.isfinite(ranges) & (ranges > 0) & (ranges < float(log.max_range) - 0.01)
    angles = np.asarray(log.angles, np.float64)
    return reference.poses, ranges, valid, angles


def step_pairs(name: str, sideways: float) -> list[dict]:
    """The pairs whose reference step is more than ``sideways`` m sideways, each
    aligned from the reference's step and from :func:`grid_search` (module docstring)."""
    from scipy.spatial import cKDTree

    poses, ranges, valid, angles = _log_scans(name)
    steps = se2_between(poses[:-1], poses[1:])
    rows = []
    for i in np.flatnonzero(np.abs(steps[:, 1]) > sideways).tolist():
        a = end_points(ranges[i], valid[i], angles)
        b = end_points(ranges[i + 1], valid[i + 1], angles)
        if min(a.shape[0], b.shape[0]) < 10:
            continue
        tree = cKDTree(a)
        from_reference, _, _ = icp(a, b, steps[i])
        from_grid, _, _ = icp(a, b, grid_search(tree, b))
        if misfit(tree, b, from_reference) < misfit(tree, b, from_grid):
            from_grid = from_reference
        rows.append({"scan": i + 1, "reference_step": [round(float(v), 4) for v in steps[i]],
                     "scan_step": [round(float(v), 4) for v in from_grid],
                     "misfit_reference_m": misfit(tree, b, steps[i]), "misfit_scans_m": misfit(tree, b, from_grid),
                     "shift_m": float(np.hypot(*(from_grid[:2] - steps[i][:2]))),
                     "turn_deg": float(np.degrees(wrap_angle(from_grid[2] - steps[i][2])))})
    return rows


def log_pairs(name: str, stride: int) -> list[dict]:
    poses, ranges, valid, angles = _log_scans(name)
    rows = []
    for i in range(0, poses.shape[0] - 1, stride):
        relative = se2_between(poses[i][None], poses[i + 1][None])[0]
        a = end_points(ranges[i], valid[i], angles)
        b = end_points(ranges[i + 1], valid[i + 1], angles)
        if min(a.shape[0], b.shape[0]) < 10:
            continue
        pose, inliers, rms = icp(a, b, relative)
        turn = wrap_angle(pose[2] - relative[2])
        rows.append({"scan": i, "rms_m": rms, "inliers": inliers / b.shape[0],
                     "icp_turn_deg": float(np.degrees(turn)), "icp_shift_m": float(np.hypot(*(pose[:2] - relative[:2])))})
    return rows


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--logs", default="fr-campus,intel,seattle,infinite-corridor,fhw,csail,belgioioso",
                        help="corrected logs (jaxslam.datasets.perturb.CORRECTED_LOGS), comma separated")
    parser.add_argument("--stride", type=int, default=5, help="every STRIDE-th consecutive pair")
    parser.add_argument("--steps-over", type=float, default=None, metavar="M",
                        help="check the pairs whose reference step is more than M m sideways (module docstring)")
    parser.add_argument("--name", default="")
    args = parser.parse_args(argv)
    if args.steps_over is not None:
        return steps_main(args)
    table, logs = [], {}
    for name in [n for n in args.logs.split(",") if n]:
        print(f"{name} ...", file=sys.stderr, flush=True)
        rows = log_pairs(name, args.stride)
        rms = np.array([r["rms_m"] for r in rows])
        rms = rms[np.isfinite(rms)]
        q1, q2, q3 = np.percentile(rms, [25, 50, 75])
        summary = {"log": name, "pairs": len(rows), "rms_q1_m": q1, "rms_median_m": q2, "rms_q3_m": q3,
                   "inliers_median": float(np.median([r["inliers"] for r in rows])),
                   "icp_turn_median_abs_deg": float(np.median(np.abs([r["icp_turn_deg"] for r in rows])))}
        table.append(summary)
        logs[name] = {"summary": summary, "pairs": rows}
    print_table(table, list(table[0]))
    suffix = f"_{args.name}" if args.name else ""
    print(write_json(f"scan_pair_agreement{suffix}", {"stride": args.stride,
                                                      "gates_m": GATES, "logs": logs}))
    return 0


def steps_main(args) -> int:
    table, logs = [], {}
    for name in [n for n in args.logs.split(",") if n]:
        print(f"{name} ...", file=sys.stderr, flush=True)
        rows = step_pairs(name, args.steps_over)
        logs[name] = rows
        for r in rows:
            table.append({"log": name, "scan": r["scan"],
                          "reference_step": " ".join(f"{v:+.2f}" for v in r["reference_step"][:2])
                          + f" {np.degrees(r['reference_step'][2]):+.1f}deg",
                          "scan_step": " ".join(f"{v:+.2f}" for v in r["scan_step"][:2])
                          + f" {np.degrees(r['scan_step'][2]):+.1f}deg",
                          "misfit_reference_m": round(r["misfit_reference_m"], 3),
                          "misfit_scans_m": round(r["misfit_scans_m"], 3),
                          "shift_m": round(r["shift_m"], 2), "turn_deg": round(r["turn_deg"], 1)})
    if table:
        print_table(table, list(table[0]))
    suffix = f"_{args.name}" if args.name else ""
    print(write_json(f"scan_pair_steps{suffix}", {"steps_over_m": args.steps_over, "cap_m": CAP, "logs": logs}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
