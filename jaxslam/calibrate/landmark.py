r"""Differentiable log marginal likelihood of the landmark filters (RB/ERB-UPF).

The filter's one-step estimate of the likelihood of scan :math:`t` is

.. math:: \hat p(z_t \mid z_{1:t-1}) = \sum_m \bar w^{[m]}_{t-1}\, g^{[m]}_t,

with :math:`\bar w_{t-1}` the normalised weights after the previous step and
:math:`g^{[m]}_t = \mathcal N(\nu; 0, S)` the weight increment (eq. 11 of Kim, Kim &
Chung 2011; only matched observations contribute, new landmarks have no likelihood).
:math:`\log \hat Z = \sum_t \log \hat p(z_t \mid z_{1:t-1})`.

:func:`differentiable_step` is :func:`jaxslam.feature.filter.step` with two
changes that leave every forward value bit-identical (tested):

* stop-gradient resampling (Scibior & Wood 2021,
  :func:`jaxslam.core.resampling.selective_resample_stop_gradient`): after
  resampling the log-weights are :math:`-\log N + \log w[a] - \bot(\log w[a])`, so
  :math:`\nabla \log \hat Z` is the Fisher-identity score estimate;
* it returns :math:`\log \hat p(z_t \mid z_{1:t-1})` instead of ``Info``.

Sampling is already reparameterised in the filter (pose = mean + L eps with
``eps ~ N(0, I)`` drawn from the key), so gradients flow through the proposal's mean
and factor, the prediction's unscented transform, the landmark updates and
initialisations. Discrete choices (data association, the gates, the new-landmark
rule, the resampling indices, skipping stationary scans) carry no gradient.

**Calibration** (:func:`calibrate`: :func:`jaxslam.calibrate.fit.ascend` and
:func:`jaxslam.calibrate.fit.select_iterate` on this objective). The objective is the filter's estimate of
:math:`\log Z` under the detection/clutter mixture likelihood by default
(``likelihood="mixture"``, ``Config.likelihood``; see
:mod:`jaxslam.feature.particle`), not under the paper's gated weights: with the
gated weights the innovations that leave the (Mahalanobis) gate stop counting, so
the gradient pulls the measurement noise down (the gate shrinks with the noise, so
smaller noise leaves out more of the innovations that would count against it;
``docs/calibration.md``). The calibrated levels are meant for
either weight: ``jaxslam run --params`` runs the paper's filter with them.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.calibrate.fit import CalibrationResult, ascend, select_iterate, split_window
from jaxslam.core.resampling import normalize_log_weights, selective_resample_stop_gradient
from jaxslam.runtime.driver import step_keys
from jaxslam.feature import filter as feature_filter
from jaxslam.feature.experiment import ALGORITHMS, params_for
from jaxslam.feature.params import Config, Params
from jaxslam.feature.particle import particle_step

# The noise levels calibrated by default (log-space parameters).
NOISE_NAMES = ("speed_std", "steering_std", "range_std", "bearing_std")


def differentiable_step(
    key: Array, state: feature_filter.State, control: Array, observation: feature_filter.Observation,
    params: Params, config: Config,
) -> tuple[feature_filter.State, Array]:
    """One scan of the filter with stop-gradient resampling.

    Same arguments, same random streams and the same new state (bit for bit) as
    :func:`jaxslam.feature.filter.step`; returns ``(state, log_likelihood_increment)``
    (0 for a skipped stationary scan or a scan in which every particle failed).
    """
    dtype = state.poses.dtype
    params = feature_filter.cast_params(params, dtype)
    control = jnp.asarray(control, dtype)
    observation = feature_filter.Observation(
        jnp.asarray(observation.values, dtype), jnp.asarray(observation.mask, bool)
    )
    control, observation, *_ = feature_filter.clean_inputs(control, observation)
    k_sample, k_resample = jax.random.split(key)
    particle_keys = jax.random.split(k_sample, config.num_particles)

    def active_step(state):
        out = jax.vmap(particle_step, (0, 0, 0, 0, None, None, None, None))(
            particle_keys, state.poses, state.pose_sqrt_covs, state.landmarks, control, observation, params, config
        )
        any_finite = jnp.any(out.finite)
        # Double where: a failed particle's increment is -inf and its cotangent zero.
        increment = jnp.where(out.finite, out.log_weight_increment, 0.0)
        weighted = jnp.where(out.finite, state.log_weights + increment, -jnp.inf)
        log_weights = jnp.where(any_finite, weighted, state.log_weights)
        log_likelihood = jnp.where(any_finite, logsumexp(jnp.where(any_finite, weighted, 0.0)), 0.0)
        log_w = normalize_log_weights(log_weights)
        ancestors, resampled, new_log_w = selective_resample_stop_gradient(
            k_resample, log_w, params.resample_threshold, config.resampler
        )
        cumulative = jnp.where(
            any_finite, state.cumulative_log_likelihood + out.log_weight_increment, state.cumulative_log_likelihood
        )
        moved = feature_filter.State(out.pose, out.pose_sqrt, new_log_w, cumulative, out.landmarks)
        # Gather everything but the weights: the carried weights are already per slot.
        gathered = jax.lax.cond(
            resampled,
            lambda s: jax.tree_util.tree_map(lambda x: x[ancestors], s),
            lambda s: s,
            moved._replace(log_weights=None),
        )
        return gathered._replace(log_weights=new_log_w), log_likelihood.astype(dtype)

    def idle_step(state):
        return state._replace(log_weights=normalize_log_weights(state.log_weights)), jnp.zeros((), dtype)

    if not config.skip_stationary:
        return active_step(state)
    moving = jnp.any((control[:, 2] > 0) & (control[:, 0] != 0))
    return jax.lax.cond(moving, active_step, idle_step, state)


def log_likelihoods(
    key: Array, params: Params, config: Config, controls: Array, observations: Array, obs_mask: Array,
    initial_pose: Array | None = None, checkpoint: bool = True,
) -> Array:
    """``(T,)`` one-step log-likelihood estimates of a whole sequence; the same keys as
    the filter's scan ``jaxslam.feature.filter.run``
    (:func:`jaxslam.runtime.driver.step_keys`). With ``checkpoint`` each step is
    rematerialised in the backward pass (``jax.checkpoint``), so memory does not hold
    every step's intermediates (the scan still stores each step's state)."""
    state = feature_filter.init(key, params, config, initial_pose)
    keys = step_keys(key, np.shape(controls)[0])

    def body(s, xs):
        k, u, z, m = xs
        return differentiable_step(k, s, u, feature_filter.Observation(z, m), params, config)

    if checkpoint:
        body = jax.checkpoint(body)
    dtype = state.poses.dtype
    xs = (keys, jnp.asarray(controls, dtype), jnp.asarray(observations, dtype), jnp.asarray(obs_mask, bool))
    _, increments = jax.lax.scan(body, state, xs)
    return increments


def with_log_noise(params: Params, log_noise: Array, names: Sequence[str] = NOISE_NAMES) -> Params:
    """``params`` with ``names[i] = exp(log_noise[i])``."""
    return params._replace(**{name: jnp.exp(log_noise[i]) for i, name in enumerate(names)})


def log_noise_of(params: Params, names: Sequence[str] = NOISE_NAMES) -> np.ndarray:
    """The log of the named noise levels of ``params``."""
    return np.log(np.array([float(getattr(params, name)) for name in names]))


_PROGRAMS: dict[Any, Any] = {}


def value_and_grads(config: Config, names: Sequence[str] = NOISE_NAMES):
    """Jitted ``(keys (S,), log_noise, params, controls, observations, obs_mask,
    initial_pose) -> (values (S,), grads (S, len(names)))`` of ``log Z / T`` per filter."""
    names = tuple(names)
    if ("grad", config, names) not in _PROGRAMS:

        def one(log_noise, key, params, controls, observations, obs_mask, initial_pose):
            inc = log_likelihoods(key, with_log_noise(params, log_noise, names), config, controls, observations,
                                  obs_mask, initial_pose)
            return jnp.mean(inc)

        batched = jax.vmap(jax.value_and_grad(one), (None, 0, None, None, None, None, None))
        _PROGRAMS[("grad", config, names)] = jax.jit(lambda keys, th, *rest: batched(th, keys, *rest))
    return _PROGRAMS[("grad", config, names)]


def increments_program(config: Config, names: Sequence[str] = NOISE_NAMES):
    """Jitted ``(keys (S,), log_noise, params, controls, observations, obs_mask,
    initial_pose) -> (S, T)`` one-step log-likelihoods (forward only)."""
    names = tuple(names)
    if ("increments", config, names) not in _PROGRAMS:

        def one(key, log_noise, params, controls, observations, obs_mask, initial_pose):
            return log_likelihoods(key, with_log_noise(params, log_noise, names), config, controls, observations,
                                   obs_mask, initial_pose, checkpoint=False)

        _PROGRAMS[("increments", config, names)] = jax.jit(
            jax.vmap(one, (0, None, None, None, None, None, None))
        )
    return _PROGRAMS[("increments", config, names)]


def validation_score(
    config: Config, names: Sequence[str], params: Any, data: tuple, fit_window: int, particles: int,
    likelihood: str, dtype: Any = jnp.float32,
) -> Callable[[jax.Array, Any], np.ndarray]:
    """``score(keys (S,), log_noise) -> (S,)``: the mean one-step log-likelihood of
    scans ``fit_window:`` of ``data`` (controls, observations, obs_mask, initial pose of
    the whole window) under filters of ``particles`` particles weighing by
    ``likelihood``, run from the first scan."""
    if likelihood not in ("gated", "mixture"):
        raise ValueError(f"validation likelihood must be 'gated' or 'mixture', got {likelihood!r}")
    increments = increments_program(dataclasses.replace(config, num_particles=particles, likelihood=likelihood),
                                    names)

    def score(keys, th):
        return np.asarray(increments(keys, jnp.asarray(th).astype(dtype), params, *data))[:, fit_window:].mean(1)

    return score


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
    decay: float = 1.0,
    validation: float = 0.25,
    validate_every: int = 5,
    validation_filters: int = 8,
    validation_particles: int | None = None,
    validation_margin: float = 2.0,
    guard_likelihood: str | None = "gated",
) -> CalibrationResult:
    r"""Maximise the landmark filter's log marginal likelihood estimate over the log
    noise levels and keep the iterate that does best on held-out scans (see the module
    docstring).

    The keywords are ``jaxslam calibrate``'s options one for one; the grid calibration
    (:func:`jaxslam.calibrate.grid.calibrate_grid`) takes the same names with other
    defaults (fewer particles and steps for its costlier filter).

    Args:
        sequence: landmark sequence (Victoria Park or the simulator).
        algorithm: ``erb-upf`` or ``rb-upf``.
        particles: particles per filter in the fit.
        filters: filters (fresh seeds) averaged per step.
        steps: Adam steps.
        learning_rate: Adam step size on the log noise levels.
        window: first ``window`` scans used (default all), fit and validation together.
        seed: base seed of the filters' keys.
        params: starting parameters (full or overrides on ``params_for``).
        names: the noise levels fitted (default speed, steering, range, bearing).
        config: overrides of :class:`~jaxslam.feature.params.Config` fields.
        dtype: float dtype.
        likelihood: the weight whose :math:`\log Z` is maximised (``Config.likelihood``:
            ``"mixture"``, the default, or the paper's ``"gated"``, biased to small noise).
        callback: ``callback(step, mean_log_likelihood, values)`` after each step.
        decay: final step size as a fraction of ``learning_rate`` (cosine; 1: constant).
        validation: the fraction of the window held out at its end (0: no validation,
            keep the iterate with the best training objective).
        validate_every: score every this many iterates (the start and last always).
        validation_filters: filters per candidate (the same keys for all candidates).
        validation_particles: particles of the validation filters (default
            ``particles``; use the count the calibrated filter will run with).
        validation_margin: standard errors a candidate must beat the start by.
        guard_likelihood: the weights of the filter the calibrated levels are for
            (``"gated"``, the paper's, which ``jaxslam run`` uses, or ``"mixture"``):
            an iterate is kept only if none of the validation filters run with them
            does worse on the held-out scans than with the start (None: no guard).
    """
    if algorithm not in ALGORITHMS:
        raise ValueError(f"algorithm must be one of {sorted(ALGORITHMS)}, got {algorithm!r}")
    if min(particles, filters, steps, validation_filters) < 1:
        raise ValueError("particles, filters, steps and validation_filters must be >= 1")
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
    fit_window = split_window(window, validation)
    overrides = {"likelihood": likelihood, **(config or {})}
    cfg = Config(num_particles=particles, proposal=ALGORITHMS[algorithm], **overrides)
    params_arr = jax.tree_util.tree_map(lambda x: jnp.asarray(x, dtype), params)

    def data(scans):
        return (jnp.asarray(sequence.controls[:scans], dtype), jnp.asarray(sequence.observations[:scans], dtype),
                jnp.asarray(sequence.obs_mask[:scans], bool), jnp.zeros(3, dtype))

    fit_data = data(fit_window)
    program = value_and_grads(cfg, names)
    theta = jnp.asarray(log_noise_of(params, names), dtype)
    score, guard, val_particles = None, None, validation_particles or particles
    if fit_window < window:
        val_data = data(window)
        score = validation_score(cfg, names, params_arr, val_data, fit_window, val_particles, likelihood, dtype)
        if guard_likelihood is not None:
            guard = validation_score(cfg, names, params_arr, val_data, fit_window, val_particles, guard_likelihood,
                                     dtype)

    ascent = ascend(program, (params_arr, *fit_data), theta, steps, learning_rate, filters, seed, decay, callback)
    best, train_best, record = select_iterate(ascent, seed, score, (fit_window, window, val_particles), validate_every,
                                              validation_filters, validation_margin, guard)
    if record is not None:
        record = dataclasses.replace(record, likelihood=likelihood, guard_likelihood=guard_likelihood)
    path = ascent.trajectory
    after = with_log_noise(params, np.log(np.asarray(path[best], float)), names)
    after = jax.tree_util.tree_map(lambda x: np.asarray(x).tolist(), after)
    return CalibrationResult(
        names=names,
        before={n: float(getattr(params, n)) for n in names},
        after={n: float(getattr(after, n)) for n in names},
        last=dict(zip(names, map(float, path[-1]))), best_step=best, train_best_step=train_best,
        log_likelihood=ascent.log_likelihood, gradient_variance=ascent.gradient_variance, trajectory=path,
        validation=record, compile_s=ascent.compile_s, wall_s=ascent.wall_s, config=cfg, params=after,
        window=window, fit_window=fit_window, filters=filters,
    )
