"""Table 1 of Zandara & Nicholson (2009): run time with 30 particles, 10 runs each,
for SRUPF-GM without pose correction, GMapping(-style) and SRUPF-GM with pose
correction.

The paper's NSH log is not available; the default is the raw Intel log (911
keyframes with GMapping's 1 m / 0.5 rad thresholds), where the reference GMapping
C++ time is known (55 s with 30 particles). Writes
``benchmarks/results/grid_table1_<dataset>.json`` and ``..._<dataset>.png``.

    python benchmarks/grid_table1.py [--dataset intel] [--runs 10] [--particles 30]
"""

from __future__ import annotations

import argparse

import numpy as np
from grid_common import (
    GMAPPING_CPP_INTEL_S,
    RESULTS,
    machine_info,
    run_in_subprocess,
    save_json,
)

ALGORITHMS = ("srupf-gm-npc", "gmapping", "srupf-gm")
LABELS = {
    "srupf-gm-npc": "SRUPF-GM without pose correction",
    "gmapping": "GMapping-style (JAX)",
    "srupf-gm": "SRUPF-GM with pose correction",
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="intel")
    ap.add_argument("--runs", type=int, default=10)
    ap.add_argument("--particles", type=int, default=30)
    ap.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS))
    args = ap.parse_args()

    table = {}
    for algorithm in args.algorithms:
        runs = []
        for seed in range(args.runs):
            rec = run_in_subprocess({"dataset": args.dataset, "algorithm": algorithm, "particles": args.particles,
                                     "seed": seed})
            print(algorithm, seed, {k: rec.get(k) for k in ("wall_s", "compile_s", "trans_err_mean_m",
                                                           "rot_err_mean_deg", "error")}, flush=True)
            runs.append(rec)
        ok = [r for r in runs if "error" not in r]
        walls = np.array([r["wall_s"] for r in ok])
        entry = {"label": LABELS[algorithm], "runs": runs, "n_ok": len(ok)}
        if ok:
            entry.update(wall_mean_s=float(walls.mean()), wall_std_s=float(walls.std(ddof=1)) if len(ok) > 1 else 0.0,
                         compile_mean_s=float(np.mean([r["compile_s"] for r in ok])),
                         peak_rss_mb_max=float(max(r["peak_rss_mb"] for r in ok)))
            for key in ("trans_err_mean_m", "rot_err_mean_deg"):
                vals = [r[key] for r in ok if key in r]
                if vals:
                    entry[key + "_mean"] = float(np.mean(vals))
                    entry[key + "_std"] = float(np.std(vals))
        table[algorithm] = entry

    reference = GMAPPING_CPP_INTEL_S.get(args.particles) if args.dataset == "intel" else None
    payload = {"dataset": args.dataset, "particles": args.particles, "runs": args.runs, "table": table,
               "gmapping_cpp_reference_s": reference, "machine": machine_info()}
    out = RESULTS / f"grid_table1_{args.dataset}.json"
    save_json(out, payload)
    print("wrote", out)
    print(f"{'algorithm':40s} {'mean s':>8s} {'std s':>7s} {'trans m':>8s} {'rot deg':>8s}")
    for algorithm, e in table.items():
        if e["n_ok"]:
            print(f"{e['label']:40s} {e['wall_mean_s']:8.2f} {e['wall_std_s']:7.2f} "
                  f"{e.get('trans_err_mean_m_mean', float('nan')):8.3f} {e.get('rot_err_mean_deg_mean', float('nan')):8.2f}")
    if reference:
        print(f"{'GMapping C++ (reference, issue 4)':40s} {reference:8.2f}")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    names = [a for a in table if table[a]["n_ok"]]
    means = [table[a]["wall_mean_s"] for a in names]
    stds = [table[a]["wall_std_s"] for a in names]
    ax.barh([LABELS[a] for a in names], means, xerr=stds, color="tab:blue")
    if reference:
        ax.axvline(reference, color="tab:red", ls="--", label=f"GMapping C++ {reference} s")
        ax.legend(loc="lower right")
    ax.set_xlabel(f"run time (s), {args.particles} particles, {args.runs} runs, {args.dataset}")
    fig.tight_layout()
    fig.savefig(RESULTS / f"grid_table1_{args.dataset}.png", dpi=120)


if __name__ == "__main__":
    main()
