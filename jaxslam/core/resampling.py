r"""Resampling from log-weights, effective sample size and selective resampling.

All resamplers take ``(key, log_weights)`` with ``log_weights`` of shape ``(N,)``
(unnormalised is fine) and return ancestor indices ``(num,)`` (``num`` defaults to
``N``) in ``[0, N)``:

* multinomial: ``num`` i.i.d. draws from the categorical distribution;
* stratified: one uniform draw in each stratum ``[(i + u_i) / num]``;
* systematic: a single uniform offset, ``(i + u) / num``;
* residual: ``floor(num w_i)`` deterministic copies, the remaining draws multinomial
  on the residual weights (Liu & Chen 1998).

All are unbiased: the expected number of copies of particle ``i`` is ``num w_i``.
Cumulative sums are normalised by their last element and indices clipped, so a
float32 cumulative sum ending below 1 never indexes out of range.

Weight trouble is handled by design: NaN log-weights count as ``-inf``; if every
weight underflows (all ``-inf``) the weights are taken as uniform rather than NaN.
"""

from __future__ import annotations

from typing import Callable

import jax
import jax.numpy as jnp
from jax import Array
from jax.scipy.special import logsumexp

from jaxslam.core.numerics import normalize_log_weights
from jaxslam.core.spec import choose

Resampler = Callable[[Array, Array], Array]


def effective_sample_size(log_weights: Array) -> Array:
    """``1 / sum(w_i^2)`` of the normalised weights, computed in log space."""
    normalized = normalize_log_weights(log_weights)
    return jnp.exp(-logsumexp(2.0 * normalized))


def log_likelihood_increment(log_weights: Array, log_weight_increments: Array) -> Array:
    r"""The filter's estimate of the step's log-likelihood,

    .. math:: \log \hat p(z_t \mid z_{1:t-1}) = \log \sum_m \bar w^{[m]}_{t-1}\, g^{[m]}_t,

    from the log-weights before the step (normalised here: :math:`\bar w`) and each
    particle's log weight increment :math:`\log g^{[m]}_t`. Summed over the steps it is
    :math:`\log \hat Z`, the particle estimate of the log marginal likelihood. NaN
    increments count as ``-inf``; if every increment is ``-inf`` the result is
    ``-inf``, never NaN.
    """
    clean = jnp.where(jnp.isnan(log_weight_increments), -jnp.inf, log_weight_increments)
    return logsumexp(normalize_log_weights(log_weights) + clean)


def _cdf(log_weights: Array) -> Array:
    weights = jnp.exp(normalize_log_weights(log_weights))
    cdf = jnp.cumsum(weights)
    return cdf / cdf[-1]


def _invert_cdf(cdf: Array, positions: Array) -> Array:
    idx = jnp.searchsorted(cdf, positions, side="right")
    return jnp.clip(idx, 0, cdf.shape[0] - 1).astype(jnp.int32)


def _sizes(log_weights: Array, num: int | None) -> tuple[int, jnp.dtype]:
    """The number of draws (``num`` or one per weight) and the float dtype of the positions."""
    return (log_weights.shape[0] if num is None else num), jnp.result_type(log_weights.dtype, float)


def _at_positions(log_weights: Array, num: int | None, positions) -> Array:
    """Indices of the weights' CDF at ``positions(num, dtype) -> (num,)`` in ``[0, 1)``."""
    num, dtype = _sizes(log_weights, num)
    return _invert_cdf(_cdf(log_weights), positions(num, dtype))


def systematic(key: Array, log_weights: Array, num: int | None = None) -> Array:
    """Systematic resampling: one uniform offset for all ``num`` positions."""
    return _at_positions(log_weights, num,
                         lambda n, dtype: (jnp.arange(n, dtype=dtype) + jax.random.uniform(key, (), dtype)) / n)


def systematic_rows(key: Array, cdf: Array, num: Array, start: Array, size: int) -> Array:
    """A block of ``size`` consecutive rows of a systematic draw of ``num`` indices.

    The rows are ``start`` to ``start + size - 1`` (``num`` and ``start`` may be
    traced): positions ``(i + u) / num`` on the weights' running sum ``cdf`` (of any
    scale, e.g. ``jnp.cumsum(jnp.exp(log_weights))``), with the one offset ``u`` of
    :func:`systematic` for the same key. Drawing a sample block by block in this way,
    the caller computes ``cdf`` once; indices past the last weight are
    ``cdf.shape[0]`` (the caller clips them to the weights it holds)."""
    dtype = cdf.dtype
    at = (start + jnp.arange(size) + jax.random.uniform(key, (), dtype)) / jnp.asarray(num, dtype) * cdf[-1]
    return jnp.searchsorted(cdf, at, side="right")


def stratified(key: Array, log_weights: Array, num: int | None = None) -> Array:
    """Stratified resampling: one uniform draw per stratum."""
    return _at_positions(log_weights, num,
                         lambda n, dtype: (jnp.arange(n, dtype=dtype) + jax.random.uniform(key, (n,), dtype)) / n)


def multinomial(key: Array, log_weights: Array, num: int | None = None) -> Array:
    """Multinomial resampling: ``num`` independent categorical draws."""
    return _at_positions(log_weights, num, lambda n, dtype: jax.random.uniform(key, (n,), dtype))


def residual(key: Array, log_weights: Array, num: int | None = None) -> Array:
    """Residual resampling: deterministic ``floor(num w)`` copies, the rest multinomial."""
    num, dtype = _sizes(log_weights, num)
    weights = jnp.exp(normalize_log_weights(log_weights))
    scaled = num * weights
    counts = jnp.floor(scaled).astype(jnp.int32)
    counts_cdf = jnp.cumsum(counts)
    slots = jnp.arange(num)
    deterministic = jnp.searchsorted(counts_cdf, slots, side="right").astype(jnp.int32)
    leftover = jnp.maximum(scaled - counts, 0.0).astype(dtype)
    # If rounding left no residual mass, fall back to the weights themselves.
    leftover_log = jnp.where(jnp.sum(leftover) > 0, jnp.log(leftover), jnp.log(weights))
    extra = multinomial(key, leftover_log, num)
    return jnp.where(slots < counts_cdf[-1], deterministic, extra).astype(jnp.int32)


RESAMPLERS: dict[str, Resampler] = {
    "systematic": systematic,
    "stratified": stratified,
    "multinomial": multinomial,
    "residual": residual,
}


def get_resampler(method: str | Resampler) -> Resampler:
    """A resampler by name (``systematic``, ``stratified``, ``multinomial``, ``residual``),
    or ``method`` itself when it is one."""
    return choose(RESAMPLERS, method, "resampler")


def selective_resample(
    key: Array,
    log_weights: Array,
    threshold: Array | float = 0.5,
    method: str | Resampler = "systematic",
) -> tuple[Array, Array, Array]:
    """Resample only when ``ESS < threshold * N`` (Grisetti et al. 2005).

    Args:
        key: PRNG key.
        log_weights: ``(N,)``.
        threshold: traced ratio of ``N``; 1.0+ always resamples, 0 never.
        method: resampler name or function (static).

    Returns:
        ``(ancestors (N,), resampled (), new_log_weights (N,))``: identity ancestors
        and the normalised weights when no resampling happened, uniform weights when
        it did. Callers holding large per-particle buffers should gather them under
        ``lax.cond(resampled, ...)``.
    """
    n = log_weights.shape[0]
    normalized = normalize_log_weights(log_weights)
    ess = effective_sample_size(normalized)
    resampled = ess < threshold * n
    drawn = get_resampler(method)(key, normalized)
    ancestors = jnp.where(resampled, drawn, jnp.arange(n, dtype=jnp.int32))
    uniform = jnp.full_like(normalized, -jnp.log(jnp.asarray(n, normalized.dtype)))
    new_log_weights = jnp.where(resampled, uniform, normalized)
    return ancestors, resampled, new_log_weights


def stop_gradient_log_weights(log_weights: Array, ancestors: Array) -> Array:
    r"""Log-weights after resampling that carry the score (Scibior & Wood 2021).

    ``-log N + logw[a] - stop_gradient(logw[a])``: the value is exactly the uniform
    ``-log N`` (the forward pass does not change), the gradient is that of the
    resampled particles' own log-weights, so the gradient of the log-likelihood
    estimate is the Fisher-identity score estimate. A non-finite ``logw[a]``
    (a particle that should not be drawn) contributes no gradient rather than NaN.

    Args:
        log_weights: ``(N,)`` normalised log-weights before resampling.
        ancestors: ``(N,)`` indices drawn from them.
    """
    n = log_weights.shape[0]
    chosen = log_weights[ancestors]
    safe = jnp.where(jnp.isfinite(chosen), chosen, 0.0)
    return -jnp.log(jnp.asarray(n, log_weights.dtype)) + (safe - jax.lax.stop_gradient(safe))


def selective_resample_stop_gradient(key: Array, log_weights: Array, *args, **kwargs) -> tuple[Array, Array, Array]:
    """:func:`selective_resample` with stop-gradient resampling (Scibior & Wood 2021);
    the same arguments (``threshold``, ``method`` after ``log_weights``).

    The same ancestors, flag and forward values as :func:`selective_resample` (bit for
    bit); where it resampled, the new log-weights are
    :func:`stop_gradient_log_weights`, so that gradients of the log marginal
    likelihood estimate flow through resampling. The index draw itself carries no
    gradient (it is discrete).
    """
    ancestors, resampled, new_log_weights = selective_resample(key, log_weights, *args, **kwargs)
    carried = stop_gradient_log_weights(normalize_log_weights(log_weights), ancestors)
    return ancestors, resampled, jnp.where(resampled, carried, new_log_weights)
