"""``jaxslam calibrate``: fit the noise levels of a landmark filter (RB/ERB-UPF) or of
SRUPF-GM on a dataset and write ``OUT/calibration.json`` and ``OUT/calibration.png``;
``jaxslam run --params OUT/calibration.json`` runs with the result. GMapping is
refused (its proposal is not the Gaussian prediction that
:mod:`jaxslam.calibrate.grid` differentiates)."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

from jaxslam.datasets.registry import ALGORITHMS, algorithms

ALGORITHM_CHOICES = tuple(ALGORITHMS)
LANDMARK = algorithms("landmark")
GRID = ("srupf-gm",)
# --window when not given: landmark scans, laser scans (a few dozen keyframes of an indoor log).
DEFAULT_WINDOW = {"landmark": 200, "laser": 600}


def add_parser(sub, positive_int, nonneg_int) -> None:
    cal = sub.add_parser(
        "calibrate",
        help="fit a filter's noise levels by gradient ascent on its log-likelihood estimate",
    )
    cal.add_argument("--dataset", default=None,
                     help="landmark dataset name (see `jaxslam datasets`); default: the built-in simulator")
    cal.add_argument("--algorithm", choices=sorted(ALGORITHM_CHOICES), default="erb-upf",
                     help="filter: the landmark filters (erb-upf, rb-upf) or srupf-gm (odometry noise q_* and "
                          "matcher noise match_noise)")
    cal.add_argument("--out", type=Path, required=True, help="output folder (created)")
    cal.add_argument("--particles", type=positive_int, default=20, help="particles per filter")
    cal.add_argument("--filters", type=positive_int, default=4, help="filters (seeds) averaged per Adam step")
    cal.add_argument("--steps", type=positive_int, default=100, help="Adam steps")
    cal.add_argument("--learning-rate", type=float, default=0.05, help="Adam step size on the log noise levels")
    cal.add_argument("--window", type=positive_int, default=None,
                     help="the first WINDOW scans of the log are used (default 200 landmark scans, 600 laser scans)")
    cal.add_argument("--samples", type=positive_int, default=4,
                     help="srupf-gm: draws from each particle's prediction per keyframe")
    cal.add_argument("--seed", type=nonneg_int, default=0, help="base seed (the simulator's world too)")
    cal.add_argument("--likelihood", choices=["mixture", "gated"], default="mixture",
                     help="the weight whose log-likelihood is maximised: the detection/clutter mixture (default) "
                          "or the paper's gated weights (biased towards small measurement noise)")
    cal.add_argument("--decay", type=float, default=1.0,
                     help="final Adam step size as a fraction of --learning-rate (cosine schedule; 1: constant)")
    cal.add_argument("--validation", type=float, default=0.25,
                     help="fraction of the window held out at its end to choose the iterate kept (0: keep the one "
                          "with the best training objective)")
    cal.add_argument("--validate-every", type=positive_int, default=5, help="score every this many Adam iterates")
    cal.add_argument("--validation-filters", type=positive_int, default=8,
                     help="filters per validated iterate (the same keys for all)")
    cal.add_argument("--validation-particles", type=positive_int, default=None,
                     help="particles of the validation filters (default --particles; use the count you will run)")
    cal.add_argument("--guard-likelihood", choices=["gated", "mixture", "none"], default="gated",
                     help="weights of the filter you will run (jaxslam run: gated): an iterate is kept only if "
                          "no validation filter with them does worse than with the start ('none': no guard)")
    cal.add_argument("--float64", action="store_true", help="double precision")
    cal.add_argument("--no-plots", action="store_true", help="skip calibration.png")
    cal.add_argument("--json", action="store_true",
                     help="print the fitted values, objectives and times as JSON in place of the short summary")


def run(args) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    from jaxslam.calibrate.landmark import calibrate
    from jaxslam.app.outputs import write_json
    from jaxslam.app.data import resolve_dataset
    from jaxslam.app.errors import RunError

    if args.algorithm not in LANDMARK + GRID:
        raise RunError(f"calibrate supports the landmark filters ({', '.join(LANDMARK)}) and {', '.join(GRID)}; "
                       f"{args.algorithm!r} has no differentiable proposal to calibrate (see jaxslam.calibrate.grid)")
    info, path, kind = resolve_dataset(args.dataset, args.algorithm)
    wanted = "landmark" if args.algorithm in LANDMARK else "laser"
    if kind != wanted:
        raise RunError(f"{args.algorithm} needs {wanted} data; {args.dataset!r} is {kind} data")
    window = args.window or DEFAULT_WINDOW[kind]
    out = Path(args.out)
    options = dict(particles=args.particles, filters=args.filters, steps=args.steps, learning_rate=args.learning_rate,
                   window=window, seed=args.seed, dtype=jnp.float64 if args.float64 else jnp.float32,
                   decay=args.decay, validation=args.validation, validate_every=args.validate_every,
                   validation_filters=args.validation_filters, validation_particles=args.validation_particles)
    # --float64: JAX's 64-bit mode for this calibration only
    with jax.enable_x64(True) if args.float64 else contextlib.nullcontext():
        if kind == "landmark":
            if info is None:
                raise RunError(f"calibrate needs a landmark dataset name, got {args.dataset!r}")
            if not info.simulated:
                info.paths()
            sequence = info.load(seed=args.seed, max_steps=window)
            out.mkdir(parents=True, exist_ok=True)
            result = calibrate(sequence, args.algorithm, likelihood=args.likelihood,
                               guard_likelihood=None if args.guard_likelihood == "none" else args.guard_likelihood,
                               **options)
        else:
            from jaxslam.calibrate.grid import calibrate_grid
            from jaxslam.app.data import load_log

            log, _ = load_log(info, path, args.seed, None, None)
            out.mkdir(parents=True, exist_ok=True)
            result = calibrate_grid(log, samples=args.samples, **options)
    name = info.name if info is not None else str(path)
    payload = {"dataset": name, "algorithm": args.algorithm, "particles": args.particles, "seed": args.seed,
               **result.to_json()}
    write_json(out / "calibration.json", payload)
    if not args.no_plots:
        plot_curve(payload, out / "calibration.png")
    return summary(payload)


def summary(payload: dict[str, Any]) -> dict[str, Any]:
    """What ``jaxslam calibrate --json`` prints: the fitted values, the objective at the
    start and at the kept iterate (training: ``log Z`` per fitted scan; held out: per
    held-out scan, None without validation), and the times [s]."""
    train = payload["log_likelihood"]
    best = payload["best_step"]
    validation = payload.get("validation")
    held_out = None
    if validation is not None:
        scores = dict(zip(validation["steps"], validation["mean_scores"], strict=True))
        held_out = {"before": scores.get(0), "after": scores.get(validation["selected_step"])}
    return {
        **{k: payload[k] for k in ("dataset", "algorithm", "params_before", "params_after")},
        "kept_step": best, "steps": payload["steps"],
        "objective_unit": payload["log_likelihood_unit"],
        "objective_train": {"before": train[0] if train else None,
                            "after": train[best] if best < len(train) else None},
        "objective_held_out": held_out,
        "compile_s": payload["compile_s"], "time_s": payload["time_s"],
    }


def report(result: dict[str, Any], out: str | Path) -> str:
    """A few lines for the terminal at the end of a calibration: the fitted values,
    the objective before and after, the times and where the files are (the whole
    record is ``out/calibration.json``).

    Args:
        result: what :func:`run` returned.
        out: the output folder.
    """
    out = Path(out)

    def value(v) -> str:
        return "[" + ", ".join(f"{x:.4g}" for x in v) + "]" if isinstance(v, list) else f"{v:.4g}"

    def pair(objective) -> str:
        before, after = objective["before"], objective["after"]
        return " -> ".join("-" if x is None else f"{x:.4f}" for x in (before, after))

    width = max(len(name) for name in result["params_after"])
    rows = [(f"{name:<{width}}", f"{value(result['params_before'][name])} -> {value(after)}")
            for name, after in result["params_after"].items()]
    objective = f"{pair(result['objective_train'])} per fitted scan"
    if result["objective_held_out"] is not None:
        objective += f", {pair(result['objective_held_out'])} per held-out scan"
    rows.append(("objective", f"{objective} (log Z, mean over filters)"))
    kept = " (the start: no iterate did better)" if result["kept_step"] == 0 else ""
    rows.append(("kept", f"Adam iterate {result['kept_step']} of {result['steps']}{kept}"))
    rows.append(("time", f"compilation {result['compile_s']:.1f} s, fit {result['time_s']:.1f} s"))
    present = sorted(p.name for p in out.iterdir() if p.is_file()) if out.is_dir() else []
    rows.append(("files", f"{out}: {', '.join(present)}"))
    rows.append(("use", f"jaxslam run --params {out / 'calibration.json'} ..."))
    label_width = max(len(label) for label, _ in rows)
    head = f"{result['algorithm']} calibrated on {result['dataset']}"
    return "\n".join([head, *(f"  {label:<{label_width}}  {text}" for label, text in rows)])


def plot_curve(payload: dict[str, Any], path: Path, title: str | None = None) -> Path:
    """The objective per Adam step (with the held-out scores of the validated iterates
    on a second axis) and the parameters relative to their start, from a
    ``calibration.json`` payload."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxslam.app.plotting import save

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4))
    ax1.plot(payload["log_likelihood"], label="objective (fitted scans)")
    best, train_best = payload.get("best_step"), payload.get("train_best_step")
    if best is not None:
        ax1.axvline(best, color="0.3", lw=0.8, label=f"kept iterate (step {best})")
    if train_best is not None and train_best != best:
        ax1.axvline(train_best, color="0.6", lw=0.8, ls="--", label=f"best objective (step {train_best})")
    val = payload.get("validation")
    if val:
        twin = ax1.twinx()
        twin.plot(val["steps"], val["mean_scores"], "o-", color="C3", ms=3)
        twin.set_ylabel(f"held-out log Z-hat / scan ({val['particles']} p, {val['filters']} filters)",
                        color="C3", fontsize=8)
        ax1.plot([], [], "o-", color="C3", ms=3, label=f"held out: scans {val['fit_scans']}-{val['scans']}")
    ax1.legend(fontsize=8)
    ax1.set_xlabel("Adam step")
    ax1.set_ylabel("log Z-hat / scan (mean over filters)")
    ax1.set_title(title or f"{payload['algorithm']}, {payload['dataset']}")
    path_values = np.asarray(payload["parameter_trajectory"])
    before = np.concatenate([np.ravel(payload["params_before"][n]) for n in payload["names"]])
    for i, name in enumerate(payload.get("columns") or payload["names"]):
        ax2.plot(path_values[:, i] / before[i], label=name)
    if best is not None:
        ax2.axvline(best, color="0.3", lw=0.8)
    ax2.set_yscale("log")
    ax2.set_xlabel("Adam step")
    ax2.set_ylabel("value / starting value")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def load_params_file(path: str | Path) -> dict[str, float]:
    """The fitted noise levels of a ``calibration.json`` (``params_after``: numbers, or
    lists for a vector parameter such as SRUPF-GM's ``match_noise``), for ``jaxslam
    run --params``; a clear error for a missing or malformed file."""
    from jaxslam.datasets.paths import DataFormatError
    from jaxslam.app.errors import RunError

    path = Path(path)
    if not path.exists():
        raise RunError(f"--params {str(path)!r}: no such file (write one with `jaxslam calibrate --out DIR`)")
    try:
        payload = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataFormatError(path, err.lineno, f"not valid JSON: {err.msg}") from None
    values = payload.get("params_after") if isinstance(payload, dict) else None

    def number(v):
        return isinstance(v, (int, float)) and not isinstance(v, bool)

    def ok(v):
        return number(v) or (isinstance(v, list) and len(v) > 0 and all(number(x) for x in v))

    if not isinstance(values, dict) or not all(ok(v) for v in values.values()):
        raise DataFormatError(path, 1, "expected an object with 'params_after': {name: number or list of numbers}")
    return {str(k): [float(x) for x in v] if isinstance(v, list) else float(v) for k, v in values.items()}
