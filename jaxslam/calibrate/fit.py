r"""Fit the landmark filters' noise levels by gradient ascent on the log marginal
likelihood estimate (:mod:`jaxslam.calibrate.landmark`).

Each Adam step (optax) runs ``len(seeds)`` filters on the window with fresh keys
(``vmap`` over keys), averages their gradients of ``log Z / T`` with respect to the
log noise levels, and records the mean objective and the variance of the per-filter
gradients. The value/gradient program is compiled once per static configuration.

The objective is the filter's estimate of :math:`\log Z` under the detection/clutter
mixture likelihood by default (``likelihood="mixture"``, ``Config.likelihood``; see
:mod:`jaxslam.feature.particle`), not under the paper's gated weights: with the gated
weights the innovations that leave the (Mahalanobis) gate stop counting, so the
gradient pulls the measurement noise down (simulator, all four levels fitted from 3x
and 1/3x off, 20 particles: range and bearing end at 0.83-0.95 of the truth under
the gated weights, 0.96-1.04 under the mixture). The calibrated levels are meant for
either weight: ``jaxslam run --params`` runs the paper's filter with them.
"""

from __future__ import annotations

import dataclasses
import time
from typing import Any, Sequence

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxslam.calibrate.landmark import NOISE_NAMES, log_likelihoods, log_noise_of, with_log_noise
from jaxslam.feature.experiment import ALGORITHMS, params_for
from jaxslam.feature.params import Config, Params


@dataclasses.dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    Attributes:
        names: the calibrated parameters.
        before, after: their values before and after: ``after`` is the best iterate,
            the parameters of the step with the largest mean objective (``best_step``;
            the start itself if no step improved on it), not the last one. The
            objective has cliffs the gradient cannot see: noise levels small enough
            for the filters to lose track (a discrete change of association) make
            ``log Z`` collapse, and Adam can step over that edge (Victoria Park's
            first half: +14.1 per scan at step 11, -3.1 at step 13, never above 0
            again).
        last: the parameters after the last Adam step.
        best_step: the index (into ``log_likelihood``) of ``after``.
        log_likelihood: per Adam step, the mean over filters of ``log Z / T`` at the
            parameters of that step (before its update).
        gradient_variance: per step, the variance over filters of each gradient
            component, ``(steps, len(names))``.
        trajectory: per step, the parameter values, ``(steps + 1, len(names))``.
        compile_s, wall_s: compilation time and the time of all steps [s].
        config: the static configuration; ``params``: the full parameters after.
    """

    names: tuple[str, ...]
    before: dict[str, float]
    after: dict[str, float]
    last: dict[str, float]
    best_step: int
    log_likelihood: list[float]
    gradient_variance: list[list[float]]
    trajectory: list[list[float]]
    compile_s: float
    wall_s: float
    config: Config
    params: Params
    window: int
    filters: int

    def to_json(self) -> dict[str, Any]:
        return {
            "names": list(self.names), "params_before": self.before, "params_after": self.after,
            "params_last": self.last, "best_step": self.best_step,
            "log_likelihood": self.log_likelihood, "log_likelihood_unit": "log Z / scans (mean over filters)",
            "gradient_variance": self.gradient_variance, "parameter_trajectory": self.trajectory,
            "compile_s": self.compile_s, "time_s": self.wall_s, "steps": len(self.log_likelihood),
            "window": self.window, "filters_per_step": self.filters,
            "config": dataclasses.asdict(self.config),
        }


_PROGRAMS: dict[Any, Any] = {}


def value_and_grads(config: Config, names: Sequence[str] = NOISE_NAMES):
    """Jitted ``(keys (S,), log_noise, params, controls, observations, obs_mask,
    initial_pose) -> (values (S,), grads (S, len(names)))`` of ``log Z / T`` per filter."""
    names = tuple(names)
    if (config, names) not in _PROGRAMS:

        def one(log_noise, key, params, controls, observations, obs_mask, initial_pose):
            inc = log_likelihoods(key, with_log_noise(params, log_noise, names), config, controls, observations,
                                  obs_mask, initial_pose)
            return jnp.mean(inc)

        batched = jax.vmap(jax.value_and_grad(one), (None, 0, None, None, None, None, None))
        _PROGRAMS[(config, names)] = jax.jit(lambda keys, th, *rest: batched(th, keys, *rest))
    return _PROGRAMS[(config, names)]


def calibrate(
    sequence: Any,
    algorithm: str = "erb-upf",
    particles: int = 20,
    filters: int = 4,
    steps: int = 100,
    learning_rate: float = 0.05,
    window: int | None = None,
    seed: int = 0,
    params: Params | dict[str, Any] | None = None,
    names: Sequence[str] = NOISE_NAMES,
    config: dict[str, Any] | None = None,
    dtype: Any = jnp.float32,
    callback: Any = None,
    likelihood: str = "mixture",
) -> CalibrationResult:
    r"""Maximise the log marginal likelihood estimate over the log noise levels.

    Args:
        sequence: landmark sequence (Victoria Park or the simulator).
        algorithm: ``erb-upf`` or ``rb-upf``.
        particles: particles per filter.
        filters: filters (fresh seeds) averaged per step.
        steps: Adam steps.
        learning_rate: Adam step size on the log noise levels.
        window: first ``window`` scans used (default all).
        seed: base seed of the filters' keys.
        params: starting parameters (full or overrides on ``params_for``).
        names: the noise levels fitted (default speed, steering, range, bearing).
        config: overrides of :class:`Config` fields.
        dtype: float dtype.
        likelihood: the weight whose :math:`\log Z` is maximised (``Config.likelihood``:
            ``"mixture"``, the default, or the paper's ``"gated"``, biased to small noise).
        callback: ``callback(step, mean_log_likelihood, values)`` after each step.
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {sorted(ALGORITHMS)}, got {algorithm!r}")
    if min(particles, filters, steps) < 1:
        raise ValueError("particles, filters and steps must be >= 1")
    if not isinstance(params, Params):
        params = params_for(sequence, **(params or {}))
    names = tuple(names)
    unknown = [n for n in names if n not in Params._fields]
    if unknown:
        raise ValueError(f"unknown parameter(s) {unknown}")
    total = int(np.shape(sequence.controls)[0])
    window = total if window is None else min(int(window), total)
    if window < 1:
        raise ValueError("window must be >= 1 scan")
    cfg = Config(num_particles=particles, proposal=ALGORITHMS[algorithm], **{"likelihood": likelihood, **(config or {})})
    program = value_and_grads(cfg, names)
    params_arr = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)
    data = (
        jnp.asarray(sequence.controls[:window], dtype),
        jnp.asarray(sequence.observations[:window], dtype),
        jnp.asarray(sequence.obs_mask[:window], bool),
        jnp.zeros(3, dtype),
    )
    theta = jnp.asarray(log_noise_of(params, names), dtype)
    optimiser = optax.adam(learning_rate)
    opt_state = optimiser.init(theta)
    base = jax.random.PRNGKey(seed)
    curve, variances, path = [], [], [np.exp(np.asarray(theta, float)).tolist()]
    start = time.perf_counter()
    keys = jax.random.split(jax.random.fold_in(base, 0), filters)
    compiled = program.lower(keys, theta, params_arr, *data).compile()
    compile_s = time.perf_counter() - start
    start = time.perf_counter()
    for i in range(steps):
        keys = jax.random.split(jax.random.fold_in(base, i), filters)
        values, grads = compiled(keys, theta, params_arr, *data)
        values, grads = np.asarray(values, float), np.asarray(grads, float)
        ok = np.isfinite(values) & np.all(np.isfinite(grads), axis=1)
        if not ok.any():
            raise FloatingPointError(f"step {i}: no filter gave a finite log-likelihood and gradient at {path[-1]}")
        mean_grad = grads[ok].mean(0)
        curve.append(float(values[ok].mean()))
        variances.append(grads[ok].var(0).tolist())
        # Adam minimises: ascend the log-likelihood.
        updates, opt_state = optimiser.update(jnp.asarray(-mean_grad, dtype), opt_state, theta)
        theta = optax.apply_updates(theta, updates)
        path.append(np.exp(np.asarray(theta, float)).tolist())
        if callback is not None:
            callback(i, curve[-1], path[-1])
    wall_s = time.perf_counter() - start
    best = int(np.argmax(curve))
    last = dict(zip(names, path[-1]))
    after = with_log_noise(params, np.log(np.asarray(path[best], float)), names)
    after = jax.tree_util.tree_map(lambda x: np.asarray(x).tolist(), after)
    return CalibrationResult(
        names=names,
        before={n: float(getattr(params, n)) for n in names},
        after={n: float(getattr(after, n)) for n in names},
        last={n: float(v) for n, v in last.items()}, best_step=best,
        log_likelihood=curve, gradient_variance=variances, trajectory=path,
        compile_s=compile_s, wall_s=wall_s, config=cfg, params=after, window=window, filters=filters,
    )
