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
"""

from __future__ import annotations

from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.core.resampling import normalize_log_weights, selective_resample_stop_gradient
from jaxslam.runtime.driver import step_keys
from jaxslam.feature import filter as feature_filter
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
