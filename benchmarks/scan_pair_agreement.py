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

    python benchmarks/scan_pair_agreement.py --logs fr-campus,intel,seattle --stride 5

Writes ``benchmarks/results/scan_pair_agreement[_NAME].json``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

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


def log_pairs(name: str, stride: int) -> list[dict]:
    from jaxslam.datasets.carmen import load_carmen
    from jaxslam.datasets.perturb import load_reference_log

    reference = load_reference_log(name)
    log = load_carmen(reference.path, max_backstep=np.inf)
    ranges = np.asarray(log.ranges, np.float64)
    valid = np.asarray(log.valid) & np.isfinite(ranges) & (ranges > 0) & (ranges < float(log.max_range) - 0.01)
    angles = np.asarray(log.angles, np.float64)
    poses = reference.poses
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
    parser.add_argument("--name", default="")
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    raise SystemExit(main())
