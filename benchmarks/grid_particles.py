"""Fig. 3 of Zandara & Nicholson (2009) on the raw Intel log: run time against the
number of particles (10 to 1000) and against the added odometry noise, plus the
relations error (Kümmerle et al. 2009) against the number of particles, for
SRUPF-GM (pc, npc) and the GMapping-style filter; GMapping C++ reference times
(issue 4) are drawn for comparison. Each point runs ``--seeds`` seeds (default 10,
each a fresh process) and reports the relations error's mean, standard deviation and
95% Student-t interval over them (:func:`jaxslam.metrics.stats.mean_ci`); the error
figure shows the interval and every seed.

Writes ``benchmarks/results/grid_particles_<dataset>.json`` and the figures
``grid_time_vs_particles_<dataset>.png``, ``grid_error_vs_particles_<dataset>.png``,
``grid_time_vs_noise_<dataset>.png``.

    python benchmarks/grid_particles.py [--particles 10 30 50 100 300 1000] [--seeds 10]
        [--noise-scales 0.5 1 2 4] [--skip-noise] [--name NAME]
"""

from __future__ import annotations

import argparse

import numpy as np
from grid_common import (
    GMAPPING_CPP_INTEL_S,
    GMAPPING_CPP_PEAK_MB,
    RESULTS,
    machine_info,
    run_in_subprocess,
    save_json,
)

from jaxslam.metrics.stats import mean_ci

ALGORITHMS = ("srupf-gm", "srupf-gm-npc", "gmapping")
COLORS = {"srupf-gm": "tab:blue", "srupf-gm-npc": "tab:green", "gmapping": "tab:orange"}

# The noise each filter adds, scaled together by the noise sweep.
NOISE_KEYS = {
    "srupf-gm": ("q_linear", "q_angular", "q_linear_per_m", "q_angular_per_rad", "q_angular_per_m"),
    "srupf-gm-npc": ("q_linear", "q_angular", "q_linear_per_m", "q_angular_per_rad", "q_angular_per_m"),
    "gmapping": ("srr", "srt", "str_", "stt"),
}


def noise_overrides(algorithm: str, scale: float) -> dict:
    from jaxslam.grid.types import default_params

    base = default_params(np.zeros(2))._asdict()
    return {k: float(base[k]) * scale for k in NOISE_KEYS[algorithm]}


def summarise(records):
    ok = [r for r in records if "error" not in r]
    if not ok:
        return {"n_ok": 0}
    out = {"n_ok": len(ok), "wall_mean_s": float(np.mean([r["wall_s"] for r in ok])),
           "wall_std_s": float(np.std([r["wall_s"] for r in ok])),
           "s_per_keyframe": float(np.mean([r["s_per_keyframe"] for r in ok])),
           "peak_rss_mb": float(max(r["peak_rss_mb"] for r in ok))}
    for key in ("trans_err_mean_m", "trans_err_std_m", "rot_err_mean_deg", "rot_err_std_deg"):
        vals = [r[key] for r in ok if key in r]
        if vals:
            out[key] = float(np.mean(vals))
    errors = [r["trans_err_mean_m"] for r in ok if "trans_err_mean_m" in r]
    if errors:
        stats = mean_ci(errors)  # over seeds: one run per point cannot tell a trend from seed noise
        out.update(trans_err_seeds_m=errors, trans_err_seed_std_m=stats["std"],
                   trans_err_ci_m=[stats["ci_low"], stats["ci_high"]])
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", default="intel")
    ap.add_argument("--particles", type=int, nargs="+", default=[10, 30, 50, 100, 300, 1000])
    ap.add_argument("--algorithms", nargs="+", default=list(ALGORITHMS))
    ap.add_argument("--seeds", type=int, default=10, help="seeds 0..N-1 per point")
    ap.add_argument("--noise-scales", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0])
    ap.add_argument("--noise-particles", type=int, default=30)
    ap.add_argument("--skip-noise", action="store_true")
    ap.add_argument("--name", default=None,
                    help="results grid_particles_NAME.json and figures *_NAME.png (default: the dataset)")
    ap.add_argument("--replot", nargs="+", default=None, metavar="NAME",
                    help="only draw the figures (named after --name) from grid_particles_NAME.json files, "
                         "their sweeps merged (e.g. two algorithms run separately)")
    args = ap.parse_args()
    name = args.name or args.dataset
    if args.replot:
        import json

        sweep, noise, reference = {}, {}, {}
        for other in args.replot:
            payload = json.loads((RESULTS / f"grid_particles_{other}.json").read_text())
            sweep.update(payload["sweep"])
            noise.update(payload.get("noise_sweep") or {})
            reference = payload.get("gmapping_cpp_reference_s") or reference
        plot(sweep, noise, reference, args.dataset, name, args.noise_particles)
        return

    # Built before any run, so that a problem here cannot throw away a long sweep.
    noise_params = {} if args.skip_noise else {
        (a, scale): noise_overrides(a, scale) for a in args.algorithms for scale in args.noise_scales}
    reference = GMAPPING_CPP_INTEL_S if args.dataset == "intel" else {}

    def save(sweep, noise):
        payload = {"dataset": args.dataset, "particles": args.particles, "seeds": args.seeds, "sweep": sweep,
                   "noise_sweep": noise, "noise_particles": args.noise_particles,
                   "gmapping_cpp_reference_s": reference, "gmapping_cpp_peak_mb": GMAPPING_CPP_PEAK_MB,
                   "machine": machine_info()}
        for algorithm, rows in sweep.items():
            speedups = {}
            for n, t in reference.items():
                s = rows.get(str(n), {}).get("summary", {})
                if s.get("n_ok"):
                    speedups[str(n)] = t / s["wall_mean_s"]
            payload.setdefault("speedup_vs_gmapping_cpp", {})[algorithm] = speedups
        save_json(RESULTS / f"grid_particles_{name}.json", payload)

    sweep = {}
    for algorithm in args.algorithms:
        sweep[algorithm] = {}
        for n in args.particles:
            records = []
            for seed in range(args.seeds):
                rec = run_in_subprocess({"dataset": args.dataset, "algorithm": algorithm, "particles": n,
                                         "seed": seed})
                print(algorithm, n, seed, {k: rec.get(k) for k in ("wall_s", "peak_rss_mb", "trans_err_mean_m",
                                                                  "rot_err_mean_deg", "error")}, flush=True)
                records.append(rec)
            sweep[algorithm][str(n)] = {"summary": summarise(records), "runs": records}
            save(sweep, {})  # after every point: a long sweep stopped early keeps what it ran

    noise = {}
    if not args.skip_noise:
        for algorithm in args.algorithms:
            noise[algorithm] = {}
            for scale in args.noise_scales:
                rec = run_in_subprocess({"dataset": args.dataset, "algorithm": algorithm,
                                         "particles": args.noise_particles, "seed": 0,
                                         "params": noise_params[algorithm, scale]})
                print("noise", algorithm, scale, {k: rec.get(k) for k in ("wall_s", "trans_err_mean_m", "error")},
                      flush=True)
                noise[algorithm][str(scale)] = {"summary": summarise([rec]), "runs": [rec]}

    if noise:
        save(sweep, noise)

    plot(sweep, noise, reference, args.dataset, name, args.noise_particles)
    print("wrote", RESULTS / f"grid_particles_{name}.json")


def plot(sweep: dict, noise: dict, reference: dict, dataset: str, name: str, noise_particles: int) -> None:
    """The figures of a sweep: time and relations error against particles (every seed
    and the 95% interval), and time against the noise scale."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def plot_vs_particles(key, ylabel, fname, log=True):
        fig, ax = plt.subplots(figsize=(6, 4))
        for algorithm, rows in sweep.items():
            xs = sorted(int(n) for n in rows if rows[n]["summary"].get("n_ok") and key in rows[n]["summary"])
            ys = [rows[str(n)]["summary"][key] for n in xs]
            ax.plot(xs, ys, "o-", color=COLORS.get(algorithm), label=algorithm)
            if key == "trans_err_mean_m":  # the spread over seeds: 95% interval and every seed
                for x in xs:
                    s = rows[str(x)]["summary"]
                    lo, hi = s.get("trans_err_ci_m", [np.nan, np.nan])
                    if np.isfinite(lo):
                        ax.plot([x, x], [lo, hi], "-", color=COLORS.get(algorithm), lw=3, alpha=0.5)
                    ax.plot([x] * len(s["trans_err_seeds_m"]), s["trans_err_seeds_m"], ".",
                            color=COLORS.get(algorithm), alpha=0.4)
        if key == "wall_mean_s" and reference:
            counts = sorted(reference, key=int)  # JSON keys are strings
            ax.plot([int(n) for n in counts], [reference[n] for n in counts], "s--", color="tab:red",
                    label="GMapping C++ (reference, README machine)")
        ax.set_xscale("log")
        if log:
            ax.set_yscale("log")
        ax.set_xlabel("particles")
        ax.set_ylabel(ylabel)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        ax.set_title(dataset)
        fig.tight_layout()
        fig.savefig(RESULTS / fname, dpi=120)

    plot_vs_particles("wall_mean_s", "run time (s)", f"grid_time_vs_particles_{name}.png")
    plot_vs_particles("trans_err_mean_m", "relations error, translation (m)",
                      f"grid_error_vs_particles_{name}.png", log=False)
    if noise:
        fig, ax = plt.subplots(figsize=(6, 4))
        for algorithm, rows in noise.items():
            xs = [float(s) for s in rows if rows[s]["summary"].get("n_ok")]
            ys = [rows[str(s)]["summary"]["wall_mean_s"] for s in rows if rows[s]["summary"].get("n_ok")]
            ax.plot(xs, ys, "o-", color=COLORS.get(algorithm), label=algorithm)
        ax.set_xlabel("added noise (x default)")
        ax.set_ylabel(f"run time (s), {noise_particles} particles")
        ax.set_xscale("log")
        ax.grid(True, alpha=0.3)
        ax.legend()
        fig.tight_layout()
        fig.savefig(RESULTS / f"grid_time_vs_noise_{name}.png", dpi=120)


if __name__ == "__main__":
    main()
