"""Accuracy and speed of RB-UPF and ERB-UPF against the particle count, Victoria Park.

For each particle count and algorithm: GPS error after rigid alignment (mean, RMS,
max), landmarks of the best particle, resamplings, wall time after compilation and
compilation time (reported apart), ms per scan and per particle-scan.

    python benchmarks/erb_particles.py [--particles 1 3 10 30 100 300 1000] [--seed 0]

Writes ``benchmarks/results/erb_particles.json`` and ``erb_particles.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, print_table, write_json  # noqa: E402

from jaxslam.datasets import victoria_park  # noqa: E402
from jaxslam.feature.experiment import run_landmark_slam  # noqa: E402
from jaxslam.metrics.gps import gps_error  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[1, 3, 10, 30, 100, 300, 1000])
    parser.add_argument("--algorithms", nargs="+", default=["rb-upf", "erb-upf"])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--name", default="erb_particles")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=args.steps)
    rows = []
    for n in args.particles:
        for algorithm in args.algorithms:
            res = run_landmark_slam(seq, algorithm, particles=n, seed=args.seed, progress=False)
            err = gps_error(res.times, res.trajectory, seq.gps_times, seq.gps_xy)
            rows.append(
                dict(
                    algorithm=algorithm,
                    particles=n,
                    seed=args.seed,
                    steps=res.steps,
                    gps_mean_m=err["gps_mean_m"],
                    gps_rms_m=err["gps_rms_m"],
                    gps_max_m=err["gps_max_m"],
                    landmarks=res.landmarks,
                    resamplings=res.resamplings,
                    wall_s=res.wall_s,
                    compile_s=res.compile_s,
                    ms_per_scan=1000 * res.wall_s / res.steps,
                    us_per_particle_scan=1e6 * res.wall_s / (res.steps * n),
                )
            )
            r = rows[-1]
            print(f"{algorithm} N={n}: GPS mean {r['gps_mean_m']:.2f} m, wall {r['wall_s']:.1f} s, "
                  f"compile {r['compile_s']:.1f} s", flush=True)
            write_json(args.name, dict(dataset="victoria-park", seed=args.seed, runs=rows, complete=False))
    path = write_json(args.name, dict(dataset="victoria-park", seed=args.seed, runs=rows, complete=True))
    print_table(rows, ["algorithm", "particles", "gps_mean_m", "gps_rms_m", "gps_max_m", "landmarks",
                       "resamplings", "wall_s", "compile_s", "ms_per_scan"])

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for algorithm, color in (("rb-upf", "tab:red"), ("erb-upf", "tab:green")):
        mine = [r for r in rows if r["algorithm"] == algorithm]
        if not mine:
            continue
        n = [r["particles"] for r in mine]
        axes[0].loglog(n, [r["gps_mean_m"] for r in mine], "o-", color=color, label=f"{algorithm} mean")
        axes[0].loglog(n, [r["gps_max_m"] for r in mine], "x--", color=color, label=f"{algorithm} max")
        axes[1].loglog(n, [r["wall_s"] for r in mine], "o-", color=color, label=f"{algorithm} wall")
        axes[1].loglog(n, [r["compile_s"] for r in mine], "x:", color=color, label=f"{algorithm} compile")
    axes[0].set_xlabel("particles")
    axes[0].set_ylabel("GPS error [m]")
    axes[1].set_xlabel("particles")
    axes[1].set_ylabel("seconds")
    axes[0].legend(fontsize=8)
    axes[1].legend(fontsize=8)
    axes[0].set_title("Victoria Park accuracy")
    axes[1].set_title("run time (after compilation) and compile time")
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
