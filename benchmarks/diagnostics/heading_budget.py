r"""Where a run's heading error comes from: the scans whose tracking match was trusted,
or the ones where it was refused and the odometry was followed.

For the runs that ``benchmarks/grid_robustness.py`` keeps (``/tmp/grid_robustness/TAG/
*.npz``) on a perturbed GMapping-corrected log, every scan-to-scan increment's heading
error against the corrected log (the reference the suite scores against) is

.. math:: e_k = \mathrm{wrap}\big(\Delta\theta_k - \Delta\theta^{ref}_k\big), \qquad
    \Delta\theta_k = \theta_k - \theta_{k-1},

and the same for the generated odometry (regenerated from the reference, the level and
the run's seed with :func:`jaxslam.datasets.perturb.perturb_odometry`, as the suite made
it). Summed over a scan range, :math:`\sum e_k` is the heading the run has gathered
there; it is split by the scan's ``Info.track_accepted`` (the tracking match was
trusted) and ``Info.keyframe``. A run that keeps its heading where matches are trusted
and loses it where they are refused shows it as a large refused sum.

Two ways to do better where matches are refused can be read off the same scans
(``--compare``), without running the filter:

* ``laser``: the scan-to-scan heading of :mod:`jaxslam.grid.laser_odometry` (where it
  trusts its match; the odometry's heading elsewhere);
* ``bias``: the odometry's heading less a running estimate of its systematic error,
  :math:`\hat e_k = \hat b\, d_k + \hat r\, \Delta\theta^{odo}_k` (heading bias per
  metre, rotation scale), fitted by least squares to the trusted scans' differences
  :math:`\Delta\theta^{odo} - \Delta\theta` (those under 10 deg) with a forgetting factor
  :math:`e^{-(d + 0.3 |\Delta\theta|)/L}` per scan (``--bias-length`` :math:`L` m).

Each is scored on the refused scans by the sum and the sum of absolute values of its
heading error, next to the odometry's.

    python benchmarks/diagnostics/heading_budget.py --log fr-campus --level high \
        --runs '/tmp/grid_robustness/campus/*.npz' --scans 302:1300 --compare laser bias \
        --name heading_budget_campus

Prints the table and writes ``benchmarks/results/NAME.json``.
"""

from __future__ import annotations

import argparse
import glob
import re
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import print_table, write_json  # noqa: E402
from grid_common import heading_errors  # noqa: E402

from jaxslam.datasets.geometry import se2_between, wrap_angle  # noqa: E402


def heading_increments(poses: np.ndarray) -> np.ndarray:
    """``(S-1, 3)`` robot-frame increments between consecutive poses."""
    poses = np.asarray(poses, np.float64)
    return se2_between(poses[:-1], poses[1:])


def budget(errors: np.ndarray, accepted: np.ndarray, keyframe: np.ndarray) -> dict[str, float]:
    """Sums (deg) of ``errors`` over all scans and by class; ``accepted``/``keyframe`` are
    the flags of the same increments."""
    accepted = np.asarray(accepted, bool)
    keyframe = np.asarray(keyframe, bool)
    deg = np.degrees(errors)
    classes = {"all": np.ones_like(accepted), "trusted": accepted, "refused": ~accepted,
               "refused_keyframe": ~accepted & keyframe, "refused_between": ~accepted & ~keyframe}
    out: dict[str, float] = {}
    for name, mask in classes.items():
        out[f"{name}_n"] = int(mask.sum())
        out[f"{name}_deg"] = float(deg[mask].sum())
    out["all_abs_deg"] = float(np.abs(deg).sum())
    return out


def bias_prediction(odom_inc: np.ndarray, run_inc: np.ndarray, accepted: np.ndarray, length: float,
                    outlier: float = np.radians(10.0)) -> np.ndarray:
    """``(n,)`` the predicted odometry heading error of each increment from the trusted
    increments before it (module docstring, ``bias``)."""
    dist = np.hypot(odom_inc[:, 0], odom_inc[:, 1])
    normal = np.zeros((2, 2))
    rhs = np.zeros(2)
    ridge = 1e-2 * np.eye(2)
    out = np.zeros(len(odom_inc))
    for k in range(len(odom_inc)):
        phi = np.array([dist[k], odom_inc[k, 2]])
        out[k] = phi @ np.linalg.solve(normal + ridge, rhs)
        forget = np.exp(-(dist[k] + 0.3 * abs(odom_inc[k, 2])) / length)
        normal *= forget
        rhs *= forget
        difference = wrap_angle(odom_inc[k, 2] - run_inc[k, 2])
        if accepted[k] and abs(difference) < outlier:
            normal += np.outer(phi, phi)
            rhs += phi * difference
    return out


def seed_of(path: str) -> int:
    match = re.search(r"_s(\d+)\.npz$", path)
    if match is None:
        raise ValueError(f"{path}: no seed in the name (expected ..._s<seed>.npz)")
    return int(match.group(1))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--log", default="fr-campus", help="corrected log the runs perturbed")
    parser.add_argument("--level", default="high")
    parser.add_argument("--runs", action="append", required=True, help="glob of saved runs (.npz)")
    parser.add_argument("--scans", default=None, help="A:B, the increments of scans A..B-1 (default: all)")
    parser.add_argument("--compare", nargs="*", default=[], choices=["laser", "bias"])
    parser.add_argument("--bias-length", type=float, default=10.0)
    parser.add_argument("--name", default="heading_budget")
    args = parser.parse_args(argv)

    from jaxslam.datasets.perturb import NOISE_LEVELS, load_reference_log, perturb_odometry

    reference = load_reference_log(args.log)
    paths = sorted({p for pattern in args.runs for p in glob.glob(pattern)})
    if not paths:
        raise SystemExit(f"no runs match {args.runs}")
    rows = []
    for path in paths:
        run = np.load(path)
        if "info_track_accepted" not in run.files:
            raise SystemExit(f"{path}: no tracking flags (a GMapping C++ run?)")
        seed = seed_of(path)
        odom, _ = perturb_odometry(reference.poses, NOISE_LEVELS[args.level], seed)
        n = min(len(run["trajectory"]), len(reference.poses))
        lo, hi = (1, n) if args.scans is None else (int(s) for s in args.scans.split(":"))
        rows_k = np.arange(lo, min(hi, n)) - 1  # increment k-1 ends at scan k
        accepted = run["info_track_accepted"][rows_k]
        keyframe = run["info_keyframe"][rows_k]
        run_err = heading_errors(run["trajectory"], reference.poses)[rows_k]
        odo_err = heading_errors(odom, reference.poses)[rows_k]
        row: dict = {"run": Path(path).stem, "scans": f"{lo}:{hi}"}
        row.update({f"run_{k}": v for k, v in budget(run_err, accepted, keyframe).items()})
        row["odometry_all_deg"] = float(np.degrees(odo_err.sum()))
        refused = ~accepted.astype(bool)
        row["odometry_refused_deg"] = float(np.degrees(odo_err[refused].sum()))
        row["odometry_refused_abs_deg"] = float(np.degrees(np.abs(odo_err[refused]).sum()))
        if "laser" in args.compare:
            from jaxslam.datasets.carmen import load_carmen
            from jaxslam.datasets.perturb import make_perturbed_log
            from jaxslam.grid.laser_odometry import laser_heading_increments

            made = make_perturbed_log(args.log, args.level, seed, Path("/tmp/heading_budget_logs"))
            increments, info = laser_heading_increments(load_carmen(made.log_path))
            laser_err = wrap_angle(increments[:n - 1, 2] - heading_increments(reference.poses[:n])[:, 2])[rows_k]
            row["laser_trusted_on_refused"] = int(info["accepted"][rows_k][refused].sum())
            row["laser_refused_deg"] = float(np.degrees(laser_err[refused].sum()))
            row["laser_refused_abs_deg"] = float(np.degrees(np.abs(laser_err[refused]).sum()))
        if "bias" in args.compare:
            all_acc = run["info_track_accepted"][: n - 1].astype(bool)
            predicted = bias_prediction(heading_increments(odom[:n]), heading_increments(run["trajectory"][:n]),
                                        all_acc, args.bias_length)
            bias_err = wrap_angle(odo_err - predicted[rows_k])
            row["bias_refused_deg"] = float(np.degrees(bias_err[refused].sum()))
            row["bias_refused_abs_deg"] = float(np.degrees(np.abs(bias_err[refused]).sum()))
        rows.append(row)
    shown = ["run", "run_all_deg", "run_trusted_deg", "run_refused_n", "run_refused_deg", "odometry_refused_deg",
             "odometry_refused_abs_deg"] + [k for k in rows[0] if k.startswith(("laser_", "bias_"))]
    print_table(rows, shown)
    path = write_json(args.name, {"log": args.log, "level": args.level, "runs": paths, "scans": args.scans,
                                  "compare": args.compare, "bias_length": args.bias_length, "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
