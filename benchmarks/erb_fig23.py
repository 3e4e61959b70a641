"""The ERB paper's Figs. 2-3 as a statistic: RB vs ERB with 3 particles over many seeds.

Kim, Kim & Chung (2011) show one run in which the RB filter with 3 particles diverges
(around 886-900 s) while ERB keeps its particles diverse. Here both filters run the
same seeds (identical random streams for a seed), each algorithm as one ensemble
(:func:`jaxslam.feature.ensemble.run_landmark_ensemble`). Per seed: GPS error after
rigid alignment, divergence (GPS RMS error above ``--diverged-m``), resamplings and
the variance of the normalised weights. Reported: the divergence rate of each filter
with its 95% Wilson interval, the paired outcome (seeds where only RB or only ERB
diverged), mean resamplings and weight variance with 95% t intervals, and the growth
of the weight variance (mean over the last quarter of the run divided by the first).
The figure shows the GPS error of every seed, the cumulative resamplings and the
weight variance over time (mean over seeds).

    python benchmarks/erb_fig23.py [--seeds 50] [--particles 3]

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
from jaxslam.feature.ensemble import run_landmark_ensemble  # noqa: E402
from jaxslam.metrics.gps import gps_error  # noqa: E402
from jaxslam.metrics.stats import mean_ci, rate_ci  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=3)
    parser.add_argument("--seeds", type=int, default=50, help="seeds 0 .. SEEDS-1")
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--diverged-m", type=float, default=10.0)
    parser.add_argument("--name", default="erb_fig23")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=args.steps)
    seeds = list(range(args.seeds))
    per_alg, totals, curves = {}, {}, {}
    for algorithm in ("rb-upf", "erb-upf"):
        res = run_landmark_ensemble(seq, algorithm, particles=args.particles, seeds=seeds)
        errs = [gps_error(seq.times, res.trajectory[i], seq.gps_times, seq.gps_xy) for i in range(len(seeds))]
        wv = res.info["weight_variance"]  # (S, T)
        quarter = wv.shape[1] // 4
        growth = (wv[:, -quarter:].mean(axis=1) + 1e-12) / (wv[:, :quarter].mean(axis=1) + 1e-12)
        rows = [
            dict(
                algorithm=algorithm,
                seed=s,
                gps_mean_m=e["gps_mean_m"],
                gps_rms_m=e["gps_rms_m"],
                gps_max_m=e["gps_max_m"],
                diverged=bool(e["gps_rms_m"] > args.diverged_m),
                resamplings=int(res.resamplings[i]),
                mean_weight_variance=float(wv[i].mean()),
                weight_variance_growth=float(growth[i]),
                landmarks=int(res.landmarks[i]),
            )
            for i, (s, e) in enumerate(zip(seeds, errs))
        ]
        per_alg[algorithm] = rows
        diverged = sum(r["diverged"] for r in rows)
        totals[algorithm] = dict(
            runs=len(rows),
            diverged=diverged,
            divergence_rate=rate_ci(diverged, len(rows)),
            resamplings=mean_ci([r["resamplings"] for r in rows]),
            mean_weight_variance=mean_ci([r["mean_weight_variance"] for r in rows]),
            weight_variance_growth_median=float(np.median(growth)),
            gps_mean_m=mean_ci([r["gps_mean_m"] for r in rows]),
            gps_mean_m_median=float(np.median([r["gps_mean_m"] for r in rows])),
            wall_s=res.wall_s,
            compile_s=res.compile_s,
        )
        curves[algorithm] = dict(
            resampled=np.cumsum(res.info["resampled"], axis=1).mean(axis=0),
            weight_variance=wv.mean(axis=0),
            gps=[r["gps_rms_m"] for r in rows],
        )
        t = totals[algorithm]
        print(f"{algorithm}: diverged {diverged}/{len(rows)} (rate {t['divergence_rate']['rate']:.2f}, 95% CI "
              f"{t['divergence_rate']['ci_low']:.2f}-{t['divergence_rate']['ci_high']:.2f}), resamplings "
              f"{t['resamplings']['mean']:.0f}, GPS mean {t['gps_mean_m']['mean']:.2f} m "
              f"(median {t['gps_mean_m_median']:.2f}), wall {res.wall_s:.1f} s", flush=True)

    rb = {r["seed"]: r["diverged"] for r in per_alg["rb-upf"]}
    erb = {r["seed"]: r["diverged"] for r in per_alg["erb-upf"]}
    paired = dict(
        both=sum(rb[s] and erb[s] for s in seeds),
        only_rb=sum(rb[s] and not erb[s] for s in seeds),
        only_erb=sum(erb[s] and not rb[s] for s in seeds),
        neither=sum(not rb[s] and not erb[s] for s in seeds),
    )
    rows = per_alg["rb-upf"] + per_alg["erb-upf"]
    path = write_json(
        args.name,
        dict(
            figure="Kim, Kim & Chung 2011, Figs. 2-3",
            dataset="victoria-park",
            particles=args.particles,
            seeds=seeds,
            diverged_rule=f"GPS RMS error > {args.diverged_m} m",
            runs=rows,
            totals=totals,
            paired=paired,
        ),
    )
    print_table(rows, ["algorithm", "seed", "resamplings", "mean_weight_variance", "gps_mean_m", "gps_rms_m", "diverged"])
    print(totals)
    print("paired outcomes:", paired)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    colors = {"rb-upf": "tab:red", "erb-upf": "tab:green"}
    for j, algorithm in enumerate(("rb-upf", "erb-upf")):
        c = curves[algorithm]
        x = j + np.random.default_rng(0).uniform(-0.15, 0.15, len(c["gps"]))
        axes[0].plot(x, c["gps"], ".", color=colors[algorithm])
        axes[1].plot(seq.times, c["resampled"], color=colors[algorithm], label=algorithm)
        window = 100
        smooth = np.convolve(c["weight_variance"], np.ones(window) / window, mode="same")
        axes[2].plot(seq.times, smooth, color=colors[algorithm], lw=0.8, label=algorithm)
    axes[0].axhline(args.diverged_m, color="k", lw=0.8, ls="--", label=f"RMS {args.diverged_m} m (divergence rule)")
    axes[0].set_xticks([0, 1], ["rb-upf", "erb-upf"])
    axes[0].set_yscale("log")
    axes[0].set_ylabel("GPS RMS error per seed [m]")
    axes[0].set_title(f"{len(seeds)} seeds, {args.particles} particles")
    axes[1].set_title("cumulative resamplings (mean over seeds)")
    axes[2].set_title("weight variance (mean over seeds, 100-scan mean)")
    for ax in axes:
        ax.legend(fontsize=8)
    axes[1].set_xlabel("time [s]")
    axes[2].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
