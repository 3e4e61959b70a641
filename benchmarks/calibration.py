"""Noise calibration by differentiating the landmark filter (issue #16).

Parts (``--part``, repeatable; default all):

* ``sim``: simulator recovery. The simulator's true noise levels, then starting from
  all four noise levels 3x too large and 3x too small, ``calibrate`` on the first
  ``--sim-window`` scans; reports the recovered / true ratios.
* ``time``: the time of one value-and-gradient evaluation of ``log Z`` on the first
  ``--time-scans`` Victoria Park scans with ``--time-particles`` particles (1 filter),
  compilation apart.
* ``vp``: Victoria Park: calibrate on the first half (the first ``--vp-window`` scans
  of it), then run the whole log with the paper's noise and with the calibrated noise
  (``--vp-particles`` particles, ``--vp-seeds`` seeds, one ensemble each) and compare
  the second half's log-likelihood estimate (under both weights, the mixture
  likelihood that calibration maximises and the paper's gated weights) and GPS error
  (the paper's filter, gated weights, with either set of noise levels). The
  calibrated levels are the best iterate (largest objective); the last iterate is
  evaluated too when it differs. ``--vp-from JSON`` re-evaluates a calibration stored
  by an earlier run instead of running it again.

``--likelihood`` picks the objective (``mixture``, the default of
:func:`jaxslam.calibrate.calibrate`, or the paper's ``gated`` weights).

Writes ``benchmarks/results/calibration.json`` and ``calibration_*.png``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from _common import RESULTS, machine_info, print_table, write_json  # noqa: E402

from jaxslam.calibrate import landmark as L  # noqa: E402
from jaxslam.calibrate.fit import calibrate, value_and_grads  # noqa: E402
from jaxslam.feature.experiment import params_for  # noqa: E402
from jaxslam.feature.params import Config  # noqa: E402

NAMES = L.NOISE_NAMES


def progress(label: str):
    """Adam-step progress line (calibrate's callback)."""
    start = time.perf_counter()

    def show(step, log_likelihood, values):
        levels = ", ".join(f"{n} {v:.4g}" for n, v in zip(NAMES, values))
        print(f"  {label} step {step + 1}: log Z/scan {log_likelihood:.4f}; {levels} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)

    return show


def part_sim(args) -> dict:
    from jaxslam.datasets.landmark_sim import simulate

    seq = simulate(seed=args.seed, num_steps=args.sim_window)
    true = params_for(seq)
    truth = {n: float(getattr(true, n)) for n in NAMES}
    runs = []
    for factor in (3.0, 1.0 / 3.0):
        start = {n: v * factor for n, v in truth.items()}
        res = calibrate(seq, "erb-upf", particles=args.sim_particles, filters=args.filters, steps=args.sim_steps,
                        learning_rate=args.learning_rate, params=start, seed=args.seed,
                        config=dict(capacity=96, local_size=48), likelihood=args.likelihood,
                        callback=progress(f"sim x{factor:.3g}"))
        ratios = {n: res.after[n] / truth[n] for n in NAMES}
        runs.append({"start_factor": factor, "after": res.after, "ratio_to_true": ratios,
                     "within_20pct": {n: abs(r - 1) <= 0.2 for n, r in ratios.items()},
                     "log_likelihood": res.log_likelihood, "parameter_trajectory": res.trajectory,
                     "gradient_variance": res.gradient_variance, "compile_s": res.compile_s, "time_s": res.wall_s})
        print(f"start x{factor:.3g}: " + ", ".join(f"{n} {ratios[n]:.3f}" for n in NAMES), flush=True)
    return {"truth": truth, "likelihood": args.likelihood, "window": args.sim_window, "particles": args.sim_particles, "filters": args.filters,
            "steps": args.sim_steps, "learning_rate": args.learning_rate, "runs": runs}


def part_time(args) -> dict:
    from jaxslam.datasets import victoria_park

    seq = victoria_park.load_sequence(max_steps=args.time_scans)
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params_for(seq))
    cfg = Config(num_particles=args.time_particles, likelihood=args.likelihood)
    program = value_and_grads(cfg)
    keys = jax.random.split(jax.random.PRNGKey(0), 1)
    theta = jnp.asarray(L.log_noise_of(params), jnp.float32)
    data = (jnp.asarray(seq.controls, jnp.float32), jnp.asarray(seq.observations, jnp.float32),
            jnp.asarray(seq.obs_mask), jnp.zeros(3, jnp.float32))
    t0 = time.perf_counter()
    compiled = program.lower(keys, theta, params, *data).compile()
    compile_s = time.perf_counter() - t0
    times = []
    for i in range(args.time_repeats):
        t0 = time.perf_counter()
        values, grads = jax.block_until_ready(compiled(jax.random.split(jax.random.PRNGKey(i), 1), theta, params,
                                                       *data))
        times.append(time.perf_counter() - t0)
    # The forward pass alone, for the ratio.
    fwd = jax.jit(lambda k, th: jnp.mean(L.log_likelihoods(k, L.with_log_noise(params, th), cfg, *data,
                                                           checkpoint=False)))
    fwd(keys[0], theta).block_until_ready()
    t0 = time.perf_counter()
    fwd(keys[0], theta).block_until_ready()
    forward_s = time.perf_counter() - t0
    print(f"one gradient step, {seq.controls.shape[0]} scans, {args.time_particles} particles: "
          f"{np.median(times):.2f} s (forward {forward_s:.2f} s, compile {compile_s:.1f} s)", flush=True)
    return {"scans": int(seq.controls.shape[0]), "particles": args.time_particles, "gradient_step_s": times,
            "gradient_step_median_s": float(np.median(times)), "forward_s": forward_s, "compile_s": compile_s,
            "log_likelihood_per_scan": float(values[0]), "gradient": np.asarray(grads[0]).tolist()}


def _evaluate(seq, params, args, half) -> dict:
    from jaxslam.feature.ensemble import run_landmark_ensemble
    from jaxslam.metrics.gps import gps_error

    seeds = tuple(range(args.vp_seeds))
    ens = run_landmark_ensemble(seq, "erb-upf", particles=args.vp_particles, seeds=seeds, params=params)
    cfg = ens.config
    p = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params)
    data = (jnp.asarray(seq.controls, jnp.float32), jnp.asarray(seq.observations, jnp.float32),
            jnp.asarray(seq.obs_mask), jnp.zeros(3, jnp.float32))
    keys = jnp.stack([jax.random.PRNGKey(s) for s in seeds])
    incs = {}
    for lik in ("mixture", "gated"):
        c = dataclasses.replace(cfg, likelihood=lik)
        ll_fn = jax.jit(jax.vmap(lambda k, c=c: L.log_likelihoods(k, p, c, *data, checkpoint=False)))
        incs[lik] = np.asarray(ll_fn(keys))
    rows = []
    second = seq.times >= seq.times[half]
    for i, seed in enumerate(seeds):
        err = gps_error(seq.times, ens.trajectory[i], seq.gps_times, seq.gps_xy)
        later = err["used"] & (seq.gps_times >= seq.times[half])
        rows.append({"seed": seed, "heldout_log_likelihood_per_scan": float(incs[args.likelihood][i][second].mean()),
                     "heldout_mixture_log_likelihood_per_scan": float(incs["mixture"][i][second].mean()),
                     "heldout_gated_log_likelihood_per_scan": float(incs["gated"][i][second].mean()),
                     "heldout_gps_mean_m": float(np.nanmean(err["errors_m"][later])),
                     "gps_mean_m": float(err["gps_mean_m"])})

    def mean(key):
        return float(np.mean([r[key] for r in rows]))

    return {"per_seed": rows, "likelihood": args.likelihood,
            "heldout_log_likelihood_per_scan": mean("heldout_log_likelihood_per_scan"),
            "heldout_mixture_log_likelihood_per_scan": mean("heldout_mixture_log_likelihood_per_scan"),
            "heldout_gated_log_likelihood_per_scan": mean("heldout_gated_log_likelihood_per_scan"),
            "heldout_gps_mean_m": mean("heldout_gps_mean_m"),
            "heldout_gps_mean_sd_m": float(np.std([r["heldout_gps_mean_m"] for r in rows], ddof=1))
            if len(rows) > 1 else None}


def part_vp(args) -> dict:
    from jaxslam.datasets import victoria_park

    seq = victoria_park.load_sequence()
    half = seq.controls.shape[0] // 2
    if args.vp_from:
        # Re-evaluate a stored calibration (its parameter trajectory and curve) without
        # running it again.
        try:
            cal = json.loads(Path(args.vp_from).read_text())["vp"]["calibration"]
            curve, path = cal["log_likelihood"], cal["parameter_trajectory"]
        except (OSError, ValueError, KeyError) as error:
            raise SystemExit(f"{args.vp_from}: no Victoria Park calibration in it ({error})") from error
        best = int(np.argmax(curve))  # as calibrate(): curve[i] is the objective at path[i]
        cal = {**cal, "from": str(args.vp_from), "best_step": best,
               "after": dict(zip(NAMES, path[best])), "last": dict(zip(NAMES, path[-1]))}
    else:
        res = calibrate(seq, "erb-upf", particles=args.vp_cal_particles, filters=args.filters, steps=args.vp_steps,
                        learning_rate=args.learning_rate, window=min(args.vp_window, half), seed=args.seed,
                        likelihood=args.likelihood, callback=progress("vp"))
        cal = {"likelihood": args.likelihood, "window": res.window, "particles": args.vp_cal_particles,
               "filters": args.filters, "parameter_trajectory": res.trajectory,
               "steps": args.vp_steps, "before": res.before, "after": res.after, "last": res.last,
               "best_step": res.best_step, "log_likelihood": res.log_likelihood,
               "gradient_variance": res.gradient_variance, "compile_s": res.compile_s, "time_s": res.wall_s}
    print("calibrated (best iterate, step %d):" % cal["best_step"], cal["after"], flush=True)
    out = {"calibration": cal, "half_scan": int(half), "particles": args.vp_particles, "seeds": args.vp_seeds}
    candidates = [("paper", params_for(seq)), ("calibrated", params_for(seq, **cal["after"]))]
    if cal["last"] != cal["after"]:
        candidates.append(("calibrated_last", params_for(seq, **cal["last"])))
    for name, params in candidates:
        out[name] = _evaluate(seq, params, args, half)
        print(name, out[name]["heldout_log_likelihood_per_scan"], out[name]["heldout_gps_mean_m"], flush=True)
    return out


def plot(payload: dict, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxslam.plotting import save

    if "sim" in payload:
        sim = payload["sim"]
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        for run in sim["runs"]:
            axes[0].plot(run["log_likelihood"], label=f"start x{run['start_factor']:.3g}")
            path = np.asarray(run["parameter_trajectory"])
            for i, n in enumerate(NAMES):
                axes[1].plot(path[:, i] / sim["truth"][n], color=f"C{i}",
                             ls="-" if run["start_factor"] > 1 else "--", label=n if run["start_factor"] > 1 else None)
        axes[0].set_xlabel("Adam step")
        axes[0].set_ylabel("log Z-hat / scan")
        axes[0].legend()
        axes[1].axhspan(0.8, 1.2, color="0.9")
        axes[1].set_yscale("log")
        axes[1].set_xlabel("Adam step")
        axes[1].set_ylabel("value / true value")
        axes[1].legend(fontsize=8)
        axes[1].set_title("simulator recovery (solid: from 3x, dashed: from 1/3x)")
        fig.tight_layout()
        save(fig, RESULTS / f"{name}_sim.png")
    if "vp" in payload:
        cal = payload["vp"]["calibration"]
        fig, axes = plt.subplots(1, 2, figsize=(11, 4))
        axes[0].plot(cal["log_likelihood"])
        axes[0].set_xlabel("Adam step")
        axes[0].set_ylabel(f"log Z-hat / scan ({cal.get('likelihood', 'gated')} likelihood)")
        axes[0].set_title(f"Victoria Park, first {cal['window']} scans")
        if "best_step" in cal:
            axes[0].axvline(cal["best_step"], color="0.6", lw=0.8, label=f"best iterate (step {cal['best_step']})")
            axes[0].legend(fontsize=8)
        if "parameter_trajectory" in cal:
            path = np.asarray(cal["parameter_trajectory"])
            for i, n in enumerate(NAMES):
                axes[1].plot(path[:, i] / cal["before"][n], label=n)
            axes[1].set_yscale("log")
            axes[1].set_xlabel("Adam step")
            axes[1].set_ylabel("value / the paper's value")
            axes[1].legend(fontsize=8)
        fig.tight_layout()
        save(fig, RESULTS / (f"{name}_vp.png" if "sim" in payload else f"{name}.png"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", action="append", choices=["sim", "time", "vp"], default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--filters", type=int, default=4)
    ap.add_argument("--learning-rate", type=float, default=0.1)
    ap.add_argument("--sim-window", type=int, default=60)
    ap.add_argument("--sim-particles", type=int, default=20)
    ap.add_argument("--sim-steps", type=int, default=60)
    ap.add_argument("--time-scans", type=int, default=1000)
    ap.add_argument("--time-particles", type=int, default=100)
    ap.add_argument("--time-repeats", type=int, default=2)
    ap.add_argument("--vp-window", type=int, default=3615)
    ap.add_argument("--vp-cal-particles", type=int, default=20)
    ap.add_argument("--vp-steps", type=int, default=50)
    ap.add_argument("--vp-particles", type=int, default=100)
    ap.add_argument("--vp-seeds", type=int, default=5)
    ap.add_argument("--likelihood", choices=["mixture", "gated"], default="mixture")
    ap.add_argument("--vp-from", default=None, metavar="JSON",
                    help="vp part: evaluate the calibration stored in JSON instead of running it again")
    ap.add_argument("--name", default="calibration")
    args = ap.parse_args()
    parts = args.part or ["sim", "time", "vp"]
    payload = {"machine": machine_info(), "args": vars(args)}
    for part in parts:
        payload[part] = {"sim": part_sim, "time": part_time, "vp": part_vp}[part](args)
        write_json(args.name, payload)
    if "sim" in payload:
        rows = [{"start": f"x{r['start_factor']:.3g}", **{n: round(r["ratio_to_true"][n], 3) for n in NAMES}}
                for r in payload["sim"]["runs"]]
        print_table(rows, ["start"] + list(NAMES))
    plot(payload, args.name)


if __name__ == "__main__":
    main()
