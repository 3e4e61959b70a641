"""Noise calibration by differentiating the particle filters.

Parts (``--part``, repeatable; default all):

* ``sim``: simulator recovery. The simulator's true noise levels, then starting from
  all four noise levels 3x too large and 3x too small, ``calibrate`` on the first
  ``--sim-window`` scans; reports the recovered / true ratios. ``--sim-from JSON
  --revalidate`` chooses the kept iterates of stored runs again with this run's guard
  (part ``sim_revalidated``).
* ``time``: the time of one value-and-gradient evaluation of ``log Z`` on the first
  ``--time-scans`` Victoria Park scans with ``--time-particles`` particles (1 filter),
  compilation apart.
* ``vp``: Victoria Park: calibrate on the first half (the first ``--vp-window`` scans
  of it), then run the whole log with the paper's noise and with the calibrated noise
  (``--vp-particles`` particles, ``--vp-seeds`` seeds, one ensemble each) and compare
  the second half's log-likelihood estimate (under both weights, the mixture
  likelihood that calibration maximises and the paper's gated weights) and GPS error
  (the paper's filter, gated weights, with either set of noise levels). The
  calibrated levels are the iterate kept on the validation scans; the iterate with
  the best training objective is evaluated too when it differs (and the last with
  ``--vp-eval-last``). ``--vp-from JSON`` re-evaluates a calibration stored by an
  earlier run instead of running it again (its kept iterate chosen again with this
  run's validation options with ``--revalidate``). ``--vp-val-particles`` (default
  ``--vp-particles``): particles of the validation filters.

* ``grid``: SRUPF-GM (:mod:`jaxslam.calibrate.grid`): calibrate the odometry and
  matcher noise on the first ``--grid-window`` scans of ``--grid-dataset`` (Intel),
  then compare the starting and the calibrated levels with ``--grid-eval-particles``
  particles and ``--grid-seeds``: the predictive scan log-likelihood (the objective)
  on scans ``[grid-window, grid-heldout-end)`` and the relations error of whole-log
  runs.

Every calibration keeps the iterate chosen on the held-out end of its window
(``--validation``, ``--validate-every``, ``--validation-filters``,
``--guard-likelihood``: the weights of the filter you will run, by default the gated
weights of ``jaxslam run``, whose validation filters must not do worse than at the
start; see
:mod:`jaxslam.calibrate.fit`). ``--likelihood`` picks the landmark objective
(``mixture``, the default of :func:`jaxslam.calibrate.calibrate`, or the paper's
``gated`` weights).

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
from jaxslam.calibrate.fit import validation_steps  # noqa: E402
from jaxslam.calibrate.landmark import calibrate, value_and_grads  # noqa: E402
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


def _guard(args) -> str | None:
    return None if args.guard_likelihood == "none" else args.guard_likelihood


def _fit_options(args, particles: int) -> dict:
    """calibrate()'s step-size and validation options from the command line."""
    return dict(learning_rate=args.learning_rate, decay=args.decay, validation=args.validation,
                validate_every=args.validate_every, validation_filters=args.validation_filters,
                validation_particles=particles, likelihood=args.likelihood,
                guard_likelihood=_guard(args), validation_margin=args.validation_margin)


def part_sim(args) -> dict:
    from jaxslam.datasets.landmark_sim import simulate

    runs, truths = [], {}
    for seed in args.sim_seeds:
        seq = simulate(seed=seed, num_steps=args.sim_window)
        true = params_for(seq)
        truth = {n: float(getattr(true, n)) for n in NAMES}
        truths[seed] = truth
        for factor in (3.0, 1.0 / 3.0):
            start = {n: v * factor for n, v in truth.items()}
            res = calibrate(seq, "erb-upf", particles=args.sim_particles, filters=args.filters,
                            steps=args.sim_steps, params=start, seed=seed, config=dict(capacity=128, local_size=48),
                            callback=progress(f"sim seed {seed} x{factor:.3g}"),
                            **_fit_options(args, args.sim_val_particles or args.sim_particles))
            ratios = {n: res.after[n] / truth[n] for n in NAMES}
            runs.append({"seed": seed, "start_factor": factor, "after": res.after, "ratio_to_true": ratios,
                         "within_20pct": {n: abs(r - 1) <= 0.2 for n, r in ratios.items()},
                         "best_step": res.best_step, "train_best_step": res.train_best_step,
                         "validation": None if res.validation is None else res.validation.to_json(),
                         "log_likelihood": res.log_likelihood, "parameter_trajectory": res.trajectory,
                         "gradient_variance": res.gradient_variance, "compile_s": res.compile_s,
                         "time_s": res.wall_s})
            print(f"seed {seed} start x{factor:.3g} (step {res.best_step}): "
                  + ", ".join(f"{n} {ratios[n]:.3f}" for n in NAMES), flush=True)
    return {"truth": truths[args.sim_seeds[0]], "truths": truths, "seeds": list(args.sim_seeds),
            "likelihood": args.likelihood, "window": args.sim_window, "particles": args.sim_particles,
            "filters": args.filters, "steps": args.sim_steps, "learning_rate": args.learning_rate,
            "decay": args.decay, "validation": args.validation, "runs": runs}


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


def _revalidate(seq, trajectory, fit: int, window: int, likelihood: str, steps: list[int], filters: int,
                particles: int, seed: int, margin: float, guard_likelihood: str | None,
                config: dict | None = None) -> tuple[int, dict]:
    """Choose the kept iterate of a stored calibration (its parameter ``trajectory``)
    again on its held-out scans ``fit:window``, scored by ``likelihood`` filters and
    guarded by ``guard_likelihood`` filters (None: no guard), with the keys
    ``calibrate(seed=seed)`` used: the same computation as ``calibrate()``'s."""
    from jaxslam.calibrate.fit import validate
    from jaxslam.calibrate.landmark import validation_score
    from jaxslam.feature.experiment import ALGORITHMS

    cfg = Config(num_particles=particles, proposal=ALGORITHMS["erb-upf"], likelihood=likelihood, **(config or {}))
    params = jax.tree_util.tree_map(lambda x: jnp.asarray(x, jnp.float32), params_for(seq))
    data = (jnp.asarray(seq.controls[:window], jnp.float32), jnp.asarray(seq.observations[:window], jnp.float32),
            jnp.asarray(seq.obs_mask[:window], bool), jnp.zeros(3, jnp.float32))
    score = validation_score(cfg, NAMES, params, data, fit, particles, likelihood)
    guard = None if guard_likelihood is None else validation_score(cfg, NAMES, params, data, fit, particles,
                                                                    guard_likelihood)
    start = time.perf_counter()
    scores, guards, chosen = validate(score, trajectory, steps, filters, seed, margin, guard)
    record = {"fit_scans": fit, "scans": window, "filters": filters, "particles": particles,
              "margin": margin, "steps": steps, "scores": scores, "selected": chosen,
              "time_s": time.perf_counter() - start, "likelihood": likelihood, "guard_likelihood": guard_likelihood,
              "guard_scores": guards, "mean_scores": np.asarray(scores).mean(1).tolist(),
              "selected_step": steps[chosen]}
    print("re-validated:", {s: round(m, 3) for s, m in zip(steps, record["mean_scores"])}, "guard",
          None if guards is None else {s: round(min(g), 3) for s, g in zip(steps, guards)}, "kept step",
          steps[chosen], flush=True)
    return steps[chosen], record


def part_sim_revalidate(args) -> dict:
    """``--sim-from JSON --revalidate``: the stored simulator runs' kept iterates chosen
    again with this run's guard (their own held-out scans, filters, particles, keys)."""
    from jaxslam.datasets.landmark_sim import simulate

    try:
        sim = json.loads(Path(args.sim_from).read_text())["sim"]
    except (OSError, ValueError, KeyError) as error:
        raise SystemExit(f"{args.sim_from}: no simulator calibration in it ({error})") from error
    runs = []
    for run in sim["runs"]:
        seed, v = run["seed"], run["validation"]
        seq = simulate(seed=seed, num_steps=sim["window"])
        truth = sim["truths"][str(seed)]
        step, record = _revalidate(seq, run["parameter_trajectory"], v["fit_scans"], v["scans"],
                                   sim.get("likelihood", "mixture"), v["steps"], v["filters"], v["particles"], seed,
                                   v["margin"], _guard(args), config=dict(capacity=128, local_size=48))
        ratios = {n: run["parameter_trajectory"][step][i] / truth[n] for i, n in enumerate(NAMES)}
        runs.append({"seed": seed, "start_factor": run["start_factor"], "stored_best_step": run["best_step"],
                     "best_step": step, "ratio_to_true": ratios, "validation": record})
        print(f"seed {seed} start x{run['start_factor']:.3g}: stored step {run['best_step']}, kept {step}: "
              + ", ".join(f"{n} {ratios[n]:.3f}" for n in NAMES), flush=True)
    return {"from": str(args.sim_from), "guard_likelihood": _guard(args), "runs": runs}


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
        if args.revalidate:
            best, record = _revalidate(
                seq, path, int(cal["fit_window"]), int(cal["window"]), cal.get("likelihood", "mixture"),
                validation_steps(len(path) - 1, args.validate_every), args.validation_filters,
                args.vp_val_particles or args.vp_particles, args.seed, args.validation_margin, _guard(args))
            cal = {**cal, "validation": record, "train_best_step": int(np.argmax(curve)),
                   "train_best": dict(zip(NAMES, path[int(np.argmax(curve))]))}
        else:
            best = int(np.argmax(curve))  # curve[i] is the objective at path[i]
        cal = {**cal, "from": str(args.vp_from), "best_step": best,
               "after": dict(zip(NAMES, path[best])), "last": dict(zip(NAMES, path[-1]))}
    else:
        res = calibrate(seq, "erb-upf", particles=args.vp_cal_particles, filters=args.filters, steps=args.vp_steps,
                        window=min(args.vp_window, half), seed=args.seed, callback=progress("vp"),
                        **_fit_options(args, args.vp_val_particles or args.vp_particles))
        train_best = res.trajectory[res.train_best_step]
        cal = {"likelihood": args.likelihood, "window": res.window, "fit_window": res.fit_window,
               "particles": args.vp_cal_particles, "filters": args.filters, "parameter_trajectory": res.trajectory,
               "steps": args.vp_steps, "decay": args.decay, "before": res.before, "after": res.after,
               "last": res.last, "best_step": res.best_step, "train_best_step": res.train_best_step,
               "train_best": dict(zip(NAMES, train_best)),
               "validation": None if res.validation is None else res.validation.to_json(),
               "log_likelihood": res.log_likelihood,
               "gradient_variance": res.gradient_variance, "compile_s": res.compile_s, "time_s": res.wall_s}
    print("calibrated (best iterate, step %d):" % cal["best_step"], cal["after"], flush=True)
    out = {"calibration": cal, "half_scan": int(half), "particles": args.vp_particles, "seeds": args.vp_seeds}
    candidates = [("paper", params_for(seq)), ("calibrated", params_for(seq, **cal["after"]))]
    if cal.get("train_best", cal["after"]) != cal["after"] and not args.vp_from:
        candidates.append(("calibrated_train_best", params_for(seq, **cal["train_best"])))
    if cal["last"] != cal["after"] and args.vp_eval_last:
        candidates.append(("calibrated_last", params_for(seq, **cal["last"])))
    for step in args.vp_eval_steps:
        candidates.append((f"step_{step}", params_for(seq, **dict(zip(NAMES, cal["parameter_trajectory"][step])))))
    for name, params in candidates:
        out[name] = _evaluate(seq, params, args, half)
        print(name, out[name]["heldout_log_likelihood_per_scan"], out[name]["heldout_gps_mean_m"], flush=True)
    return out


def part_grid(args) -> dict:
    """SRUPF-GM on Intel: calibrate on the first --grid-window scans, then compare the
    starting and the calibrated levels on the scans after the window (predictive scan
    log-likelihood, the objective) and on the whole log (relations error)."""
    import dataclasses as dc

    from jaxslam.calibrate import grid as G
    from jaxslam.datasets.registry import load_dataset_log
    from jaxslam.datasets.registry import lookup
    from jaxslam.grid.experiment import run_grid_slam
    from jaxslam.grid.algorithms import grid_algorithm
    from jaxslam.metrics.relations import load_relations, relations_metric

    log = load_dataset_log(args.grid_dataset)
    res = G.calibrate_grid(log, particles=args.grid_particles, filters=args.filters, steps=args.grid_steps,
                           learning_rate=args.learning_rate, window=args.grid_window, seed=args.seed,
                           decay=args.decay, validation=args.validation, validate_every=args.validate_every,
                           validation_filters=args.validation_filters,
                           validation_particles=args.grid_eval_particles,
                           callback=progress_values("grid"))
    cal = {**res.to_json(), "config": None, "particles": args.grid_particles}
    print("calibrated (kept step %d):" % res.best_step, res.after, flush=True)
    out = {"dataset": args.grid_dataset, "calibration": cal, "particles": args.grid_eval_particles,
           "seeds": args.grid_seeds, "heldout_scans": [res.window, args.grid_heldout_end]}
    relations = load_relations(lookup(args.grid_dataset).relations_path())
    end = min(args.grid_heldout_end, log.num_scans)
    inputs = jax.tree_util.tree_map(jnp.asarray, G.window_inputs(log, end))
    cfg = dc.replace(res.config, num_particles=args.grid_eval_particles)
    _, increments = G.programs(cfg, res.names, 4)
    keys = jnp.stack([jax.random.PRNGKey(s) for s in args.grid_seeds])
    for label, values in (("default", res.before), ("calibrated", res.after)):
        if label == "calibrated" and res.after == res.before:
            out[label] = {**out["default"], "same_as_default": True}
            continue
        prm = grid_algorithm("srupf-gm").make_params(log.angles, log.laser_offset, values=values)
        th = jnp.asarray(G.log_noise_of(prm, res.names), jnp.float32)
        inc = np.asarray(increments(keys, th, prm, inputs))[:, res.window - 1:]
        rows = []
        for i, seed in enumerate(args.grid_seeds):
            run = run_grid_slam(log, "srupf-gm", particles=args.grid_eval_particles, seed=seed, params=values,
                                progress=False)
            metric = relations_metric(relations, run.scan_times, run.trajectory)
            rows.append({"seed": seed, "heldout_log_likelihood_per_scan": float(np.mean(inc[i])),
                         "relations_trans_mean_m": metric["trans_err_mean_m"],
                         "relations_rot_mean_deg": metric["rot_err_mean_deg"], "wall_s": run.wall_s})
            print(label, rows[-1], flush=True)
        out[label] = {"params": values, "per_seed": rows, **{
            k: float(np.mean([r[k] for r in rows]))
            for k in ("heldout_log_likelihood_per_scan", "relations_trans_mean_m", "relations_rot_mean_deg")}}
    return out


def progress_values(label: str):
    """Adam-step progress line for a calibration whose levels may be vectors."""
    start = time.perf_counter()

    def show(step, log_likelihood, values):
        levels = ", ".join(f"{v:.4g}" for v in values)
        print(f"  {label} step {step + 1}: objective {log_likelihood:.5f}; levels {levels} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)

    return show


def plot(payload: dict, name: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxslam.app.plotting import save

    if "sim" in payload:
        sim = payload["sim"]
        seeds = sim.get("seeds", [sim.get("seed", 0)])
        fig, axes = plt.subplots(len(seeds), 2, figsize=(11, 3.6 * len(seeds)), squeeze=False)
        for row, seed in zip(axes, seeds):
            truth = sim.get("truths", {}).get(str(seed)) or sim.get("truths", {}).get(seed) or sim["truth"]
            for run in (r for r in sim["runs"] if r.get("seed", seeds[0]) == seed):
                up = run["start_factor"] > 1
                row[0].plot(run["log_likelihood"], label=f"start x{run['start_factor']:.3g}")
                path = np.asarray(run["parameter_trajectory"])
                for i, n in enumerate(NAMES):
                    row[1].plot(path[:, i] / truth[n], color=f"C{i}", ls="-" if up else "--", label=n if up else None)
                if "best_step" in run:
                    row[1].axvline(run["best_step"], color="0.5", lw=0.8, ls="-" if up else "--")
            row[0].set_xlabel("Adam step")
            row[0].set_ylabel("log Z-hat / scan (fitted scans)")
            row[0].set_ylim(bottom=max(row[0].get_ylim()[0], -10))
            row[0].legend(fontsize=8)
            row[0].set_title(f"simulator seed {seed}, {sim['window']} scans")
            row[1].axhspan(0.8, 1.2, color="0.9")
            row[1].set_yscale("log")
            row[1].set_xlabel("Adam step")
            row[1].set_ylabel("value / true value")
            row[1].legend(fontsize=8)
            row[1].set_title("solid: from 3x, dashed: from 1/3x; vertical: kept iterate", fontsize=9)
        fig.tight_layout()
        save(fig, RESULTS / f"{name}_sim.png")
    if "vp" in payload:
        from jaxslam.app.calibrate import plot_curve

        cal = payload["vp"]["calibration"]
        curve = {"algorithm": "erb-upf", "dataset": "victoria-park", "names": list(NAMES),
                 "params_before": cal["before"], **{k: cal[k] for k in ("log_likelihood", "parameter_trajectory")},
                 **{k: cal.get(k) for k in ("best_step", "train_best_step", "validation")}}
        fit = cal.get("fit_window", cal["window"])
        plot_curve(curve, RESULTS / (f"{name}_vp.png" if "sim" in payload else f"{name}.png"),
                   title=f"Victoria Park: fitted on scans 0-{fit}, {cal.get('likelihood', 'gated')} likelihood")


def plot_grid(payload: dict, name: str) -> None:
    from jaxslam.app.calibrate import plot_curve

    grid = payload["grid"]
    curve = {**grid["calibration"], "algorithm": "srupf-gm", "dataset": grid["dataset"]}
    cal = grid["calibration"]
    plot_curve(curve, RESULTS / f"{name}_grid.png",
               title=f"SRUPF-GM, {grid['dataset']}: fitted on scans 0-{cal['fit_window']}, {cal['particles']} p")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part", action="append", choices=["sim", "time", "vp", "grid"], default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--filters", type=int, default=4)
    ap.add_argument("--learning-rate", type=float, default=0.1)
    ap.add_argument("--decay", type=float, default=1.0, help="final step size / learning rate (cosine)")
    ap.add_argument("--validation", type=float, default=0.25, help="held-out fraction of the window (0: none)")
    ap.add_argument("--validate-every", type=int, default=5)
    ap.add_argument("--validation-filters", type=int, default=8)
    ap.add_argument("--validation-margin", type=float, default=2.0,
                    help="standard errors of the paired difference an iterate must beat the start by")
    ap.add_argument("--guard-likelihood", choices=["gated", "mixture", "none"], default="gated",
                    help="weights of the filter you will run: no validation filter with them may do worse than "
                         "with the start ('none': no guard)")
    ap.add_argument("--sim-seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--sim-window", type=int, default=60)
    ap.add_argument("--sim-particles", type=int, default=20)
    ap.add_argument("--sim-val-particles", type=int, default=None, help="default: --sim-particles")
    ap.add_argument("--sim-steps", type=int, default=60)
    ap.add_argument("--time-scans", type=int, default=1000)
    ap.add_argument("--time-particles", type=int, default=100)
    ap.add_argument("--time-repeats", type=int, default=2)
    ap.add_argument("--vp-window", type=int, default=3615)
    ap.add_argument("--vp-cal-particles", type=int, default=20)
    ap.add_argument("--vp-steps", type=int, default=50)
    ap.add_argument("--vp-particles", type=int, default=100)
    ap.add_argument("--vp-val-particles", type=int, default=None, help="default: --vp-particles")
    ap.add_argument("--vp-eval-last", action="store_true", help="also evaluate the last iterate")
    ap.add_argument("--revalidate", action="store_true",
                    help="with --vp-from / --sim-from: choose the kept iterate again with this run's guard")
    ap.add_argument("--vp-eval-steps", type=int, nargs="*", default=[], help="also evaluate these iterates")
    ap.add_argument("--vp-seeds", type=int, default=5)
    ap.add_argument("--likelihood", choices=["mixture", "gated"], default="mixture")
    ap.add_argument("--grid-dataset", default="intel")
    ap.add_argument("--grid-window", type=int, default=600, help="scans calibrated on (fit and validation)")
    ap.add_argument("--grid-particles", type=int, default=8)
    ap.add_argument("--grid-steps", type=int, default=20)
    ap.add_argument("--grid-eval-particles", type=int, default=30)
    ap.add_argument("--grid-seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--grid-heldout-end", type=int, default=3000,
                    help="held-out predictive likelihood on scans [grid-window, this)")
    ap.add_argument("--sim-from", default=None, metavar="JSON",
                    help="sim part, with --revalidate: choose the stored runs' kept iterates again")
    ap.add_argument("--vp-from", default=None, metavar="JSON",
                    help="vp part: evaluate the calibration stored in JSON instead of running it again")
    ap.add_argument("--name", default="calibration")
    args = ap.parse_args()
    parts = args.part or ["sim", "time", "vp", "grid"]
    payload = {"machine": machine_info(), "args": vars(args)}
    for part in parts:
        if part == "sim" and args.sim_from:
            if not args.revalidate:
                raise SystemExit("--sim-from needs --revalidate (the stored runs are only chosen again)")
            payload["sim_revalidated"] = part_sim_revalidate(args)
        else:
            payload[part] = {"sim": part_sim, "time": part_time, "vp": part_vp, "grid": part_grid}[part](args)
        write_json(args.name, payload)
    if "sim_revalidated" in payload:
        print_table([{"seed": r["seed"], "start": f"x{r['start_factor']:.3g}", "stored step": r["stored_best_step"],
                      "kept step": r["best_step"], **{n: round(r["ratio_to_true"][n], 3) for n in NAMES}}
                     for r in payload["sim_revalidated"]["runs"]],
                    ["seed", "start", "stored step", "kept step"] + list(NAMES))
    if "sim" in payload:
        rows = [{"seed": r.get("seed", 0), "start": f"x{r['start_factor']:.3g}", "kept step": r.get("best_step"),
                 **{n: round(r["ratio_to_true"][n], 3) for n in NAMES}} for r in payload["sim"]["runs"]]
        print_table(rows, ["seed", "start", "kept step"] + list(NAMES))
    plot(payload, args.name)
    if "grid" in payload:
        plot_grid(payload, args.name)


if __name__ == "__main__":
    main()
