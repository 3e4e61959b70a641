r"""The filter protocol: a particle filter is a value, ``ParticleFilter(init, step)``.

As blackjax's ``SamplingAlgorithm`` and optax's ``GradientTransformation``, a filter
bundles two pure functions, built by a factory that closes over the static config and
the params (:func:`jaxslam.filters.srupf_gm`, :func:`jaxslam.filters.gmapping`,
:func:`jaxslam.filters.erb_upf`, :func:`jaxslam.filters.rb_upf`, or a filter of your own):

* ``init(*inputs) -> State``: the initial particles. The library's filters start
  deterministically, so their ``init`` takes no key;
* ``step(key, state, control, observation) -> (State, Info)``: one time step for all
  particles. ``Info`` always carries ``ess`` (before resampling), ``resampled``,
  ``ancestors`` ``(N,)`` (the identity when it did not resample) and
  ``log_likelihood_increment``, :math:`\log \hat p(z_t \mid z_{1:t-1}) = \log \sum_m
  \bar w^{[m]}_{t-1} g^{[m]}_t` (:func:`jaxslam.core.resampling.log_likelihood_increment`),
  whose sum over the steps is the filter's :math:`\log \hat Z`.

:func:`run` scans any filter over a sequence; step ``t`` uses
``jaxslam.runtime.driver.step_keys(key, T)[t]``, the keys of every other driver (the
chunked runner of the command line included), so a run through :func:`run` and one
through ``jaxslam run`` draw the same numbers. :func:`run` is not jitted: wrap it,
with the filter built inside the jitted function when its params should be traced
(a sweep over them then compiles once)::

    @jax.jit
    def log_evidence(params):
        _, infos = jaxslam.run(jaxslam.erb_upf(config, params), key, state, controls, observations)
        return infos.log_likelihood_increment.sum()

The parts a filter is made of share one signature each, so that a filter of your own
is a few lines (``examples/own_motion_model.py``):

* a motion model :class:`MotionModel`, ``f(augmented, control) -> pose`` with
  ``augmented = [pose; noise]`` (:func:`jaxslam.models.odometry.augmented_motion`,
  :func:`jaxslam.models.odometry.paper_augmented_motion`), pushed through the
  square-root unscented prediction (:func:`jaxslam.models.odometry.sqrt_unscented_predict`);
* a measurement model :class:`MeasurementModel`, ``log_likelihood(pose, observation)
  -> ()`` for one particle;
* SRUPF's proposal: the best-scoring propagated sigma point (eq. 10 of Zandara &
  Nicholson) and the square-root measurement update (eqs. 11-16,
  :func:`jaxslam.grid.srupf.sqrt_measurement_update`), then a draw around it
  (:func:`sample_pose`);
* a resampler ``jaxslam.core.resampling.Resampler``, ``(key, log_weights) ->
  ancestors``, applied when the ESS is low by :func:`reweight`.

Example, a pose-only filter with its own motion model (a robot that drives forward
``control[0]`` metres and turns ``control[1]`` radians)::

    def motion(augmented, control):
        x, y, theta, n_v, n_w = augmented
        v, w = control[0] + n_v, control[1] + n_w
        return jnp.stack([x + v * jnp.cos(theta), y + v * jnp.sin(theta), theta + w])

and the rest of ``examples/own_motion_model.py``: 30 lines from the motion model to
``jaxslam.run``.
"""

from __future__ import annotations

from typing import Any, NamedTuple, Protocol

import jax
import jax.numpy as jnp
from jax import Array

from jaxslam.core import se2
from jaxslam.core.resampling import effective_sample_size, log_likelihood_increment, selective_resample
from jaxslam.runtime.driver import num_steps, step_keys


class InitFn(Protocol):
    """``init(*inputs) -> State``: the filter's initial particles."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any: ...


class StepFn(Protocol):
    """``step(key, state, control, observation) -> (State, Info)``: one time step."""

    def __call__(self, key: Array, state: Any, control: Any, observation: Any) -> tuple[Any, Any]: ...


class ParticleFilter(NamedTuple):
    """A filter as a value: its ``init`` and its ``step`` (see the module docstring)."""

    init: InitFn
    step: StepFn


class MotionModel(Protocol):
    """``f(augmented, control) -> pose``: the pose after ``control`` with the process
    noise ``augmented[3:]`` added, for one sigma point (``augmented = [pose; noise]``)."""

    def __call__(self, augmented: Array, control: Array) -> Array: ...


class MeasurementModel(Protocol):
    """``log_likelihood(pose, observation) -> ()``: :math:`\\log p(z \\mid x)` for one pose."""

    def __call__(self, pose: Array, observation: Any) -> Array: ...


class Info(NamedTuple):
    """What every filter's ``Info`` carries (the library's filters carry more)."""

    ess: Array  # () effective sample size before resampling
    resampled: Array  # () bool
    ancestors: Array  # (N,) int32, the identity when it did not resample
    log_likelihood_increment: Array  # () log sum_m w_m g_m, weights before the step


def run(filter: ParticleFilter, key: Array, state: Any, controls: Any, observations: Any) -> tuple[Any, Any]:
    """Scan ``filter.step`` over a sequence.

    Args:
        filter: the :class:`ParticleFilter`.
        key: PRNG key of the run; step ``t`` uses
            ``jaxslam.runtime.driver.step_keys(key, T)[t]``.
        state: the state before step 0 (from ``filter.init``).
        controls: controls stacked over the ``T`` steps (a pytree, leading axis ``T``).
        observations: observations stacked over the ``T`` steps.

    Returns:
        ``(final_state, infos)``, every ``Info`` field stacked over the steps.
    """
    keys = step_keys(key, num_steps(observations))

    def body(carry, inputs):
        k, control, observation = inputs
        return filter.step(k, carry, control, observation)

    return jax.lax.scan(body, state, (keys, controls, observations))


def sample_pose(key: Array, mean: Array, sqrt_cov: Array) -> Array:
    """A pose drawn from :math:`\\mathcal N(\\text{mean}, S S^T)`, heading wrapped."""
    pose = mean + sqrt_cov @ jax.random.normal(key, (3,), mean.dtype)
    return pose.at[2].set(se2.wrap_angle(pose[2]))


def reweight(
    key: Array, log_weights: Array, log_likelihoods: Array, threshold: Array | float = 0.5,
    resampler: Any = "systematic",
) -> tuple[Array, Array, Info]:
    """Weights times the likelihoods, then selective resampling
    (:func:`jaxslam.core.resampling.selective_resample`: when ``ESS < threshold N``).

    Args:
        key: PRNG key of the resampling.
        log_weights: ``(N,)`` before the step.
        log_likelihoods: ``(N,)`` each particle's log weight increment.
        threshold: ratio of ``N``.
        resampler: a ``jaxslam.core.resampling.Resampler`` or its name (static).

    Returns:
        ``(ancestors (N,), new_log_weights (N,), info)``; gather the particles by
        ``ancestors``.
    """
    updated = log_weights + log_likelihoods
    ancestors, resampled, new_log_weights = selective_resample(key, updated, threshold, resampler)
    info = Info(
        ess=effective_sample_size(updated),
        resampled=resampled,
        ancestors=ancestors.astype(jnp.int32),
        log_likelihood_increment=log_likelihood_increment(log_weights, log_likelihoods),
    )
    return ancestors, new_log_weights, info


__all__ = [
    "Info", "InitFn", "MeasurementModel", "MotionModel", "ParticleFilter", "StepFn", "reweight", "run",
    "sample_pose",
]
