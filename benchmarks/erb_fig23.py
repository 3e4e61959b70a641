"""The ERB paper's Figs. 2-3 on Victoria Park: RB vs ERB with 3 particles, same seed.

For each seed both filters run with identical random streams. Reported per run:
resampling count, the growth of the weight variance, GPS error after rigid
alignment, and whether the run diverged (GPS RMS error above ``--diverged-m``).
The figure shows, for the first seed, the trajectories against GPS, the cumulative
resamplings and the weight variance over time.

    python benchmarks/erb_fig23.py [--seeds 0 1 2 3 4] [--particles 3]

Writes ``benchmarks/results/erb_fig23.json`` and ``erb_fig23.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

from jaxslam.datasets import victoria_park  # noqa: E402
from jaxslam.feature.experiment import run_landmark_slam  # noqa: E402
from jaxslam.metrics.gps import gps_error  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=3)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--diverged-m", type=float, default=10.0)
    parser.add_argument("--name", default="erb_fig23")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=args.steps)
    rows, curves = [], {}
    for seed in args.seeds:
        for algorithm in ("rb-upf", "erb-upf"):
            res = run_landmark_slam(seq, algorithm, particles=args.particles, seed=seed, progress=False)
            err = gps_error(res.times, res.trajectory, seq.gps_times, seq.gps_xy)
            wv = res.info["weight_variance"]
            rows.append(
                dict(
                    algorithm=algorithm,
                    seed=seed,
                    resamplings=res.resamplings,
                    mean_weight_variance=float(np.mean(wv)),
                    gps_mean_m=err["gps_mean_m"],
                    gps_rms_m=err["gps_rms_m"],
                    gps_max_m=err["gps_max_m"],
                    diverged=bool(err["gps_rms_m"] > args.diverged_m),
                    landmarks=res.landmarks,
                    wall_s=res.wall_s,
                    compile_s=res.compile_s,
                )
            )
            if seed == args.seeds[0]:
                aligned = res.trajectory[:, :2] @ err["rotation"].T + err["translation"]
                curves["gps_used"] = err["used"]
                curves[algorithm] = dict(
                    xy=aligned,
                    resampled=np.cumsum(res.info["resampled"]),
                    weight_variance=wv,
                    landmarks=res.landmark_means @ err["rotation"].T + err["translation"],
                )
            print(f"{algorithm} seed {seed}: {rows[-1]['resamplings']} resamplings, "
                  f"GPS mean {rows[-1]['gps_mean_m']:.2f} m, diverged {rows[-1]['diverged']}", flush=True)

    totals = {}
    for algorithm in ("rb-upf", "erb-upf"):
        mine = [r for r in rows if r["algorithm"] == algorithm]
        totals[algorithm] = dict(
            runs=len(mine),
            diverged=int(sum(r["diverged"] for r in mine)),
            mean_resamplings=float(np.mean([r["resamplings"] for r in mine])),
            mean_gps_mean_m=float(np.mean([r["gps_mean_m"] for r in mine])),
            median_gps_mean_m=float(np.median([r["gps_mean_m"] for r in mine])),
        )
    path = write_json(
        args.name,
        dict(
            figure="Kim, Kim & Chung 2011, Figs. 2-3",
            dataset="victoria-park",
            particles=args.particles,
            seeds=args.seeds,
            diverged_rule=f"GPS RMS error > {args.diverged_m} m",
            runs=rows,
            totals=totals,
        ),
    )
    print_table(rows, ["algorithm", "seed", "resamplings", "mean_weight_variance", "gps_mean_m", "gps_max_m", "diverged"])
    print(totals)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.8))
    used = curves["gps_used"]
    axes[0].plot(seq.gps_xy[used, 0], seq.gps_xy[used, 1], "b+", ms=2, label="GPS (jumps skipped)")
    for algorithm, color in (("rb-upf", "tab:red"), ("erb-upf", "tab:green")):
        c = curves[algorithm]
        axes[0].plot(c["landmarks"][:, 0], c["landmarks"][:, 1], "x", color=color, ms=3)
        axes[0].plot(c["xy"][:, 0], c["xy"][:, 1], color=color, lw=0.8, label=algorithm)
        axes[1].plot(seq.times, c["resampled"], color=color, label=algorithm)
        window = 100
        smooth = np.convolve(c["weight_variance"], np.ones(window) / window, mode="same")
        axes[2].plot(seq.times, smooth, color=color, lw=0.8, label=algorithm)
    axes[0].set_aspect("equal")
    axes[0].set_title(f"trajectories vs GPS (seed {args.seeds[0]}, {args.particles} particles)")
    axes[1].set_title("cumulative resamplings")
    axes[2].set_title("variance of the normalised weights (100-scan mean)")
    for ax in axes:
        ax.legend(fontsize=8)
    axes[1].set_xlabel("time [s]")
    axes[2].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
