r"""How far runs' paths lie from a reference run's, on a log without ground truth.

The logs of the robustness suite that have no reference (``fr-clinic``, ``mit-csail``,
the MRPT logs) are scored by the largest keyframe correction only, which says how much
a filter moved, not whether it was right. Where GMapping C++ maps such a log cleanly,
its path is a yardstick: not the truth, but a second opinion from another program.
This compares the per-scan paths that ``benchmarks/grid_robustness.py`` saves (the
``.npz`` files under ``--work``, ``trajectory``: one pose per scan, the same for a
jaxslam run and a GMapping C++ run) with one of them.

Each path is rigidly aligned to the reference on its first ``--align-scans`` scans
(:func:`jaxslam.metrics.gps.align_rigid_2d`, least squares; the runs start in
different frames), then for every scan

.. math:: d_k = \| R\,p_k + t - q_k \|

(:math:`p` the run's position, :math:`q` the reference's). Per run: :math:`d` at
``--points`` evenly spaced scans after the aligned stretch, its median and its
maximum. A run that agrees with the reference about as well as the reference's own
other seeds do (run them too) maps what the reference maps; a run metres away lost
its way somewhere, or the reference did. On MIT CSAIL (the
documentation's design notes, stale odometry), GMapping C++'s five seeds lie within 0.8 m of each other, and SRUPF-GM's runs
lay 5-37 m from them before the stale-odometry repair and within 0.9 m after it.

    python benchmarks/path_agreement.py --reference W/mit-csail_gmapping-cpp_s2.npz \
        W/mit-csail_gmapping-cpp_s*.npz W/mit-csail_srupf-gm_s*.npz --name csail

Writes ``benchmarks/results/path_agreement[_NAME].json``; with ``--draw LOG``, a map
of each run (its scans drawn at its keyframe poses, :func:`draw_scans`) under
``benchmarks/results/path_agreement_maps[/NAME]/``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import print_table, write_json  # noqa: E402

from jaxslam.metrics.gps import align_rigid_2d  # noqa: E402


def path_distances(path: np.ndarray, reference: np.ndarray, align_scans: int) -> np.ndarray:
    """``(n,)`` distances :math:`d_k` of the module docstring over the scans both paths
    hold (``n = min`` of their lengths), after aligning ``path`` on the first
    ``align_scans`` of them."""
    path = np.asarray(path, np.float64)
    reference = np.asarray(reference, np.float64)
    n = min(path.shape[0], reference.shape[0])
    if not 2 <= align_scans <= n:
        raise ValueError(f"align_scans must be within 2..{n} (the scans both paths hold), got {align_scans}")
    rotation, translation = align_rigid_2d(path[:align_scans, :2], reference[:align_scans, :2])
    moved = path[:n, :2] @ rotation.T + translation
    return np.hypot(*(moved - reference[:n, :2]).T)


def summarize(distances: np.ndarray, align_scans: int, points: int) -> dict[str, Any]:
    """``d`` at ``points`` evenly spaced scans from the end of the aligned stretch to
    the last scan, and the median and maximum of ``d`` over those scans."""
    after = distances[align_scans - 1 :]
    marks = np.linspace(align_scans - 1, distances.shape[0] - 1, points).round().astype(int)
    return {
        "scans": [int(m) for m in marks],
        "distance_m": [float(distances[m]) for m in marks],
        "median_m": float(np.median(after)),
        "max_m": float(after.max()),
    }


def scan_points(log, keyframes: np.ndarray, poses: np.ndarray) -> np.ndarray:
    """``(M, 2)`` world end points of the valid beams of the log's scans ``keyframes``
    seen from the robot ``poses`` (through the laser's mounting ``log.laser_offset``)."""
    from jaxslam.datasets.geometry import se2_compose

    sensor = se2_compose(np.asarray(poses, np.float64), np.asarray(log.laser_offset, np.float64))
    angles = np.asarray(log.beam_angles(), np.float64)[keyframes] + sensor[:, 2:3]
    ranges = np.asarray(log.ranges, np.float64)[keyframes]
    hit = np.asarray(log.valid, bool)[keyframes]
    return np.stack([(sensor[:, 0:1] + ranges * np.cos(angles))[hit], (sensor[:, 1:2] + ranges * np.sin(angles))[hit]], 1)


def draw_scans(log, keyframes: np.ndarray, poses: np.ndarray, out: Path, title: str) -> Path:
    """:func:`scan_points` drawn with the path: a map of any saved run, GMapping C++'s
    too (its driver writes poses, not a map)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x, y = scan_points(log, keyframes, poses).T
    fig, ax = plt.subplots(figsize=(12, 12))
    ax.scatter(x, y, s=0.05, c="k", alpha=0.3, linewidths=0)
    ax.plot(poses[:, 0], poses[:, 1], "r-", lw=0.5)
    ax.set_aspect("equal")
    ax.set_title(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80, bbox_inches="tight")
    plt.close(fig)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", nargs="+", help="saved runs (.npz with 'trajectory')")
    parser.add_argument("--reference", required=True, help="the run the others are compared with")
    parser.add_argument("--align-scans", type=int, default=300)
    parser.add_argument("--points", type=int, default=8)
    parser.add_argument("--name", default="")
    parser.add_argument("--draw", metavar="LOG", help="also draw each run's scans at its keyframe poses "
                        "(LOG: the log's name or path) under benchmarks/results/path_agreement_maps[/NAME]/")
    args = parser.parse_args(argv)

    def load(path: str) -> np.ndarray:
        with np.load(path) as data:
            if "trajectory" not in data:
                raise SystemExit(f"{path}: no 'trajectory' array (a run saved by grid_robustness.py?)")
            return data["trajectory"]

    reference = load(args.reference)
    rows = []
    for run in args.runs:
        summary = summarize(path_distances(load(run), reference, args.align_scans), args.align_scans, args.points)
        rows.append({"run": f"{Path(run).parent.name}/{Path(run).name}", "path": str(run), **summary})
    table = [{"run": r["run"], "median_m": r["median_m"], "max_m": r["max_m"],
              "at scans": " ".join(f"{s}:{d:.1f}" for s, d in zip(r["scans"], r["distance_m"]))} for r in rows]
    print_table(table, ["run", "median_m", "max_m", "at scans"])
    out = write_json("path_agreement" + (f"_{args.name}" if args.name else ""), {
        "reference": args.reference, "align_scans": args.align_scans, "rows": rows,
        "command": "python benchmarks/path_agreement.py " + " ".join(argv if argv is not None else sys.argv[1:]),
    })
    print(f"wrote {out}")
    if args.draw:
        from jaxslam.datasets.registry import load_dataset_log

        log = load_dataset_log(args.draw)
        folder = out.parent / "path_agreement_maps" / (args.name or "default")
        for run in args.runs:
            with np.load(run) as data:
                png = folder / (Path(run).parent.name + "_" + Path(run).stem + ".png")
                print(f"wrote {draw_scans(log, data['keyframes'], data['keyframe_poses'], png, Path(run).name)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
