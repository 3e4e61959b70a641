"""Accuracy and speed of RB-UPF and ERB-UPF against the particle count, Victoria Park,
as seed statistics.

For each particle count and algorithm, one ensemble of ``--seeds`` seeds run as one
program (:func:`jaxslam.feature.ensemble.run_landmark_ensemble`): per seed the GPS
error after rigid alignment (mean, RMS, max), the landmarks of the best particle and
the resamplings; per point the mean, standard deviation and 95% confidence interval
(Student t) over seeds, and per seed the filter's diagnostics
(:func:`jaxslam.metrics.particle_diagnostics.landmark_run_summary`: association
disagreement between particles, landmark-count spread, surviving ancestors, weight
entropy, lineage changes of the best particle). Wall time is that of the whole ensemble after compilation
(compilation reported apart), and per seed.

    python benchmarks/erb_particles.py [--particles 1 3 10 30 100 300 1000] [--seeds 10]

Writes ``benchmarks/results/<name>.json`` and ``<name>.png``. With ``--merge`` the
points already in ``<name>.json`` that this run does not redo are kept.

Variants of the defaults, for the same statistics: ``--params '{"resample_threshold":
0.2}'`` (overrides of :class:`~jaxslam.feature.params.Params`), ``--config '{...}'``
(of :class:`~jaxslam.feature.params.Config`), ``--max-range 50`` (the sequence's
range cut and the filter's), ``--steering acfr``
(:func:`jaxslam.datasets.victoria_park.load_sequence`); ``--label`` names the variant
in the rows (a point is one algorithm, particle count and label, so variants merge
into one file without replacing each other).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

from jaxslam.datasets import victoria_park  # noqa: E402
from jaxslam.feature.ensemble import run_landmark_ensemble  # noqa: E402
from jaxslam.metrics.gps import gps_error  # noqa: E402
from jaxslam.metrics.particle_diagnostics import landmark_run_summary  # noqa: E402
from jaxslam.metrics.stats import mean_ci  # noqa: E402


def summarise(seq, res, label: str = "") -> dict:
    """Seed statistics of one ensemble."""
    errs = [gps_error(seq.times, res.trajectory[i], seq.gps_times, seq.gps_xy) for i in range(len(res.seeds))]
    row = dict(algorithm=res.algorithm, particles=res.particles, seeds=res.seeds, steps=res.steps, label=label)
    for name in ("gps_mean_m", "gps_rms_m", "gps_max_m"):
        values = [e[name] for e in errs]
        stats = mean_ci(values)
        row[name] = stats["mean"]
        row[f"{name}_std"] = stats["std"]
        row[f"{name}_ci"] = [stats["ci_low"], stats["ci_high"]]
        row[f"{name}_per_seed"] = values
    row["gps_mean_m_median"] = float(np.median(row["gps_mean_m_per_seed"]))
    row["landmarks_per_seed"] = res.landmarks.tolist()
    row["landmarks"] = float(np.mean(res.landmarks))
    row["resamplings_per_seed"] = res.resamplings.tolist()
    row["resamplings"] = float(np.mean(res.resamplings))
    diagnostics = [landmark_run_summary({k: v[i] for k, v in res.info.items()}, seq.obs_mask, res.particles)
                   for i in range(len(res.seeds))]
    row["diagnostics_per_seed"] = diagnostics
    row["diagnostics"] = {k: float(np.mean([d[k] for d in diagnostics])) for k in diagnostics[0]}
    row["wall_s"] = res.wall_s
    row["wall_s_per_seed"] = res.wall_s / len(res.seeds)
    row["compile_s"] = res.compile_s
    row["us_per_particle_scan"] = 1e6 * res.wall_s / (res.steps * res.particles * len(res.seeds))
    return row


def plot(rows, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    series = sorted({(r.get("label", ""), r["algorithm"]) for r in rows})
    base_colors = {"rb-upf": "tab:red", "erb-upf": "tab:green"}
    others = iter(plt.rcParams["axes.prop_cycle"].by_key()["color"])
    for k, (label, algorithm) in enumerate(series):
        color = base_colors.get(algorithm) if not label else next(others)
        shift = 1.0 + 0.06 * (k - (len(series) - 1) / 2)
        mine = sorted((r for r in rows if r["algorithm"] == algorithm and r.get("label", "") == label),
                      key=lambda r: r["particles"])
        algorithm = f"{algorithm} {label}".strip()
        n = np.array([r["particles"] for r in mine], float) * shift
        mean = np.array([r["gps_mean_m"] for r in mine])
        ci = np.array([r["gps_mean_m_ci"] for r in mine])
        axes[0].errorbar(n, mean, yerr=[mean - ci[:, 0], ci[:, 1] - mean], fmt="o-", color=color, capsize=3,
                         label=f"{algorithm}: mean, 95% CI over seeds")
        for x, r in zip(n, mine):
            axes[0].plot(np.full(len(r["gps_mean_m_per_seed"]), x), r["gps_mean_m_per_seed"], ".", color=color,
                         alpha=0.35, ms=4)
            top = max(max(r["gps_mean_m_per_seed"]), np.nan_to_num(r["gps_mean_m_ci"][1]))
            axes[0].annotate(f"{len(r['seeds'])}", (x, top), textcoords="offset points",
                             xytext=(0, 4), ha="center", fontsize=7, color=color)
        axes[1].loglog(n, [r["wall_s_per_seed"] for r in mine], "o-", color=color, label=f"{algorithm} wall per seed")
    axes[0].set_xscale("log")
    axes[0].set_ylim(bottom=0, top=axes[0].get_ylim()[1] * 1.08)
    axes[0].set_xlabel("particles")
    axes[0].set_ylabel("mean GPS error [m]")
    axes[0].set_title("Victoria Park accuracy (dots: seeds; numbers: seeds per point)", fontsize=10)
    axes[1].set_xlabel("particles")
    axes[1].set_ylabel("seconds (ensemble wall / seeds)")
    axes[1].set_title("filter time per seed (run as one ensemble)")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[1, 3, 10, 30, 100, 300, 1000])
    parser.add_argument("--algorithms", nargs="+", default=["rb-upf", "erb-upf"])
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0 .. SEEDS-1")
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--name", default="erb_particles")
    parser.add_argument("--merge", action="store_true", help="keep the other points of an existing result file")
    parser.add_argument("--params", default="{}", help="JSON overrides of the filter Params")
    parser.add_argument("--config", default="{}", help="JSON overrides of the filter Config")
    parser.add_argument("--max-range", type=float, default=30.0, help="range cut of the sequence and the filter [m]")
    parser.add_argument("--steering", default="mat", choices=["mat", "acfr"], help="steering calibration")
    parser.add_argument("--label", default="", help="name of the variant (part of a point's key)")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=args.max_range, max_steps=args.steps,
                                      steering=args.steering)
    params = {"max_range": args.max_range, **json.loads(args.params)}
    config = json.loads(args.config)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rows = []
    old = RESULTS / f"{args.name}.json"
    if args.merge and old.exists():
        rows = json.loads(old.read_text()).get("runs", [])
    redo = {(a, n, args.label) for a in args.algorithms for n in args.particles}
    rows = [r for r in rows if (r["algorithm"], r["particles"], r.get("label", "")) not in redo]
    for n in args.particles:
        for algorithm in args.algorithms:
            res = run_landmark_ensemble(seq, algorithm, particles=n, seeds=seeds, params=params, config=config)
            rows.append(summarise(seq, res, args.label))
            rows[-1].update(params_overrides=params, config_overrides=config, steering=args.steering)
            rows[-1]["command"] = "python " + " ".join(sys.argv)
            r = rows[-1]
            print(f"{algorithm} {args.label} N={n}, {len(seeds)} seeds: GPS mean {r['gps_mean_m']:.2f} m "
                  f"(std {r['gps_mean_m_std']:.2f}, 95% CI {r['gps_mean_m_ci'][0]:.2f}-{r['gps_mean_m_ci'][1]:.2f}), "
                  f"wall {r['wall_s']:.1f} s, compile {r['compile_s']:.1f} s", flush=True)
            write_json(args.name, dict(dataset="victoria-park", runs=rows, complete=False))
    rows.sort(key=lambda r: (r.get("label", ""), r["algorithm"], r["particles"]))
    path = write_json(args.name, dict(dataset="victoria-park", runs=rows, complete=True))
    print_table(rows, ["label", "algorithm", "particles", "gps_mean_m", "gps_mean_m_std", "gps_mean_m_median", "gps_rms_m",
                       "gps_max_m", "landmarks", "resamplings", "wall_s_per_seed", "compile_s"])
    plot(rows, RESULTS / f"{args.name}.png")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
