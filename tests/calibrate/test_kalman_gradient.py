"""The stop-gradient particle filter's gradient against the exact Kalman gradient.

Linear-Gaussian state-space model (float64):
``x_0 ~ N(0, 1)``, ``x_t = a x_{t-1} + q e_t``, ``y_t = x_t + r d_t``. The Kalman filter
gives ``log p(y_{1:T})`` exactly and ``jax.grad`` its gradient with respect to
``(log q, log r)``. A bootstrap particle filter with reparameterised sampling
(``x = a x_prev + q eps``) and :func:`selective_resample_stop_gradient` gives the
score estimate; its mean over independent filters must match the exact gradient
within its confidence interval (plus the O(1/N) bias of ``log Z-hat``). The bootstrap
proposal needs observations that are not much sharper than the dynamics for that bias
to be small at 256 particles (q = 1, r = 0.3 fails at 128 particles).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.scipy.special import logsumexp

from jaxslam.core.resampling import selective_resample_stop_gradient

A = 0.9
T = 20
PARTICLES = 256
FILTERS = 160


def simulate(key, q, r):
    k0, k1, k2 = jax.random.split(key, 3)
    e = jax.random.normal(k1, (T,), jnp.float64)
    d = jax.random.normal(k2, (T,), jnp.float64)

    def body(x, inputs):
        ei, di = inputs
        x = A * x + q * ei
        return x, x + r * di

    _, y = jax.lax.scan(body, jax.random.normal(k0, (), jnp.float64), (e, d))
    return y


def kalman_log_likelihood(theta, y):
    q2, r2 = jnp.exp(2 * theta[0]), jnp.exp(2 * theta[1])

    def body(carry, yt):
        m, p = carry
        m, p = A * m, A * A * p + q2
        s = p + r2
        ll = -0.5 * (jnp.log(2 * jnp.pi * s) + (yt - m) ** 2 / s)
        k = p / s
        return (m + k * (yt - m), (1 - k) * p), ll

    _, lls = jax.lax.scan(body, (jnp.zeros((), jnp.float64), jnp.ones((), jnp.float64)), y)
    return jnp.sum(lls)


def particle_log_likelihood(theta, key, y, threshold):
    q, r = jnp.exp(theta[0]), jnp.exp(theta[1])
    k0, key = jax.random.split(key)
    x = jax.random.normal(k0, (PARTICLES,), jnp.float64)
    log_w = jnp.full((PARTICLES,), -jnp.log(PARTICLES * 1.0))

    def body(carry, inputs):
        x, log_w = carry
        k, yt = inputs
        k_move, k_resample = jax.random.split(k)
        x = A * x + q * jax.random.normal(k_move, (PARTICLES,), jnp.float64)
        log_w = log_w - 0.5 * (jnp.log(2 * jnp.pi * r * r) + (yt - x) ** 2 / (r * r))
        increment = logsumexp(log_w)
        log_w = log_w - increment
        ancestors, _, log_w = selective_resample_stop_gradient(k_resample, log_w, threshold)
        return (x[ancestors], log_w), increment

    _, increments = jax.lax.scan(body, (x, log_w), (jax.random.split(key, T), y))
    return jnp.sum(increments)


_particle_values_and_grads = jax.jit(
    jax.vmap(jax.value_and_grad(particle_log_likelihood), (None, 0, None, None))
)


@pytest.mark.parametrize("threshold", [1.1, 0.5])
@pytest.mark.parametrize("q,r", [(0.5, 1.0), (0.8, 0.8), (0.3, 0.5)])
def test_particle_gradient_matches_kalman(q, r, threshold):
    y = simulate(jax.random.PRNGKey(7), q, r)
    theta = jnp.log(jnp.array([q, r], jnp.float64))
    exact_value, exact_grad = jax.value_and_grad(kalman_log_likelihood)(theta, y)
    keys = jax.random.split(jax.random.PRNGKey(11), FILTERS)
    values, grads = _particle_values_and_grads(theta, keys, y, threshold)
    grads = np.asarray(grads)
    mean = grads.mean(0)
    stderr = grads.std(0, ddof=1) / np.sqrt(FILTERS)
    # The log-likelihood estimate is close (a sanity check of the filter itself) ...
    assert abs(np.mean(values) - exact_value) < 0.05 * abs(exact_value) + 0.5
    # ... and the gradient matches within 4 standard errors (+ a small bias allowance).
    bias = 0.02 * np.abs(np.asarray(exact_grad)) + 0.05
    assert np.all(np.abs(mean - np.asarray(exact_grad)) < 4 * stderr + bias), (mean, exact_grad, stderr)


def test_without_stop_gradient_the_gradient_is_biased():
    """The same filter with plain resampling (weights reset to a constant) misses the
    score of the resampled weights: its gradient is off by many standard errors, so
    the test above can fail."""
    from jaxslam.core import resampling

    q, r = 0.5, 1.0
    y = simulate(jax.random.PRNGKey(7), q, r)
    theta = jnp.log(jnp.array([q, r], jnp.float64))
    exact_grad = np.asarray(jax.grad(kalman_log_likelihood)(theta, y))
    original = resampling.selective_resample_stop_gradient
    keys = jax.random.split(jax.random.PRNGKey(11), FILTERS)
    try:
        globals()["selective_resample_stop_gradient"] = resampling.selective_resample
        grads = np.asarray(
            jax.jit(jax.vmap(jax.grad(particle_log_likelihood), (None, 0, None, None)))(theta, keys, y, 1.1)
        )
    finally:
        globals()["selective_resample_stop_gradient"] = original
    stderr = grads.std(0, ddof=1) / np.sqrt(FILTERS)
    assert np.any(np.abs(grads.mean(0) - exact_grad) > 6 * stderr + 0.05)
