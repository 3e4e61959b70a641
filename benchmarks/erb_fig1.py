"""The ERB paper's Fig. 1 on Victoria Park: log(det P_ERB / det P_RB) at every update.

ERB-UPF with 100 particles runs over the full dataset; at each update step the RB
proposal is computed on the same particles from the same sigma points (the filter's
``Info`` carries both, particle-weighted: log sum_m w_m det P^[m]). The paper's claim:
the log ratio never goes below 0 (their minimum: 9.5e-5).

    python benchmarks/erb_fig1.py [--particles 100] [--seed 0] [--steps N]

Writes ``benchmarks/results/erb_fig1.json`` and ``erb_fig1.png``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from _common import RESULTS, write_json  # noqa: E402

from jaxslam.datasets import victoria_park  # noqa: E402
from jaxslam.feature.experiment import run_landmark_slam  # noqa: E402
from jaxslam.metrics.gps import gps_error  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--particles", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=None, help="only the first N scans")
    parser.add_argument("--name", default="erb_fig1")
    args = parser.parse_args()

    seq = victoria_park.load_sequence("detections", max_range=30.0, max_steps=args.steps)
    res = run_landmark_slam(seq, "erb-upf", particles=args.particles, seed=args.seed, progress=True)
    info = res.info
    updated = np.isfinite(info["log_det_proposal_erb"]) & np.isfinite(info["log_det_proposal_rb"])
    ratio = (info["log_det_proposal_erb"] - info["log_det_proposal_rb"])[updated]
    err = gps_error(res.times, res.trajectory, seq.gps_times, seq.gps_xy)
    summary = dict(
        figure="Kim, Kim & Chung 2011, Fig. 1",
        algorithm="erb-upf",
        dataset="victoria-park",
        particles=args.particles,
        seed=args.seed,
        steps=res.steps,
        updates=int(updated.sum()),
        log_ratio_min=float(ratio.min()),
        log_ratio_max=float(ratio.max()),
        log_ratio_mean=float(ratio.mean()),
        negative_updates=int((ratio < 0).sum()),
        paper_log_ratio_min=9.5e-5,
        claim_holds=bool(ratio.min() >= 0),
        wall_s=res.wall_s,
        compile_s=res.compile_s,
        ms_per_scan=1000 * res.wall_s / res.steps,
        resamplings=res.resamplings,
        landmarks=res.landmarks,
        gps_mean_m=err["gps_mean_m"],
        gps_rms_m=err["gps_rms_m"],
        gps_max_m=err["gps_max_m"],
    )
    path = write_json(args.name, summary)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(8, 3.5))
    ax.plot(np.arange(ratio.size), ratio, lw=0.6)
    ax.axhline(0.0, color="k", lw=0.5)
    ax.set_xlabel("update step")
    ax.set_ylabel(r"$\log(\det P_{ERB} / \det P_{RB})$")
    ax.set_title(f"Victoria Park, ERB-UPF {args.particles} particles: minimum {ratio.min():.3g}")
    fig.tight_layout()
    fig.savefig(RESULTS / f"{args.name}.png", dpi=120)
    print(f"wrote {path}")
    for key in ("updates", "log_ratio_min", "negative_updates", "wall_s", "compile_s", "gps_mean_m", "landmarks"):
        print(f"  {key}: {summary[key]}")


if __name__ == "__main__":
    main()
