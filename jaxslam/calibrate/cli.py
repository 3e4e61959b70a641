"""``jaxslam calibrate``: fit the noise levels of a landmark filter on a dataset and
write ``OUT/calibration.json`` and ``OUT/calibration.png``; ``jaxslam run --params
OUT/calibration.json`` runs with the result."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

from jaxslam.datasets.registry import ALGORITHMS, algorithms

ALGORITHM_CHOICES = tuple(ALGORITHMS)
LANDMARK = algorithms("landmark")


def add_parser(sub, positive_int, nonneg_int) -> None:
    cal = sub.add_parser(
        "calibrate",
        help="fit a landmark filter's noise levels by gradient ascent on its log-likelihood estimate",
    )
    cal.add_argument("--dataset", default=None,
                     help="landmark dataset name (see `jaxslam datasets`); default: the built-in simulator")
    cal.add_argument("--algorithm", choices=sorted(ALGORITHM_CHOICES), default="erb-upf",
                     help="filter; only the landmark filters (erb-upf, rb-upf) can be calibrated so far")
    cal.add_argument("--out", type=Path, required=True, help="output folder (created)")
    cal.add_argument("--particles", type=positive_int, default=20, help="particles per filter")
    cal.add_argument("--filters", type=positive_int, default=4, help="filters (seeds) averaged per Adam step")
    cal.add_argument("--steps", type=positive_int, default=100, help="Adam steps")
    cal.add_argument("--learning-rate", type=float, default=0.05, help="Adam step size on the log noise levels")
    cal.add_argument("--window", type=positive_int, default=200, help="the first WINDOW scans of the log are used")
    cal.add_argument("--seed", type=nonneg_int, default=0, help="base seed (the simulator's world too)")
    cal.add_argument("--likelihood", choices=["mixture", "gated"], default="mixture",
                     help="the weight whose log-likelihood is maximised: the detection/clutter mixture (default) "
                          "or the paper's gated weights (biased towards small measurement noise)")
    cal.add_argument("--float64", action="store_true", help="double precision")
    cal.add_argument("--no-plots", action="store_true", help="skip calibration.png")


def run(args) -> dict[str, Any]:
    import jax
    import jax.numpy as jnp

    from jaxslam.calibrate.fit import calibrate
    from jaxslam.outputs import write_json
    from jaxslam.runs import RunError, resolve_dataset

    if args.algorithm not in LANDMARK:
        raise RunError(f"calibrate supports the landmark filters ({', '.join(LANDMARK)}) only; the grid filter "
                       f"{args.algorithm!r} has no differentiable path yet")
    info, _, kind = resolve_dataset(args.dataset, args.algorithm)
    if kind != "landmark" or info is None:
        raise RunError(f"calibrate supports landmark data only; {args.dataset!r} is {kind} data")
    if not info.simulated:
        info.paths()
    sequence = info.load(seed=args.seed, max_steps=args.window)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # --float64: JAX's 64-bit mode for this calibration only
    with jax.enable_x64(True) if args.float64 else contextlib.nullcontext():
        result = calibrate(
            sequence, args.algorithm, particles=args.particles, filters=args.filters, steps=args.steps,
            learning_rate=args.learning_rate, window=args.window, seed=args.seed,
            dtype=jnp.float64 if args.float64 else jnp.float32, likelihood=args.likelihood,
        )
    payload = {"dataset": info.name, "algorithm": args.algorithm, "particles": args.particles, "seed": args.seed,
               **result.to_json()}
    write_json(out / "calibration.json", payload)
    if not args.no_plots:
        plot_curve(payload, out / "calibration.png")
    return {k: payload[k] for k in ("dataset", "algorithm", "params_before", "params_after", "time_s")}


def plot_curve(payload: dict[str, Any], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from jaxslam.plotting import save

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    ax1.plot(payload["log_likelihood"])
    if "best_step" in payload:
        ax1.axvline(payload["best_step"], color="0.6", ls=":", label="best step (params_after)")
        ax1.legend(fontsize=8)
    ax1.set_xlabel("Adam step")
    ax1.set_ylabel("log Z-hat / scan (mean over filters)")
    ax1.set_title(f"{payload['algorithm']}, {payload['dataset']}")
    path_values = np.asarray(payload["parameter_trajectory"])
    before = np.asarray([payload["params_before"][n] for n in payload["names"]])
    for i, name in enumerate(payload["names"]):
        ax2.plot(path_values[:, i] / before[i], label=name)
    ax2.set_yscale("log")
    ax2.set_xlabel("Adam step")
    ax2.set_ylabel("value / starting value")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    return save(fig, path)


def load_params_file(path: str | Path) -> dict[str, float]:
    """The fitted noise levels of a ``calibration.json`` (``params_after``), for
    ``jaxslam run --params``; a clear error for a missing or malformed file."""
    from jaxslam.datasets.paths import DataFormatError
    from jaxslam.runs import RunError

    path = Path(path)
    if not path.exists():
        raise RunError(f"--params {str(path)!r}: no such file (write one with `jaxslam calibrate --out DIR`)")
    try:
        payload = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DataFormatError(path, err.lineno, f"not valid JSON: {err.msg}") from None
    values = payload.get("params_after") if isinstance(payload, dict) else None
    if not isinstance(values, dict) or not all(isinstance(v, (int, float)) for v in values.values()):
        raise DataFormatError(path, 1, "expected an object with 'params_after': {name: number}")
    return {str(k): float(v) for k, v in values.items()}
